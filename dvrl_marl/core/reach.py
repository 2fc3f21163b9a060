"""The batched core of PSM Reach: N worlds of :class:`dvrl_marl.envs.psm_reach.PSMReachEnv` as arrays."""

from __future__ import annotations

import math

import numpy as np

from dvrl_marl.core.arms import ArmBatch
from dvrl_marl.core.worlds import WorldRandom, check_action_batch, sample_reachable_batch, world_indices

__all__ = ["ReachCore", "GoalCoreBase", "goal_distance", "goal_reward", "position_or_sample", "reach_starts"]


def goal_distance(achieved, desired, workspace_range: float):
    """The paper's distance (m) between normalised goals, rho * ||a~ - g~||: of 3-tuples of floats (one world: a
    float) or of arrays ``(..., 3)`` (the sum written out, so that both give the same bits)."""
    if isinstance(achieved, tuple):
        dx, dy, dz = achieved[0] - desired[0], achieved[1] - desired[1], achieved[2] - desired[2]
        return workspace_range * math.sqrt(dx * dx + dy * dy + dz * dz)
    d = achieved - desired
    return workspace_range * np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1] + d[..., 2] * d[..., 2])


def goal_reward(distance, threshold: float, sparse: bool, dense_scale: float):
    """The paper's reward (Sec. III-B) and success for :func:`goal_distance`'s ``distance``: ``-1`` while it exceeds
    delta (``threshold``), else ``0``; the dense variant minus ``dense_scale`` times it. Floats or arrays alike."""
    success = distance <= threshold
    if not sparse:
        return -dense_scale * distance, success
    if isinstance(success, bool):
        return (0.0 if success else -1.0), success
    return np.where(success, 0.0, -1.0)[()], success


def position_or_sample(value, generators, tool, low, high, tool_point_drop: float) -> np.ndarray:
    """A reset option's position (metres, base frame, already checked) for every generator's world, or a reachable
    draw from each generator (``(len(generators), 3)``): tips whose tool point lies ``tool_point_drop`` below them
    (objects and goals for an object: 0)."""
    if value is not None:
        return np.broadcast_to(value, (len(generators), 3))
    return sample_reachable_batch(generators, tool, low, high, tool_point_drop)


def reach_starts(env, generators, options: dict) -> tuple[np.ndarray, np.ndarray]:
    """Where PSM Reach episodes start: the tips p_0 and the goals g, ``(len(generators), 3)`` each, from the checked
    reset ``options`` or drawn in the workspace (``env``'s boxes), p_0 then g from each generator. The single env
    (one generator, its ``np_random``) and the batched core (one per world) both reset through this, so world ``i``
    draws what the single env seeded alike draws."""
    drop = env.arm.tool_point_drop
    start = position_or_sample(options["start"], generators, env.tool, env.start_low, env.start_high, drop)
    goal = position_or_sample(options["goal"], generators, env.tool, env.goal_low, env.goal_high, drop)
    return start, goal


