"""A shipped single-arm policy driving a dVRK PSM, at the environment's control rate, as the environment moves.

Each control period (20 ms: the env's 50 Hz) the seat reads the arm's latest ``measured_cp``, builds the observation
the policy saw in training from it (the env's frame and normalisation: :func:`dvrl_marl.frames.dvrk_to_env`), asks
the policy for Delta, moves the environment's own kinematic arm from the measured tip as the env's step does
(``p <- p + eta * Delta`` in the workspace box, within the joint limits) and sends the result as ``servo_cp`` (the
tool pointing as in the env: :func:`dvrl_marl.frames.servo_cp_goal`).

Safety first:

- it refuses to move an arm that is not enabled and homed (nothing is sent);
- a ``measured_cp`` that would be older than ``stale_after_s`` (100 ms) by the next period's command, invalid, or
  unreachable by the kinematics holds the arm (``hold``) and ends the run, saying why: the hold is sent within
  100 ms of the last measurement;
- a move the workspace box clamps is clamped and logged;
- Ctrl-C or SIGTERM holds the arm and ends the run; the log (every datagram both ways) is flushed line by line.
"""

from __future__ import annotations

import math
import signal
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from dvrl_marl import frames
from dvrl_marl.dvrk.arm import ArmLink

__all__ = ["RobotSeat", "SceneRobotSeat", "RunSummary", "jaw_angle", "JAW_OPEN_ANGLE"]


@dataclass
class RunSummary:
    """What a run did: steps sent, whether the goal was reached (and at which step), why it stopped, and the
    figures of its timing and tracking."""

    steps: int = 0
    success: bool = False
    success_step: int | None = None
    final_distance_mm: float | None = None
    stopped: str = ""
    clamped: int = 0
    periods_ms: list = field(default_factory=list)
    largest_age_ms: float = 0.0
    tracking_error_mm: float | None = None
    commands: list = field(default_factory=list)

    def figures(self) -> dict:
        periods = np.asarray(self.periods_ms) if self.periods_ms else np.zeros(0)
        return {"steps": self.steps, "success": self.success, "success_step": self.success_step,
                "final_distance_mm": self.final_distance_mm, "stopped": self.stopped, "clamped": self.clamped,
                "period_ms_median": None if not len(periods) else round(float(np.median(periods)), 3),
                "period_ms_p99": None if not len(periods) else round(float(np.percentile(periods, 99)), 3),
                "largest_measurement_age_ms": round(self.largest_age_ms, 3),
                "tracking_error_mm": self.tracking_error_mm}


