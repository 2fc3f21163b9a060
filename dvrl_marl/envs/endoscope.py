"""The endoscope's view of many worlds, drawn for learning: what an image observation is made of.

The human view (``render()``, the seats' windows and pages) draws the whole scene every frame with shadows,
reflections and multisampling. The worlds are drawn here into tiles of one framebuffer, read back once per
framebuffer (into pixel buffers, taken once the next framebuffer's drawings are issued, so that a GPU draws while the
CPU puts images together). On a software renderer most of the work is the phantom, a heightfield of about 40,000
triangles that never moves: it is drawn once, with its depth, and then per world only what moves (the instruments,
the pins, the blood); a pixel is the moving layer's where that is nearer than the phantom's, else the phantom's.
With opaque geometry this is what one drawing of the whole scene gives (``tests/test_endoscope.py`` holds them
equal), at a fraction of the cost. On a GPU, whose cost is the calls per drawing, each world's whole scene is drawn
in its tile (``EndoscopeRenderer.layers``; ``benchmarks/endoscope_speed.py``, ``docs/speed.md``).

What the learning view leaves out, or draws otherwise, than the human view: no shadows, reflections, multisampling
or marks (drop lines, cues), and the blood opaque (the human view's blood lets the cavity floor show through). The
camera is the scene's ``endoscope`` (``scenes/collaborative.xml``), fixed; it is the stereo pair's left eye, and the
right eye the same camera :data:`STEREO_BASELINE_MM` to its right.
"""

from __future__ import annotations

import ctypes
from concurrent.futures import ThreadPoolExecutor

import mujoco
import numpy as np

# (the looks are re-exported: endoscope.Appearance, endoscope.held_out_only)
from dvrl_marl.suction_debris.appearance import APPEARANCES, QUANTITIES, Appearance, held_out_only  # noqa: F401
from dvrl_marl.envs.scene_mirror import SceneMirror
from dvrl_marl.rendering import uncollected
from dvrl_marl.suction_debris.scene_options import IMAGE_SIZES

__all__ = ["EndoscopeRenderer", "ThreadedEndoscopeRenderer", "endoscope_renderer", "IMAGE_SIZES", "RENDER_PARTS",
           "STEREO_BASELINE_MM",
           "SEGMENT_CLASSES", "Appearance", "APPEARANCES", "QUANTITIES", "held_out_only"]

#: What a segmentation mask's values mean (its index): nothing of the task (the table, the background), the phantom's
#: tissue, blood, a debris pin, an instrument (the arms' and the assistant's).
SEGMENT_CLASSES = ("background", "tissue", "blood", "pin", "instrument")

#: The stereo endoscope's two cameras apart (mm): the right eye's camera is the scene's ``endoscope`` (the left eye)
#: moved this far along its own x axis, looking the same way. 3D laparoscopes of the da Vinci's generation put their
#: cameras 5 mm apart (Bhayani & Andriole's ring-placement study cites 5-mm separation: Surg Endosc 22(11):2396-2400,
#: 2008, doi:10.1007/s00464-008-0032-8); the paper names the endoscope's "uniquely tight disparities" (Sec. VI).
STEREO_BASELINE_MM = 5.0

#: What :meth:`EndoscopeRenderer.render` can draw of a view.
RENDER_PARTS = ("rgb", "depth", "segmentation")
#: MuJoCo geom groups of this renderer's own model copy: what never moves, and what a world's state moves.
_STILL, _MOVING = 0, 1


