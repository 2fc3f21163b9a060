"""Stage machinery of :mod:`dvrl_marl.pipeline`.

A pipeline file (TOML) has one table per arm::

    [grasper]
    for_each = "debris"                # "cavity", "debris" or "none": the items the stages repeat for
    stages = [                         # run in order for each item
      { type = "reach", policy = "reach-lnd", target = "above_debris", height = 0.0204 },
      { type = "pick", policy = "pick-lnd-scratch", lift = 0.015 },
      { type = "reach", policy = "reach-lnd", target = "handoff", carry = true },
      { type = "release" },
    ]
    idle = [ { type = "reach", policy = "reach-lnd", target = "home" } ]   # while no item is ready
    finally = [ ... ]                                                    # after the last item

Stage types: ``reach`` (a Reach policy to a named target), ``pick`` (a Pick policy: grasp the item's debris and
lift it), ``suck`` (valve open, following the surface down to the floor, until the item's cavity is clear), ``release`` (open the jaw), and
``teleop`` (a device drives until its ``until`` condition). ``policy`` is a shipped policy name, an exported
policy folder, or ``"scripted"`` (the Meta-World-style experts). Targets: ``above_cavity``, ``cavity_floor``,
``above_debris``, ``handoff``, ``home``, ``park``; ``height`` lifts a target (metres); a reach stage hands over
within ``tolerance`` (metres, 1.5 x the scene's delta by default) of its target; ``precision = k`` runs its policy in
a frame k times smaller, with k times smaller steps, for positioning finer than the policy's own delta. Reach policies know no obstacles,
so a reach stage whose path would skim the phantom goes through waypoints: up to a safe height, across, down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import gymnasium as gym
import numpy as np

import dvrl_marl  # noqa: F401  (registers the single-arm environments)
from dvrl_marl import policies
from dvrl_marl.agents.experts import PickExpert, ReachExpert
from dvrl_marl.core import tools
from dvrl_marl.schemas import STRICT, Finite, Flag, NonNegative, Positive, PositiveInt, Text
from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.scripted_team import burst_valve
from dvrl_marl.task import load_task

__all__ = ["StageSpec", "RecentredFrame", "ArmPipeline", "load_pipeline", "available_pipelines"]

_SPECS = Path(__file__).resolve().parent / "specs"
_STAGE_TYPES = ("reach", "pick", "suck", "release", "teleop")
_TARGETS = ("above_cavity", "cavity_floor", "above_debris", "handoff", "home", "park")
_UNTIL = ("cavity_clear", "delivered", "held", "steps")
#: Reach stages travel this high above the phantom top (m) when their path would skim it.
_SAFE_HEIGHT = 0.01
#: Longest leg a reach stage hands to its policy (m).
_MAX_LEG = 0.01
#: Where the arms wait (world offsets from their RCM, metres): out of each other's way, above the phantom.
_HOME_OFFSET = {"grasper": (-0.015, 0.02, -0.08), "suction": (0.005, 0.0, -0.08)}


@dataclass(frozen=True)
class StageSpec:
    """One stage of a pipeline (see the module documentation). The annotations are the stage's schema: pydantic
    checks a spec file's stages against them (:meth:`from_dict`), the rules between fields follow."""

    __pydantic_config__ = STRICT

    type: Text
    policy: Text = "scripted"
    target: Text | None = None
    height: Finite = 0.0  # m above the target
    lift: NonNegative = 0.015
    carry: Flag = False
    valve: Text = "off"  # suction reach stages: "off", "on", or "inside" (open once inside the cavity)
    jaw: Text = "open"  # grasper reach stages: "open" or "closed"
    until: Text = "steps"  # teleop stages
    steps: PositiveInt = 50  # teleop "steps" condition
    device: Text | None = None
    timeout: PositiveInt = 400  # steps before the stage hands over (a pick or carry that lost its debris starts over)
    tolerance: Positive | None = None  # reach: hand over within this distance (m); default 1.5 x the scene's delta
    precision: Finite = 1.0  # reach: shrink the policy's frame (and its steps) by this factor for finer positioning

    def __post_init__(self):
        if self.type not in _STAGE_TYPES:
            raise ValueError(f"stage type must be one of {_STAGE_TYPES}, got {self.type!r}")
        if self.type == "reach" and self.target not in _TARGETS:
            raise ValueError(f"reach stage needs a target in {_TARGETS}, got {self.target!r}")
        if self.valve not in ("off", "on", "inside") or self.jaw not in ("open", "closed"):
            raise ValueError(f"stage valve/jaw settings invalid: valve={self.valve!r}, jaw={self.jaw!r}")
        if self.until not in _UNTIL:
            raise ValueError(f"teleop 'until' must be one of {_UNTIL}, got {self.until!r}")
        if self.type == "teleop" and not self.device:
            raise ValueError("a teleop stage needs a device name")
        if not self.precision >= 1.0:
            raise ValueError(f"stage precision must be >= 1, got {self.precision}")
        if self.timeout < 1:
            raise ValueError(f"stage timeout must be >= 1, got {self.timeout}")

    @classmethod
    def from_dict(cls, table: dict, source: str = "pipeline stage", where: str | None = None) -> "StageSpec":
        """A stage from a spec file's table, checked against the schema; errors name ``source`` and ``where``."""
        from dvrl_marl.schemas import validated

        if not isinstance(table, dict):
            raise ValueError(f"{source}: [{where}] must be a table of stage settings, got {table!r}")
        known = {f.name for f in fields(cls)}
        unknown = set(table) - known
        if unknown:
            raise ValueError(f"{source}: [{where}] unknown stage key(s) {sorted(unknown)}; known: {sorted(known)}")
        try:
            return validated(cls, table, source, table=where)
        except ValueError as error:
            raise ValueError(str(error)) from None


