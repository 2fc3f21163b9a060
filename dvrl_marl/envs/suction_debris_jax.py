"""The collaborative scene in JaxMARL's form: one world as pure functions of its state, for ``jax.jit`` and
``jax.vmap``.

    env = suction_debris_v8.jax_env(preset="benchmark")
    keys = jax.random.split(jax.random.key(0), 4096)
    observations, states = jax.jit(jax.vmap(env.reset))(keys)
    step = jax.jit(jax.vmap(env.step))
    observations, states, rewards, dones, infos = step(keys, states, actions)   # actions: {agent: (4096, 4)}

``reset(key) -> (observations, state)`` and ``step(key, state, actions) -> (observations, state, rewards, dones,
infos)``, over dicts keyed by ``agents``; ``dones["__all__"]`` says the episode ended (terminated or truncated: which,
``infos["terminated"]`` / ``infos["truncated"]``). A world whose episode ended starts the next one inside the same
step (the observation returned is the new episode's; ``infos["final_observation"]`` the ended one's last, and
``infos["is_success"]`` whether it was completed). ``observation_space(agent)`` and ``action_space(agent)`` are the
parallel env's.

**The step is the one step.** These functions trace the same core as every other form of the scene (the numpy env,
the device env; :mod:`dvrl_marl.envs.suction_debris_device`), one world a batch of one: the tests hold world i of a
vmapped batch equal to world i of the numpy batched env, step by step.

**Keys and seeds.** The scene draws its episodes from counter-based streams kept in the state (a world's 64-bit seed
and its episode count), not from the key: ``reset(key)`` starts the episode the numpy env starts with
``seed=seed_of(key)``, and the following episodes of that world are those of the same seed, wherever they are
played. ``step``'s key is taken for the API's form and not used. The state is an
:class:`~dvrl_marl.suction_debris.scene_state.EnvState` record (the scene's :class:`~dvrl_marl.suction_debris.scene_state.SceneState`, the
start level and, with the guided reward, the potentials; float64: JAX's x64 is switched on for the process), a pytree
that ``jit``, ``vmap`` and ``lax.scan`` carry; ``benchmarks/jax_env_scale.py`` prints its bytes a world and XLA's
figures for a step over many worlds (the results page has them). Some of it is NaN or inf by design (a pin that is
not falling, a cavity that never bleeds); observations and rewards are finite.

Bad input is named at trace time where it can be: an action dict missing an agent or of another width, a state of
another form. A NaN action is not refused inside a compiled step (nothing is read back): the step changes nothing of
that world and says so in ``infos["actions_finite"]``.
"""

from __future__ import annotations

from dvrl_marl.envs.scene_keywords import form_signature
from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv
from dvrl_marl.suction_debris.scene_state import SPECS, EnvState

__all__ = ["SuctionDebrisJaxEnv", "jax_env", "seed_of"]


def seed_of(key):
    """The 64-bit seed a JAX key stands for (traceable): ``reset(key)`` starts the episode the numpy env starts with
    this seed."""
    import jax
    import jax.numpy as jnp

    return jax.random.bits(key, (), jnp.uint64)