class EndoscopeRenderer:
    """Draws the endoscope's view of many worlds of one scene (``params``: the env's :class:`SuctionDebrisParams`).

    ``render(states)`` takes the core's :meth:`world_state` of each world (or ``world_states``, stacked) and returns
    ``{"rgb": (N, S, S, 3) uint8}`` and, with ``depth=True``, ``"depth": (N, S, S) float32`` (metres along the
    camera's axis), with ``segmentation=True``, ``"segmentation": (N, S, S) uint8`` (indices of
    :data:`SEGMENT_CLASSES`; a second drawing), rows top to bottom. ``tiles`` worlds are drawn per framebuffer read
    (the default fills a framebuffer of at most 1024 px a side). ``layers``: the still phantom drawn once and what
    moves over it (True), or each world's whole scene (False); None: layers on a software renderer only. ``eye_mm``:
    the camera moved that far along its own x axis (to the right in its image), the endoscope's pose and its looks'
    shifts and turns kept: :data:`STEREO_BASELINE_MM` draws the stereo pair's right eye.
    """

    def __init__(self, params, size: int = 84, depth: bool = False, tiles: int | None = None,
                 segmentation: bool = False, layers: bool | None = None, eye_mm: float = 0.0):
        from dvrl_marl.schemas import Finite, PositiveInt, validated

        self._eye = validated(Finite, eye_mm, "eye_mm") / 1000.0  # (m)
        size = validated(PositiveInt, size, "image size")
        if not IMAGE_SIZES[0] <= size <= IMAGE_SIZES[1]:
            raise ValueError(f"image size must be {IMAGE_SIZES[0]}..{IMAGE_SIZES[1]} px, got {size}")
        self.size, self.depth, self.segmentation = size, bool(depth), bool(segmentation)
        self.mirror = SceneMirror(params)
        self.mirror.make_blood_opaque()  # the composite is exact for opaque geometry
        model, data = self.mirror.model, self.mirror.data
        blood = set(self.mirror.blood_geoms)
        still = np.array([model.geom_bodyid[g] == 0 and g not in blood for g in range(model.ngeom)])
        model.geom_group[:] = np.where(still, _STILL, _MOVING)
        self._geom_class = np.array([_segment_class(model, geom, blood) for geom in range(model.ngeom)], np.uint8)
        # What a look changes, and the scene's own values to change from (and back to).
        self._tissue_materials = sorted({int(model.geom_matid[g]) for g in range(model.ngeom)
                                         if self._geom_class[g] == SEGMENT_CLASSES.index("tissue")} - {-1})
        self._blood_materials = sorted({int(model.geom_matid[g]) for g in blood} - {-1})
        self._instrument_geoms = [g for g in range(model.ngeom)
                                  if self._geom_class[g] == SEGMENT_CLASSES.index("instrument")]
        self._instrument_materials = sorted({int(model.geom_matid[g]) for g in self._instrument_geoms} - {-1})
        self._base = {"mat_rgba": model.mat_rgba.copy(), "geom_rgba": model.geom_rgba.copy(),
                      "light_diffuse": model.light_diffuse.copy(), "light_specular": model.light_specular.copy()}
        self._still_looks: dict[int, tuple] = {}  # world -> (its look's key, still rgb, depth, segments)
        self._dressings: dict[int, tuple] = {}  # world -> (its look's key, its look's dressing)
        per_side = max(1, min(1024 // size, 16))
        self.columns = per_side
        self.rows = per_side if tiles is None else max(1, -(-validated(PositiveInt, tiles, "tiles") // per_side))
        self.tiles = self.columns * self.rows if tiles is None else int(tiles)
        width, height = size * self.columns, size * self.rows
        model.vis.quality.offsamples = 0
        model.vis.global_.offwidth, model.vis.global_.offheight = width, height
        self._gl = mujoco.GLContext(width, height)
        with uncollected():
            self._set_up(model, data, size)
            #: whether the still phantom is drawn once and each world's moving layer over it (a software renderer,
            #: whose cost is the phantom's triangles per world), or each world's whole scene in its tile (a GPU, whose
            #: cost is the calls per drawing, and no layers to put together on the CPU); None: by the GL renderer
            self.layers = _software_renderer() if layers is None else bool(layers)

    def _set_up(self, model, data, size: int) -> None:
        """The GL context's resources, the scene and its still layer (the context bound throughout)."""
        self._gl.make_current()
        self._context = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_100)
        self._scene = mujoco.MjvScene(model, maxgeom=1000)
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
        self._scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
        self._camera = mujoco.MjvCamera()
        self._camera.type = mujoco.mjtCamera.mjCAMERA_FIXED
        self._camera.fixedcamid = model.camera("endoscope").id
        self._perturb = mujoco.MjvPerturb()
        self._options = {}
        for groups in ((_STILL,), (_MOVING,), (_STILL, _MOVING)):
            option = mujoco.MjvOption()
            option.geomgroup[:] = 0
            option.geomgroup[list(groups)] = 1
            self._options[groups if len(groups) > 1 else groups[0]] = option
        mujoco.mj_forward(model, data)  # the camera and lights are fixed: placed once
        camera = self._camera.fixedcamid
        data.cam_xpos[camera] += self._eye * data.cam_xmat[camera].reshape(3, 3)[:, 0]  # (the eye: along its x)
        self._base.update(cam_xpos=data.cam_xpos.copy(), cam_xmat=data.cam_xmat.copy(),
                          light_xdir=data.light_xdir.copy(), light_xpos=data.light_xpos.copy())
        extent = model.stat.extent
        self._near, self._far = model.vis.map.znear * extent, model.vis.map.zfar * extent
        #: the framebuffer's reads, the GL's own depth values (MuJoCo's mjr_readPixels turns them round in 4.0)
        self._reads = _PixelReads(size * self.columns, size * self.rows, self._context.offFBO)
        #: the scene's own still layer (rgb, raw depth, segments or None), drawn once (its segments when first asked)
        self._still = self._draw_still(self.segmentation)
        # Which way the depth buffer runs (MuJoCo 3 and 4 reverse it: 1 near, an empty pixel 0; else an empty pixel 1).
        self._reversed = float(self._still[1].max()) < 0.5

    # --- drawing -------------------------------------------------------------------------------------------
    def _draw(self, group, tile: int) -> None:
        model, data = self.mirror.model, self.mirror.data
        scene, context = self._scene, self._context
        mujoco.mjv_updateScene(model, data, self._options[group], self._perturb, self._camera,
                               mujoco.mjtCatBit.mjCAT_ALL, scene)
        s = self.size
        mujoco.mjr_render(mujoco.MjrRect((tile % self.columns) * s, (tile // self.columns) * s, s, s), scene, context)

    def _read(self, count: int, depth: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
        """The first ``count`` tiles, (count, S, S, 3) and (count, S, S) raw depth (None without ``depth``), rows
        bottom to top. Only the framebuffer's rows of tiles that hold them are read back (a few worlds in a
        framebuffer for 256: a strip)."""
        return self._tiles(count, *self._reads.take(self._reads.queue(-(-count // self.columns) * self.size, depth)))

    def _tiles(self, count: int, rgb: np.ndarray, raw: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The first ``count`` tiles of rows of the framebuffer read back (rgb, and raw depth or None), each a world's
        image (count, S, S, ...)."""
        s, columns = self.size, self.columns
        rows = -(-count // columns)
        # (each read is an array of its own: one row of tiles may stay a view of it)
        tiles = rgb.reshape(rows, s, columns, s, 3).transpose(0, 2, 1, 3, 4).reshape(-1, s, s, 3)[:count]
        if raw is None:
            return tiles, None
        return tiles, raw.reshape(rows, s, columns, s).transpose(0, 2, 1, 3).reshape(-1, s, s)[:count]

    def _bind(self) -> None:
        self._gl.make_current()
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN, self._context)

    def _draw_still(self, segmentation: bool) -> tuple:
        """The still layer in the look worn now: rgb, raw depth and (with ``segmentation``) classes, rows bottom up."""
        self._bind()
        self._draw(_STILL, 0)
        rgb, depth = self._read(1)
        segments = None
        if segmentation:
            self._set_segmenting(True)
            self._draw(_STILL, 0)
            segments = self._classes(self._read(1)[0], [self._scene_classes()])[0]
            self._set_segmenting(False)
        return rgb[0].copy(), depth[0].copy(), segments

    def _set_segmenting(self, on: bool) -> None:
        self._scene.flags[mujoco.mjtRndFlag.mjRND_SEGMENT] = on
        self._scene.flags[mujoco.mjtRndFlag.mjRND_IDCOLOR] = on

    def _scene_classes(self) -> np.ndarray:
        """Class of each of the present scene's drawn geoms, offset by one (0: nothing drawn), as the colour ids
        of a segmenting drawing index them."""
        lookup = np.zeros(self._scene.ngeom + 1, np.uint8)
        for index in range(self._scene.ngeom):
            geom = self._scene.geoms[index]
            if geom.objtype == mujoco.mjtObj.mjOBJ_GEOM:
                lookup[index + 1] = self._geom_class[geom.objid]
        return lookup

    @staticmethod
    def _classes(rgb: np.ndarray, lookups: list[np.ndarray]) -> np.ndarray:
        """Segmenting drawings' colours (ids of the scene's geoms + 1) to classes, a lookup per tile."""
        ids = rgb[..., 0].astype(np.int64) | (rgb[..., 1].astype(np.int64) << 8) | (rgb[..., 2].astype(np.int64) << 16)
        return np.stack([lookup[np.minimum(tile_ids, len(lookup) - 1)] for tile_ids, lookup in zip(ids, lookups)])

    def _dressing(self, look: dict | None) -> dict:
        """The model's colours and lights and the camera's pose in ``look`` (:meth:`Appearance.draw`'s; None: the
        scene's own), as :meth:`_wear` puts them on: worked out once per look, worn every frame."""
        base = self._base
        if look is None:
            return base
        dressing = {name: value.copy() for name, value in base.items()}
        for materials, gain in ((self._tissue_materials, look["tissue"]), (self._blood_materials, look["blood"]),
                                (self._instrument_materials, look["instrument"])):
            dressing["mat_rgba"][materials, :3] = np.clip(base["mat_rgba"][materials, :3] * gain, 0.0, 1.0)
        geoms = self._instrument_geoms  # (those without a material: their own colour)
        dressing["geom_rgba"][geoms, :3] = np.clip(base["geom_rgba"][geoms, :3] * look["instrument"], 0.0, 1.0)
        dressing["light_diffuse"] = np.clip(base["light_diffuse"] * look["light"], 0.0, 1.0)
        dressing["light_specular"] = np.clip(base["light_specular"] * look["light"], 0.0, 1.0)
        dressing["light_xdir"] = base["light_xdir"] @ _turn(*look["light_turn"]).T
        camera = self._camera.fixedcamid
        axes = base["cam_xmat"][camera].reshape(3, 3)
        turned = _turn(*look["camera_turn"]) @ axes
        # the endoscope shifted and turned about its left eye, which the right one follows (the pair is one rigid rig)
        dressing["cam_xpos"][camera] = (base["cam_xpos"][camera] + look["camera_shift"]
                                        + self._eye * (turned[:, 0] - axes[:, 0]))
        dressing["cam_xmat"][camera] = turned.ravel()
        return dressing

    def _wear(self, dressing: dict) -> None:
        """Dress the model and the camera in ``dressing`` (:meth:`_dressing`'s)."""
        model, data = self.mirror.model, self.mirror.data
        for name in ("mat_rgba", "geom_rgba", "light_diffuse", "light_specular"):
            getattr(model, name)[:] = dressing[name]
        for name in ("cam_xpos", "cam_xmat", "light_xdir", "light_xpos"):
            getattr(data, name)[:] = dressing[name]

    def parts(self, parts=None) -> tuple[str, ...]:
        """``parts`` checked (any of :data:`RENDER_PARTS`); None: the renderer's own (rgb, and depth and segmentation
        when made with them)."""
        if parts is None:
            return tuple(part for part, on in zip(RENDER_PARTS, (True, self.depth, self.segmentation)) if on)
        parts = (parts,) if isinstance(parts, str) else tuple(parts)
        unknown = [part for part in parts if part not in RENDER_PARTS]
        if unknown or not parts:
            raise ValueError(f"render: parts must be some of {RENDER_PARTS}, got {list(parts)}")
        return tuple(part for part in RENDER_PARTS if part in parts)

    def render(self, states: list[dict], looks: list[dict] | None = None, keys: list | None = None,
               frames=None, parts=None, worlds=None) -> dict:
        """The view of each world in ``states`` (the core's ``world_state`` dicts, or ``world_states``: one dict of
        them stacked); with ``looks`` (one
        :meth:`Appearance.draw` per world) each world dressed in its own: ``keys`` (a tuple of non-negative ints per
        world) name each look (a world's still layer is drawn again only when its key changes) and with ``frames``
        (each world's step in its episode) seed its image noise. ``parts`` (:meth:`parts`) draws only those: a
        segmentation alone costs one drawing of what moves, not two. ``worlds``: which worlds ``states`` are (their
        looks' layers kept apart), when they are some of a batch (default: 0, 1, ...)."""
        with uncollected():
            return self._render(states, looks, keys, frames, parts, worlds)

    def _render(self, states, looks, keys, frames, parts, worlds) -> dict:
        """:meth:`render`, garbage collection held off."""
        poses = self.mirror.poses(states)
        count, s = len(poses["qpos"]), self.size
        if looks is not None and "saline_ml" in (states if isinstance(states, dict) else states[0]):
            # the fluids are drawn in colours of their own (what each cavity holds), not the blood's material's,
            # which a look tints: the look's blood gain goes onto them
            gains = np.array([look["blood"] for look in looks], np.float64).reshape(count, 1, 3)
            poses["blood_rgba"][..., :3] = np.clip(poses["blood_rgba"][..., :3] * gains, 0.0, 1.0)
        ids = list(range(count)) if worlds is None else [int(world) for world in worlds]
        parts = self.parts(parts)
        segmentation, colour = "segmentation" in parts, "rgb" in parts or "depth" in parts
        if looks is not None:
            if keys is None or len(keys) != count or len(looks) != count:
                raise ValueError("render: one look and one key per world")
            frames = np.zeros(count, np.int64) if frames is None else np.asarray(frames, np.int64)
            for world, look, key in zip(ids, looks, keys):
                dressed = self._dressings.get(world)
                if dressed is None or dressed[0] != key:
                    self._dressings[world] = dressed = (key, self._dressing(look))
                entry = self._still_looks.get(world)
                if self.layers and (entry is None or entry[0] != key or (segmentation and entry[3] is None)):
                    self._wear(dressed[1])
                    self._still_looks[world] = (key, *self._draw_still(segmentation or self.segmentation))
        elif self.layers and segmentation and self._still[2] is None:
            self._still = self._draw_still(True)
        out = {part: np.empty((count, s, s, 3) if part == "rgb" else (count, s, s),
                              {"rgb": np.uint8, "depth": np.float32, "segmentation": np.uint8}[part])
               for part in parts}
        model, data = self.mirror.model, self.mirror.data
        # layers: what moves, drawn in colour and (for segments) again by geom ids, the depth of either placing it
        # over the still layer; else each world's whole scene, its depth read only when asked for
        drawing, read_depth = (_MOVING, True) if self.layers else ((_STILL, _MOVING), "depth" in parts)
        # Each framebuffer's reads are queued after its drawings and taken once the next framebuffer's drawings are
        # issued: the GPU draws the next worlds while the CPU waits for and puts together the last ones.
        queued = []
        for start in range(0, count, self.tiles):
            worlds = range(start, min(count, start + self.tiles))
            reads = {}
            for segmenting in (False,) * colour + (True,) * segmentation:
                self._bind()
                self._set_segmenting(segmenting)
                lookups = []
                for tile, world in enumerate(worlds):
                    if looks is not None:
                        self._wear(self._dressings[ids[world]][1])
                    self.mirror.put(poses, world)
                    mujoco.mj_kinematics(model, data)
                    self._draw(drawing, tile)
                    if segmenting:
                        lookups.append(self._scene_classes())
                # (the segments' depth: only where they place a layer that no colour drawing placed)
                with_depth = (self.layers and not colour) if segmenting else read_depth
                reads[segmenting] = (self._reads.queue(-(-len(worlds) // self.columns) * s, with_depth), lookups)
            self._set_segmenting(False)
            if queued:
                self._put_together(out, *queued.pop(), parts, looks, keys, frames, ids)
            queued.append((worlds, reads))
        for job in queued:
            self._put_together(out, *job, parts, looks, keys, frames, ids)
        if looks is not None:
            self._wear(self._base)
        return out

    def _put_together(self, out: dict, worlds: range, reads: dict, parts, looks, keys, frames, ids) -> None:
        """The images of ``worlds`` (one framebuffer's) as their rows of ``out``, from their queued reads."""
        drawn = {segmenting: (*self._tiles(len(worlds), *self._reads.take(read)), lookups)
                 for segmenting, (read, lookups) in reads.items()}
        segmentation, colour = True in drawn, False in drawn
        rows = slice(worlds.start, worlds.stop)
        if not self.layers:
            if colour:
                self._put_whole(out, rows, drawn[False], parts, looks, keys, frames, worlds)
            if segmentation:
                out["segmentation"][rows] = self._classes(drawn[True][0], drawn[True][2])[:, ::-1]
            return
        # the still layers: the scene's own one, or each world's in its look
        still = [self._still] if looks is None else [self._still_looks[ids[world]][1:] for world in worlds]
        still_rgb, still_depth = np.stack([entry[0] for entry in still]), np.stack([entry[1] for entry in still])
        moving_rgb, moving_depth, _ = drawn[not colour]  # (either drawing's depth: the same geometry)
        nearer = moving_depth > still_depth if self._reversed else moving_depth < still_depth
        if "rgb" in parts:
            out["rgb"][rows] = self._noisy(np.where(nearer[..., None], moving_rgb, still_rgb)[:, ::-1], looks,
                                           keys, frames, worlds)
        if "depth" in parts:
            out["depth"][rows] = self._metres(np.where(nearer, moving_depth, still_depth)[:, ::-1])
        if segmentation:
            segment_rgb, _, lookups = drawn[True]
            still_segments = np.stack([entry[2] for entry in still])
            classes = self._classes(segment_rgb, lookups)
            out["segmentation"][rows] = np.where(nearer, classes, still_segments)[:, ::-1]

    def _put_whole(self, out: dict, rows: slice, drawn: tuple, parts, looks, keys, frames, worlds) -> None:
        """Whole scenes' drawings (colour and raw depth) as the rows ``rows`` of ``out``."""
        rgb, raw, _ = drawn
        if "rgb" in parts:
            out["rgb"][rows] = self._noisy(rgb[:, ::-1], looks, keys, frames, worlds)
        if "depth" in parts:
            out["depth"][rows] = self._metres(raw[:, ::-1])

    @staticmethod
    def _noisy(image: np.ndarray, looks, keys, frames, worlds) -> np.ndarray:
        """The images with their looks' noise: seeded by each world's look and its frame."""
        if looks is None:
            return image
        image = image.astype(np.float32)
        for index, world in enumerate(worlds):
            if looks[world]["noise"] > 0.0:
                rng = np.random.default_rng([*(int(v) for v in keys[world]), int(frames[world])])
                image[index] += rng.normal(0.0, looks[world]["noise"], image[index].shape).astype(np.float32)
        return np.clip(np.rint(image), 0, 255)

    def _metres(self, raw: np.ndarray) -> np.ndarray:
        """OpenGL's perspective depth in metres along the camera's axis (either way the buffer runs)."""
        near, far = self._near, self._far
        z = raw.astype(np.float64)
        if self._reversed:  # 1 at the near plane, 0 at the far one
            return (near * far / ((far - near) * z + near)).astype(np.float32)
        return (near * far / (far - z * (far - near))).astype(np.float32)

    def close(self) -> None:
        if getattr(self, "_gl", None) is not None:
            # MuJoCo frees the context's framebuffers and textures by their ids in whichever GL context is current:
            # in another renderer's, ids it uses too (its images came back black). Its own, then.
            with uncollected():
                self._gl.make_current()
                self._reads.free()
                self._context.free()
                self._gl.free()
            self._gl = None

    def __del__(self):
        # a dropped env's renderer, collected: freed in its own context (close), never in the one drawing now
        try:
            self.close()
        except Exception:  # (at interpreter exit EGL may be gone before it)
            pass


class ThreadedEndoscopeRenderer:
    """:class:`EndoscopeRenderer`'s images drawn by ``contexts`` of them at once, each with a GL context of its own in
    a thread of its own. Why: on a GPU the driver's work per drawing call, on the CPU, bounds one context, and MuJoCo
    lets go of Python's lock while it draws. World ``w`` is always drawn by renderer ``w % contexts`` (its look's
    still layer is kept there). The images are the one renderer's (``tests/test_endoscope.py``)."""

    def __init__(self, params, size: int = 84, depth: bool = False, tiles: int | None = None,
                 segmentation: bool = False, contexts: int = 2, layers: bool | None = None, eye_mm: float = 0.0):
        from dvrl_marl.schemas import PositiveInt, validated

        contexts = validated(PositiveInt, contexts, "endoscope contexts")
        self._threads = [ThreadPoolExecutor(1, thread_name_prefix=f"endoscope-{index}") for index in range(contexts)]
        self._renderers = []
        try:
            with uncollected():  # (each renderer made in its own thread: its GL context is current there alone)
                for thread in self._threads:
                    self._renderers.append(thread.submit(EndoscopeRenderer, params, size, depth, tiles,
                                                         segmentation, layers, eye_mm).result())
        except BaseException:
            self.close()
            raise
        first = self._renderers[0]
        self.size, self.depth, self.segmentation = first.size, first.depth, first.segmentation
        self.layers, self.contexts = first.layers, contexts

    def parts(self, parts=None) -> tuple[str, ...]:
        """:meth:`EndoscopeRenderer.parts`."""
        return self._renderers[0].parts(parts)

    def render(self, states: list[dict], looks: list[dict] | None = None, keys: list | None = None,
               frames=None, parts=None, worlds=None) -> dict:
        """:meth:`EndoscopeRenderer.render`, each world drawn by its renderer, all of them at once."""
        count, parts = len(states["jaw"] if isinstance(states, dict) else states), self.parts(parts)
        ids = np.arange(count) if worlds is None else np.asarray([int(world) for world in worlds], np.int64)
        if looks is not None and (keys is None or len(keys) != count or len(looks) != count):
            raise ValueError("render: one look and one key per world")

        def some(values, rows):
            if isinstance(values, dict):  # (world_states: each array's rows)
                return {key: some(value, rows) if isinstance(value, dict) else np.asarray(value)[rows]
                        for key, value in values.items()}
            return None if values is None else [values[row] for row in rows]

        # garbage collection held off here, while the threads draw (each thread's own hold would end in another's)
        with uncollected():
            shares = [np.flatnonzero(ids % self.contexts == index) for index in range(self.contexts)]
            pending = [(rows, thread.submit(renderer.render, some(states, rows), some(looks, rows), some(keys, rows),
                                            None if frames is None else np.asarray(frames)[rows], parts, ids[rows]))
                       for rows, thread, renderer in zip(shares, self._threads, self._renderers) if len(rows)]
            drawn = [(rows, future.result()) for rows, future in pending]
        out = {part: np.empty((count, *images.shape[1:]), images.dtype) for part, images in drawn[0][1].items()}
        for rows, images in drawn:
            for part, value in images.items():
                out[part][rows] = value
        return out

    def close(self) -> None:
        with uncollected():
            for thread, renderer in zip(self._threads, self._renderers):
                thread.submit(renderer.close).result()  # (in its own thread, where its context is current)
        for thread in self._threads:
            thread.shutdown()
        self._renderers, self._threads = [], []

    def __del__(self):
        try:
            self.close()
        except Exception:  # (at interpreter exit the threads may be gone before it)
            pass


def endoscope_renderer(params, size: int = 84, depth: bool = False, segmentation: bool = False, contexts: int = 1,
                       eye_mm: float = 0.0):
    """The endoscope's renderer with ``contexts`` GL contexts: one, drawn in the calling thread
    (:class:`EndoscopeRenderer`), or more, each in a thread of its own (:class:`ThreadedEndoscopeRenderer`, which
    refuses a bad number by name); ``eye_mm`` as :class:`EndoscopeRenderer`'s."""
    if type(contexts) is int and contexts == 1:
        return EndoscopeRenderer(params, size, depth=depth, segmentation=segmentation, eye_mm=eye_mm)
    return ThreadedEndoscopeRenderer(params, size, depth=depth, segmentation=segmentation, contexts=contexts,
                                     eye_mm=eye_mm)


class _PixelReads:
    """Reads of the bound framebuffer's first rows into pixel buffer objects: :meth:`queue` right after the drawings
    (the GL keeps its order: later drawings do not change what it reads), :meth:`take` later, which waits only for
    that read. Its buffers, each the size of the whole framebuffer's depth, are made once and reused; the GL context
    that made them must be current at each call."""

    def __init__(self, width: int, height: int, framebuffer: int):
        from OpenGL import GL

        self._gl, self._width, self._framebuffer, self._free, self._buffers = GL, width, framebuffer, [], []
        self._capacity = width * height * np.dtype(np.float32).itemsize  # (the largest read: every row's depth)

    def queue(self, height: int, depth: bool) -> tuple:
        """Queue a read of the framebuffer's ``height`` bottom rows (rgb, and raw depth with ``depth``)."""
        GL = self._gl
        GL.glBindFramebuffer(GL.GL_READ_FRAMEBUFFER, self._framebuffer)  # (as MuJoCo's own read: its offscreen one)
        GL.glReadBuffer(GL.GL_COLOR_ATTACHMENT0)
        read = []
        for form, kind, channels, dtype in ((GL.GL_RGB, GL.GL_UNSIGNED_BYTE, 3, np.uint8),
                                            (GL.GL_DEPTH_COMPONENT, GL.GL_FLOAT, 1, np.float32))[:1 + bool(depth)]:
            size = self._width * height * channels * np.dtype(dtype).itemsize
            if self._free:
                buffer = self._free.pop()
                GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, buffer)
            else:
                buffer = int(GL.glGenBuffers(1))
                self._buffers.append(buffer)
                GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, buffer)
                GL.glBufferData(GL.GL_PIXEL_PACK_BUFFER, self._capacity, None, GL.GL_STREAM_READ)
            GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
            GL.glReadPixels(0, 0, self._width, height, form, kind, ctypes.c_void_p(0))
            read.append((buffer, size, (height, self._width, channels) if channels > 1 else (height, self._width),
                         dtype))
        GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, 0)  # (MuJoCo's own reads go to memory)
        return tuple(read)

    def take(self, read: tuple) -> tuple[np.ndarray, np.ndarray | None]:
        """A queued read's rows (bottom to top): rgb (rows, width, 3) uint8 and raw depth (rows, width) or None."""
        GL = self._gl
        arrays = []
        for buffer, size, shape, dtype in read:
            GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, buffer)
            address = GL.glMapBufferRange(GL.GL_PIXEL_PACK_BUFFER, 0, size, GL.GL_MAP_READ_BIT)
            if not address:
                GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, 0)
                raise RuntimeError("the endoscope's renderer could not map its pixel buffer")
            mapped = np.ctypeslib.as_array((ctypes.c_ubyte * size).from_address(int(address)))
            arrays.append(mapped.view(dtype).reshape(shape).copy())
            GL.glUnmapBuffer(GL.GL_PIXEL_PACK_BUFFER)
            self._free.append(buffer)
        GL.glBindBuffer(GL.GL_PIXEL_PACK_BUFFER, 0)
        return arrays[0], arrays[1] if len(arrays) > 1 else None

    def free(self) -> None:
        """Delete the buffers (their GL context current)."""
        if self._buffers:
            self._gl.glDeleteBuffers(len(self._buffers), self._buffers)
        self._buffers, self._free = [], []


def _software_renderer() -> bool:
    """Whether the current GL context is drawn by the CPU (Mesa's llvmpipe or softpipe, SwiftShader)."""
    from OpenGL import GL

    name = (GL.glGetString(GL.GL_RENDERER) or b"").decode(errors="replace").lower()
    return any(word in name for word in ("llvmpipe", "softpipe", "swiftshader", "software"))


def _segment_class(model, geom: int, blood: set) -> int:
    name = model.geom(geom).name
    if geom in blood:
        return SEGMENT_CLASSES.index("blood")
    if name == "phantom":
        return SEGMENT_CLASSES.index("tissue")
    if name.startswith("debris_"):
        return SEGMENT_CLASSES.index("pin")
    if model.geom_bodyid[geom] != 0 or name.endswith("shaft"):  # the arms' links, the assistant's instrument
        return SEGMENT_CLASSES.index("instrument")
    return SEGMENT_CLASSES.index("background")


def _turn(about_x: float, about_y: float) -> np.ndarray:
    """A small rotation: ``about_x`` then ``about_y`` radians."""
    cx, sx, cy, sy = np.cos(about_x), np.sin(about_x), np.cos(about_y), np.sin(about_y)
    return np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]]) @ np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx],
                                                                                   [0.0, sx, cx]])