@dataclass(frozen=True)
class ArmPlan:
    for_each: str
    stages: tuple[StageSpec, ...]
    idle: tuple[StageSpec, ...] = ()
    final: tuple[StageSpec, ...] = field(default=())


class RecentredFrame:
    """A single-arm policy's normalised frame placed anywhere: x~ = (x - centre) / workspace_range."""

    def __init__(self, centre, workspace_range: float):
        self.centre = np.asarray(centre, dtype=np.float64)
        self.workspace_range = float(workspace_range)

    def normalise(self, position) -> np.ndarray:
        return (np.asarray(position, dtype=np.float64) - self.centre) / self.workspace_range


def available_pipelines() -> list[str]:
    return sorted(p.stem for p in _SPECS.glob("*.toml"))


def load_pipeline(name_or_path) -> dict[str, ArmPlan]:
    """Read a pipeline file (a shipped name such as ``"learned_team"`` or a path) into per-arm plans."""
    path = Path(name_or_path)
    if path.suffix != ".toml":
        path = _SPECS / f"{name_or_path}.toml"
    if not path.is_file():
        raise FileNotFoundError(f"no pipeline {name_or_path!r}; shipped: {available_pipelines()}")
    from dvrl_marl.files import read_toml

    table = read_toml(path)
    plans = {}
    for arm, spec in table.items():
        if arm not in ("suction", "grasper"):
            raise ValueError(f"{path}: unknown arm {arm!r}; expected 'suction' or 'grasper'")
        if not isinstance(spec, dict):
            raise ValueError(f"{path}: [{arm}] must be a table (for_each, stages, idle, finally), got {spec!r}")
        unknown = set(spec) - {"for_each", "stages", "idle", "finally"}
        if unknown:
            raise ValueError(f"{path}: unknown key(s) {sorted(unknown)} for arm {arm!r}")
        for_each = spec.get("for_each", "none")
        if for_each not in ("cavity", "debris", "none"):
            raise ValueError(f"{path}: for_each must be 'cavity', 'debris' or 'none', got {for_each!r}")
        stages = {key: tuple(StageSpec.from_dict(stage, str(path), f"{arm}.{key}[{index}]")
                             for index, stage in enumerate(spec.get(key, [])))
                  for key in ("stages", "idle", "finally")}
        plans[arm] = ArmPlan(for_each=for_each, stages=stages["stages"], idle=stages["idle"], final=stages["finally"])
    return plans


def pipeline_policies(name_or_path) -> set[str]:
    """The shipped (or exported) policies a pipeline's stages name: what must be there for it to run learned."""
    return {stage.policy for plan in load_pipeline(name_or_path).values()
            for stage in (*plan.stages, *plan.idle, *plan.final) if stage.policy != "scripted"}


