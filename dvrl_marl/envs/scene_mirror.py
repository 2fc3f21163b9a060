"""The collaborative scene in MuJoCo, only to be seen: a model that shows one world of the core's state.

The core (:mod:`dvrl_marl.suction_debris.rules`) steps the worlds; to render one, its state is written into this model
(joint values, jaw, blood surfaces, pins) and drawn. Nothing here feeds back into the step.
"""

from __future__ import annotations

import math

import mujoco
import numpy as np

from dvrl_marl import assets
from dvrl_marl.arm import Arm
from dvrl_marl.assets import JAW_FINGER_OPEN_ANGLE
from dvrl_marl.rendering import SceneRenderer
from dvrl_marl.scene import geom_top, load_model, object_id
from dvrl_marl.suction_debris.phantom import Cavity, Phantom
from dvrl_marl.suction_debris.rules import AGENTS, SPILL_MARGIN, TOOLS
from dvrl_marl.suction_debris.scene_geometry import ARM_PREFIXES, SceneGeometry

__all__ = ["SceneMirror", "fluid_colour", "FLUID_COLOURS"]

#: The fluids' colours (rgb) beside liquid blood's (the scene file's blood material): a clot darker, saline nearly
#: clear; a mix takes each part's colour by its volume (red blood thinned to pink, then to clear).
FLUID_COLOURS = {"clot": (0.18, 0.01, 0.02), "saline": (0.86, 0.9, 0.93)}
#: The state's fluid keys (:meth:`CollaborativeCore.world_states` of a scene with fluids).
FLUID_KEYS = ("saline_ml", "clot_ml", "spill")
#: A spill is drawn this far above the phantom's top (m).
SPILL_LIFT = 0.0003


