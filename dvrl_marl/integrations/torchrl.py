"""TorchRL adapter: the batched collaborative env as a TorchRL ``EnvBase`` with ``batch_size=[N]``.

```python
from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv
env = SuctionDebrisTorchRLEnv(num_envs=1024, surgeon="scripted")   # any batched_env keyword
td = env.rollout(100)                                              # td["agents", "observation"]: (N, T, n, d)
```

Agents are grouped as TorchRL and BenchMARL expect: ``("agents", "observation")`` ``(N, n_agents, obs_dim)``,
``("agents", "action")`` ``(N, n_agents, 4)`` in [-1, 1], ``("agents", "reward")`` ``(N, n_agents, 1)``, with
``state`` ``(N, state_dim)`` beside them for a centralised (MAPPO) critic, and the team's ``done`` /
``terminated`` / ``truncated`` ``(N, 1)``. Agents are in ``env.agent_names`` order. Tensors are float32 (what
TorchRL's modules take); the core computes in float64. Worlds are reset by TorchRL's ``"_reset"`` mask (the
core's autoreset is off), each from its own seed stream. ``is_success`` ``(N, 1)`` says which worlds completed
the task this step. Needs ``pip install torchrl``.

The env's options that help learning pass through like any other keyword: ``reward_type="guided"``,
``observation_features=...``, ``start_level=...``. A curriculum sets the level of the next episodes with
:meth:`SuctionDebrisTorchRLEnv.set_start_level`, or per reset with a ``"level"`` entry ``(N,)`` beside
``"_reset"``. ``group_map`` is ``{"agents": agent_names}`` (BenchMARL's grouping;
:mod:`dvrl_marl.integrations.benchmarl` ships the task).

Where the step runs: ``backend="numpy"`` steps the worlds on the host and hands the tensors to ``device``;
``backend="jax"`` steps them on ``device`` itself (:mod:`dvrl_marl.envs.suction_debris_device`: compiled by JAX, the
state kept there, tensors exchanged without a copy, start levels included). The default is ``"jax"`` for a CUDA device
and ``"numpy"`` for the CPU.
"""

from __future__ import annotations

import numpy as np

try:
    import torch
    from tensordict import TensorDict
    from torchrl.data import Bounded, Categorical, Composite, Unbounded
    from torchrl.envs import EnvBase
except ImportError as error:  # pragma: no cover - exercised where torchrl is missing
    raise ImportError("dvrl_marl.integrations.torchrl needs TorchRL: pip install torchrl") from error

from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv

__all__ = ["SuctionDebrisTorchRLEnv"]

#: The env's image observations under TorchRL's names (the others keep theirs).
_PIXELS = {"image": "pixels", "image_right": "pixels_right"}


class SuctionDebrisTorchRLEnv(EnvBase):
    """suction_debris_v8, N worlds, as a TorchRL environment (see the module documentation)."""

    def __init__(self, num_envs: int = 1, device="cpu", seed: int | None = None, backend: str | None = None,
                 **kwargs):
        if kwargs.get("autoreset_mode", "disabled") != "disabled":
            raise ValueError("SuctionDebrisTorchRLEnv resets worlds through TorchRL's '_reset' mask; "
                             "autoreset_mode cannot be set")
        kwargs["autoreset_mode"] = "disabled"
        try:
            device = torch.device(device)
        except (RuntimeError, TypeError) as error:
            raise ValueError(f"SuctionDebrisTorchRLEnv: device {device!r} is not a torch device ({error})") from None
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"SuctionDebrisTorchRLEnv: device {str(device)!r} needs CUDA, which this torch "
                             f"({torch.__version__}) cannot use here; use device='cpu'")
        backend = backend or ("jax" if device.type == "cuda" else "numpy")
        if backend not in ("numpy", "jax"):
            raise ValueError(f"SuctionDebrisTorchRLEnv: backend must be 'numpy' or 'jax', got {backend!r}")
        #: where the step runs: "numpy" (the host) or "jax" (``device``)
        self.backend = backend
        if backend == "jax":
            from dvrl_marl.envs.suction_debris_device import SuctionDebrisDeviceEnv

            self.batched = SuctionDebrisDeviceEnv(num_envs, device=device, **kwargs)
        else:
            self.batched = SuctionDebrisBatchedEnv(num_envs, **kwargs)
        super().__init__(device=device, batch_size=torch.Size([self.batched.num_envs]))
        self.agent_names = list(self.batched.possible_agents)
        n, agents = self.batched.num_envs, len(self.agent_names)
        space = self.batched.observation_space(self.agent_names[0])
        #: image observations (the env's ``image_size``): the endoscope's view at the root, as TorchRL's ``"pixels"``
        #: (one camera: every agent's), with ``"pixels_right"`` (the stereo pair's right eye), ``"depth"`` and
        #: ``"segmentation"`` when the env draws them
        self.images = bool(getattr(self.batched, "image_size", 0))
        obs_dim = (space["observation"] if self.images else space).shape[0]
        state_dim = self.batched.state_space.shape[0]
        self.observation_spec = Composite(
            agents=Composite(observation=Unbounded(shape=(n, agents, obs_dim), dtype=torch.float32, device=device),
                             shape=(n, agents)),
            state=Unbounded(shape=(n, state_dim), dtype=torch.float32, device=device),
            shape=(n,),
        )
        if self.images:
            size = self.batched.image_size
            self.observation_spec["pixels"] = Bounded(0, 255, shape=(n, size, size, 3), dtype=torch.uint8,
                                                      device=device)
            if self.batched.image_stereo:
                self.observation_spec["pixels_right"] = Bounded(0, 255, shape=(n, size, size, 3), dtype=torch.uint8,
                                                                device=device)
            if self.batched.image_depth:
                self.observation_spec["depth"] = Unbounded(shape=(n, size, size), dtype=torch.float32, device=device)
            if self.batched.image_segmentation:
                top = int(space["segmentation"].high.max())
                self.observation_spec["segmentation"] = Bounded(0, top, shape=(n, size, size), dtype=torch.uint8,
                                                                device=device)
        self.action_spec = Composite(
            agents=Composite(action=Bounded(-1.0, 1.0, shape=(n, agents, 4), dtype=torch.float32, device=device),
                             shape=(n, agents)),
            shape=(n,),
        )
        self.reward_spec = Composite(
            agents=Composite(reward=Unbounded(shape=(n, agents, 1), dtype=torch.float32, device=device),
                             shape=(n, agents)),
            shape=(n,),
        )
        flag = Categorical(2, shape=(n, 1), dtype=torch.bool, device=device)
        self.observation_spec["is_success"] = flag.clone()
        self.done_spec = Composite(done=flag.clone(), terminated=flag.clone(), truncated=flag.clone(), shape=(n,))
        self._seed = seed

    @property
    def group_map(self) -> dict:
        """Every agent in one group, ``"agents"`` (the keys of the tensordicts)."""
        return {"agents": list(self.agent_names)}

    def set_start_level(self, level, worlds=None) -> None:
        """The start level of the next episodes (see :mod:`dvrl_marl.suction_debris.start_levels`)."""
        self.batched.set_start_level(level, worlds)

    def _tensor(self, array) -> torch.Tensor:
        if isinstance(array, torch.Tensor):
            return array.to(device=self.device, dtype=torch.float32)
        return torch.as_tensor(np.asarray(array, dtype=np.float32), device=self.device)

    def _observation(self, observations=None) -> dict:
        observations = self.batched.observations() if observations is None else observations
        extra = {}
        if self.images:
            first = observations[self.agent_names[0]]
            extra = {_PIXELS.get(key, key): torch.as_tensor(value, device=self.device)
                     for key, value in first.items() if key != "observation"}
            observations = {agent: observations[agent]["observation"] for agent in self.agent_names}
        stacked = self._tensor(_stack([observations[agent] for agent in self.agent_names], axis=1))
        agents = TensorDict({"observation": stacked}, batch_size=stacked.shape[:2], device=self.device)
        return {"agents": agents, "state": self._tensor(self.batched.state()), **extra}

    def _reset(self, tensordict=None, **kwargs):
        mask = None
        on_host = self.backend == "numpy"
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(self.batch_size)
            mask = mask.cpu().numpy() if on_host else mask
        seed, self._seed = self._seed, None
        options = {} if mask is None else {"reset_mask": mask}
        if tensordict is not None and "level" in tensordict.keys():
            options["level"] = tensordict.get("level").reshape(self.batch_size).cpu().numpy().astype(np.float64)
        observations, _ = self.batched.reset(seed=seed, options=options or None)
        flags = torch.zeros((*self.batch_size, 1), dtype=torch.bool, device=self.device)
        return TensorDict({**self._observation(None if on_host else observations), "is_success": flags.clone(),
                           "done": flags,
                           "terminated": flags.clone(), "truncated": flags.clone()}, batch_size=self.batch_size,
                          device=self.device)

    def _step(self, tensordict):
        on_host = self.backend == "numpy"
        action = tensordict.get(("agents", "action")).detach()
        action = action.cpu().numpy().astype(np.float64) if on_host else action.double()
        actions = {agent: action[:, index] for index, agent in enumerate(self.agent_names)}
        observations, rewards, terminations, truncations, infos = self.batched.step(actions)
        reward = _stack([rewards[agent] for agent in self.agent_names], axis=1)[..., None]
        terminated = torch.as_tensor(terminations[self.agent_names[0]], device=self.device)[:, None]
        truncated = torch.as_tensor(truncations[self.agent_names[0]], device=self.device)[:, None]
        out = self._observation(None if on_host else observations)
        out["agents"].set("reward", self._tensor(reward))
        out["is_success"] = torch.as_tensor(infos[self.agent_names[0]]["is_success"], device=self.device)[:, None]
        return TensorDict({**out, "done": terminated | truncated, "terminated": terminated, "truncated": truncated},
                          batch_size=self.batch_size, device=self.device)

    def _set_seed(self, seed: int | None):
        self._seed = seed  # applied at the next reset: world i gets seed + i
        return seed

    def render(self, world: int | None = None):
        return self.batched.render(world)


def _stack(values, axis: int):
    return torch.stack(values, dim=axis) if isinstance(values[0], torch.Tensor) else np.stack(values, axis=axis)
