"""Scripted experts for the collaborative scene (suction_debris_v0): the suction arm and the surgeon (LND).

They read only their agent's observation plus the scene's fixed layout (:meth:`SuctionDebrisEnv.layout`), so they
can sit in the surgeon seat or act as an agent's policy. Their plan keeps the instruments apart: the suction clears
the cavity farther from its own RCM first and parks on its own side afterwards; the surgeon only works in cavities
the suction has cleared.
"""

from __future__ import annotations

import numpy as np

__all__ = ["ScriptedSuction", "ScriptedSurgeon"]

#: Heights above the phantom top (normalised units are scene-specific, so these are metres, converted in for_env).
_SAFE_HEIGHT = 0.010
_PARK_HEIGHT = 0.030


class _Scripted:
    def __init__(self, layout, observation_layout, workspace_range: float):
        self.layout = layout
        self.slices = observation_layout
        self.gain = layout.gain
        self.safe_z = layout.phantom_top + _SAFE_HEIGHT / workspace_range
        self.park_z = layout.phantom_top + _PARK_HEIGHT / workspace_range
        self.near = 0.001 / workspace_range  # 1 mm

    @classmethod
    def for_env(cls, env):
        """An expert for ``env`` (a :class:`~dvrl_marl.envs.suction_debris_v0.SuctionDebrisEnv`)."""
        unwrapped = getattr(env, "unwrapped", env)
        return cls(unwrapped.layout(), unwrapped.observation_layout, unwrapped.workspace_range)

    def reset(self) -> None:
        """Stateless; present so a scripted expert can stand wherever a device can."""

    def _towards(self, tip, target) -> np.ndarray:
        return np.clip((np.asarray(target) - tip) * self.gain, -1.0, 1.0)

    def _via_safe_height(self, tip, target, tolerance) -> np.ndarray:
        """Rise to the safe height before travelling sideways, then descend on the target."""
        horizontal = np.linalg.norm(np.asarray(target[:2]) - tip[:2])
        if horizontal > tolerance:
            return np.array([target[0], target[1], max(self.safe_z, target[2])])
        return np.asarray(target, dtype=float)


class ScriptedSuction(_Scripted):
    """Clears each cavity in turn (valve open while inside it), then parks out of the surgeon's way."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        base = np.asarray(layout.base_positions["suction"][:2])
        distances = [np.linalg.norm(np.asarray(c) - base) for c in layout.cavity_centres]
        self.order = list(np.argsort(distances)[::-1])  # farthest cavity first
        self.park = np.array([base[0] + 0.005 / workspace_range, base[1], self.park_z])

    def __call__(self, observation) -> np.ndarray:
        obs = np.asarray(observation)
        tip = obs[self.slices["own_tip"]]
        blood = obs[self.slices["blood"]]
        for cavity in self.order:
            if blood[cavity] >= self.layout.blood_threshold_fraction[cavity] and blood[cavity] > 0.0:
                cx, cy = self.layout.cavity_centres[cavity]
                bottom = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
                move = self._towards(tip, self._via_safe_height(tip, bottom, 2 * self.near))
                inside = np.hypot(tip[0] - cx, tip[1] - cy) < self.layout.cavity_mouth_radius and tip[2] < self.layout.phantom_top
                return np.append(move, 1.0 if inside else -1.0).astype(np.float32)
        return np.append(self._towards(tip, self._via_safe_height(tip, self.park, 4 * self.near)), -1.0).astype(np.float32)


class ScriptedSurgeon(_Scripted):
    """Picks each revealed debris in a cleared cavity, carries it over the phantom to the hand-off point."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        base = np.asarray(layout.base_positions["grasper"][:2])
        self.home = np.array([base[0] - 0.015 / workspace_range, base[1] + 0.02 / workspace_range, self.park_z])

    def _cavity_of(self, position) -> int:
        distances = [np.hypot(position[0] - cx, position[1] - cy) for cx, cy in self.layout.cavity_centres]
        return int(np.argmin(distances))

    def __call__(self, observation) -> np.ndarray:
        obs = np.asarray(observation)
        tip = obs[self.slices["own_tip"]]
        blood = obs[self.slices["blood"]]
        debris = obs[self.slices["debris"]].reshape(-1, 6)
        handoff = obs[self.slices["handoff"]]
        held = [d for d in debris if d[4] > 0.5]
        if held:
            pin = held[0][:3]
            # Carry: move so that the pin (not the tip) reaches the hand-off point, above the phantom.
            target_for_pin = self._via_safe_height(pin, handoff, 2 * self.near)
            return np.append(self._towards(pin, target_for_pin), -1.0).astype(np.float32)
        candidates = [
            d[:3] for d in debris
            if d[3] > 0.5 and d[5] < 0.5
            and blood[self._cavity_of(d[:3])] < self.layout.blood_threshold_fraction[self._cavity_of(d[:3])]
        ]
        if candidates:
            pin = min(candidates, key=lambda c: np.linalg.norm(c - tip))
            if np.linalg.norm(pin - tip) <= self.near:
                return np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)  # close the jaw on it
            return np.append(self._towards(tip, self._via_safe_height(tip, pin, self.near)), 1.0).astype(np.float32)
        return np.append(self._towards(tip, self._via_safe_height(tip, self.home, 4 * self.near)), 1.0).astype(np.float32)