class GoalCoreBase:
    """What the Reach and Pick cores share: workspace, normalisation, goals, the paper's reward, episode clocks.

    Built from a single-world environment ``template`` (its validated parameters); ``max_episode_steps`` truncates
    a world's episode (the single environment's ``TimeLimit``).
    """

    action_width = 3

    def __init__(self, template, num_worlds: int, max_episode_steps: int | None):
        if int(num_worlds) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_worlds!r}")
        self.template = template
        self.num_worlds = n = int(num_worlds)
        self.name = type(template).__name__
        self.max_episode_steps = None if max_episode_steps is None else int(max_episode_steps)
        self.tool = template.tool
        self.arm = ArmBatch(self.tool, n, template.arm.base_position, template.arm.tool_point_drop)
        self.tip_low, self.tip_high = template.tip_low.copy(), template.tip_high.copy()
        self.centre = template.workspace_centre.copy()
        self.workspace_range = template.workspace_range
        self.inverse_range = 1.0 / template.workspace_range
        self.step_size = template.step_size
        self.distance_threshold = template.distance_threshold
        self.sparse = template.reward_type == "sparse"
        self.dense_scale = template.dense_scale
        self.goal = np.zeros((n, 3))
        self.goal_normalised = np.zeros((n, 3))
        self.elapsed = np.zeros(n, dtype=np.int64)
        self.random = WorldRandom(n)

    def normalise(self, position: np.ndarray) -> np.ndarray:
        """x~ = (x - p_c) / rho for base-frame positions (..., 3) (paper Eq. 2)."""
        return (position - self.centre) * self.inverse_range

    def reward_and_success(self, achieved: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The paper's reward for normalised achieved goals ``(N, 3)`` against each world's goal."""
        distance = goal_distance(achieved, self.goal_normalised, self.workspace_range)
        return goal_reward(distance, self.distance_threshold, self.sparse, self.dense_scale)

    def worlds_of(self, worlds) -> np.ndarray:
        return world_indices(worlds, self.num_worlds, self.name)

    def read_actions(self, actions) -> np.ndarray:
        return check_action_batch(actions, self.num_worlds, self.action_width, self.name)

    def reset(self, worlds=None, *, seed=None, options=None) -> None:
        """Reset ``worlds`` (all by default); ``seed`` re-seeds every world's stream first (see WorldRandom)."""
        if seed is not None:
            self.random.seed(seed)
        parsed = self.template.parse_reset_options(options)
        indices = self.worlds_of(worlds)
        if len(indices) == 0:
            return
        self._reset_worlds(indices, [self.random[i] for i in indices.tolist()], parsed)
        self.goal_normalised[indices] = self.normalise(self.goal[indices])
        self.elapsed[indices] = 0

    def _reset_worlds(self, worlds: np.ndarray, generators: list, options: dict) -> None:
        """Draw new episodes for ``worlds`` (each from its own generator, in the single env's order)."""
        raise NotImplementedError

    def truncation(self) -> np.ndarray:
        if self.max_episode_steps is None:
            return np.zeros(self.num_worlds, dtype=bool)
        return self.elapsed >= self.max_episode_steps


class ReachCore(GoalCoreBase):
    """N worlds of PSM Reach. ``step`` returns ``(reward, terminated, truncated, success)`` arrays of shape (N,)."""

    def _reset_worlds(self, worlds, generators, options) -> None:
        start, self.goal[worlds] = reach_starts(self.template, generators, options)
        self.arm.set_tips(worlds, start)

    def __init__(self, template, num_worlds: int, max_episode_steps: int | None):
        super().__init__(template, num_worlds, max_episode_steps)
        self.tip_normalised = np.zeros((self.num_worlds, 3))

    def reset(self, worlds=None, *, seed=None, options=None) -> None:
        super().reset(worlds, seed=seed, options=options)
        self.tip_normalised = self.normalise(self.arm.tip)

    def achieved_goal(self) -> np.ndarray:
        """p~ of every world, normalised once per step (reward and observation share it)."""
        return self.tip_normalised

    def observation(self) -> dict:
        tip = self.tip_normalised
        return {"observation": tip.copy(), "achieved_goal": tip.copy(), "desired_goal": self.goal_normalised.copy()}

    def success(self) -> np.ndarray:
        return self.reward_and_success(self.achieved_goal())[1]

    def step(self, actions):
        delta = self.read_actions(actions)
        self.arm.move(self.step_size * delta, self.tip_low, self.tip_high)
        self.elapsed += 1
        self.tip_normalised = self.normalise(self.arm.tip)
        reward, success = self.reward_and_success(self.tip_normalised)
        return reward, np.zeros(self.num_worlds, dtype=bool), self.truncation(), success

    def info(self, success: np.ndarray) -> dict:
        return {"is_success": success}

    def world_state(self, world: int) -> dict:
        """World ``world``'s state as the single environment's ``set_state`` takes it."""
        return {"tip": self.arm.tip[world].copy(), "goal": self.goal[world].copy()}
