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
from dvrl_marl.core.reach import GoalCoreBase, position_or_sample
from dvrl_marl.core.tools import jaw_target

__all__ = ["PickCore", "simulate_free_object", "REST_LINEAR_SPEED", "REST_ANGULAR_SPEED", "GRASP_BONUS_STEPS",
           "easy_tips", "pick_potential", "pick_starts", "grasp_events", "carried_floor"]

#: The object is considered at rest (and physics stops being stepped for it) below these speeds.
REST_LINEAR_SPEED = 1e-4  # m/s
REST_ANGULAR_SPEED = 1e-2  # rad/s


#: The guided reward's potential gains this many steps' worth (eta each) while the object is held, so that a grasp pays
#: at once and a drop costs as much (a value of this library: the paper learnt Pick from demonstrations instead).
GRASP_BONUS_STEPS = 5.0


def easy_tips(share, start, grasp_tip, goal_tip):
    """Where an easy episode starts: a point ``share`` (in [0, 1), per world) of the way the scripted expert goes,
    from ``start`` down to ``grasp_tip`` (the tip where the jaws hold the object) and on to ``goal_tip`` (the tip
    where the held object is at its goal); arrays ``(N, 3)`` or ``(3,)``. Returns the tips and whether each lies on
    the second leg, where the object is held."""
    share = np.asarray(share, dtype=np.float64)[..., None]
    down = grasp_tip - start
    carry = goal_tip - grasp_tip
    down_length = np.sqrt(np.sum(down * down, axis=-1, keepdims=True))
    carry_length = np.sqrt(np.sum(carry * carry, axis=-1, keepdims=True))
    along = share * (down_length + carry_length)
    held = along >= down_length
    first = start + down * np.where(down_length > 0.0, along / np.maximum(down_length, 1e-12), 1.0)
    second = grasp_tip + carry * np.where(carry_length > 0.0, (along - down_length) / np.maximum(carry_length, 1e-12),
                                          0.0)
    return np.where(held, second, first), held[..., 0]


def pick_starts(env, generators, options: dict, level: float):
    """Where PSM Pick episodes start, one row per generator: the tips p_0, the goals g (for the object), the objects'
    centres (base frame, m) and whether each starts held. From the checked reset ``options`` or drawn (``env``'s
    boxes): p_0 = p_c, the object under it on the table, g reachable in the goal box; below ``level`` 1 an episode is
    easy with probability 1 - level and starts along the expert's way (:func:`easy_tips`), holding the object on its
    second leg. Each generator draws g, then the level's two numbers, as the single env draws from its
    ``np_random``; the single env (one generator) and the batched core (one per world) both reset through this."""
    count = len(generators)
    start, obj = np.empty((count, 3)), np.empty((count, 3))  # (filled in place: cheaper than broadcasting, per reset)
    start[:] = env.workspace_centre if options["start"] is None else options["start"]
    goal = position_or_sample(options["goal"], generators, env.tool, env.goal_low, env.goal_high, 0.0)
    if options["object"] is None:
        obj[:, :2] = start[:, :2]
        obj[:, 2] = env.object_rest_height
    else:
        obj[:] = options["object"]
    held = np.zeros(count, dtype=bool)
    if level < 1.0:  # (level 1 draws nothing: the default task bit for bit)
        draws = np.array([generator.random(2) for generator in generators])
        easy = draws[:, 0] >= level
        drop = np.array([0.0, 0.0, env.arm.tool_point_drop])
        tips, on_carry = easy_tips(draws[:, 1], start, obj + drop, goal + drop)
        start = np.where(easy[:, None], np.clip(tips, env.tip_low, env.tip_high), start)
        held = easy & on_carry
        if held.any():  # in the jaws, as the grasp rule leaves it: the tool point, by way of the world frame
            base = env.arm.base_position
            obj = np.where(held[:, None], (start + base - drop) - base, obj)
    return start, goal, obj, held


def grasp_events(grasped, closed, sensed):
    """The paper's grasp rule (Sec. III-C): ``(release, grab)``. A held object is released where the jaw opened to
    the grasp threshold or past it (``closed`` False); one not held is grabbed where the jaw closed below it and the
    proximity sensor between the jaws senses the object. Bools (one world) or boolean arrays alike."""
    return grasped & (closed ^ True), (grasped ^ True) & closed & sensed