class SceneMirror:
    """The MuJoCo model of ``params.scene`` with ``params.debris_count`` pins; :meth:`show` writes a world's state
    (:meth:`CollaborativeCore.world_state`) into it, :meth:`render` draws it (:class:`SceneRenderer` options)."""

    def __init__(self, params, render_mode: str | None = None, **renderer_options):
        self.model = _model_with_debris(params.scene, params.debris_count)
        self.data = mujoco.MjData(self.model)
        self.arms = {agent: Arm(self.model, self.data, ARM_PREFIXES[agent], TOOLS[agent]) for agent in AGENTS}
        self.cavities = self.geometry().phantom.cavities
        self._blood_geoms = [object_id(self.model, "geom", f"blood_{i}") for i in range(len(self.cavities))]
        self._blood_rgba = [self.model.geom_rgba[g].copy() for g in self._blood_geoms]
        self._blood_surfaces: dict[tuple[int, float], tuple[float, float]] = {}  # (cavity, ml) -> (depth, radius)
        self._spill_radius = np.array([cavity.mouth_radius + SPILL_MARGIN for cavity in self.cavities])
        material = self.model.geom_matid[self._blood_geoms[0]]  # liquid blood's colour: the scene file's
        self._blood_rgb = (self.model.mat_rgba[material, :3] if material >= 0
                           else self.model.geom_rgba[self._blood_geoms[0], :3]).copy()
        bodies = [object_id(self.model, "body", f"debris_{i}") for i in range(params.debris_count)]
        self._debris_qpos = [int(self.model.jnt_qposadr[self.model.body_jntadr[b]]) for b in bodies]
        self.renderer = SceneRenderer(self.model, self.data, render_mode, **renderer_options)

    def geometry(self) -> SceneGeometry:
        """The scene's geometry as MuJoCo compiled it (the core reads the file's text: a test holds them equal)."""
        geom = object_id(self.model, "geom", "phantom")
        size = self.model.hfield_size[self.model.geom_dataid[geom]]
        px, py, pz = (float(v) for v in self.model.geom_pos[geom])
        top = pz + float(size[2])
        cavities = tuple(Cavity(px + cx, py + cy, top, assets.CAVITY_MOUTH_RADIUS, assets.CAVITY_DEPTH)
                         for cx, cy in assets.CAVITY_CENTRES)
        phantom = Phantom(px, py, float(size[0]), float(size[1]), top, geom_top(self.model, "table"), cavities)
        mujoco.mj_kinematics(self.model, self.data)
        handoff = tuple(float(v) for v in self.data.site_xpos[object_id(self.model, "site", "handoff")])
        return SceneGeometry(phantom, {agent: arm.base_position.copy() for agent, arm in self.arms.items()}, handoff)

    def show(self, state: dict) -> None:
        """Write one world's state into the model."""
        joints = state.get("joints")
        for agent in AGENTS:
            tip = np.asarray(state["tips"][agent], dtype=np.float64).tolist()
            if joints is None:
                self.arms[agent].set_tip(*tip)
            else:
                self.arms[agent].set_solved_tip(*tip, tuple(np.asarray(joints[agent], dtype=np.float64).tolist()))
        self.arms["grasper"].set_jaw(float(state["jaw"]))
        if "saline_ml" in state:  # a scene with fluids: the surface, its colour and a spill as poses() works them out
            one = {key: np.asarray(state[key])[None] for key in ("blood_ml", *FLUID_KEYS)}
            rgba, radius, z = self._fluid_poses(one)
            for index, geom in enumerate(self._blood_geoms):
                self.model.geom_rgba[geom], self.model.geom_size[geom][0] = rgba[0, index], radius[0, index]
                self.model.geom_pos[geom][2] = z[0, index]
        else:
            for index, volume in enumerate(np.asarray(state["blood_ml"], dtype=np.float64).tolist()):
                self._show_blood(index, volume)
        for index, address in enumerate(self._debris_qpos):
            if state["delivered"][index]:  # handed to the assistant: out of the scene
                self.data.qpos[address:address + 3] = (0.0, 0.0, -1.0)
                continue
            self.data.qpos[address:address + 3] = state["debris_positions"][index]
            # Capsule axis is the body z axis: turn it horizontal (about y), then to the pin's yaw (about z).
            half_yaw, c = 0.5 * float(state["debris_yaws"][index]), math.sqrt(0.5)
            self.data.qpos[address + 3:address + 7] = (c * math.cos(half_yaw), -c * math.sin(half_yaw),
                                                       c * math.cos(half_yaw), c * math.sin(half_yaw))

    def poses(self, states) -> dict:
        """What :meth:`show` writes for many worlds, worked out for all at once: ``states`` is a list of
        :meth:`CollaborativeCore.world_state` dicts or one dict of them stacked (``world_states``); :meth:`put` then
        writes world ``i``'s into the model. The same model as :meth:`show` gives (the arms' joints as the core
        solved them)."""
        if isinstance(states, dict):
            stacked = states
        else:
            states = list(states)
            if any(state.get("joints") is None for state in states):
                raise ValueError("poses: each state needs the arms' joints (the core's world_state has them)")
            keys = ("jaw", "blood_ml", "debris_positions", "debris_yaws", "delivered")
            stacked = {key: np.stack([np.asarray(state[key]) for state in states])
                       for key in keys + (FLUID_KEYS if "saline_ml" in states[0] else ())}
            stacked["joints"] = {agent: np.stack([np.asarray(state["joints"][agent], np.float64) for state in states])
                                 for agent in AGENTS}
        jaw = np.asarray(stacked["jaw"], np.float64)
        count = len(jaw)
        qpos = np.tile(self.data.qpos, (count, 1))  # (every joint written below but a handed-over pin's turn: unseen)
        for agent in AGENTS:
            qpos[:, self.arms[agent].joint_qpos_addresses] = np.asarray(stacked["joints"][agent], np.float64)
        qpos[:, self.arms["grasper"].jaw_qpos_addresses] = (JAW_FINGER_OPEN_ANGLE * jaw)[:, None]
        positions = np.asarray(stacked["debris_positions"], np.float64)
        half_yaws, delivered = 0.5 * np.asarray(stacked["debris_yaws"], np.float64), np.asarray(stacked["delivered"])
        c = math.sqrt(0.5)
        for index, address in enumerate(self._debris_qpos):  # (as show: out of the scene once handed over)
            qpos[:, address:address + 3] = np.where(delivered[:, index, None], (0.0, 0.0, -1.0), positions[:, index])
            cos, sin = np.cos(half_yaws[:, index]), np.sin(half_yaws[:, index])
            turned = np.stack([c * cos, -c * sin, c * cos, c * sin], axis=-1)
            qpos[:, address + 3:address + 7] = np.where(delivered[:, index, None], qpos[:, address + 3:address + 7],
                                                        turned)
        if "saline_ml" in stacked:
            rgba, radius, z = self._fluid_poses(stacked)
            return {"qpos": qpos, "blood_rgba": rgba, "blood_radius": radius, "blood_z": z}
        volumes = np.asarray(stacked["blood_ml"], np.float64)
        depth, radius = self._surfaces(volumes)
        shown = (volumes > 0.0) & (radius > 1e-4)
        rgba = np.where(shown[..., None], np.array(self._blood_rgba), 0.0)
        rgba[..., :3] = np.where(shown[..., None], rgba[..., :3], self.model.geom_rgba[self._blood_geoms, :3])
        floors = np.array([cavity.floor_z for cavity in self.cavities])
        heights = self.model.geom_size[self._blood_geoms, 1]
        return {"qpos": qpos, "blood_rgba": rgba, "blood_radius": radius, "blood_z": floors + depth - heights}

    def _surfaces(self, volumes: np.ndarray):
        """Each cavity's surface holding ``volumes`` (W, C) ml: its height above the floor and its radius."""
        surfaces = np.array([[self._blood_surface(index, volume) for index, volume in enumerate(row)]
                             for row in volumes.tolist()]).reshape(*volumes.shape, 2)
        return surfaces[..., 0], surfaces[..., 1]

    def _fluid_poses(self, stacked: dict):
        """A scene with fluids: each cavity's surface (blood and saline), coloured by what it holds (dark clot, red
        blood, pink mix, clear saline: :func:`fluid_colour`), and a spill drawn as the mix spread over the phantom
        around its cavity. Returns the geoms' rgba (W, C, 4), radii and centres' heights (W, C)."""
        blood, saline = np.asarray(stacked["blood_ml"], np.float64), np.asarray(stacked["saline_ml"], np.float64)
        clot, spill = np.asarray(stacked["clot_ml"], np.float64), np.asarray(stacked["spill"], bool)
        depth, radius = self._surfaces(blood + saline)
        heights = self.model.geom_size[self._blood_geoms, 1]
        floors = np.array([cavity.floor_z for cavity in self.cavities])
        z = np.where(spill, np.array([cavity.top_z for cavity in self.cavities]) + SPILL_LIFT, floors + depth) - heights
        radius = np.where(spill, self._spill_radius, radius)
        shown = spill | ((blood + saline > 0.0) & (radius > 1e-4))
        alpha = np.array([self.model.mat_rgba[m, 3] if m >= 0 else 1.0 for m in self.model.geom_matid[self._blood_geoms]])
        rgba = np.concatenate([fluid_colour(np.maximum(blood - clot, 0.0), clot, saline, self._blood_rgb),
                               np.broadcast_to(alpha, blood.shape)[..., None]], axis=-1)
        return np.where(shown[..., None], rgba, 0.0), radius, z

    def put(self, poses: dict, world: int) -> None:
        """Write world ``world`` of :meth:`poses` into the model (what :meth:`show` would)."""
        self.data.qpos[:] = poses["qpos"][world]
        geoms = self._blood_geoms
        self.model.geom_rgba[geoms] = poses["blood_rgba"][world]
        self.model.geom_size[geoms, 0] = poses["blood_radius"][world]
        self.model.geom_pos[geoms, 2] = poses["blood_z"][world]

    @property
    def blood_geoms(self) -> list[int]:
        """The geoms that draw each cavity's blood surface."""
        return list(self._blood_geoms)

    def make_blood_opaque(self) -> None:
        """Draw the blood opaque (the learning view's; the human view lets the cavity floor show through)."""
        for geom in self._blood_geoms:  # (its colour is its material's)
            material = self.model.geom_matid[geom]
            if material >= 0:
                self.model.mat_rgba[material][3] = 1.0

    def _blood_surface(self, index: int, volume_ml: float) -> tuple[float, float]:
        """Cavity ``index``'s blood surface holding ``volume_ml``: its height above the floor and its radius."""
        surface = self._blood_surfaces.get((index, volume_ml))
        if surface is None:  # (Newton's method in Python: worked out once per volume; most cavities keep theirs)
            cavity = self.cavities[index]
            depth = cavity.fill_depth(volume_ml)
            surface = (depth, cavity.surface_radius(depth))
            if len(self._blood_surfaces) >= 65536:
                self._blood_surfaces.clear()
            self._blood_surfaces[index, volume_ml] = surface
        return surface

    def _show_blood(self, index: int, volume_ml: float) -> None:
        geom = self._blood_geoms[index]
        depth, radius = self._blood_surface(index, volume_ml)
        if volume_ml <= 0.0 or radius <= 1e-4:
            self.model.geom_rgba[geom][3] = 0.0
            return
        self.model.geom_rgba[geom] = self._blood_rgba[index]
        self.model.geom_size[geom][0] = radius
        self.model.geom_pos[geom][2] = self.cavities[index].floor_z + depth - self.model.geom_size[geom][1]

    def blood_surface_height(self, index: int) -> float:
        """The drawn blood surface's height in cavity ``index`` (m)."""
        geom = self._blood_geoms[index]
        return float(self.model.geom_pos[geom][2] + self.model.geom_size[geom][1])

    def render(self):
        return self.renderer.render()

    @property
    def viewer(self):
        return self.renderer.viewer

    def close(self) -> None:
        self.renderer.close()


