"""One seat of the collaborative scene as a Gymnasium environment, the partner inside it.

```python
import gymnasium as gym
import dvrl_marl

env = gym.make("dvrl_marl/SurgeonSeat-v8")                      # the LND seat; the learned suction works beside it
env = gym.make("dvrl_marl/SurgeonSeat-v8", partner="scripted")  # the scripted suction instead
```

## Description
What a surgeon (or a policy cloned from one) sees and does in ``suction_debris_v8``: the seat's observation, its
action, the team's reward; the other arm is driven inside ``step()``. Minari records datasets from it
(:mod:`dvrl_marl.datasets`), behaviour cloning learns from them, and single-agent libraries train on it.

## Action and Observation Spaces
Those of the seat's agent in :mod:`dvrl_marl.envs.suction_debris_v8`: ``Box(-1, 1, (4,), float32)`` and the flat
``Box(float64)`` observation (own tip, tool, other tip, blood, debris, hand-off point).

## Rewards, Starting State, Episode End
The scene's, for the seat's agent (sparse team reward by default; ``reward_type="dense"``). ``info`` is the scene's
info for the seat plus ``partner_action``: what the partner did this step (zeros at reset).

## Arguments
``seat`` (``"grasper"``, default, or ``"suction"``); ``partner``: ``"pipeline"`` (default: the learned_team
pipeline's arm, the learned Reach policy for the suction), ``"scripted"`` (the built-in expert), a shipped policy
name or a policy folder, or any ``policy(observation) -> action``; ``render_mode`` ("rgb_array"); every other
keyword goes to the scene (``preset=``, ``bleeding_ml_s=``, ``max_cycles=``...).

## Version History
- v8: on suction_debris_v8 (the seat's version is its scene's).
"""

from __future__ import annotations

import gymnasium as gym
import numpy as np

from dvrl_marl.envs import suction_debris
from dvrl_marl.envs.scene_keywords import form_signature
from dvrl_marl.envs.suction_debris_batched import SuctionDebrisBatchedEnv
from dvrl_marl.suction_debris import layout

__all__ = ["SeatEnv", "PARTNERS"]

PARTNERS = ("pipeline", "scripted")


class SeatEnv(gym.Env):
    """One seat of the collaborative scene (see the module documentation)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 50}

    def __init__(self, seat: str = "grasper", partner="pipeline", render_mode=None, **scene_kwargs):
        if seat not in suction_debris.AGENTS:
            raise ValueError(f"SeatEnv: seat must be one of {suction_debris.AGENTS}, got {seat!r}")
        for key in ("surgeon", "surgeon_seat"):  # the partner fills the other seat; the seat is this env's
            if key in scene_kwargs:
                raise TypeError(f"SeatEnv() got an unexpected keyword argument {key!r}: the other arm is the "
                                "partner's (partner=...), this one the agent's")
        self.scene = suction_debris.parallel_env(render_mode=render_mode, **scene_kwargs)
        self.seat = seat
        self.partner_seat = next(agent for agent in suction_debris.AGENTS if agent != seat)
        self.partner = self._partner(partner)
        self.render_mode = render_mode
        self.observation_space = self.scene.observation_space(seat)
        self.action_space = self.scene.action_space(seat)
        self._partner_observation = None

    def _partner(self, partner):
        if callable(partner) and not isinstance(partner, str):
            return partner
        if partner == "scripted":
            from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

            return (ScriptedSuction if self.partner_seat == "suction" else ScriptedSurgeon).for_env(self.scene)
        if partner == "pipeline":
            from dvrl_marl.pipeline import ArmPipeline, load_pipeline

            return ArmPipeline(load_pipeline("learned_team")[self.partner_seat], self.partner_seat, self.scene)
        if isinstance(partner, str):
            from dvrl_marl import policies

            return policies.load_seat(partner, self.partner_seat, "SeatEnv: partner")
        raise ValueError(f"SeatEnv: partner must be one of {PARTNERS}, a policy name or folder, or a callable; "
                         f"got {partner!r}")

    def _partner_view(self, observations: dict) -> np.ndarray:
        """The partner reads the plain observation in the scene's units (features and normalisation are the
        learner's): the returned one's plain part, or, when the scene normalised it, the scene's own plain view."""
        if self.scene.observation_scaling is not None:
            return self.scene.seat_observation(self.partner_seat)
        own = observations[self.partner_seat]
        if isinstance(own, dict):  # image observations: the partner reads the observation beside them
            own = own["observation"]
        return own[: layout.plain_width(self.scene.observation_layout)]

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        observations, infos = self.scene.reset(seed=seed, options=options)
        if hasattr(self.partner, "reset"):
            self.partner.reset()
        self._partner_observation = self._partner_view(observations)
        return observations[self.seat], self._info(infos[self.seat], np.zeros(layout.ACTION_WIDTH, dtype=np.float32))

    def step(self, action):
        if self._partner_observation is None:
            raise ValueError("SeatEnv: step() called before reset()")
        partner_action = np.asarray(self.partner(self._partner_observation), dtype=np.float32)
        observations, rewards, terminations, truncations, infos = self.scene.step(
            {self.seat: action, self.partner_seat: partner_action})
        self._partner_observation = self._partner_view(observations)
        if not self.scene.agents:
            self._partner_observation = None
        return (observations[self.seat], float(rewards[self.seat]), bool(terminations[self.seat]),
                bool(truncations[self.seat]), self._info(infos[self.seat], partner_action))

    @staticmethod
    def _info(info: dict, partner_action) -> dict:
        return {"is_success": bool(info["is_success"]), "blood_remaining": float(info["blood_remaining"]),
                "debris_delivered": int(info["debris_delivered"]), "collision": bool(info["collision"]),
                "partner_action": np.asarray(partner_action, dtype=np.float32)}

    def render(self):
        return self.scene.render()

    def close(self):
        self.scene.close()


# (written out: the seat's own keywords, then the scene's, which it passes on; the partner fills the other seat)
SeatEnv.__init__.__signature__ = form_signature(
    SeatEnv.__init__, SuctionDebrisBatchedEnv.__init__,
    without=("num_envs", "autoreset_mode", "render_world", "surgeon", "surgeon_seat"))