class SuctionDebrisJaxEnv:
    """One world of ``suction_debris_v8`` as pure functions (see the module documentation). Takes the parallel env's
    keyword arguments but for the host's (``surgeon``, ``render_mode``, ``image_size``)."""

    def __init__(self, **options):
        from dvrl_marl.envs.suction_debris_device import SuctionDebrisDeviceEnv
        from dvrl_marl.suction_debris.task import TASK

        for option in ("num_envs", "autoreset_mode", "device", "arrays", "check_actions"):
            if option in options:
                raise ValueError(f"{TASK}: jax_env() is one world, stepped where JAX puts it, its ended "
                                 f"episodes restarted in the step; {option}= is the batched env's")
        # the traced functions of the device env, at one world (a vmapped batch of them is N worlds)
        self._one = SuctionDebrisDeviceEnv(1, device="cpu", arrays="jax", check_actions=False,
                                           autoreset_mode="same_step", **options)
        import jax
        import jax.numpy as jnp

        self._jax, self._jnp = jax, jnp
        host = self._one.host
        host.reset(seed=0)
        potential = host.guided_potentials()
        #: a world's state at rest: what reset() draws a new episode into (its stream key replaced by the key's)
        self._template = jax.tree_util.tree_map(lambda value: jnp.asarray(value)[0], EnvState(
            scene=host.core.get_state(), levels=host.levels.copy(), potential=dict(potential)))
        self.name = host.name
        self.agents = list(host.possible_agents)
        self.num_agents = len(self.agents)
        self.action_width = host.action_space(self.agents[0]).shape[0]

    def observation_space(self, agent):
        return self._one.observation_space(agent)

    def action_space(self, agent):
        return self._one.action_space(agent)

    @property
    def state_keys(self) -> tuple:
        """The names of the scene record's fields (:data:`dvrl_marl.suction_debris.scene_state.SPECS`)."""
        return tuple(SPECS)

    # --- the pure functions ---------------------------------------------------------------------------------
    def reset(self, key):
        """``(observations, state)`` of a new episode: the one the numpy env starts with ``seed=seed_of(key)``."""
        jnp = self._jnp
        seed = seed_of(self._check_key(key, "reset"))
        state = self._template.replace(scene=self._template.scene.replace(
            stream_key_low=(seed & jnp.uint64(0xFFFFFFFF)).astype(jnp.int64),
            stream_key_high=(seed >> jnp.uint64(32)).astype(jnp.int64),
            stream_episode=jnp.zeros((), dtype=jnp.int64)))
        batch = self._batch(state)
        restarted, observations, _ = self._one._traced_restart(batch, jnp.ones((1,), dtype=bool))
        return self._world(observations), self._world(restarted)

    def step(self, key, state, actions):
        """``(observations, state, rewards, dones, infos)`` after one step of both arms (see the module docs)."""
        self._check_key(key, "step")
        self._check_state(state)
        jnp = self._jnp
        if not isinstance(actions, dict) or set(actions) != set(self.agents):
            raise ValueError(f"{self.name}: actions must be a dict over the agents {self.agents}, got "
                             f"{sorted(actions) if isinstance(actions, dict) else type(actions).__name__}")
        commands = {}
        for agent in self.agents:
            value = jnp.asarray(actions[agent], dtype=jnp.float64)
            if value.shape != (self.action_width,):
                raise ValueError(f"{self.name}: agent {agent!r}'s action must have shape ({self.action_width},) in "
                                 f"one world (vmap maps the worlds), got {value.shape}")
            commands[agent] = value[None]
        stepped, observations, rewards, terminated, truncated, infos = self._one._traced_step(self._batch(state),
                                                                                               commands)
        done = (terminated | truncated)[0]
        dones = {agent: done for agent in self.agents}
        dones["__all__"] = done
        out_infos = {"terminated": terminated[0], "truncated": truncated[0], "is_success": infos["is_success"][0],
                     "final_observation": self._world(infos["final_observation"]),
                     "actions_finite": infos["actions_finite"]}
        return (self._world(observations), self._world(stepped), self._world(rewards), dones, out_infos)

    # --- one world as a batch of one --------------------------------------------------------------------------
    def _batch(self, state):
        return self._jax.tree_util.tree_map(lambda value: value[None], state)

    def _world(self, tree):
        return self._jax.tree_util.tree_map(lambda value: value[0], tree)

    def _check_key(self, key, where: str):
        jax = self._jax
        dtype = getattr(key, "dtype", None)
        typed = dtype is not None and jax.dtypes.issubdtype(dtype, jax.dtypes.prng_key)
        raw = dtype is not None and str(dtype) == "uint32" and getattr(key, "shape", None) == (2,)
        if not (typed and key.shape == ()) and not raw:
            raise ValueError(f"{self.name}: {where}'s key must be one JAX key (jax.random.key(0), or a raw "
                             f"jax.random.PRNGKey(0)); vmap maps a batch of them; got "
                             f"{getattr(key, 'dtype', type(key).__name__)} {getattr(key, 'shape', '')}")
        return key

    def _check_state(self, state) -> None:
        """The state of one world, as reset() gave it (shapes and dtypes: named at trace time)."""
        self._one.check_state(state, num_worlds=None)


def jax_env(**options) -> SuctionDebrisJaxEnv:
    """The scene in JaxMARL's form (:class:`SuctionDebrisJaxEnv`); the parallel env's keyword arguments but those of
    the host (a seat's filler, rendering, images: refused on a device) and the batch's."""
    return SuctionDebrisJaxEnv(**options)


#: What one world stepped by JAX does not take: the batch's keywords and the host's (a seat, a window, images).
_NOT_ONE_JAX_WORLD = ("num_envs", "autoreset_mode", "render_world", "surgeon", "surgeon_seat", "render_mode", "width",
                      "height", "image_size", "image_depth", "image_segmentation", "image_stereo", "image_appearance",
                      "image_contexts")
jax_env.__signature__ = form_signature(jax_env, SuctionDebrisBatchedEnv.__init__, without=_NOT_ONE_JAX_WORLD)