def carried_floor(low, high, rest_height, grasp_offset):
    """The tip's floor while an object hangs ``grasp_offset`` (m, vertical; negative: below the tip) under it: raised
    so that the object stays above the table (it rests at ``rest_height``), never above the box's ceiling ``high``,
    never below the box's floor ``low``. Floats (one world: a float) or arrays alike."""
    floor = rest_height - grasp_offset
    if isinstance(floor, float):
        return max(low, min(floor, high))
    return np.maximum(low, np.minimum(floor, high))


def pick_potential(jaws, obj, goal, grasped, step_size: float):
    """The guided reward's potential, in steps of ``step_size``: minus the object's way to the goal, minus the jaws'
    way to the object while it is not held, plus :data:`GRASP_BONUS_STEPS` while it is (positions in one frame,
    ``(..., 3)``). The guided reward adds its change over a step to the paper's sparse reward (potential-based
    shaping, Ng et al. 1999: the optimal policies stay those of the sparse task)."""
    reach = jaws - obj
    carry = obj - goal
    reach = np.sqrt(np.sum(reach * reach, axis=-1))
    carry = np.sqrt(np.sum(carry * carry, axis=-1))
    return np.where(grasped, GRASP_BONUS_STEPS, -reach / step_size) - carry / step_size


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
        # The learning options (the single env's page): start levels, the jaw's rule, the guided reward.
        self.start_level = template.start_level
        self.jaw_command = template.jaw_command
        self.guided = template.reward_type == "guided"
        self.sparse = self.sparse or self.guided  # the guided reward is the sparse one plus a potential's change
        self.potential = np.zeros(n)

    def object_world(self) -> np.ndarray:
        return self.qpos[:, self._object]

    def _reset_worlds(self, worlds, generators, options) -> None:
        count = len(worlds)
        level = self.start_level if options["level"] is None else options["level"]
        start, self.goal[worlds], obj, held = pick_starts(self.template, generators, options, level)
        self.arm.set_tips(worlds, start)
        jaw = np.where(held, 0.0, self.initial_jaw)
        self.arm.jaw[worlds] = jaw
        qpos = np.tile(self.model.qpos0, (count, 1))  # mj_resetData
        qpos[:, self._joints] = self.arm.q[worlds]
        qpos[:, self._jaws] = (JAW_FINGER_OPEN_ANGLE * jaw)[:, None]
        qpos[:, self._object] = obj + self.arm.base_position
        qpos[:, self._object_quat] = (1.0, 0.0, 0.0, 0.0)
        self.qpos[worlds] = qpos
        self.qvel[worlds] = 0.0
        self.warmstart[worlds] = 0.0
        self.grasped[worlds] = held
        if held.any():
            self.grasp_offset[worlds[held]] = qpos[held][:, self._object] - self.arm.tip_world()[worlds[held]]
        self.at_rest[worlds] = held | (obj[:, 2] <= self.object_rest_height + 1e-9)
        self.unstable[worlds] = False

    def reset(self, worlds=None, *, seed=None, options=None) -> None:
        super().reset(worlds, seed=seed, options=options)
        indices = self.worlds_of(worlds)
        self.object_normalised[indices] = self.normalise(self.object_world()[indices] - self.arm.base_position)
        if self.guided:
            self.potential[indices] = self._potential()[indices]

    def set_start_level(self, level: float) -> None:
        """The level later resets draw at (a checked float; see the single env's ``set_start_level``)."""
        self.start_level = level

    def _potential(self) -> np.ndarray:
        base = self.arm.base_position
        return pick_potential(self.arm.tool_point_world() - base, self.qpos[:, self._object] - base, self.goal,
                              self.grasped, self.step_size)

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
        if self.grasped.any():  # a carried object stays above the table
            low = np.broadcast_to(low, (self.num_worlds, 3)).copy()
            low[self.grasped, 2] = carried_floor(low[self.grasped, 2], self.tip_high[2], self.object_rest_height,
                                                 self.grasp_offset[self.grasped, 2])
        arm.move(self.step_size * action[:, :3], low, self.tip_high)
        jaw = jaw_target(action[:, 3], self.jaw_command)
        arm.jaw = jaw
        self.qpos[:, self._joints] = arm.q
        self.qpos[:, self._jaws] = (JAW_FINGER_OPEN_ANGLE * jaw)[:, None]

        # The paper's grasp rule.
        tip_world = arm.tip_world()
        obj = self.qpos[:, self._object]
        sensed = np.all(np.abs(obj - arm.tool_point_world()) <= self.grasp_half_extents, axis=1)
        release, grab = grasp_events(self.grasped, jaw < self.grasp_threshold, sensed)
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
        if self.guided:
            potential = self._potential()
            reward = reward + (potential - self.potential)
            self.potential = potential
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
