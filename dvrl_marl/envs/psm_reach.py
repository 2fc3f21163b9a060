"""PSM Reach: move the tool tip of a dVRK PSM to a goal position (paper Sec. III-B).

## Description
A single Patient Side Manipulator holds an EndoWrist pointing down. The agent moves the end effector, position
p in the PSM base (remote centre of motion) frame, towards a goal g. In ``PSMReach-v1`` p is the frame the dVRK
itself reports and commands (``measured_cp`` / ``servo_cp``: the wrist-yaw frame origin, 10.2 mm behind the jaw
control point), as in the original dVRL code whose p_c the task uses, so targets go to the robot unconverted
(:mod:`dvrl_marl.frames`); ``tip_frame="tool_point"`` makes p the tool point itself (jaw control point / tube tip).
As in the paper the arm is kinematic: every step sets new joint values by inverse kinematics, the way the dVRK takes new set points at 50 Hz. The policy
uses only the tip position, so it runs on any EndoWrist: ``tool="lnd"`` (Large Needle Driver) or
``tool="suction_irrigation"``.

## Action Space
``Box(-1, 1, (3,), float32)``: Delta. The tip moves by ``p <- p + eta * Delta`` (eta = 1 mm), then is
projected back into the workspace box, above the table and within the joint limits. Values outside [-1, 1] are
clipped; NaN/inf or a wrong shape raise ``ValueError``.

## Observation Space
``Dict`` of ``float64`` Boxes, positions normalised as in the paper, x~ = (x - p_c) / rho:

| key | shape | content |
|---|---|---|
| ``observation`` | (3,) | p~, the tip |
| ``achieved_goal`` | (3,) | p~ |
| ``desired_goal`` | (3,) | g~ |

## Rewards
Sparse (``PSMReach-v1``): ``-1`` while ``rho * ||p~ - g~|| > delta`` (delta = 3 mm), else ``0``. Dense
(``PSMReachDense-v1``): minus the distance in metres. ``compute_reward`` is vectorised for HER.

## Starting State
p_0 and g uniform in the reachable workspace: the box p_c +/- rho (p_c = (0, 0, -0.11) m, rho = 5 cm) above the
table (the tool point stays 3 mm above it: the start box's floor is 13.2 mm above the table top, and p = p_c
puts the tool point 3.2 mm above it, as in the original code) and within the joint limits. ``reset(options={"start": ..., "goal": ...})``
sets either in metres (base frame).

## Episode End
No termination (the paper); ``max_episode_steps=100`` truncates. ``info["is_success"]`` reports the goal.

## Arguments
``tool``, ``reward_type`` ("sparse" | "dense"), ``tip_frame`` ("measured_cp", registered; or "tool_point"),
``render_mode`` ("rgb_array" | "depth_array" | "human"), and the
paper's parameters ``workspace_centre``, ``workspace_range`` (rho), ``step_size`` (eta), ``distance_threshold``
(delta), ``control_dt``, ``tip_clearance``; defaults in ``tasks/psm_reach.toml``.

## Batched form
``gym.make_vec("dvrl_marl/PSMReach-v1", num_envs=N, vectorization_mode="vector_entry_point")`` steps N worlds as
arrays (see the batched page); world ``i`` seeded ``s`` is this environment seeded ``s + i``.

## Version History
- v1: the current version: p is the dVRK's measured_cp frame (wrist-yaw origin), as on the robot and in the
  original code. Policies: ``reach-lnd``, ``reach-suction-irrigation``. (v0, never released, observed the tool point;
  commit 36a42a0 reproduces its records.)
"""

from __future__ import annotations

import numpy as np
from gymnasium import spaces

from dvrl_marl.core.reach import reach_starts
from dvrl_marl.envs.single_arm import PSMGoalEnv

__all__ = ["PSMReachEnv"]


class PSMReachEnv(PSMGoalEnv):
    """PSM Reach (see the module documentation)."""

    task_name = "psm_reach"
    reset_option_keys = ("goal", "start")

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        spec = self.spec_task
        #: Where p_0 and g are drawn (uniformly, reachable ones only): the workspace (the paper), or the original
        #: code's p_0 = p_c and goal box (``start_distribution`` / ``goal_distribution="original"``).
        self.start_low, self.start_high = self.workspace_low, self.workspace_high
        if spec.start_distribution == "original":
            self.start_low = self.start_high = self.workspace_centre.copy()
        self.goal_low, self.goal_high = self.workspace_low, self.workspace_high
        if spec.goal_distribution == "original":
            self.goal_low, self.goal_high = self._original_goal_box(tool_point=False)
        bound = np.full(3, max(self.position_bound, float(np.max(np.abs(self.normalise(self.goal_low)))),
                               float(np.max(np.abs(self.normalise(self.goal_high))))))
        position = spaces.Box(-bound, bound, dtype=np.float64)
        self.observation_space = spaces.Dict(
            {"observation": position, "achieved_goal": position, "desired_goal": position}
        )
        self.action_space = spaces.Box(-1.0, 1.0, shape=(3,), dtype=np.float32)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        start, goal = (rows[0] for rows in reach_starts(self, [self.np_random], self.parse_reset_options(options)))
        self.arm.set_tip(*start.tolist())
        self._set_goal(goal)
        tip = self._normalised_tuple(*self.arm.tip)
        return self._observation(tip), {"is_success": self._reward_and_success(tip)[1]}

    def step(self, action):
        dx, dy, dz = self._read_action(action)
        eta = self.step_size
        self.arm.move(eta * dx, eta * dy, eta * dz, self._tip_low, self._tip_high)
        tip = self._normalised_tuple(*self.arm.tip)
        reward, success = self._reward_and_success(tip)
        return self._observation(tip), reward, False, False, {"is_success": success}

    def set_state(self, *, tip, goal) -> None:
        """Put the tip and goal (metres, base frame) where a batched world has them, e.g. to render that world."""
        self.arm.set_tip(*np.asarray(tip, dtype=np.float64).tolist())
        self._set_goal(np.asarray(goal, dtype=np.float64))

    def _observation(self, tip) -> dict:
        return {
            "observation": np.array(tip),
            "achieved_goal": np.array(tip),
            "desired_goal": np.array(self._goal_normalised),
        }
