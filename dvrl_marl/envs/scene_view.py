"""What a person watching or working the collaborative scene is shown: progress, cues, the scene's outline, the pins
in view, and the marks drawn into the picture. The env computes none of it; the window, the browser page and the
person-like operators read it through a :class:`SceneView` of the env.
"""

from __future__ import annotations

import math

import numpy as np

from dvrl_marl.envs.marks import COLOURS, Mark, add_marks
from dvrl_marl.suction_debris.rules import AGENTS, PIN_SENSOR_RANGE, closest_on_segment, distance

__all__ = ["SceneView"]


class SceneView:
    """One world of a collaborative env (the parallel env, or a seat wrapped around it) as a person follows it."""

    def __init__(self, env):
        self.env = getattr(env, "unwrapped", env)

    def progress(self) -> dict:
        """Where the episode stands, for a person watching it: blood left per cavity (ml), debris found (uncovered
        or delivered), delivered and in all, elapsed time (s), steps, whether the field is clear, and each arm's
        tool tip (world frame, m) with the jaw opening (0 closed .. 1 open) and whether the suction valve is open."""
        env = self.env
        return {
            "blood_ml": [float(v) for v in env.blood.remaining_ml],
            "debris_found": int(sum(pin.visible or pin.delivered for pin in env.debris)),
            "debris_delivered": int(sum(pin.delivered for pin in env.debris)),
            "debris_total": len(env.debris),
            "time_s": env.steps * env.params.control_dt,
            "steps": env.steps,
            "success": bool(env.core.is_complete()[0]),
            "tips": {agent: [float(v) for v in env.arms[agent].tip_world()] for agent in AGENTS},
            "jaw": float(env.arms["grasper"].jaw),
            "valve_open": bool(env.valve_open),
            "irrigating": bool(env.core.irrigating[0]),
            **(self._fluids() if env.core.fluids else {}),
        }

    def _fluids(self) -> dict:
        """A scene with fluids: each cavity's clot and saline (ml), the saline used (ml), overflows so far and
        whether a spill covers the phantom now."""
        core = self.env.core
        return {"clot_ml": [float(v) for v in core.clot_ml[0]], "saline_ml": [float(v) for v in core.saline_ml[0]],
                "saline_used_ml": float(core.saline_used_ml[0]), "overflow_events": int(core.overflow_events[0]),
                "spilling": bool((core.spill_s[0] > 0.0).any())}

    def blood_text(self) -> list[str]:
        """Each cavity's blood as a person reads it: ml left, or "clear" once below ``blood_threshold_ml`` (a
        cleared cavity may still hold a few tenths of a millilitre, which rounded reads like the threshold)."""
        env = self.env
        threshold = env.params.blood_threshold_ml
        return ["clear" if v < threshold or v <= 0.0 else f"{v:.1f} ml" for v in env.blood.remaining_ml]

    def cues(self, agent: str) -> dict:
        """What a person working ``agent``'s arm cannot read from one endoscope view: the tip's height above the
        surface below it (mm) and above the blood there (suction); whether its last move was refused because the
        other instrument is in the way (``blocked``); for the grasper, the nearest pin's distance from the jaws
        (mm), whether closing now takes it (``in_reach``), whether it holds one and how far that is from the hand-off
        (mm, judged as the scene judges it); for the suction, whether it drew blood in the last step."""
        env = self.env
        if agent not in AGENTS:
            raise ValueError(f"{env.name}: unknown agent {agent!r}; agents are {list(AGENTS)}")
        x, y, z = env.arms[agent].tip_world()
        cues = {"tip_height_mm": 1000.0 * (z - env.phantom.surface_height(x, y)),
                "blocked": bool(env.core.blocked[agent][0])}
        if agent == "suction":
            cavity = env.phantom.cavity_at(x, y)
            wet = cavity >= 0 and env.blood.remaining_ml[cavity] > 0.0
            cues["above_blood_mm"] = 1000.0 * (z - env.blood.surface_z[cavity]) if wet else None
            cues["drawing"] = env.valve_open and float(env.core.drawn_ml[0]) > 0.0
            cues["irrigating"] = bool(env.core.irrigating[0])
            cues["spill"] = bool((env.core.spill_s[0] > 0.0).any())
            return cues
        tip = (x, y, z)
        held_pin = self._held_pin()
        held = held_pin is not None
        cues["holding"] = held
        cues["handoff_mm"] = (1000.0 * math.dist(self._judged_point(held_pin), env.handoff)
                              if held else None)
        core = env.core
        ends = [pin.axis_ends() for pin in env.debris]
        start, end = (np.array([pair[k] for pair in ends]) for k in (0, 1))
        # as the grasp rule measures it: from the jaws to each pin's axis
        gaps = distance(np.asarray(tip), closest_on_segment(np.asarray(tip), start, end))
        free = core.visible[0] & ~core.delivered[0] & ~core.held[0]
        nearest = float(gaps[free].min()) if free.any() else None
        cues["pin_mm"] = None if nearest is None else 1000.0 * nearest
        cues["in_reach"] = not held and nearest is not None and nearest <= PIN_SENSOR_RANGE
        return cues

    def outline(self) -> dict:
        """The scene's fixed geometry in millimetres (world frame), for a person's top and side views: the
        phantom's top (x, y half extents about its centre, height), each cavity (centre, mouth radius, floor), the
        hand-off point and the workspace box."""
        env = self.env
        phantom = env.phantom
        mm = 1000.0
        return {
            "phantom": {"centre": [mm * phantom.centre_x, mm * phantom.centre_y], "half": [mm * phantom.half_x,
                        mm * phantom.half_y], "top": mm * phantom.top_z, "table": mm * phantom.table_z},
            "cavities": [{"centre": [mm * c.centre_x, mm * c.centre_y], "radius": mm * c.mouth_radius,
                          "floor": mm * c.floor_z} for c in phantom.cavities],
            "handoff": [mm * v for v in env.handoff],
            "workspace": {"low": [mm * v for v in env.core.low.tolist()],
                          "high": [mm * v for v in env.core.high.tolist()]},
        }

    def pins(self) -> list[dict]:
        """The pins a person can see (uncovered, not yet delivered): position (mm, world), whether held, and for a
        held pin ``grip_mm``, the point the hand-off judges (where the jaws hold it)."""
        env = self.env
        return [{"mm": [1000.0 * v for v in pin.position], "held": pin.held,
                 **({"grip_mm": [1000.0 * v for v in self._judged_point(index)]} if pin.held else {})}
                for index, pin in enumerate(env.debris) if pin.visible and not pin.delivered]

    def marks(self) -> list:
        """The drop lines drawn into the scene (:mod:`dvrl_marl.envs.marks`): one per arm, tip to surface."""
        env = self.env
        reach = self.cues("grasper")["in_reach"]
        marks = []
        for agent in AGENTS:
            x, y, z = env.arms[agent].tip_world()
            colour = COLOURS["in_reach"] if agent == "grasper" and reach else COLOURS[agent]
            marks.append(Mark((x, y, z), (x, y, env.phantom.surface_height(x, y)), colour))
        return marks

    def draw_marks(self, scene) -> None:
        """Add the marks to an updated ``MjvScene`` (the renderers call this for every frame)."""
        add_marks(scene, self.marks(), self.env.handoff)

    def cue_rows(self, agent) -> tuple[list[str], list[str]]:
        """``agent``'s cues as rows of a panel (labels, values)."""
        cues = self.cues(agent)
        labels, values = ["Tip height"], [f"{cues['tip_height_mm']:.1f} mm above the surface"]
        if agent == "grasper":
            labels.append("Jaw")
            if cues["holding"]:
                values.append(f"closed, holding a pin: {cues['handoff_mm']:.1f} mm to the hand-off")
            else:
                pin = "no pin in sight" if cues["pin_mm"] is None else (
                    f"pin IN REACH ({cues['pin_mm']:.1f} mm): close" if cues["in_reach"]
                    else f"nearest pin {cues['pin_mm']:.1f} mm")
                values.append(("open" if self.env.arms["grasper"].jaw >= self.env.params.grasp_threshold else "closed")
                              + f", {pin}")
        else:
            labels.append("Valve")
            depth = ("not over blood" if cues["above_blood_mm"] is None
                     else f"{cues['above_blood_mm']:.1f} mm above the blood")
            valve = "IRRIGATING" if cues["irrigating"] else "open" if self.env.valve_open else "closed"
            values.append(valve + (", drawing" if cues["drawing"] else "") + f", {depth}")
            if self.env.params.irrigation_ml_s > 0.0:
                labels.append("Saline")
                values.append(f"{float(self.env.core.saline_used_ml[0]):.1f} ml used (hold I to irrigate)")
            if cues["spill"]:
                labels.append("SPILL")
                values.append("a cavity overflowed: the pins around it are hidden a while")
        if cues["blocked"]:
            labels.append("BLOCKED")
            values.append("the other instrument is in the way")
        return labels, values

    def _held_pin(self):
        holding = int(self.env.core.holding[0])
        return None if holding < 0 else holding

    def _judged_point(self, index: int) -> list[float]:
        """Where the hand-off judges held pin ``index``: where the jaws hold it, or (without ``deliver_at_grip``)
        its centre."""
        core = self.env.core
        if self.env.params.deliver_at_grip:
            return (core.arms["grasper"].tip_world()[0] + core.grip_offset[0]).tolist()
        return core.debris_position[0, index].tolist()
