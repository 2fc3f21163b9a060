"""The collaborative scene's batched env on an accelerator: the step compiled whole, its state kept on the device.

``batched_env(num_envs=N, device="cuda")`` (or ``"cpu"``) returns this env. The one implementation of the step
(:class:`~dvrl_marl.suction_debris.rules.CollaborativeCore`), the guided reward, the observation features and the
observation scaling, the automatic resets included, are traced by JAX (``pip install "dvrl-marl[jax]"``; a GPU
needs JAX's CUDA build) and compiled into one function per env; the worlds' state never leaves the device. Actions
go in and observations, rewards and flags come out as torch tensors on that device (``arrays="jax"``: JAX arrays),
exchanged through DLPack without a copy, so a torch learner on the same GPU never waits for a host round trip.

The API is the batched env's: ``reset(seed=...)`` and ``step({agent: (N, 4)})`` giving ``(observations, rewards,
terminations, truncations, infos)``, dicts over the agents. What differs:

- worlds reset automatically within the step that ended them (``same_step``); ``infos["is_success"]`` says which
  episodes ended completed (``(N,)``, meaningful where ``terminations | truncations``), ``infos["final_observation"]``
  and ``infos["final_state"]`` the observations and the global state the step ended on (a learner's bootstrap).
  ``autoreset_mode="disabled"``: ``reset(options={"reset_mask": mask})`` restarts the worlds of a mask, on the device
  (the TorchRL adapter's way);
- the arrays are float64 (the core's), observations as the numpy env's;
- a reset of every world runs on the host through the numpy env and moves the state to the device (``seed`` and
  ``level`` are taken); start levels (``start_level=``, ``set_start_level``, a ``level`` reset option) draw easy
  episodes on the device; a seat's filler (``surgeon=``) and rendering are the numpy env's;
- actions are checked for shape on the host and for NaN/inf on the device: a step given NaN or inf changes no
  world (as the numpy env, which refuses them before anything changes) and is refused by a ``ValueError``, at once
  (``check_actions=True``: one boolean read back per step) or at the next ``step`` or ``reset`` (``False``: no wait on
  the device; the refused step's outputs are not the worlds'); ``reset_mask`` is read as the numpy env reads it
  (booleans of shape (N,), or world indices);
- ``step_function`` is the step as a pure function of ``world_state`` and the actions, for a learner that compiles
  its own loop around it (``jax.lax.scan``; :mod:`dvrl_marl.training.jax_mappo`).

The step on JAX is the step on numpy: ``tests/test_device_env.py`` holds them equal step by step (to 1e-9) from the
same state, with the benchmark's setting and with the defaults. JAX's float64 is switched on for the process.
"""

from __future__ import annotations

import copy
import functools

import numpy as np

from dvrl_marl.envs.scene_keywords import form_signature
from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv
from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.scene_state import EnvState, register_with_jax
from dvrl_marl.suction_debris.task import TASK

__all__ = ["SuctionDebrisDeviceEnv", "batched_env", "jax_device"]

#: Options the device env refuses (the numpy env's), with why.
_HOST_ONLY = {"surgeon": "a seat's filler runs on the host", "render_mode": "rendering mirrors one world on the host",
              "image_size": "image observations are drawn by OpenGL on the host"}


def jax_device(device):
    """The JAX device for ``device``: ``"cpu"``, ``"cuda"``/``"gpu"`` (the first GPU), ``"cuda:1"``, a torch device or a
    JAX device."""
    import jax

    if hasattr(device, "platform"):  # a JAX device already
        return device
    text = str(device)
    kind, colon, index = text.partition(":")
    platform = {"cuda": "gpu", "gpu": "gpu", "cpu": "cpu"}.get(kind)
    if platform is None or (colon and not index.isdigit()):
        raise ValueError(f"device must be 'cpu', 'cuda' or 'cuda:<index>', got {device!r}")
    try:
        devices = jax.devices(platform)
    except RuntimeError:
        raise ValueError(f"device {device!r}: JAX sees no {platform.upper()} here (a GPU needs JAX's CUDA build: "
                         f"pip install 'jax[cuda12]'); JAX's devices: {jax.devices()}") from None
    position = int(index) if index else 0
    if not 0 <= position < len(devices):
        raise ValueError(f"device {device!r}: JAX sees {len(devices)} {platform.upper()} device(s)")
    return devices[position]


