"""PSM Pick: grasp a small cylinder with the Large Needle Driver and carry it to a goal (paper Sec. III-C).

## Description
The LND starts at the workspace centre p_c with its jaw open, right above a 3 mm cylinder lying on the table. The
agent must descend, close the jaw on the object, and bring the object to the goal g. The arm is kinematic (eta
steps through inverse kinematics); the object has MuJoCo physics: it rests on the table and falls when released.
Grasping follows the paper's rule: when the jaw value is below ``grasp_threshold`` (0.25) and the proximity sensor
between the jaws sees the object, the object is rigidly attached to the gripper; opening the jaw to the threshold
or more releases it. Nothing else moves the object through the jaws (the instrument has no contacts).

## Action Space
``Box(-1, 1, (4,), float32)``: [Delta, phi]. ``p <- p + eta * Delta`` (eta = 1 mm, projected into the workspace,
above the table, within the joint limits; a carried object is kept above the table too), ``j = (phi + 1) / 2``.

## Observation Space
``Dict`` of ``float64`` Boxes, positions normalised as in the paper (x~ = (x - p_c) / rho):

| key | shape | content |
|---|---|---|
| ``observation`` | (7,) | [p~, 2j - 1, o~] |
| ``achieved_goal`` | (3,) | o~, the object |
| ``desired_goal`` | (3,) | g~ |

## Rewards
Sparse (``PSMPick-v1``): ``-1`` while ``rho * ||o~ - g~|| > delta`` (3 mm), else ``0``. Dense
(``PSMPickDense-v1``): minus the object-goal distance in metres.

## Starting State
p_0 = p_c = (0, 0, -0.10) m, jaw open, the object on the table directly below the gripper, g uniform in the
box the jaws cover (p_c +/- rho, rho = 2.5 cm, 10.2 mm below p's box) at heights the object can reach (not below
its resting height). p is the dVRK's measured_cp (as in the original code), so the jaws start 13.2 mm above the
table and descend 10.2 mm to the object's centre. ``reset(options=...)``
accepts ``start``, ``goal`` and ``object`` positions in metres (base frame); an object above the table falls.

## Episode End
No termination; ``max_episode_steps=100`` truncates. ``info`` has ``is_success`` and ``grasped``; if MuJoCo
becomes unstable the episode truncates with ``info["sim_unstable"] = True`` and the last finite observation.

## Arguments
``reward_type``, ``render_mode``, ``tip_frame``, ``grasp_threshold`` and the paper's parameters as in PSM Reach;
defaults in
``tasks/psm_pick.toml``.

## Learning options
Devices for training from scratch, off by default (the registered task is the paper's); a policy learnt with them
is evaluated on the task without them (``baselines/configs/pick_lnd_ppo_scratch.toml``, the shipped
``pick-lnd-scratch``):

- ``start_level`` (0 to 1, ``"easy"`` = 0, ``"default"`` = 1; default 1), or ``reset(options={"level": x})`` for one
  reset, or ``set_start_level(x)`` (also on the batched env) for later ones: with probability ``1 - x`` an episode
  is easy, starting at a uniform share of the scripted expert's way: down from the start to the object with the jaw
  open, then (the object held in the closed jaws, as the grasp rule leaves it) on to the goal. Level 1 draws nothing:
  the default task bit for bit.
- ``jaw_command="switch"``: the jaw opens when ``phi > 0`` and closes otherwise (a grasp is one decision); the
  default ``"proportional"`` is the paper's ``j = (phi + 1) / 2``. A policy learnt with the switch sends -1 or 1,
  which the proportional jaw maps to the same closed or open jaw.
- ``reward_type="guided"``: the sparse reward plus the change over the step of a potential (in steps of eta): minus
  the object's distance to the goal, minus the jaws' distance to the object while it is not held, plus 5 steps'
  worth while it is held (potential-based shaping: the sparse task's optimal policies stay optimal). It is not a
  function of the goals alone, so ``compute_reward`` (HER) refuses it.

## Batched form
``gym.make_vec("dvrl_marl/PSMPick-v1", num_envs=N, vectorization_mode="vector_entry_point")`` steps N worlds as
arrays (see the batched page); world ``i`` seeded ``s`` is this environment seeded ``s + i``.

## Version History
- v1: the current version: p is the dVRK's measured_cp frame (see PSM Reach); the grasp rule senses at the jaws. A
  released object lands without sinking into the table (``scenes/pick_lnd_v1.xml``: at most 0.44 mm). Policy:
  ``pick-lnd``. (v0, never released, observed the jaw control point and let the object sink up to 6.3 mm; commit
  36a42a0 reproduces its records.) Its learning options (start levels, the switch jaw, the guided reward) leave the
  default task unchanged.
"""

from __future__ import annotations


import mujoco
import numpy as np
from gymnasium import spaces

