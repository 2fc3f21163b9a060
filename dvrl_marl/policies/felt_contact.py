"""A seat that feels the other instrument: a move the arm did not make as commanded, near the other instrument, is
taken as a touch, and the arm keeps back from where it touched for a while.

A seat that reads the other arm's tip from the endoscope misplaces it by several millimetres on looks it has not met
(measured: a median error of 7-13 mm where its pushes began; ``docs/results.md``), and then pushes into an instrument
that rests in its way, step after step. Its own joints tell it what its estimate does not: the scene never lets
instruments pass through each other (a refused move, or one that slides along the other instrument), so the tip
moves less than it was told, or elsewhere. A real arm feels that as a tracking error.

``policy.json``'s ``felt_contact`` table (with ``keep_clear``, whose geometry it reads: the tips' places in the
observation, the arms' remote centres, the action's gain) says, in the observation's units: ``threshold``, the part of
the last command the tip did not make (the command less the move, its length) above which it was stopped; ``near``,
how close the other instrument's axis, as estimated, must be for that to be a touch (a cavity's wall stops moves
too; those far from the other instrument are not touches); ``retreat``, how far behind the place it touched the tip
then keeps, and ``hold_steps``, for how many steps. The touch's direction is that of the part not made (into the
other instrument): for ``hold_steps`` steps after a touch, the tip's move along it is limited so that the tip stays
``retreat`` behind the plane through the touch across it (it backs off at once, one step's length at most), its
other moves as commanded: it waits there, or goes round.

State is kept per world (the last tip and command, the touch); ``reset(worlds)`` forgets it where episodes begin,
and a batch of another shape begins them all.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.suction_debris.instruments import segment_distance
from dvrl_marl.suction_debris.layout import MOVE

__all__ = ["FeltContact"]


class FeltContact:
    """``felt(action, observation)``: the action ``(N, A)`` with its motion kept behind a recent touch (module
    documentation); ``observation`` ``(N, d)`` is what the policy reads (its own tip measured, the other's
    estimated)."""

    def __init__(self, rule: dict, keep_clear: dict):
        self.own_tip, self.other_tip = slice(*keep_clear["own_tip"]), slice(*keep_clear["other_tip"])
        self.own_centre = np.asarray(keep_clear["own_centre"], dtype=np.float64)
        self.other_centre = np.asarray(keep_clear["other_centre"], dtype=np.float64)
        self.step = 1.0 / float(keep_clear["gain"])  # an action of 1 moves the tip this far (observation units)
        self.threshold, self.near = float(rule["threshold"]), float(rule["near"])
        self.retreat, self.hold_steps = float(rule["retreat"]), int(rule["hold_steps"])
        self._tip = None  # each world's tip at the last call (NaN: no last call in this episode)
        self._sent = None  # the motion sent at the last call (observation units)
        self._point = self._normal = self._left = None  # the last touch: where, its direction, steps left

    def reset(self, worlds=None) -> None:
        if self._tip is None or worlds is None:
            self._tip = None
            return
        worlds = np.asarray(worlds)
        self._tip[worlds] = np.nan
        self._left[worlds] = 0

    def _start(self, n: int) -> None:
        self._tip = np.full((n, 3), np.nan)
        self._sent = np.zeros((n, 3))
        self._point, self._normal = np.zeros((n, 3)), np.zeros((n, 3))
        self._left = np.zeros(n, dtype=np.int64)

    def __call__(self, action: np.ndarray, observation: np.ndarray) -> np.ndarray:
        shape = np.shape(action)
        action = np.array(action, dtype=np.float64).reshape(-1, shape[-1])
        observation = np.asarray(observation, dtype=np.float64).reshape(len(action), -1)
        if self._tip is None or len(self._tip) != len(action):
            self._start(len(action))
        tip, other = observation[:, self.own_tip], observation[:, self.other_tip]
        missed = self._sent - (tip - self._tip)  # the part of the last command not made (NaN after a reset)
        missed_length = np.linalg.norm(missed, axis=1)
        near = segment_distance(tip, self.own_centre, other, self.other_centre) < self.near
        touched = np.isfinite(missed_length) & (missed_length > self.threshold) & near
        if touched.any():
            self._point[touched] = tip[touched]
            self._normal[touched] = missed[touched] / missed_length[touched, None]
            self._left[touched] = self.hold_steps
        held = self._left > 0
        if held.any():
            motion = action[held, :3] * self.step
            normal = self._normal[held]
            along = np.sum(motion * normal, axis=1)
            # the farthest along the touch's direction the tip may go: `retreat` behind the plane of the touch
            allowed = -self.retreat - np.sum((tip[held] - self._point[held]) * normal, axis=1)
            kept = np.minimum(along, np.maximum(allowed, -self.step))  # (backing off one step's length at most)
            action[held, :3] = np.clip((motion + (kept - along)[:, None] * normal) / self.step, -1.0, 1.0)
            self._left[held] -= 1
        self._tip = tip.copy()
        self._sent = action[:, MOVE] * self.step
        return action.reshape(shape)