class SuctionDebrisDeviceEnv:
    """N worlds of the collaborative scene stepped on ``device`` (see the module documentation)."""

    def __init__(self, num_envs: int = 1, *, device="cpu", arrays: str = "torch", check_actions: bool = True,
                 autoreset_mode: str = "same_step", **kwargs):
        try:
            import jax
        except ImportError:
            raise ImportError('the device env needs JAX: pip install "dvrl-marl[jax]"') from None
        for option, why in _HOST_ONLY.items():
            if kwargs.get(option):  # (None, and image_size 0, ask for nothing of the host)
                raise ValueError(f"{TASK}: {option}= is not taken on a device ({why}); use the numpy env")
        if autoreset_mode not in ("same_step", "disabled"):
            raise ValueError(f"{TASK}: autoreset_mode must be 'same_step' or 'disabled', got {autoreset_mode!r}")
        if arrays not in ("torch", "jax"):
            raise ValueError(f"{TASK}: arrays must be 'torch' or 'jax', got {arrays!r}")
        jax.config.update("jax_enable_x64", True)  # the core is float64
        #: the numpy env this one mirrors: options, spaces, layouts and the first reset are its own
        self.host = SuctionDebrisBatchedEnv(num_envs, autoreset_mode="disabled", **kwargs)
        #: the env the traced functions run through (a copy: its arrays are JAX's while a function is traced)
        self._tracing = copy.deepcopy(self.host)
        self._resting = self._tracing.core.get_state()  # (numpy: what the tracing env holds between traces)
        register_with_jax()
        self.name = self.host.name
        self.num_envs = self.host.num_envs
        self.possible_agents = list(self.host.possible_agents)
        self.agents = list(self.possible_agents)
        self.device = jax_device(device)
        self.arrays = arrays
        self.check_actions = bool(check_actions)
        self.autoreset_mode = autoreset_mode
        self._jax = jax
        self._state = None
        self._refused = None  # check_actions=False: the last step's actions_finite, read at the next call
        self._step = jax.jit(self._traced_step, donate_argnums=(0,))
        self._restart = jax.jit(self._traced_restart, donate_argnums=(0,))
        self._global = jax.jit(self._traced_global_state)

    # --- spaces and facts: the numpy env's ----------------------------------------------------------------
    def observation_space(self, agent):
        return self.host.observation_space(agent)

    def action_space(self, agent):
        return self.host.action_space(agent)

    @property
    def state_space(self):
        return self.host.state_space

    #: The numpy env's fixed facts, read through this env (its state-dependent methods are not: the state is here).
    FACTS = ("params", "layout", "state_layout", "observation_layout", "feature_spec", "observation_scaling",
             "workspace_range", "workspace_centre", "phantom", "handoff", "reward_type", "guidance", "metadata",
             "state_observations")

    def __getattr__(self, name):
        if name in type(self).FACTS:
            return getattr(self.host, name)
        if name in ("render", "observations", "set_tip_positions", "restore", "mirror"):
            raise AttributeError(f"{self.name}: {name}() is the numpy env's (batched_env without device=): the "
                                 "worlds' state lives on the device here")
        raise AttributeError(name)

    # --- the traced functions -----------------------------------------------------------------------------
    def _rest(self) -> None:
        """Put the tracing env's state back to numpy (no JAX value outlives the function being traced)."""
        self._tracing.core.set_state(self._resting)

    def _load(self, state: EnvState) -> None:
        self._tracing.core.set_state(state.scene, copy=False)

    def _unload(self, potential, levels) -> EnvState:
        return EnvState(scene=self._tracing.core.get_state(copy=False), levels=levels, potential=potential)

    def _traced_step(self, state, actions):
        xp = self._jax.numpy
        env = self._tracing
        core = env.core
        self.check_state(state)
        self._load(state)
        finite = xp.all(xp.stack([xp.all(xp.isfinite(actions[agent])) for agent in self.possible_agents]))
        commands = {agent: xp.clip(actions[agent], -1.0, 1.0) for agent in self.possible_agents}
        restart = functools.partial(env.start_at_levels, levels=state.levels) if self.autoreset_mode == "same_step" \
            else None
        rewards, terminated, truncated, potential, ended = env.transition(commands, state.potential, restart)
        if ended is None:  # (without autoreset: what the step ended on is the worlds' present)
            ended = {"is_success": core.complete, "final_observation": env.observations(), "final_state": env.state()}
        success, final, final_state = ended["is_success"], ended["final_observation"], ended["final_state"]
        infos = {"is_success": success, "final_observation": final, "final_state": final_state,
                 "actions_finite": finite, "state": env.state()}
        # Actions with NaN or inf touch no world: the state stays as it was (the numpy env refuses them before any
        # state changes; here the refusal is read back after the step, which must then have changed nothing). A cond
        # picks one state's buffers (an elementwise where over every array cost the step 17 % at N = 1,024 on a CPU).
        stepped = self._unload(potential, state.levels)
        kept = self._jax.lax.cond(finite, lambda: stepped, lambda: state)
        out = kept, env.observations(), rewards, terminated, truncated, infos
        self._rest()
        return out

    def _traced_restart(self, state, mask):
        """New episodes in the worlds of ``mask``, on the device."""
        xp = self._jax.numpy
        env = self._tracing
        self.check_state(state)
        self._load(state)
        env.start_at_levels(mask, state.levels)
        potential = {agent: xp.where(mask, value, state.potential[agent])
                     for agent, value in env.guided_potentials().items()}
        out = self._unload(potential, state.levels), env.observations(), env.state()
        self._rest()
        return out

    # --- API ----------------------------------------------------------------------------------------------
    def reset(self, seed=None, options=None):
        """New episodes: every world (on the host, the state then moved to the device), or, with
        ``options={"reset_mask": mask}`` ((N,) booleans of any library) and no seed, the worlds of the mask, on the
        device."""
        options = dict(options or {})
        mask = options.pop("reset_mask", None)
        level = options.pop("level", None)
        if options:
            raise ValueError(f"{self.name}: the device env takes the reset options reset_mask and level only (got "
                             f"{sorted(options)}); use the numpy env for the others")
        if mask is not None and self._state is None:
            raise ValueError(f"{self.name}: the first reset starts every world; reset_mask is for the resets after it")
        self._raise_refused_actions()
        mask = None if mask is None else self._mask_in(mask)  # checked before the level touches anything
        if level is not None:
            self.set_start_level(level, None if mask is None else np.asarray(self._host_array(mask), dtype=bool))
        if mask is not None and seed is None:
            self._state, observations, self._global_state = self._restart(self._state, mask)
            return self._out(observations), {}
        self.host.reset(seed=seed)
        potential = self.host.guided_potentials()
        state = EnvState(scene=self.host.core.get_state(), levels=self.host.levels.copy(),
                         potential={agent: np.asarray(value) for agent, value in potential.items()})
        self._state = self._jax.device_put(state, self.device)
        # (the host's observations and state are the device's: the same state, held equal by the tests)
        observations = self._jax.device_put(self.host.observations(), self.device)
        self._global_state = self._jax.device_put(self.host.state(), self.device)
        return self._out(observations), {}

    def _mask_in(self, mask):
        """``reset_mask`` on the device, read as the numpy env reads it: booleans of shape (N,), or world indices
        (integers in [0, N)); anything else refused by name. A boolean torch or JAX array stays where it is."""
        if type(mask).__module__.startswith(("torch", "jax")) and str(mask.dtype) in ("torch.bool", "bool"):
            if tuple(mask.shape) != (self.num_envs,):
                raise ValueError(f"{self.name}: reset mask must have shape ({self.num_envs},), got {tuple(mask.shape)}")
            return self._in(mask, dtype="bool")
        from dvrl_marl.core.worlds import world_indices

        try:
            host = self._host_array(mask)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{self.name}: reset mask must be booleans of shape ({self.num_envs},) or world indices, "
                             f"got {mask!r}") from error
        chosen = np.zeros(self.num_envs, dtype=bool)
        chosen[world_indices(host, self.num_envs, self.name)] = True
        return self._jax.device_put(chosen, self.device)

    def _raise_refused_actions(self) -> None:
        """``check_actions=False``: a step given NaN or inf, held (its worlds unchanged), is refused at the next call."""
        refused, self._refused = self._refused, None
        if refused is not None and not bool(refused[0]):
            self._refuse(refused[1], "the last step's actions were refused: it changed no world (they are as before "
                                     "it), and its outputs are not the worlds'")

    def _refuse(self, commands: dict, outcome: str) -> None:
        """The numpy env's refusal of these actions (its rules and words, read on the host), and what came of them."""
        from dvrl_marl.core.worlds import check_action_batch

        for agent in self.possible_agents:
            try:
                check_action_batch(self._host_array(commands[agent]), self.num_envs, 4, f"{self.name}: agent {agent!r}")
            except ValueError as error:
                raise ValueError(f"{error}; {outcome}") from None
        raise ValueError(f"{self.name}: actions contain NaN or inf; {outcome}")  # (not reached: one agent's did)

    def set_start_level(self, level, worlds=None) -> None:
        """The start level (:mod:`dvrl_marl.suction_debris.start_levels`) of the next episodes of ``worlds`` (default all; a
        mask or indices), automatic resets included (checked on the host, then sent to the device)."""
        self.host.set_start_level(level, worlds)
        if self._state is not None:
            self._state = self._state.replace(levels=self._jax.device_put(self.host.levels, self.device))

    @staticmethod
    def _host_array(value):
        return value.detach().cpu().numpy() if type(value).__module__.startswith("torch") else np.asarray(value)

    def step(self, actions):
        if self._state is None:
            raise RuntimeError(f"{self.name}: call reset() before step()")
        if not isinstance(actions, dict) or set(actions) != set(self.possible_agents):
            raise ValueError(f"{self.name}: actions must be a dict over the agents {self.possible_agents}, got "
                             f"{sorted(actions) if isinstance(actions, dict) else type(actions).__name__}")
        commands = {}
        for agent in self.possible_agents:
            try:
                value = self._in(actions[agent])
            except (TypeError, ValueError) as error:
                raise ValueError(f"{self.name}: agent {agent!r}: actions are not numeric: {actions[agent]!r}") from error
            if tuple(value.shape) != (self.num_envs, layout.ACTION_WIDTH):
                raise ValueError(f"{self.name}: agent {agent!r}: actions must have shape ({self.num_envs}, "
                                 f"{layout.ACTION_WIDTH}), got "
                                 f"{tuple(value.shape)}")
            commands[agent] = value
        self._raise_refused_actions()
        state, observations, rewards, terminated, truncated, infos = self._step(self._state, commands)
        self._state = state  # (with NaN or inf actions, the state before the step)
        if self.check_actions and not bool(infos["actions_finite"]):
            self._global_state = None
            self._refuse(commands, "no world was changed")
        self._global_state = infos["state"]
        if not self.check_actions:  # read at the next call, when the step is long done: no wait on the device here
            self._refused = (infos["actions_finite"], commands)
        out = self._out
        infos = {"is_success": out(infos["is_success"]), "final_observation": out(infos["final_observation"]),
                 "final_state": out(infos["final_state"])}
        return (out(observations), out(rewards), {agent: out(terminated) for agent in self.agents},
                {agent: out(truncated) for agent in self.agents}, {agent: infos for agent in self.agents})

    # --- the step as a function, for a caller that compiles its own loop around it ----------------------------
    @property
    def step_function(self):
        """The step as a pure function of the worlds' state and the actions, for a learner that compiles it into its
        own loop (``jax.lax.scan``: :mod:`dvrl_marl.training.jax_mappo`): ``step(state, actions) -> (state,
        observations, rewards, terminated, truncated, infos)``, JAX arrays; ``actions`` a dict over the agents of
        ``(N, 4)`` float64 (clipped to the box; NaN is not checked, ``infos["actions_finite"]`` says), ``infos`` with
        ``is_success``, ``final_observation``, ``final_state`` and ``state`` (the global state after the automatic
        resets). Traceable only: call it inside ``jax.jit``."""
        if self.autoreset_mode != "same_step":
            raise ValueError(f"{self.name}: step_function resets ended worlds in the step; make the env with "
                             "autoreset_mode='same_step'")
        return self._traced_step

    @property
    def world_state(self) -> EnvState:
        """The worlds' state on the device (an :class:`~dvrl_marl.suction_debris.scene_state.EnvState` of JAX arrays: the
        scene's record, the start levels and the guided reward's potentials; what :attr:`step_function` takes and
        gives)."""
        if self._state is None:
            raise RuntimeError(f"{self.name}: call reset() before reading world_state")
        return self._state

    @world_state.setter
    def world_state(self, state: EnvState) -> None:
        if self._state is None:
            raise ValueError(f"{self.name}: call reset() before setting world_state")
        self.check_state(state)
        self._state = state
        self._global_state = None  # (computed from the new state when asked)

    def check_state(self, state, num_worlds="env") -> None:
        """``ValueError`` naming what of ``state`` is not an :class:`EnvState` of this env's worlds (the numpy env's
        check: shapes and dtypes only, so it runs at trace time)."""
        self.host.check_state(state, num_worlds)

    def _traced_global_state(self, state):
        self._load(state)
        out = self._tracing.state()
        self._rest()
        return out

    def state(self):
        """(N, state_dim): the global state on the device."""
        if self._state is None:
            raise RuntimeError(f"{self.name}: call reset() before state()")
        if self._global_state is None:
            self._global_state = self._global(self._state)
        return self._out(self._global_state)

    def close(self) -> None:
        self.host.close()

    # --- arrays in and out ----------------------------------------------------------------------------------
    def _in(self, value, dtype: str = "float64"):
        jnp = self._jax.numpy
        if type(value).__module__.startswith("torch"):
            import torch

            value = value.detach()
            wanted = torch.bool if dtype == "bool" else torch.float64
            if value.dtype != wanted:
                value = value.to(wanted)
            if value.device.type == "cpu":
                return self._jax.device_put(value.numpy(), self.device)
            return self._jax.dlpack.from_dlpack(value.contiguous())
        return self._jax.device_put(jnp.asarray(value, dtype=getattr(jnp, dtype)), self.device)

    def _out(self, value):
        if isinstance(value, dict):  # (in the agents' order: JAX hands dicts back sorted)
            order = [key for key in self.possible_agents if key in value] + sorted(set(value) - set(self.agents))
            return {key: self._out(value[key]) for key in order}
        if self.arrays == "jax":
            return value
        import torch

        return torch.from_dlpack(value)



