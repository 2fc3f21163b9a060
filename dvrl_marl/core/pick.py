"""The batched core of PSM Pick: N worlds of :class:`dvrl_marl.envs.psm_pick.PSMPickEnv` as arrays.

The arm, the jaw, the paper's grasp rule and a carried object are arithmetic over all worlds. A released object
falls under MuJoCo physics, as in the single environment: only the worlds whose object is falling are stepped,
one after the other in a scratch ``MjData`` loaded with that world's integration state (qpos, qvel and the solver's
warm start, kept per world), so each world evolves exactly as its single environment would.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from dvrl_marl.assets import JAW_FINGER_OPEN_ANGLE
from dvrl_marl.core.reach import GoalCoreBase

__all__ = ["PickCore", "simulate_free_object", "REST_LINEAR_SPEED", "REST_ANGULAR_SPEED"]

#: The object is considered at rest (and physics stops being stepped for it) below these speeds.
REST_LINEAR_SPEED = 1e-4  # m/s
REST_ANGULAR_SPEED = 1e-2  # rad/s


def simulate_free_object(model, data, n_substeps: int, qvel_address: int) -> tuple[bool, bool]:
    """Step ``data`` for ``n_substeps`` physics steps while a free object falls.

    Returns ``(stable, at_rest)``. If MuJoCo went unstable (a warning or a non-finite position) the positions are
    restored, every velocity is zeroed and the warnings cleared. An object that stopped on a contact has its
    velocity zeroed and ``at_rest`` True. The single environment and the batched core both step through this.
    """
    saved_qpos = data.qpos.copy()
    mujoco.mj_step(model, data, nstep=n_substeps)
    if np.any(data.warning.number) or not np.all(np.isfinite(data.qpos)):  # a MuJoCo warning, or worse
        data.qpos[:] = saved_qpos
        data.qvel[:] = 0.0
        for warning in data.warning:
            warning.number = 0
        return False, False
    velocity = data.qvel[qvel_address:qvel_address + 6]
    linear = math.sqrt(float(velocity[0] ** 2 + velocity[1] ** 2 + velocity[2] ** 2))
    angular = math.sqrt(float(velocity[3] ** 2 + velocity[4] ** 2 + velocity[5] ** 2))
    if linear < REST_LINEAR_SPEED and angular < REST_ANGULAR_SPEED and data.ncon > 0:
        velocity[:] = 0.0
        return True, True
    return True, False


class PickCore(GoalCoreBase):
    """N worlds of PSM Pick. ``step`` returns ``(reward, terminated, truncated, success)`` arrays of shape (N,);
    :attr:`grasped` and :attr:`unstable` (a world whose physics failed this step, which truncates it) are kept."""

    action_width = 4

    def __init__(self, template, num_worlds: int, max_episode_steps: int | None):
        super().__init__(template, num_worlds, max_episode_steps)
        n = self.num_worlds
        self.model = template.model
        self._scratch = mujoco.MjData(self.model)  # physics of one falling world at a time
        self.n_substeps = template.n_substeps
        self.grasp_threshold = template.grasp_threshold
        self.initial_jaw = template.initial_jaw
        self.object_rest_height = template.object_rest_height
        self.goal_low = template.goal_low.copy()
        self.goal_high = template.goal_high.copy()
        self.grasp_half_extents = np.asarray(template.arm.grasp_zone_half_extents_base)
        self._joints = template.arm.joint_qpos_addresses
        self._jaws = template.arm.jaw_qpos_addresses
        adr = template.object_qpos_address
        self._object = slice(adr, adr + 3)
        self._object_quat = slice(adr + 3, adr + 7)
        vel = template.object_qvel_address
        self._object_velocity = slice(vel, vel + 6)
        self._qvel_address = vel
        # Per-world MuJoCo integration state (the object's pose lives in qpos).
        self.qpos = np.tile(self.model.qpos0, (n, 1))
        self.qvel = np.zeros((n, self.model.nv))
        self.warmstart = np.zeros((n, self.model.nv))
        self.grasped = np.zeros(n, dtype=bool)
        self.grasp_offset = np.zeros((n, 3))
        self.at_rest = np.ones(n, dtype=bool)
        self.unstable = np.zeros(n, dtype=bool)
        self.object_normalised = np.zeros((n, 3))

    def object_world(self) -> np.ndarray:
        return self.qpos[:, self._object]

    def _reset_worlds(self, worlds, generators, options) -> None:
        count = len(worlds)
        start = self.centre if options["start"] is None else options["start"]
        start = np.broadcast_to(start, (count, 3))
        self.goal[worlds] = self._position_or_sample(options["goal"], generators, self.goal_low, self.goal_high,
                                                     tool_point_drop=0.0)
        if options["object"] is None:
            obj = np.empty((count, 3))
            obj[:, :2] = start[:, :2]
            obj[:, 2] = self.object_rest_height
        else:
            obj = np.broadcast_to(options["object"], (count, 3))
        self.arm.set_tips(worlds, start)
        self.arm.jaw[worlds] = self.initial_jaw
        qpos = np.tile(self.model.qpos0, (count, 1))  # mj_resetData
        qpos[:, self._joints] = self.arm.q[worlds]
        qpos[:, self._jaws] = JAW_FINGER_OPEN_ANGLE * self.initial_jaw
        qpos[:, self._object] = obj + self.arm.base_position
        qpos[:, self._object_quat] = (1.0, 0.0, 0.0, 0.0)
        self.qpos[worlds] = qpos
        self.qvel[worlds] = 0.0
        self.warmstart[worlds] = 0.0
        self.grasped[worlds] = False
        self.at_rest[worlds] = obj[:, 2] <= self.object_rest_height + 1e-9
        self.unstable[worlds] = False

    def reset(self, worlds=None, *, seed=None, options=None) -> None:
        super().reset(worlds, seed=seed, options=options)
        indices = self.worlds_of(worlds)
        self.object_normalised[indices] = self.normalise(self.object_world()[indices] - self.arm.base_position)

    def observation(self) -> dict:
        tip = self.normalise(self.arm.tip)
        state = np.concatenate([tip, (2.0 * self.arm.jaw - 1.0)[:, None], self.object_normalised], axis=1)
        return {"observation": state, "achieved_goal": self.object_normalised.copy(),
                "desired_goal": self.goal_normalised.copy()}

    def success(self) -> np.ndarray:
        return self.reward_and_success(self.object_normalised)[1]

    def step(self, actions):
        action = self.read_actions(actions)
        arm = self.arm
        low = self.tip_low
        if self.grasped.any():
            # A carried object stays above the table: raise the tip's floor by how far the object hangs below it.
            floor = self.object_rest_height - self.grasp_offset[:, 2]
            raise_floor = self.grasped & (floor > low[2])
            low = np.broadcast_to(low, (self.num_worlds, 3)).copy()
            low[raise_floor, 2] = np.minimum(floor[raise_floor], self.tip_high[2])
        arm.move(self.step_size * action[:, :3], low, self.tip_high)
        jaw = (action[:, 3] + 1.0) * 0.5
        arm.jaw = jaw
        self.qpos[:, self._joints] = arm.q
        self.qpos[:, self._jaws] = (JAW_FINGER_OPEN_ANGLE * jaw)[:, None]

        # The paper's grasp rule.
        tip_world = arm.tip_world()
        obj = self.qpos[:, self._object]
        closed = jaw < self.grasp_threshold
        release = self.grasped & ~closed
        sensed = np.all(np.abs(obj - arm.tool_point_world()) <= self.grasp_half_extents, axis=1)
        grab = ~self.grasped & closed & sensed
        if release.any() or grab.any():
            self.at_rest[release] = False
            self.qvel[release | grab, self._object_velocity] = 0.0
            self.grasp_offset[grab] = obj[grab] - tip_world[grab]
            self.grasped = (self.grasped & ~release) | grab
        if self.grasped.any():
            self.qpos[self.grasped, self._object] = tip_world[self.grasped] + self.grasp_offset[self.grasped]
        self.unstable[:] = False
        falling = ~self.grasped & ~self.at_rest
        if falling.any():
            for world in np.flatnonzero(falling).tolist():
                self._simulate(world)
        self.object_normalised = self.normalise(self.qpos[:, self._object] - arm.base_position)
        self.elapsed += 1
        reward, success = self.reward_and_success(self.object_normalised)
        return reward, np.zeros(self.num_worlds, dtype=bool), self.truncation() | self.unstable, success

    def _simulate(self, world: int) -> None:
        data = self._scratch
        data.qpos[:] = self.qpos[world]
        data.qvel[:] = self.qvel[world]
        data.qacc_warmstart[:] = self.warmstart[world]
        stable, at_rest = simulate_free_object(self.model, data, self.n_substeps, self._qvel_address)
        self.qpos[world] = data.qpos
        self.qvel[world] = data.qvel
        self.warmstart[world] = data.qacc_warmstart
        self.at_rest[world] = at_rest
        self.unstable[world] = not stable

    def info(self, success: np.ndarray) -> dict:
        return {"is_success": success, "grasped": self.grasped.copy()}

    def world_state(self, world: int) -> dict:
        """World ``world``'s state as the single environment's ``set_state`` takes it."""
        adr = self._object.start
        return {"tip": self.arm.tip[world].copy(), "goal": self.goal[world].copy(), "jaw": float(self.arm.jaw[world]),
                "object_pose": self.qpos[world, adr:adr + 7].copy(), "grasped": bool(self.grasped[world])}