class RobotSeat:
    """``policy`` (a shipped single-arm policy: ``policies.load("reach-lnd")`` or ``"pick-lnd"``) on ``arm`` towards
    ``goal`` (metres, the env's frame: the PSM base frame, the measured_cp point; Pick: the object's goal). ``env``:
    the environment whose step it repeats (by default the policy's, with its tool). For Pick the object is the env's
    own model of it, starting at ``object_position`` (default: on the table below the first measured tip), grasped and
    carried by the env's rule as the measured tip moves; the jaw goes out as ``jaw/servo_jp``."""

    #: How long before each tick the seat reads and computes (s): a single-arm step takes well under a millisecond.
    compute_margin_s = 0.003

    def __init__(self, arm: ArmLink, policy, *, goal, env=None, tool: str = "lnd", rate_hz: float = 50.0,
                 stale_after_s: float = 0.1, clock=time.monotonic, sleep=time.sleep, log=None, object_position=None):
        if env is None:
            import gymnasium as gym

            import dvrl_marl  # noqa: F401  (registers the environments)

            env_id = getattr(policy, "spec", {}).get("env_id") or "dvrl_marl/PSMReach-v1"
            env = gym.make(env_id, **({"tool": tool} if "Reach" in env_id else {}))
        self.env = env.unwrapped
        #: Pick: the object is the environment's own model of it (no camera sees it), held to the measured tip
        self.picks = hasattr(self.env, "object_position")
        if object_position is not None and not self.picks:
            raise ValueError("object_position is for a Pick policy; Reach has no object")
        self.object_position = object_position
        self.env.reset(seed=0)  # (its arm and goal made; each step then starts from the measured tip)
        self._loop(arm, policy, rate_hz, stale_after_s, clock, sleep, log)
        self.tool = self.env.tool.name if hasattr(self.env.tool, "name") else tool
        self.goal = self.env.parse_reset_options({"goal": goal})["goal"]  # (checked as the env checks a goal)
        self.tip_frame = getattr(self.env, "tip_frame", "measured_cp")
        self.base_pose = frames.BasePose()

    def _loop(self, arm, policy, rate_hz, stale_after_s, clock, sleep, log) -> None:
        if not (isinstance(rate_hz, (int, float)) and math.isfinite(rate_hz) and 0 < rate_hz <= 1000):
            raise ValueError(f"rate_hz must be in (0, 1000], got {rate_hz!r}")
        if not (isinstance(stale_after_s, (int, float)) and math.isfinite(stale_after_s) and stale_after_s > 0):
            raise ValueError(f"stale_after_s must be a positive number of seconds, got {stale_after_s!r}")
        self.arm, self.policy = arm, policy
        self.period = 1.0 / rate_hz
        self.stale_after = float(stale_after_s)
        self.clock, self.sleep = clock, sleep
        self.log = log if log is not None else arm.link.log

    def from_dvrk(self, position) -> np.ndarray:
        """The env's tip for a measured_cp position."""
        return frames.dvrk_to_env(position, self.base_pose, tool=self.tool, env_tip_frame=self.tip_frame)

    def to_dvrk(self, target) -> np.ndarray:
        """The servo_cp goal (4x4, the arm's base frame) for an env tip."""
        return frames.servo_cp_goal(target, self.base_pose, tool=self.tool, env_tip_frame=self.tip_frame)

    def tool_command(self) -> float | None:
        """The jaw angle to send after the pose (Pick), or None."""
        return jaw_angle(self.env.arm.jaw) if self.picks else None

    # --- one control period -------------------------------------------------------------------------------------
    def start(self, tip) -> None:
        """A Pick episode's object (given, else the env's: on the table below the tip) and goal, from the tip."""
        if self.picks:
            self.env.reset(options={"start": np.asarray(tip, dtype=np.float64), "goal": self.goal,
                                    "object": self.object_position})

    def observation(self, tip) -> dict:
        """The env's observation for a tip ``p`` (metres, env frame) and the seat's goal (Pick: and the env's
        object and jaw)."""
        if self.picks:
            self.env.arm.set_tip(*np.asarray(tip, dtype=np.float64).tolist())
            if self.env.grasped:
                self.env._carry_object()
            self.env._update_object_normalised()
            return self.env._observation()
        tip = self.env.normalise(np.asarray(tip, dtype=np.float64))
        return {"observation": tip.copy(), "achieved_goal": tip.copy(),
                "desired_goal": self.env.normalise(self.goal)}

    def target(self, tip, action) -> tuple[np.ndarray, bool]:
        """Where the env's step takes the tip from ``tip`` by ``action``, and whether the box clamped it (Pick:
        the env's jaw and object follow, :attr:`jaw` says the jaw)."""
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        move = np.clip(action[:3], -1.0, 1.0)
        if self.picks:
            self.env.arm.set_tip(*np.asarray(tip, dtype=np.float64).tolist())
            self.env.step(np.clip(action[:4], -1.0, 1.0).astype(np.float32))
        else:
            self.env.set_state(tip=tip, goal=self.goal)
            self.env.step(move.astype(np.float32))
        reached = np.asarray(self.env.arm.tip, dtype=np.float64)
        unclamped = np.asarray(tip, dtype=np.float64) + self.env.step_size * move
        return reached, not np.allclose(reached, unclamped, atol=1e-9)

    def reached(self, tip) -> tuple[bool, float]:
        """Whether the env's goal is met (Reach: the measured tip within delta; Pick: the env's object), and the
        distance (m)."""
        if self.picks:
            distance = float(np.linalg.norm(self.env.object_position() - self.goal))
        else:
            distance = float(np.linalg.norm(np.asarray(tip) - self.goal))
        return distance <= self.env.distance_threshold, distance

    def _stop(self, summary: RunSummary, reason: str, **details) -> None:
        self.arm.hold()
        summary.stopped = reason
        self.log.note(self.clock(), "hold", reason=reason, **details)

    # --- a run --------------------------------------------------------------------------------------------------
    def wait_until_ready(self, timeout_s: float = 2.0) -> tuple[bool, str]:
        """Read the streamer until the arm says it is enabled and homed and a measured_cp has come (or the time is
        up)."""
        deadline = self.clock() + timeout_s
        while True:
            self.arm.update()
            ready, why = self.arm.ready()
            if ready and self.arm.measured_cp() is None:
                ready, why = False, f"{self.arm.name}: no measured_cp received"
            if ready or self.clock() >= deadline:
                return ready, why
            self.sleep(0.01)

    def run(self, steps: int = 100, *, stop_on_success: bool = True, settle_s: float = 0.5) -> RunSummary:
        """Up to ``steps`` control periods (the env's episode: 100); returns a :class:`RunSummary`."""
        if not isinstance(steps, int) or isinstance(steps, bool) or steps < 1:
            raise ValueError(f"steps must be a positive integer, got {steps!r}")
        summary = RunSummary()
        ready, why = self.wait_until_ready()
        if not ready:  # refuse to move: nothing is sent
            summary.stopped = f"refused: {why}"
            self.log.note(self.clock(), "refused", reason=why)
            self.log.note(self.clock(), "end", **summary.figures())
            return summary
        previous_handler = None
        if threading.current_thread() is threading.main_thread():
            previous_handler = signal.signal(signal.SIGTERM, _raise_interrupt)
        last_target = None
        try:
            # Each period: sense and compute a few milliseconds before the tick, send on the tick (the command's
            # timing then does not carry the computation's jitter; the measurement is that much old at most).
            margin = min(self.compute_margin_s, self.period / 2)
            deadline = self.clock() + margin
            last_sent = None
            for step in range(steps):
                self._wait_until(deadline - margin)
                now = self.clock()  # (the period's time: what came by now counts, as it was read in this update)
                self.arm.update()
                measured = self.arm.measured_cp()
                age = math.inf if measured is None else max(0.0, now - measured.received)
                summary.largest_age_ms = max(summary.largest_age_ms, 1000.0 * age if math.isfinite(age) else 0.0)
                # (stale if it would pass the limit before the next period's check: the hold is sent within the limit)
                if measured is None or not measured.valid or age + self.period > self.stale_after:
                    why = "no measured_cp" if measured is None else \
                        "measured_cp invalid" if not measured.valid else f"measured_cp {1000 * age:.0f} ms old"
                    self._stop(summary, f"stale measurement: {why}", step=step)
                    break
                tip = self.from_dvrk(measured.position)
                if step == 0:
                    self.start(tip)
                    self.log.note(now, "start", tip=tip.tolist(), measured=measured.position.tolist())
                success, distance = self.reached(tip)
                summary.final_distance_mm = None if distance is None else 1000.0 * distance
                if success and not summary.success:
                    summary.success, summary.success_step = True, step
                    if stop_on_success:
                        break
                try:
                    target, clamped = self.target(tip, self.policy(self.observation(tip)))
                except Exception as error:  # noqa: BLE001  (an unreachable measured tip, a policy that fails)
                    self._stop(summary, f"cannot act: {error}", step=step)
                    break
                if clamped:
                    summary.clamped += 1
                    self.log.note(now, "clamped", step=step, target=target.tolist())
                goal = self.to_dvrk(target)
                self._wait_until(deadline)
                self.arm.servo_cp(goal)
                jaw = self.tool_command()
                if jaw is not None:  # the env's jaw, as the dVRK's jaw angle
                    self.arm.jaw_servo_jp(jaw)
                sent = self.clock()
                if last_sent is not None:
                    summary.periods_ms.append(1000.0 * (sent - last_sent))
                last_sent, last_target = sent, goal[:3, 3]
                summary.steps += 1
                summary.commands.append(goal[:3, 3].tolist())
                deadline += self.period
            else:
                summary.stopped = "steps done"
            if not summary.stopped:
                summary.stopped = "goal reached" if summary.success else "steps done"
            if last_target is not None and settle_s > 0 and not summary.stopped.startswith(("stale", "cannot")):
                summary.tracking_error_mm = self._settled_error(last_target, settle_s)
        except KeyboardInterrupt:
            self._stop(summary, "interrupted (Ctrl-C or SIGTERM)")
        finally:
            if previous_handler is not None:
                signal.signal(signal.SIGTERM, previous_handler)
        self.log.note(self.clock(), "end", **summary.figures())
        return summary

    def _wait_until(self, deadline: float) -> None:
        """Sleep to ``deadline``; on the real clock, the last two milliseconds are waited out by reading the clock (a
        sleep overshoots by up to a millisecond or two, which the loop's period would carry)."""
        remaining = deadline - self.clock()
        if self.sleep is not time.sleep or self.clock is not time.monotonic:
            self.sleep(max(0.0, remaining))
            return
        if remaining > 0.003:
            time.sleep(remaining - 0.002)
        while time.monotonic() < deadline:
            pass

    def _settled_error(self, commanded, settle_s: float) -> float | None:
        """|commanded - measured| (mm) of the last goal, ``settle_s`` after it was sent."""
        end = self.clock() + settle_s
        while self.clock() < end:
            self.sleep(min(0.01, max(0.0, end - self.clock())))
            self.arm.update()
        measured = self.arm.measured_cp()
        if measured is None:
            return None
        return round(1000.0 * float(np.linalg.norm(measured.position - np.asarray(commanded))), 4)