def batched_env(num_envs: int = 1, *, device=None, arrays: str = "torch", check_actions: bool = True, **kwargs):
    """N worlds stepped as arrays; the keyword arguments of ``parallel_env``, plus ``num_envs``, ``autoreset_mode``
    and ``render_world``. ``device`` (``"cpu"``, ``"cuda"``, ``"cuda:1"``): the step compiled by JAX and run there,
    torch tensors in and out, or JAX arrays with ``arrays="jax"``; ``check_actions=False`` leaves a compiled step's
    actions unchecked (:class:`SuctionDebrisDeviceEnv`); None (the default): numpy
    (:class:`~dvrl_marl.envs.suction_debris_batched.SuctionDebrisBatchedEnv`), whose actions are always checked."""
    if device is None:
        if arrays != "torch" or check_actions is not True:
            option = "arrays" if arrays != "torch" else "check_actions"
            raise ValueError(f"{TASK}: {option}= is a device env's (batched_env(device=...)); the numpy env gives "
                             "numpy arrays and checks every action")
        return SuctionDebrisBatchedEnv(num_envs, **kwargs)
    return SuctionDebrisDeviceEnv(num_envs, device=device, arrays=arrays, check_actions=check_actions, **kwargs)


# (written out: the device env's own keywords, then the batched env's, then the preset and the task's parameters)
batched_env.__signature__ = form_signature(batched_env, SuctionDebrisDeviceEnv.__init__,
                                           SuctionDebrisBatchedEnv.__init__)