from dvrl_marl.core.pick import carried_floor, grasp_events, pick_potential, pick_starts, simulate_free_object
from dvrl_marl.core.tools import JAW_COMMANDS, jaw_target
from dvrl_marl.envs.single_arm import PSMGoalEnv
from dvrl_marl.scene import object_id
from dvrl_marl.suction_debris.start_levels import DEFAULT, checked_level

__all__ = ["PSMPickEnv"]

#: Normalised object positions are bounded by this in the observation space (the table is smaller).
_OBJECT_BOUND = 50.0


class PSMPickEnv(PSMGoalEnv):
    """PSM Pick (see the module documentation)."""

    task_name = "psm_pick"
    reset_option_keys = ("goal", "start", "object", "level")
    reward_types = ("sparse", "dense", "guided")

    def __init__(self, *, grasp_threshold: float | None = None, start_level=DEFAULT, jaw_command: str = "proportional",
                 **kwargs):
        tool = kwargs.pop("tool", "lnd")
        if tool != "lnd":  # Pick needs the jaw
            raise ValueError(f"PSMPickEnv: tool must be 'lnd' (Pick needs the jaw of the Large Needle Driver), got {tool!r}")
        if jaw_command not in JAW_COMMANDS:
            raise ValueError(f"PSMPickEnv: jaw_command must be one of {JAW_COMMANDS}, got {jaw_command!r}")
        #: The learning options (this page's "Learning options"); the defaults are the paper's task.
        self.start_level = checked_level(start_level, "PSMPickEnv: start_level")
        self.jaw_command = jaw_command
        super().__init__(tool="lnd", grasp_threshold=grasp_threshold, **kwargs)
        self.grasp_threshold = float(self.spec_task.grasp_threshold)
        self.initial_jaw = float(self.spec_task.initial_jaw if self.spec_task.initial_jaw is not None else 1.0)
        body = object_id(self.model, "body", "object")
        joint = self.model.body_jntadr[body]
        #: Where the object's free joint lives in ``qpos`` / ``qvel``.
        self.object_qpos_address = self._object_qpos = int(self.model.jnt_qposadr[joint])
        self.object_qvel_address = self._object_qvel = int(self.model.jnt_dofadr[joint])
        geom = object_id(self.model, "geom", "object")
        #: Height (base frame) of the object's centre when it stands on the table.
        self.object_rest_height = self.table_height + float(self.model.geom_size[geom][1])
        # Goals are for the object, which the jaws carry: the box the tool point covers, on or above the table.
        drop = np.array([0.0, 0.0, self.arm.tool_point_drop])
        self.goal_low = self.workspace_low - drop
        self.goal_low[2] = max(self.goal_low[2], self.object_rest_height)
        self.goal_high = self.workspace_high - drop
        if self.spec_task.goal_distribution == "original":
            self.goal_low, self.goal_high = self._original_goal_box(tool_point=True)

        bound = np.full(3, _OBJECT_BOUND)
        tip_bound = np.full(3, self.position_bound)
        self.observation_space = spaces.Dict(
            {
                "observation": spaces.Box(
                    np.concatenate([-tip_bound, [-1.0], -bound]), np.concatenate([tip_bound, [1.0], bound]),
                    dtype=np.float64,
                ),
                "achieved_goal": spaces.Box(-bound, bound, dtype=np.float64),
                "desired_goal": spaces.Box(-bound, bound, dtype=np.float64),
            }
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.grasped = False
        self._grasp_offset = (0.0, 0.0, 0.0)
        self._object_at_rest = True
        self._object_normalised = (0.0, 0.0, 0.0)
        self._potential = 0.0

    def set_start_level(self, level) -> None:
        """The start level of later resets (a curriculum's hook; ``reset(options={"level": x})`` sets one reset's)."""
        self.start_level = checked_level(level, "PSMPickEnv.set_start_level")

    def parse_reset_options(self, options) -> dict:
        options = self._check_options(options)
        level = options.get("level")
        parsed = super().parse_reset_options({key: value for key, value in options.items() if key != "level"})
        parsed["level"] = None if level is None else checked_level(level, "PSMPickEnv: reset option 'level'")
        return parsed

    def _option_bounds(self, key: str) -> tuple:
        if key == "goal":
            return self.goal_low, self.goal_high, 0.0
        if key == "object":
            # The object may sit anywhere over the workspace on or above the table (not inside it); it need not be
            # reachable by the tool.
            return np.array([self.goal_low[0], self.goal_low[1], self.object_rest_height]), self.goal_high, None
        return super()._option_bounds(key)

    # --- object state -----------------------------------------------------------------------------------
    def object_position(self) -> np.ndarray:
        """The object's centre in the base frame (metres)."""
        return self.arm.to_base(self.data.qpos[self._object_qpos:self._object_qpos + 3])

    def _place_object(self, position_base: np.ndarray) -> None:
        adr = self._object_qpos
        self.data.qpos[adr:adr + 3] = self.arm.to_world(position_base)
        self.data.qpos[adr + 3:adr + 7] = (1.0, 0.0, 0.0, 0.0)
        self.data.qvel[self._object_qvel:self._object_qvel + 6] = 0.0

    def _update_object_normalised(self) -> None:
        adr = self._object_qpos
        self._object_normalised = self._normalised_tuple(*self.arm.base_point(*self.data.qpos[adr:adr + 3].tolist()))

    def _carry_object(self) -> None:
        tx, ty, tz = self.arm.tip_world()
        ox, oy, oz = self._grasp_offset
        adr = self._object_qpos
        self.data.qpos[adr:adr + 3] = (tx + ox, ty + oy, tz + oz)

    def _simulate_object(self) -> bool:
        """Step physics for a free, moving object. Returns False if MuJoCo went unstable (state restored)."""
        stable, at_rest = simulate_free_object(self.model, self.data, self.n_substeps, self._object_qvel)
        self._object_at_rest = self._object_at_rest or at_rest
        return stable

    # --- Gymnasium API ------------------------------------------------------------------------------------
    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        parsed = self.parse_reset_options(options)
        mujoco.mj_resetData(self.model, self.data)
        level = self.start_level if parsed["level"] is None else parsed["level"]
        start, goal, obj, held = (rows[0] for rows in pick_starts(self, [self.np_random], parsed, level))
        held = bool(held)
        self.arm.set_tip(*start.tolist())
        self.arm.set_jaw(0.0 if held else self.initial_jaw)
        self._set_goal(goal)
        self._place_object(obj)
        self.grasped = held
        self._grasp_offset = tuple((self.arm.to_world(obj) - self.arm.tip_world()).tolist()) if held else (0.0, 0.0, 0.0)
        self._object_at_rest = held or bool(obj[2] <= self.object_rest_height + 1e-9)
        self._update_object_normalised()
        self._potential = self._current_potential()
        return self._observation(), self._info(self._reward_and_success(self._object_normalised)[1])

    def _current_potential(self) -> float:
        if self.reward_type != "guided":
            return 0.0
        jaws = self.arm.to_base(self.arm.tool_point_world())
        return float(pick_potential(jaws, self.object_position(), self.goal, self.grasped, self.step_size))

    def step(self, action):
        dx, dy, dz, phi = self._read_action(action)
        eta = self.step_size
        high = self._tip_high
        low = self._tip_low
        if self.grasped:  # a carried object stays above the table
            low = (low[0], low[1], carried_floor(low[2], high[2], self.object_rest_height, self._grasp_offset[2]))
        self.arm.move(eta * dx, eta * dy, eta * dz, low, high)
        jaw = jaw_target(phi, self.jaw_command)
        self.arm.set_jaw(jaw)

        adr = self._object_qpos
        closed = jaw < self.grasp_threshold
        release = grab = False
        if closed or self.grasped:  # (open jaws holding nothing: the rule has no event to give; most steps)
            # (the sensor is read only where it can grab: it is the rule's costliest input)
            sensed = closed and not self.grasped and self.arm.grasp_sensor(self.data.qpos[adr:adr + 3])
            release, grab = grasp_events(self.grasped, closed, sensed)
        if release:
            self.grasped = False
            self._object_at_rest = False
            self.data.qvel[self._object_qvel:self._object_qvel + 6] = 0.0
        elif grab:
            self.grasped = True
            tx, ty, tz = self.arm.tip_world()
            ox, oy, oz = self.data.qpos[adr:adr + 3].tolist()
            self._grasp_offset = (ox - tx, oy - ty, oz - tz)
            self.data.qvel[self._object_qvel:self._object_qvel + 6] = 0.0

        unstable = False
        if self.grasped:
            self._carry_object()
            self._update_object_normalised()
        elif not self._object_at_rest:
            unstable = not self._simulate_object()
            self._update_object_normalised()
        # (an object at rest and not held kept its place: its normalised position stands)
        reward, success = self._reward_and_success(self._object_normalised)
        if self.reward_type == "guided":
            potential = self._current_potential()
            reward, self._potential = reward + (potential - self._potential), potential
        info = self._info(success)
        if unstable:
            info["sim_unstable"] = True
        return self._observation(), reward, False, unstable, info

    def set_state(self, *, tip, goal, jaw, object_pose, grasped=False) -> None:
        """Put the arm, goal and object (pose: world position + quaternion) where a batched world has them."""
        self.arm.set_tip(*np.asarray(tip, dtype=np.float64).tolist())
        self.arm.set_jaw(float(jaw))
        self._set_goal(np.asarray(goal, dtype=np.float64))
        self.data.qpos[self._object_qpos:self._object_qpos + 7] = object_pose
        self.grasped = bool(grasped)
        self._update_object_normalised()

    def _info(self, success: bool) -> dict:
        return {"is_success": success, "grasped": self.grasped}

    def _observation(self) -> dict:
        tip = self._normalised_tuple(*self.arm.tip)
        obj = self._object_normalised
        return {
            "observation": np.array((*tip, 2.0 * self.arm.jaw - 1.0, *obj)),
            "achieved_goal": np.array(obj),
            "desired_goal": np.array(self._goal_normalised),
        }
