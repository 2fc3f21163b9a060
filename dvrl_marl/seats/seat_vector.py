"""The surgeon seat as a Gymnasium vector environment: N seats at once, the partners inside.

```python
import gymnasium as gym
import dvrl_marl

envs = gym.make_vec("dvrl_marl/SurgeonSeat-v8", num_envs=256, vectorization_mode="vector_entry_point",
                    partner="scripted")                     # N worlds of the batched core, the partners batched
observations, infos = envs.reset(seed=0)                    # world i == gym.make(...).reset(seed=0 + i)
observations, rewards, terminations, truncations, infos = envs.step(envs.action_space.sample())
```

With a partner that acts on a batch of observations (``"scripted"``, a learned policy's name or folder, or any
``policy(observations (N, d)) -> actions (N, 4)``) the worlds run on the collaborative scene's batched core
(:mod:`dvrl_marl.envs.suction_debris_batched`), and world ``i`` seeded ``s`` follows the seat env seeded ``s + i``.
The ``"pipeline"`` partner (the seat's default) plans one world at a time, so with it the vector is Gymnasium's
``SyncVectorEnv`` of seat envs: it works the same way, one world at a time.

Observations ``(N, obs_dim)``, rewards and flags ``(N,)``; ``infos`` holds the seat env's info keys as arrays (with
Gymnasium's ``"_key"`` masks). ``autoreset_mode``: ``"next_step"`` (Gymnasium's default) or ``"same_step"``
(``infos["final_obs"]``, rows valid where ``infos["_final_obs"]``).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np
from gymnasium.vector.utils import batch_space

from dvrl_marl.envs import suction_debris
from dvrl_marl.envs.vector import autoreset_metadata

__all__ = ["SeatVectorEnv", "make_seat_vector"]

_INFO_KEYS = ("is_success", "blood_remaining", "debris_delivered", "collision")


class SeatVectorEnv(gym.vector.VectorEnv):
    """N seats of the collaborative scene on its batched core (see the module documentation)."""

    def __init__(self, num_envs: int = 1, seat: str = "grasper", partner="scripted",
                 autoreset_mode: str = "next_step", **scene_kwargs):
        if seat not in suction_debris.AGENTS:
            raise ValueError(f"SeatVectorEnv: seat must be one of {suction_debris.AGENTS}, got {seat!r}")
        if autoreset_mode not in ("next_step", "same_step"):
            raise ValueError(f"SeatVectorEnv: autoreset_mode must be 'next_step' or 'same_step', got "
                             f"{autoreset_mode!r}")
        partner_seat = next(agent for agent in suction_debris.AGENTS if agent != seat)
        self.batched = suction_debris.batched_env(num_envs=num_envs,
                                                     surgeon=_batched_partner(partner, partner_seat),
                                                     surgeon_seat=partner_seat, autoreset_mode="disabled",
                                                     **scene_kwargs)
        self.seat, self.partner_seat = seat, partner_seat
        self.num_envs = self.batched.num_envs
        self.autoreset_mode = autoreset_mode
        self.metadata = {"render_modes": ["rgb_array"], "render_fps": 50,
                         "autoreset_mode": autoreset_metadata(autoreset_mode)}
        self.render_mode = scene_kwargs.get("render_mode")
        self.single_observation_space = self.batched.observation_space(seat)
        self.single_action_space = self.batched.action_space(seat)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self._needs_reset = np.zeros(self.num_envs, dtype=bool)
        self._all = np.ones(self.num_envs, dtype=bool)

    def reset(self, *, seed=None, options=None):
        observations, infos = self.batched.reset(seed=seed, options=options)
        mask = (options or {}).get("reset_mask")
        self._needs_reset[self._all if mask is None else self.batched.core.worlds_of(mask)] = False
        return observations[self.seat], self._info(infos[self.seat])

    def step(self, actions):
        pending = self._needs_reset.copy() if self.autoreset_mode == "next_step" else None
        observations, rewards, terminations, truncations, infos = self.batched.step({self.seat: actions})
        reward = np.asarray(rewards[self.seat], dtype=np.float64)
        terminated, truncated = terminations[self.seat].copy(), truncations[self.seat].copy()
        observation, info = observations[self.seat], self._info(infos[self.seat])
        if pending is not None and pending.any():  # these worlds start a new episode instead of stepping
            reset_observations, reset_infos = self.batched.reset(options={"reset_mask": pending})
            observation = reset_observations[self.seat]
            info = self._info(reset_infos[self.seat])
            reward[pending] = 0.0
            terminated[pending] = truncated[pending] = False
        done = terminated | truncated
        if self.autoreset_mode == "next_step":
            self._needs_reset = done
        elif done.any():
            info.update(final_obs=observation, _final_obs=done, final_info=dict(info), _final_info=done)
            observations, reset_infos = self.batched.reset(options={"reset_mask": done})
            observation = observations[self.seat]
        return observation, reward, terminated, truncated, info

    def _info(self, info: dict) -> dict:
        out = {key: np.asarray(info[key]) for key in _INFO_KEYS}
        out.update({f"_{key}": self._all for key in _INFO_KEYS})
        return out

    def render(self):
        return self.batched.render()

    def close_extras(self, **kwargs):
        batched = getattr(self, "batched", None)  # None when the constructor refused its arguments
        if batched is not None:
            batched.close()


def _batched_partner(partner, partner_seat: str):
    """A partner that acts on a batch: "scripted" (the batched env binds it), a learned policy of ``partner_seat``, or
    a callable."""
    if partner == "pipeline":
        raise ValueError("the pipeline partner plans one world at a time; make_seat_vector gives it a "
                         "SyncVectorEnv")
    if isinstance(partner, str) and partner != "scripted":
        from dvrl_marl import policies

        return policies.load_seat(partner, partner_seat, "SeatVectorEnv: partner")
    return partner


def make_seat_vector(num_envs: int = 1, partner="pipeline", **kwargs) -> gym.vector.VectorEnv:
    """``gym.make_vec(<SurgeonSeat id>, vectorization_mode="vector_entry_point")``: a :class:`SeatVectorEnv` on the
    batched core, or for the ``"pipeline"`` partner a ``SyncVectorEnv`` of seat envs."""
    from dvrl_marl.schemas import PositiveInt, validated

    num_envs = validated(PositiveInt, num_envs, "make_vec: num_envs")
    if partner == "pipeline":
        from dvrl_marl.seats.seat_env import SeatEnv

        vector_kwargs = {key: kwargs.pop(key) for key in ("autoreset_mode",) if key in kwargs}
        if vector_kwargs.get("autoreset_mode", "next_step") != "next_step":
            raise ValueError("the pipeline partner's seats run in a SyncVectorEnv: autoreset_mode 'next_step' only")
        return gym.vector.SyncVectorEnv([lambda: SeatEnv(partner="pipeline", **kwargs) for _ in range(num_envs)])
    return SeatVectorEnv(num_envs, partner=partner, **kwargs)