class _StagePolicy:
    """A single-arm policy with the frame it was trained in (range rho, step eta, the box its states covered, and
    which point of the tool its p is: ``tool_point_drop`` above the scene's tool point, 10.2 mm for the measured_cp frame)."""

    def __init__(self, kind: str, name: str):
        task = load_task("psm_reach" if kind == "reach" else "psm_pick")
        policy = None if name == "scripted" else policies.load(name)
        default_id = "dvrl_marl/PSMReach-v1" if kind == "reach" else "dvrl_marl/PSMPick-v1"
        if policy is None:  # the scripted experts plan at the tool point itself (no drop to the jaws)
            env = gym.make(default_id, tip_frame="tool_point").unwrapped
        else:
            env = gym.make(policy.spec.get("env_id", default_id)).unwrapped
        # The table cuts the training box (Reach: z~ in [-0.21, 1]); legs are centred on what the policy has seen.
        self.trained_box_centre = (env.normalise(env.tip_low) + env.normalise(env.tip_high)) / 2
        self.tool_point_drop = env.arm.tool_point_drop
        env.close()
        if policy is None:
            self.workspace_range, self.step_size = task.workspace_range, task.step_size
            gain = self.workspace_range / self.step_size
            self.act = ReachExpert(gain) if kind == "reach" else PickExpert(gain, 0.001 / self.workspace_range)
        else:
            self.workspace_range = float(policy.spec.get("workspace_range", task.workspace_range))
            self.step_size = float(policy.spec.get("step_size", task.step_size))
            self.act = policy


