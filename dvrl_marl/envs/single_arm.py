"""What PSM Reach and PSM Pick share: the paper's workspace, normalisation, eta steps and sparse reward.

Subclasses define the task-specific state (an object for Pick), their spaces and their reset distribution. The
arm is kinematic (paper Sec. III-A): a step moves the tip by ``eta * Delta`` through the closed-form IK; no MuJoCo
call is made unless a free object needs physics or a frame is rendered.
"""

from __future__ import annotations

import math

import gymnasium as gym
import mujoco
import numpy as np

from dvrl_marl import kinematics
from dvrl_marl.arm import Arm
from dvrl_marl.core.reach import goal_distance, goal_reward
from dvrl_marl.rendering import RENDER_MODES, SceneRenderer, render_modes_here
from dvrl_marl.scene import geom_top, load_model, object_id
from dvrl_marl.task import TaskSpec, load_task

__all__ = ["PSMGoalEnv"]

class PSMGoalEnv(gym.Env):
    """Base class of the single-arm goal environments (see :class:`PSMReachEnv` and :class:`PSMPickEnv`)."""

    # Every mode (gym.make reads the class: "human" stays ours, never Gymnasium's HumanRendering); each instance
    # advertises what this machine can show (render_modes_here).
    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 50}
    #: Name of the task file in ``tasks/`` holding the defaults.
    task_name: str = ""
    #: Reset options this environment accepts (positions in metres, base frame).
    reset_option_keys: tuple[str, ...] = ("goal", "start")
    #: The rewards this environment computes (the paper's sparse one and its dense variant).
    reward_types: tuple[str, ...] = ("sparse", "dense")

    def __init__(
        self,
        *,
        tool: str = "lnd",
        reward_type: str = "sparse",
        render_mode: str | None = None,
        workspace_centre=None,
        workspace_range: float | None = None,
        step_size: float | None = None,
        distance_threshold: float | None = None,
        tip_clearance: float | None = None,
        control_dt: float | None = None,
        task: str | None = None,
        tip_frame: str = "tool_point",
        width: int = 640,
        height: int = 480,
        **task_overrides,
    ):
        if reward_type not in self.reward_types:
            raise ValueError(f"{type(self).__name__}: reward_type must be one of {self.reward_types}, got {reward_type!r}")
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(f"{type(self).__name__}: render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
        # What this machine can show, and the mode asked for (Gymnasium's checker holds an env to its own mode; a
        # window that cannot open says so when it is first needed).
        here = render_modes_here(RENDER_MODES)
        self.metadata = {**self.metadata, "render_modes": here + ([render_mode] if render_mode not in here + [None]
                                                                  else [])}
        spec = load_task(task or self.task_name).with_overrides(
            workspace_centre=None if workspace_centre is None else tuple(float(v) for v in workspace_centre),
            workspace_range=workspace_range,
            step_size=step_size,
            distance_threshold=distance_threshold,
            tip_clearance=tip_clearance,
            control_dt=control_dt,
            **task_overrides,
        ).validate()
        if tool not in spec.scenes:
            raise ValueError(f"{type(self).__name__}: tool must be one of {sorted(spec.scenes)}, got {tool!r}")
        self.spec_task: TaskSpec = spec
        self.tool = kinematics.get_tool(tool)
        self.reward_type = reward_type
        self.render_mode = render_mode

        # The paper's parameters, as plain floats for the step path.
        self.workspace_centre = np.array(spec.workspace_centre, dtype=np.float64)
        self.workspace_range = float(spec.workspace_range)
        self.step_size = float(spec.step_size)
        self.distance_threshold = float(spec.distance_threshold)
        self._centre = tuple(spec.workspace_centre)
        self._inv_range = 1.0 / self.workspace_range

        self.model = load_model(spec.scenes[tool])
        self.data = mujoco.MjData(self.model)
        #: Which point of the tool p is: "tool_point" or the dVRK's "measured_cp" (registered); see dvrl_marl.kinematics.
        self.tip_frame = tip_frame
        self.arm = Arm(self.model, self.data, "psm/", self.tool, tip_frame=tip_frame)
        if not np.allclose(self.arm.base_rotation[:, 2], (0.0, 0.0, 1.0)):
            raise ValueError("single-arm scenes need an upright PSM base (the table is a floor in its frame)")
        self.dt = float(spec.control_dt)
        self.n_substeps = max(1, round(self.dt / self.model.opt.timestep))
        #: Table top height in the base frame; the tool point stays ``tip_clearance`` above it.
        self.table_height = geom_top(self.model, "table") - float(self.arm.base_position[2])
        reach = self.workspace_range + spec.workspace_margin
        low = self.workspace_centre - reach
        high = self.workspace_centre + reach
        low[2] = max(low[2], self.table_height + spec.tip_clearance + self.arm.tool_point_drop)
        if low[2] >= high[2]:
            raise ValueError(f"the workspace lies entirely below the table (tip floor {low[2]:.4f} m)")
        #: The tip's allowed box (base frame): the paper's p_c +/- rho (+ ``workspace_margin``), floored above the
        #: table; ``workspace_low``/``workspace_high``: the same without the margin (where starts and goals lie).
        self.tip_low, self.tip_high = low, high
        margin = np.full(3, spec.workspace_margin)
        self.workspace_low, self.workspace_high = np.maximum(low, self.workspace_centre - self.workspace_range), high - margin
        self._tip_low, self._tip_high = tuple(low.tolist()), tuple(high.tolist())
        self.dense_scale = float(spec.dense_scale)
        #: Observed positions stay within this many rho of p_c (1 unless ``workspace_margin`` widens the box).
        self.position_bound = 1.0 + spec.workspace_margin / self.workspace_range + 1e-9
        if not self.arm.reachable(*self.workspace_centre.tolist()):
            raise ValueError(f"the workspace centre {spec.workspace_centre} is outside the {tool} joint limits")
        self._goal_mocap = self.model.body_mocapid[object_id(self.model, "body", "goal")]
        self.goal = np.zeros(3)
        self._goal_normalised = (0.0, 0.0, 0.0)
        self._renderer = SceneRenderer(self.model, self.data, render_mode, width=width, height=height)

    # --- helpers for subclasses ---------------------------------------------------------------------------
    def normalise(self, position) -> np.ndarray:
        """p~ = (p - p_c) / rho (paper Eq. 2), for base-frame positions (..., 3)."""
        return (np.asarray(position, dtype=np.float64) - self.workspace_centre) * self._inv_range

    def denormalise(self, normalised) -> np.ndarray:
        """Inverse of :meth:`normalise`."""
        return np.asarray(normalised, dtype=np.float64) * self.workspace_range + self.workspace_centre

    def _normalised_tuple(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        c, k = self._centre, self._inv_range
        return ((x - c[0]) * k, (y - c[1]) * k, (z - c[2]) * k)

    def _read_action(self, action) -> list[float]:
        """Validate an action and return it as clipped Python floats."""
        try:
            array = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{type(self).__name__}: action {action!r} is not numeric") from error
        if array.shape != self.action_space.shape:
            raise ValueError(
                f"{type(self).__name__}: action must have shape {self.action_space.shape}, got {array.shape}"
            )
        values = array.tolist()
        for value in values:
            if not math.isfinite(value):
                raise ValueError(f"{type(self).__name__}: action {values} contains NaN or inf")
        return [-1.0 if v < -1.0 else 1.0 if v > 1.0 else v for v in values]

    def _original_goal_box(self, tool_point: bool) -> tuple[np.ndarray, np.ndarray]:
        """The original code's goal box: x, y within p_c +/- rho, z from ``original_goal_floor`` above the table up
        rho more; for the end effector it measured (``tool_point=False``: the dVRK's measured_cp, converted to this
        env's p), or for an object (``tool_point=True``)."""
        floor = self.table_height + self.spec_task.original_goal_floor
        if not tool_point:
            floor -= self.tool.measured_cp_to_tool_point - self.arm.tool_point_drop
        low = self.workspace_centre - self.workspace_range
        high = self.workspace_centre + self.workspace_range
        low[2], high[2] = floor, floor + self.workspace_range
        return low, high

    def _position_option(self, options: dict, key: str, low, high, reach_drop: float | None) -> np.ndarray | None:
        """A position reset option in metres (base frame), checked against [low, high] and, unless ``reach_drop``
        is None, the arm's reach (a point ``reach_drop`` above the tool point must be reachable as the tip)."""
        if key not in options or options[key] is None:
            return None
        try:
            value = np.asarray(options[key], dtype=np.float64)
        except (TypeError, ValueError) as error:
            raise ValueError(f"{type(self).__name__}: reset option {key!r} must be 3 numbers (m)") from error
        if value.shape != (3,) or not np.all(np.isfinite(value)):
            raise ValueError(f"{type(self).__name__}: reset option {key!r} must be 3 finite numbers (m), got {options[key]!r}")
        tolerance = 1e-12
        if np.any(value < np.asarray(low) - tolerance) or np.any(value > np.asarray(high) + tolerance):
            raise ValueError(
                f"{type(self).__name__}: reset option {key!r} = {value.tolist()} is outside "
                f"[{np.asarray(low).tolist()}, {np.asarray(high).tolist()}] (base frame, m)"
            )
        value = np.clip(value, low, high)
        if reach_drop is not None and not kinematics.within_limits(self.tool, value - (0.0, 0.0, reach_drop)):
            raise ValueError(f"{type(self).__name__}: reset option {key!r} = {value.tolist()} is not reachable by the arm")
        return value

    def parse_reset_options(self, options) -> dict:
        """Validate reset ``options`` and return each position option in metres (base frame), or None if absent.

        The vector environments call this too, so a single and a batched reset accept exactly the same options.
        """
        options = self._check_options(options)
        return {key: self._position_option(options, key, *self._option_bounds(key)) for key in self.reset_option_keys}

    def _option_bounds(self, key: str) -> tuple:
        """(low, high, reach_drop) for a position reset option (see :meth:`_position_option`)."""
        return self.tip_low, self.tip_high, self.arm.tool_point_drop

    def _check_options(self, options) -> dict:
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise ValueError(f"{type(self).__name__}: reset options must be a dict, got {type(options).__name__}")
        unknown = set(options) - set(self.reset_option_keys)
        if unknown:
            raise ValueError(
                f"{type(self).__name__}: unknown reset option(s) {sorted(unknown)}; expected {list(self.reset_option_keys)}"
            )
        return options

    def _set_goal(self, goal: np.ndarray) -> None:
        self.goal = goal.copy()
        self._goal_normalised = self._normalised_tuple(*goal.tolist())
        self.data.mocap_pos[self._goal_mocap] = self.arm.to_world(goal)

    def _reward_and_success(self, achieved: tuple[float, float, float]) -> tuple[float, bool]:
        # (the paper's reward, written once: core.reach; the guided reward adds its potential's change to it)
        distance = goal_distance(achieved, self._goal_normalised, self.workspace_range)
        return goal_reward(distance, self.distance_threshold, self.reward_type != "dense", self.dense_scale)

    # --- Gymnasium API ------------------------------------------------------------------------------------
    def compute_reward(self, achieved_goal, desired_goal, info) -> np.ndarray:
        """The paper's reward for (batches of) normalised goals: -1 while rho*||a~ - g~|| > delta, else 0.

        Dense variant: minus the distance in metres. Shapes ``(..., 3)`` give rewards of shape ``(...)``.
        """
        if self.reward_type == "guided":  # HER would relabel it wrongly: the potential reads the jaws, not the goals
            raise ValueError(f"{type(self).__name__}: reward_type='guided' is not a function of the goals alone (its "
                             "potential reads the jaws and the grasp), so compute_reward cannot relabel it; HER needs "
                             "reward_type='sparse' or 'dense'")
        achieved, desired = (np.asarray(goal, dtype=np.float64) for goal in (achieved_goal, desired_goal))
        distance = goal_distance(achieved, desired, self.workspace_range)
        return goal_reward(distance, self.distance_threshold, self.reward_type == "sparse", self.dense_scale)[0]

    def render(self):
        return self._renderer.render()

    @property
    def window(self):
        """``render_mode="human"``: the scene's window (:class:`dvrl_marl.viewer.ViewerWindow`); None otherwise."""
        return self._renderer.viewer

    def close(self):
        self._renderer.close()
