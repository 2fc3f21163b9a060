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
    """Shared by both experts. ``__call__`` takes one observation ``(d,)`` or a batch ``(N, d)`` (the batched
    environment's worlds)."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        self.layout = layout
        self.slices = observation_layout
        self.gain = layout.gain
        self.safe_z = layout.phantom_top + _SAFE_HEIGHT / workspace_range
        self.park_z = layout.phantom_top + _PARK_HEIGHT / workspace_range
        self.near = 0.001 / workspace_range  # 1 mm
        self.cavity_centres = np.asarray(layout.cavity_centres, dtype=np.float64)  # (C, 2)
        self.threshold = np.asarray(layout.blood_threshold_fraction, dtype=np.float64)

    @classmethod
    def for_env(cls, env):
        """An expert for ``env`` (a single or batched suction_debris_v0 environment)."""
        unwrapped = getattr(env, "unwrapped", env)
        return cls(unwrapped.layout(), unwrapped.observation_layout, unwrapped.workspace_range)

    def reset(self) -> None:
        """Stateless; present so a scripted expert can stand wherever a device can."""

    def __call__(self, observation) -> np.ndarray:
        obs = np.asarray(observation)
        if obs.ndim == 2:
            return self.act(obs.astype(np.float64, copy=False))
        return self.act_one(obs)

    def act(self, obs: np.ndarray) -> np.ndarray:
        """Actions ``(N, 4)`` for observations ``(N, d)``."""
        raise NotImplementedError

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        """The action for one observation: the same plan on plain rows, several times faster than ``act`` on one
        row (the single env's seat calls it every step); a test holds both to the same actions."""
        raise NotImplementedError

    def _towards_one(self, tip, target) -> np.ndarray:
        return np.clip((np.asarray(target) - tip) * self.gain, -1.0, 1.0)

    def _via_safe_height_one(self, tip, target, tolerance) -> np.ndarray:
        horizontal = np.linalg.norm(np.asarray(target[:2]) - tip[:2])
        if horizontal > tolerance:
            return np.array([target[0], target[1], max(self.safe_z, target[2])])
        return np.asarray(target, dtype=float)

    def _towards(self, tip, target) -> np.ndarray:
        return np.clip((target - tip) * self.gain, -1.0, 1.0)

    def _via_safe_height(self, tip, target, tolerance) -> np.ndarray:
        """Rise to the safe height before travelling sideways, then descend on the target (rows of (N, 3));
        ``tolerance`` is a number or one per row."""
        target = np.broadcast_to(target, tip.shape)
        offset = target[:, :2] - tip[:, :2]
        far = np.sqrt(offset[:, 0] * offset[:, 0] + offset[:, 1] * offset[:, 1]) > tolerance
        via = target.copy()
        via[:, 2] = np.where(far, np.maximum(self.safe_z, target[:, 2]), target[:, 2])
        return via

    @staticmethod
    def _with_tool(move, tool) -> np.ndarray:
        action = np.empty((move.shape[0], 4), dtype=np.float32)
        action[:, :3] = move
        action[:, 3] = tool
        return action


class ScriptedSuction(_Scripted):
    """Clears each cavity in turn (valve open while inside it), then parks out of the surgeon's way."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        base = np.asarray(layout.base_positions["suction"][:2])
        distances = [np.linalg.norm(np.asarray(c) - base) for c in layout.cavity_centres]
        self.order = [int(i) for i in np.argsort(distances)[::-1]]  # farthest cavity first
        self.park = np.array([base[0] + 0.005 / workspace_range, base[1], self.park_z])

    def act(self, obs: np.ndarray) -> np.ndarray:
        tip = obs[:, self.slices["own_tip"]]
        blood = obs[:, self.slices["blood"]]
        target = np.broadcast_to(self.park, tip.shape).copy()
        tolerance = np.full(len(obs), 4 * self.near)
        valve = np.full(len(obs), -1.0)
        for cavity in reversed(self.order):  # the first cavity in the order that still needs clearing wins
            pending = (blood[:, cavity] >= self.threshold[cavity]) & (blood[:, cavity] > 0.0)
            cx, cy = self.cavity_centres[cavity]
            target[pending] = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
            tolerance[pending] = 2 * self.near
            inside = (np.hypot(tip[:, 0] - cx, tip[:, 1] - cy) < self.layout.cavity_mouth_radius) & (
                tip[:, 2] < self.layout.phantom_top)
            valve[pending] = np.where(inside[pending], 1.0, -1.0)
        return self._with_tool(self._towards(tip, self._via_safe_height(tip, target, tolerance)), valve)

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip = obs[self.slices["own_tip"]]
        blood = obs[self.slices["blood"]]
        for cavity in self.order:
            if blood[cavity] >= self.layout.blood_threshold_fraction[cavity] and blood[cavity] > 0.0:
                cx, cy = self.layout.cavity_centres[cavity]
                bottom = (cx, cy, self.layout.cavity_floor[cavity] + self.layout.clearance)
                move = self._towards_one(tip, self._via_safe_height_one(tip, bottom, 2 * self.near))
                inside = np.hypot(tip[0] - cx, tip[1] - cy) < self.layout.cavity_mouth_radius and tip[2] < self.layout.phantom_top
                return np.append(move, 1.0 if inside else -1.0).astype(np.float32)
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.park, 4 * self.near)), -1.0).astype(np.float32)


class ScriptedSurgeon(_Scripted):
    """Picks each revealed debris in a cleared cavity, carries it over the phantom to the hand-off point."""

    def __init__(self, layout, observation_layout, workspace_range: float):
        super().__init__(layout, observation_layout, workspace_range)
        base = np.asarray(layout.base_positions["grasper"][:2])
        self.home = np.array([base[0] - 0.015 / workspace_range, base[1] + 0.02 / workspace_range, self.park_z])

    def act(self, obs: np.ndarray) -> np.ndarray:
        n = len(obs)
        rows = np.arange(n)
        tip = obs[:, self.slices["own_tip"]]
        blood = obs[:, self.slices["blood"]]
        debris = obs[:, self.slices["debris"]].reshape(n, -1, 6)
        handoff = obs[:, self.slices["handoff"]]
        # Default: wait at home with the jaw open.
        action = self._with_tool(self._towards(tip, self._via_safe_height(tip, self.home, 4 * self.near)), 1.0)

        # A pin whose cavity is clear, visible and not delivered, nearest the tip.
        dx = debris[:, :, None, 0] - self.cavity_centres[:, 0]
        dy = debris[:, :, None, 1] - self.cavity_centres[:, 1]
        cavity = np.argmin(np.hypot(dx, dy), axis=2)  # (N, D)
        cleared = blood[rows[:, None], cavity] < self.threshold[cavity]
        candidate = (debris[:, :, 3] > 0.5) & (debris[:, :, 5] < 0.5) & cleared
        offset = debris[:, :, :3] - tip[:, None, :]
        distance = np.linalg.norm(offset, axis=2)
        hunting = candidate.any(axis=1)
        if hunting.any():
            nearest = np.argmin(np.where(candidate, distance, np.inf), axis=1)
            pin = debris[rows, nearest, :3]
            on_it = distance[rows, nearest] <= self.near
            move = self._towards(tip, self._via_safe_height(tip, pin, self.near))
            approach = self._with_tool(move, 1.0)
            approach[on_it] = (0.0, 0.0, 0.0, -1.0)  # close the jaw on it
            action[hunting] = approach[hunting]

        held = debris[:, :, 4] > 0.5
        carrying = held.any(axis=1)
        if carrying.any():
            pin = debris[rows, np.argmax(held, axis=1), :3]
            # Carry: move so that the pin (not the tip) reaches the hand-off point, above the phantom.
            move = self._towards(pin, self._via_safe_height(pin, handoff, 2 * self.near))
            action[carrying] = self._with_tool(move, -1.0)[carrying]
        return action

    def _cavity_of(self, position) -> int:
        distances = [np.hypot(position[0] - cx, position[1] - cy) for cx, cy in self.layout.cavity_centres]
        return int(np.argmin(distances))

    def act_one(self, obs: np.ndarray) -> np.ndarray:
        tip = obs[self.slices["own_tip"]]
        blood = obs[self.slices["blood"]]
        debris = obs[self.slices["debris"]].reshape(-1, 6)
        handoff = obs[self.slices["handoff"]]
        held = [d for d in debris if d[4] > 0.5]
        if held:
            pin = held[0][:3]
            target_for_pin = self._via_safe_height_one(pin, handoff, 2 * self.near)
            return np.append(self._towards_one(pin, target_for_pin), -1.0).astype(np.float32)
        candidates = [
            d[:3] for d in debris
            if d[3] > 0.5 and d[5] < 0.5
            and blood[self._cavity_of(d[:3])] < self.layout.blood_threshold_fraction[self._cavity_of(d[:3])]
        ]
        if candidates:
            pin = min(candidates, key=lambda c: np.linalg.norm(c - tip))
            if np.linalg.norm(pin - tip) <= self.near:
                return np.array([0.0, 0.0, 0.0, -1.0], dtype=np.float32)
            return np.append(self._towards_one(tip, self._via_safe_height_one(tip, pin, self.near)), 1.0).astype(np.float32)
        return np.append(self._towards_one(tip, self._via_safe_height_one(tip, self.home, 4 * self.near)), 1.0).astype(np.float32)