class ArmPipeline:
    """Runs one arm's plan on the collaborative env's observations: ``pipeline(observation) -> action``.

    It can fill the env's surgeon seat (it is a callable) or drive an agent. ``devices`` maps names used by
    teleop stages to :mod:`dvrl_marl.teleop` devices.
    """

    def __init__(self, plan: ArmPlan, agent: str, env, devices: dict | None = None):
        unwrapped = getattr(env, "unwrapped", env)
        self.plan, self.agent = plan, agent
        self.layout = unwrapped.layout()
        self.slices = unwrapped.observation_layout
        self.scene_centre = np.asarray(unwrapped.workspace_centre, dtype=np.float64)
        self.scene_range = float(unwrapped.workspace_range)
        self.scene_step = float(unwrapped.params.step_size)
        self.delta = float(unwrapped.params.distance_threshold)
        self.base = self._world(self.layout.base_positions[agent])
        # a scene that irrigates: the suck stage irrigates clots in bursts, and a shut valve is 0 (-1 irrigates)
        self.irrigates = agent == "suction" and bool(getattr(self.layout, "irrigates", False))
        self.shut = tools.shut_command(self.irrigates)
        self.devices = dict(devices or {})
        self._policies: dict[tuple[str, str], _StagePolicy] = {}
        for stage in plan.stages + plan.idle + plan.final:
            if stage.type in ("reach", "pick"):
                self._policy(stage)
            if stage.type == "teleop" and stage.device not in self.devices:
                raise ValueError(f"teleop stage needs device {stage.device!r}; pass devices={{...}}")
        self.log: list[tuple[int, str]] = []  # (step, "stage started/ended ...") of the current episode
        self.reset()

    @classmethod
    def from_file(cls, pipeline, agent: str, env, devices: dict | None = None) -> "ArmPipeline":
        plans = load_pipeline(pipeline)
        if agent not in plans:
            raise ValueError(f"pipeline {pipeline!r} has no plan for {agent!r}")
        return cls(plans[agent], agent, env, devices)

    # --- bookkeeping --------------------------------------------------------------------------------------
    def reset(self) -> None:
        self.item: int | None = None
        self.done_items: set[int] = set()
        self.sequence: tuple[StageSpec, ...] = ()
        self.stage_index = 0
        self.stage_steps = 0
        self.stage_goal = None
        self.frame = None
        self.steps = 0
        self.mode = "start"  # "item", "idle", "final"
        self.tool = 1.0 if self.agent == "grasper" else self.shut
        self.timeouts = 0
        self.log.clear()
        for device in self.devices.values():
            device.reset()

    def _policy(self, stage: StageSpec) -> _StagePolicy:
        key = (stage.type, stage.policy)
        if key not in self._policies:
            self._policies[key] = _StagePolicy(stage.type, stage.policy)
        return self._policies[key]

    def _world(self, normalised) -> np.ndarray:
        return np.asarray(normalised, dtype=np.float64) * self.scene_range + self.scene_centre

    def _parse(self, observation) -> dict:
        obs = np.asarray(observation, dtype=np.float64)
        debris = obs[self.slices["debris"]].reshape(-1, layout.PIN_WIDTH)
        return {
            "tip": self._world(obs[self.slices["own_tip"]]),
            "tool": float(obs[self.slices["own_tool"]][0]),
            "blood": obs[self.slices["blood"]],
            "debris_position": self._world(debris[:, layout.PIN_POSITION]),
            "visible": debris[:, layout.PIN_VISIBLE] > 0.5, "held": debris[:, layout.PIN_HELD] > 0.5,
            "delivered": debris[:, layout.PIN_DELIVERED] > 0.5,
            "handoff": self._world(obs[self.slices["handoff"]]),
        }

    # --- items ----------------------------------------------------------------------------------------------
    def _cavity_clear(self, state, cavity: int) -> bool:
        return state["blood"][cavity] < self.layout.blood_threshold_fraction[cavity] or state["blood"][cavity] <= 0

    def _cavity_of(self, position) -> int:
        centres = [self._world((cx, cy, 0.0))[:2] for cx, cy in self.layout.cavity_centres]
        return int(np.argmin([np.hypot(*(position[:2] - c)) for c in centres]))

    def _item_done(self, state, item: int) -> bool:
        if self.plan.for_each == "cavity":
            return self._cavity_clear(state, item)
        return bool(state["delivered"][item])

    def _next_item(self, state) -> int | None:
        if self.plan.for_each == "cavity":
            centres = [self._world((cx, cy, 0.0)) for cx, cy in self.layout.cavity_centres]
            order = np.argsort([-np.hypot(*(c[:2] - self.base[:2])) for c in centres])  # farthest first
            for cavity in order:
                if not self._cavity_clear(state, int(cavity)):
                    return int(cavity)
            return None
        if self.plan.for_each == "debris":
            held = np.flatnonzero(state["held"])
            if len(held):
                return int(held[0])
            ready = [i for i in range(len(state["visible"]))
                     if state["visible"][i] and not state["delivered"][i]
                     and self._cavity_clear(state, self._cavity_of(state["debris_position"][i]))]
            if not ready:
                return None
            return min(ready, key=lambda i: np.linalg.norm(state["debris_position"][i] - state["tip"]))
        return None

    def _all_items_done(self, state) -> bool:
        if self.plan.for_each == "cavity":
            return all(self._cavity_clear(state, c) for c in range(len(state["blood"])))
        if self.plan.for_each == "debris":
            return bool(np.all(state["delivered"]))
        return True

    def _start_sequence(self, mode: str, sequence, state) -> None:
        self.mode, self.sequence, self.stage_index = mode, tuple(sequence), 0
        self._start_stage(state)

    def _start_stage(self, state) -> None:
        self.stage_steps = 0
        self.stage_goal = None
        self.frame = None
        if self.stage_index < len(self.sequence):
            stage = self.sequence[self.stage_index]
            self.log.append((self.steps, f"start {self.mode} stage {self.stage_index} {stage.type} item={self.item}"))
            if stage.type == "reach":
                self.stage_goal = self._target(stage, state)
                if stage.carry and self.item is not None and state["held"][self.item]:
                    # Move the tip so that the carried debris, not the tip, reaches the target.
                    self.stage_goal = self.stage_goal - (state["debris_position"][self.item] - state["tip"])
                self.waypoints = self._waypoints(state["tip"], self.stage_goal, stage)
                self._start_leg(state["tip"], stage)
            elif stage.type == "pick":
                policy = self._policy(stage)
                pin = state["debris_position"][self.item]
                # Pick was trained with the object 20.4 mm below the workspace centre: re-centre on that.
                drop = stage.height or 0.0204
                self.frame = RecentredFrame(pin + (0.0, 0.0, drop), policy.workspace_range)
                self.stage_goal = pin + (0.0, 0.0, stage.lift)

    def _waypoints(self, tip, goal, stage: StageSpec) -> list[np.ndarray]:
        """Reach policies know no obstacles: lift to a safe height, travel, then descend onto the goal."""
        tolerance = self._tolerance(stage)
        safe_z = self._world((0.0, 0.0, self.layout.phantom_top))[2] + _SAFE_HEIGHT
        if np.hypot(*(goal[:2] - tip[:2])) <= tolerance or (tip[2] >= safe_z and goal[2] >= safe_z):
            return self._split(tip, [goal])
        points = []
        if tip[2] < safe_z:
            points.append(np.array([tip[0], tip[1], safe_z]))
        points.append(np.array([goal[0], goal[1], max(goal[2], safe_z)]))
        points.append(goal)
        return self._split(tip, points)

    def _split(self, start, points) -> list[np.ndarray]:
        """Cut a path into legs of at most ``_MAX_LEG``: on short legs a learned Reach policy moves nearly straight."""
        legs, previous = [], np.asarray(start, dtype=float)
        for point in points:
            count = max(1, int(np.ceil(np.linalg.norm(point - previous) / _MAX_LEG)))
            legs += [previous + (point - previous) * (k / count) for k in range(1, count + 1)]
            previous = point
        return legs

    def _start_leg(self, tip, stage: StageSpec) -> None:
        policy = self._policy(stage)
        self.leg_goal = self.waypoints.pop(0)
        # Re-centre the policy's frame so that the leg's midpoint sits at the centre of the box it was trained in.
        midpoint = (np.asarray(tip) + self.leg_goal) / 2
        # A normalised policy is scale-free: in a frame shrunk by `precision` its delta (and steps) shrink alike.
        frame_range = policy.workspace_range / stage.precision
        self.frame = RecentredFrame(midpoint - policy.trained_box_centre * frame_range, frame_range)

    def _tolerance(self, stage: StageSpec) -> float:
        # A policy trained on the sparse reward settles just inside its own delta; allow for the margin.
        return stage.tolerance if stage.tolerance is not None else 1.5 * self.delta

    def _target(self, stage: StageSpec, state) -> np.ndarray:
        up = np.array([0.0, 0.0, stage.height])
        if stage.target in ("above_cavity", "cavity_floor"):
            cx, cy = self.layout.cavity_centres[self.item]
            floor = self.layout.cavity_floor[self.item] + self.layout.clearance
            z = self.layout.phantom_top if stage.target == "above_cavity" else floor
            return self._world((cx, cy, z)) + up
        if stage.target == "above_debris":
            return state["debris_position"][self.item] + up
        if stage.target == "handoff":
            return state["handoff"] + up
        home = self.base + np.array(_HOME_OFFSET[self.agent])
        if stage.target == "park":
            home = home + (0.0, 0.0, 0.01)
        return home + up

    # --- the policy -----------------------------------------------------------------------------------------
    def __call__(self, observation) -> np.ndarray:
        state = self._parse(observation)
        self._observation = observation
        self._advance(state)
        action = self._act(state)
        self.steps += 1
        self.stage_steps += 1
        return action

    def _advance(self, state) -> None:
        """Hand over between stages, items and modes."""
        for _ in range(len(self.plan.stages) + len(self.plan.idle) + len(self.plan.final) + 3):
            if self.mode == "item" and self.item is not None and self._item_done(state, self.item):
                # Finished (or someone else finished it): but let a release stage run if the jaw holds nothing.
                self.done_items.add(self.item)
                self.log.append((self.steps, f"item {self.item} done"))
                self.item = None
                self.mode = "start"
            if self.mode in ("start", "idle"):
                item = self._next_item(state)
                if item is not None:
                    self.item = item
                    self._start_sequence("item", self.plan.stages, state)
                elif self._all_items_done(state) and self.plan.for_each != "none":
                    if self.mode != "final":
                        self._start_sequence("final", self.plan.final, state)
                elif self.mode != "idle":
                    self._start_sequence("idle", self.plan.idle, state)
            if self.stage_index < len(self.sequence) and self._stage_done(state):
                self.log.append((self.steps, f"end {self.mode} stage {self.stage_index}"))
                self.stage_index = 0 if self._lost_item(state) else self.stage_index + 1
                self._start_stage(state)
                continue
            if self.stage_index >= len(self.sequence) and self.mode in ("item", "idle") and self.sequence:
                if self.mode == "idle" and self._next_item(state) is None:
                    return  # nothing to do yet: hold at the end of the idle stages
                self.mode = "start"
                continue
            return

    def _lost_item(self, state) -> bool:
        """A pick that ended without holding its debris (or a carry that dropped it) starts the item over."""
        stage = self.sequence[self.stage_index]
        needs_hold = stage.type == "pick" or (stage.type == "reach" and stage.carry)
        lost = (self.mode == "item" and needs_hold and self.item is not None and not state["held"][self.item]
                and not state["delivered"][self.item])
        if lost:
            self.log.append((self.steps, f"retry item {self.item}: not holding it after stage {self.stage_index}"))
        return lost

    def _stage_done(self, state) -> bool:
        stage = self.sequence[self.stage_index]
        if self.stage_steps >= stage.timeout:
            self.timeouts += 1
            self.log.append((self.steps, f"timeout in stage {self.stage_index} ({stage.type})"))
            return True
        if stage.type == "reach":
            if np.linalg.norm(state["tip"] - self.leg_goal) <= self._tolerance(stage) and self.waypoints:
                self._start_leg(state["tip"], stage)
            if stage.carry and self.item is not None:
                return bool(state["delivered"][self.item])
            return not self.waypoints and np.linalg.norm(state["tip"] - self.leg_goal) <= self._tolerance(stage)
        if stage.type == "pick":
            held = bool(state["held"][self.item])
            return held and np.linalg.norm(state["debris_position"][self.item] - self.stage_goal) <= self.delta
        if stage.type == "suck":
            return self.item is None or self._cavity_clear(state, self.item)
        if stage.type == "release":
            return self.stage_steps >= 1
        return self._until(stage, state)

    def _until(self, stage: StageSpec, state) -> bool:
        if stage.until == "steps":
            return self.stage_steps >= stage.steps
        if stage.until == "cavity_clear":
            return self.item is not None and self._cavity_clear(state, self.item)
        if stage.until == "held":
            return self.item is not None and bool(state["held"][self.item])
        return self.item is not None and bool(state["delivered"][self.item])

    def _act(self, state) -> np.ndarray:
        if self.stage_index >= len(self.sequence):
            return np.array([0.0, 0.0, 0.0, self.tool], dtype=np.float32)
        stage = self.sequence[self.stage_index]
        if stage.type == "teleop":
            action = np.asarray(self.devices[stage.device].action(self._observation), dtype=np.float32)
            self.tool = float(action[3])
            return action
        if stage.type == "suck":
            # Follow the falling surface down to the cavity floor with the valve open (irrigating a clot in bursts
            # where the scene irrigates).
            self.tool = 1.0
            if self.irrigates and self.item is not None and self._inside_cavity(state["tip"]):
                self.tool = burst_valve(np.asarray(self._observation, dtype=np.float64), self.slices, self.item)
            floor = self._target(StageSpec("reach", target="cavity_floor"), state) if self.item is not None else state["tip"]
            step = np.clip((floor - state["tip"]) / self.scene_step, -1.0, 1.0)
            return np.append(step, self.tool).astype(np.float32)
        if stage.type == "release":
            self.tool = 1.0
            return np.array([0.0, 0.0, 0.0, 1.0], dtype=np.float32)
        policy = self._policy(stage)
        scale = policy.step_size / self.scene_step  # a policy step of eta_policy in units of the scene's eta
        if stage.type == "reach":
            scale /= stage.precision
            tip = self.frame.normalise(state["tip"])
            goal = self.frame.normalise(self.leg_goal)
            delta = np.asarray(policy.act({"observation": tip, "achieved_goal": tip, "desired_goal": goal}))[:3]
            if self.agent == "suction":
                inside = self._inside_cavity(state["tip"])
                self.tool = {"off": self.shut, "on": 1.0, "inside": 1.0 if inside else self.shut}[stage.valve]
            else:
                self.tool = 1.0 if stage.jaw == "open" and not stage.carry else -1.0
            return np.append(np.clip(delta * scale, -1, 1), self.tool).astype(np.float32)
        # pick (a policy's p is the dVRK's measured_cp, above the scene's tool point; reach legs need no such
        # shift: their frames are re-centred on each leg, so a translation cancels)
        tip = self.frame.normalise(state["tip"] + (0.0, 0.0, policy.tool_point_drop))
        obj = self.frame.normalise(state["debris_position"][self.item])
        goal = self.frame.normalise(self.stage_goal)
        jaw_observed = state["tool"]
        action = np.asarray(policy.act({"observation": np.concatenate([tip, [jaw_observed], obj]),
                                        "achieved_goal": obj, "desired_goal": goal}))
        self.tool = float(action[3])
        return np.append(np.clip(action[:3] * scale, -1, 1), action[3]).astype(np.float32)

    def _inside_cavity(self, tip) -> bool:
        for index, (cx, cy) in enumerate(self.layout.cavity_centres):
            centre = self._world((cx, cy, self.layout.phantom_top))
            radius = self.layout.cavity_mouth_radius * self.scene_range
            if math.hypot(tip[0] - centre[0], tip[1] - centre[1]) < radius and tip[2] < centre[2]:
                return True
        return False