def fluid_colour(blood, clot, saline, blood_rgb) -> np.ndarray:
    """The colour (..., 3) of a cavity's fluid from what it holds (ml, arrays alike): liquid blood ``blood_rgb``,
    the others :data:`FLUID_COLOURS`, each weighted by its volume."""
    parts = np.stack([np.asarray(blood, np.float64), np.asarray(clot, np.float64), np.asarray(saline, np.float64)], -1)
    total = parts.sum(axis=-1, keepdims=True)
    colours = np.array([blood_rgb, FLUID_COLOURS["clot"], FLUID_COLOURS["saline"]], np.float64)
    return np.where(total > 0.0, parts @ colours / np.where(total > 0.0, total, 1.0), colours[0])


def _model_with_debris(scene: str, count: int) -> mujoco.MjModel:
    """The scene with exactly ``count`` pins in play: extra pins (copies of debris_0) when the file has fewer, the
    file's surplus ones out of sight and out of contact."""
    model = load_model(scene)
    available = 0
    while mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, f"debris_{available}") >= 0:
        available += 1
    if count > available:
        return _model_with_more_debris(scene, count)
    for index in range(count, available):
        geom = object_id(model, "geom", f"debris_{index}")
        model.geom_rgba[geom][3] = 0.0
        model.geom_contype[geom] = 0
        model.geom_conaffinity[geom] = 0
        body = object_id(model, "body", f"debris_{index}")
        model.body_pos[body] = (0.0, 0.0, -1.0)
        model.qpos0[model.jnt_qposadr[model.body_jntadr[body]] + 2] = -1.0
    return model


def _model_with_more_debris(scene: str, count: int) -> mujoco.MjModel:
    spec = mujoco.MjSpec.from_file(str(assets.scene_path(scene)))
    # Lookups through the lists (MjSpec.geom/.body by name are newer than the mujoco floor, 3.2).
    template = next(geom for geom in spec.geoms if geom.name == "debris_0")
    bodies = {body.name for body in spec.bodies}
    index = 0
    while f"debris_{index}" in bodies:
        index += 1
    while index < count:
        body = spec.worldbody.add_body(name=f"debris_{index}", pos=[0.0, 0.0, -1.0])
        body.add_freejoint(name=f"debris_{index}")
        body.add_geom(name=f"debris_{index}", type=mujoco.mjtGeom.mjGEOM_CAPSULE, size=template.size,
                      material=template.material, density=template.density)
        index += 1
    return spec.compile()