class SceneRobotSeat(RobotSeat):
    """A seat of the collaborative scene (``policies.load("marl-grasper")``, ...) on ``arm``: the arm is the seat's,
    the rest of the scene (the other arm, worked by ``partner``, the blood and the pins) is the env's model of it, one
    world of ``suction_debris`` with ``preset``'s scene, seeded ``seed``. Each period the seat's arm in the model is
    put where the robot measured it, the policy acts on the scene's observation, and the model's step (the partner's
    move, suction, grasps, the hand-off) gives the next goal. The run ends when the scene is cleared. The grasper's
    jaw goes out as ``jaw/servo_jp``; the suction's valve has no dVRK command (it stays in the model)."""

    #: The scene's step (the partner, suction, grasps) takes a few milliseconds, now and then more; read much earlier,
    #: the latest measurement (the streamer sends every 10 ms) may predate the last command: 8 ms before the tick
    #: cost one of three seeded scenes, 3 ms keeps the measurement after it.
    compute_margin_s = 0.003

    def __init__(self, arm: ArmLink, policy, *, partner="scripted", preset: str = "default", seed: int = 0,
                 rate_hz: float = 50.0, stale_after_s: float = 0.1, clock=time.monotonic, sleep=time.sleep, log=None):
        from dvrl_marl.envs import suction_debris
        from dvrl_marl.suction_debris.presets import evaluation_options

        self.agent = policy.spec.get("agent") if hasattr(policy, "spec") else None
        if self.agent not in ("suction", "grasper"):
            raise ValueError("SceneRobotSeat needs a seat of the collaborative scene (a policy trained for the "
                             "'suction' or 'grasper' seat)")
        other = "suction" if self.agent == "grasper" else "grasper"
        self.env = suction_debris.batched_env(num_envs=1, autoreset_mode="disabled", surgeon=partner,
                                              surgeon_seat=other, **evaluation_options(preset))
        self.env.reset(seed=seed)
        self._loop(arm, policy, rate_hz, stale_after_s, clock, sleep, log)
        core_arm = self.env.core.arms[self.agent]
        self.tool = core_arm.tool.name
        self.tip_frame = "tool_point"  # (the scene's tips are the tools' points, in the world)
        self.base_pose = frames.BasePose(tuple(np.asarray(core_arm.base_position).tolist()))
        self.picks, self.goal = False, None

    @staticmethod
    def start_pose(policy, preset: str = "default", seed: int = 0) -> np.ndarray:
        """The servo_cp pose (4x4, the arm's base frame) where the scene's model starts the seat's arm."""
        from dvrl_marl.envs import suction_debris
        from dvrl_marl.suction_debris.presets import evaluation_options

        agent = policy.spec["agent"]
        env = suction_debris.batched_env(num_envs=1, autoreset_mode="disabled", **evaluation_options(preset))
        env.reset(seed=seed)
        arm = env.core.arms[agent]
        return frames.servo_cp_goal(arm.tip_world()[0], frames.BasePose(tuple(np.asarray(arm.base_position).tolist())),
                                    tool=arm.tool.name, env_tip_frame="tool_point")

    def start(self, tip) -> None:
        pass

    def _place(self, tip) -> None:
        self.env.set_tip_positions({self.agent: np.asarray(tip, dtype=np.float64)[None]})

    def observation(self, tip):
        self._place(tip)
        return self.env.observations()[self.agent][0]

    def target(self, tip, action) -> tuple[np.ndarray, bool]:
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1), -1.0, 1.0)
        self._place(tip)
        self.env.step({self.agent: action[None]})
        reached = np.asarray(self.env.core.arms[self.agent].tip_world()[0])
        unclamped = np.asarray(tip, dtype=np.float64) + self.env.params.step_size * action[:3]
        return reached, not np.allclose(reached, unclamped, atol=1e-9)

    def reached(self, tip) -> tuple[bool, None]:
        """Whether the modelled scene is cleared (every cavity, every pin delivered)."""
        return bool(self.env.core.complete[0]), None

    def tool_command(self) -> float | None:
        return jaw_angle(float(self.env.core.arms["grasper"].jaw[0])) if self.agent == "grasper" else None


#: The jaw's opening angle (rad) at j = 1: the original dVRL scene turned each of the LND's two jaws 0.4106 * j rad
#: (``shared/reference/psm_facts.md``), so the angle between them is twice that; it lies inside the dVRK's jaw range
#: (-0.698 .. 1.396 rad).
JAW_OPEN_ANGLE = 2 * 0.4106


def jaw_angle(jaw: float) -> float:
    """The dVRK's ``jaw/servo_jp`` angle (rad) for the env's jaw ``j`` in [0, 1]."""
    return JAW_OPEN_ANGLE * float(np.clip(jaw, 0.0, 1.0))


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt
