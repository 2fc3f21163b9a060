"""Observation features a policy computes from its own observation: the same arithmetic in numpy and torch.

A collaborative agent's observation lists every pin slot (position, visible, held, delivered; hidden pins read as
zeros, the workspace centre) and the hand-off point as absolute, normalised positions. What the grasper must act
on is a choice among those slots: the nearest pin still to collect, or, while it holds one, the way to the
assistant. A tanh network computes differences of positions easily (they are linear) but a masked minimum over
slots poorly (measured: beside the scripted suction the grasper's plain-observation actor held a pin in about half
of its lessons and still carried it toward a phantom target). :func:`suction_debris_targets` hands it that choice
as vectors relative to its own tip, from nothing but the agent's observation (no privileged state): the trainer's
actors read ``observation + features`` and the exported numpy policy computes the same features before its first
layer (its ``policy.json`` names them, see :func:`apply`).

:func:`suction_debris_routes` adds what the env's wall rule asks of a policy: the cavity still to clear, and how far
the tip must rise before a wall stops standing between it and its target. A feature set's definition is part of
every policy exported with it: change one only under a new name.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.suction_debris import layout

__all__ = ["spec", "suction_debris_targets", "suction_debris_routes", "suction_debris_cleared_pins",
           "suction_debris_cleared_pins_zoom", "suction_debris_bleeding", "psm_pick_zoom", "pick_spec", "SCENE_FEATURE_SETS", "routes_geometry", "feature_count", "apply", "FEATURES",
           "check_spec", "observation_width"]

#: A distance no pin in the normalised workspace reaches (masked slots).
_FAR = 1e6


class _Ops:
    """The handful of array operations that differ between numpy (or JAX, whose ``jax.numpy`` takes numpy's calls)
    and torch."""

    def __init__(self, x):
        self.dtype = x.dtype
        self.torch = None
        if isinstance(x, np.ndarray):
            self.np = np
        elif type(x).__module__.startswith("torch"):
            import torch

            self.torch, self.device = torch, x.device
        else:  # a JAX array (under jax.jit too)
            import jax.numpy

            self.np = jax.numpy

    def where(self, condition, a, b):
        return self.np.where(condition, a, b) if self.torch is None else self.torch.where(condition, a, b)

    def concatenate(self, parts):
        return self.np.concatenate(parts, axis=-1) if self.torch is None else self.torch.cat(parts, dim=-1)

    def as_float(self, mask):
        return mask.astype(self.dtype) if self.torch is None else mask.to(self.dtype)

    def arange(self, count):
        return self.np.arange(count) if self.torch is None else self.torch.arange(count, device=self.device)

    def constant(self, values):
        values = np.asarray(values, dtype=np.float64)
        if self.torch is None:
            return self.np.asarray(values.astype(self.dtype))
        return self.torch.as_tensor(values, dtype=self.dtype, device=self.device)

    def row(self, x, index):
        """``x[..., index, :]`` for each leading index (``x`` (..., K, k), ``index`` (...))."""
        if self.torch is None:
            return self.np.take_along_axis(x, index[..., None, None], axis=-2)[..., 0, :]
        return self.torch.gather(x, -2, index[..., None, None].expand(*index.shape, 1, x.shape[-1]))[..., 0, :]

    def positive_part(self, x):
        return self.np.maximum(x, 0.0) if self.torch is None else x.clamp_min(0.0)

    def tanh(self, x):
        return self.np.tanh(x) if self.torch is None else self.torch.tanh(x)


def _squared(v):
    """Squared lengths of the last axis's 2 or 3 components (a sum written out: numpy reduces a short axis slowly)."""
    out = v[..., 0] * v[..., 0] + v[..., 1] * v[..., 1]
    return out + v[..., 2] * v[..., 2] if v.shape[-1] == 3 else out


def _nearest(ops, offset, pending):
    """``offset`` (..., K, 3) from the tip to K candidates, ``pending`` (..., K): the offset to the nearest pending
    one (zeros when none is) and whether there is one."""
    distance = ops.where(pending, _squared(offset), _FAR)
    has = pending.any(-1)
    return ops.row(offset, distance.argmin(-1)) * ops.as_float(has)[..., None], has


def feature_count(name: str) -> int:
    """How many features ``name`` appends."""
    if name not in FEATURES:
        raise ValueError(f"unknown observation features {name!r} (known: {sorted(FEATURES)})")
    return FEATURES[name]


def _part(observation, name: str, cavities: int, debris: int):
    """The observation's part ``name`` (:func:`dvrl_marl.suction_debris.layout.observation_layout`)."""
    return observation[..., layout.observation_layout(cavities, debris)[name]]


def _slots(observation, cavities, debris):
    """``(..., debris, PIN_WIDTH)``: every pin's slot."""
    return _part(observation, "debris", cavities, debris).reshape(*observation.shape[:-1], debris, layout.PIN_WIDTH)


def _flags(slots):
    """Each pin's visible, held and delivered flags, as booleans."""
    return slots[..., layout.PIN_VISIBLE] > 0.5, slots[..., layout.PIN_HELD] > 0.5, slots[..., layout.PIN_DELIVERED] > 0.5


def _targets_parts(ops, observation, cavities, debris):
    tip, other = _part(observation, "own_tip", cavities, debris), _part(observation, "other_tip", cavities, debris)
    slots = _slots(observation, cavities, debris)
    position = slots[..., layout.PIN_POSITION]
    visible, held, delivered = _flags(slots)
    pending = visible & ~held & ~delivered
    to_pin, has_pin = _nearest(ops, position - tip[..., None, :], pending)
    holding = held.any(-1)
    handoff = _part(observation, "handoff", cavities, debris)
    held_position = (position * ops.as_float(held)[..., None]).sum(-2)  # at most one pin is held
    carry = (handoff - held_position) * ops.as_float(holding)[..., None]
    return [to_pin, ops.as_float(has_pin)[..., None], ops.as_float(holding)[..., None], carry, handoff - tip,
            other - tip]


def suction_debris_targets(observation, *, cavities: int, debris: int):
    """``(..., obs_dim)`` -> ``(..., 14)``, for either agent of ``suction_debris_v8``:

    - ``to_pin`` (3): from the agent's tip to the nearest pin that is visible, not held and not delivered (zeros
      when there is none), and ``has_pin`` (1): whether there is one;
    - ``holding`` (1): whether the grasper holds a pin; ``carry`` (3): from the held pin to the hand-off point
      (zeros when nothing is held);
    - ``to_handoff`` (3): from the tip to the hand-off point; ``to_other`` (3): from the tip to the other arm's tip.
    """
    ops = _Ops(observation)
    return ops.concatenate(_targets_parts(ops, observation, cavities, debris))


def spec(name: str, layout, debris: int) -> dict:
    """The feature set ``name`` for a scene: its name, the observation's layout (cavities, debris slots) and, for the
    sets that need it, the scene's fixed geometry (``layout``: an env's ``layout()``). What :func:`apply` takes, what
    an exported policy records, and what the env's ``observation_features`` option computes."""
    feature_count(name)
    if name not in SCENE_FEATURE_SETS:
        raise ValueError(f"observation features {name!r} are not the collaborative scene's (its sets: "
                         f"{list(SCENE_FEATURE_SETS)})")
    out = {"name": name, "cavities": len(layout.cavity_centres), "debris": int(debris)}
    if name in NEEDS_GEOMETRY:
        out.update(routes_geometry(layout))
    if getattr(layout, "fluids", False):  # the observation ends with the fluids' slots (read by no feature)
        out["fluids"] = True
    return out


def pick_spec(env, zoom: float = 0.2) -> dict:
    """:func:`psm_pick_zoom`'s spec for a PSM Pick env (its tool point's drop below p, normalised); ``zoom`` 0.2 rho
    is 5 mm at the paper's rho = 2.5 cm."""
    unwrapped = env.unwrapped
    return {"name": "psm_pick_zoom", "tool_point_drop": float(unwrapped.arm.tool_point_drop / unwrapped.workspace_range),
            "zoom": float(zoom)}


def routes_geometry(layout) -> dict:
    """The scene facts :func:`suction_debris_routes` needs, from an env's ``layout()`` (normalised, JSON-ready)."""
    return {"cavity_centres": [[float(v) for v in c] for c in layout.cavity_centres],
            "cavity_mouth_radius": float(layout.cavity_mouth_radius),
            "cavity_targets_z": [float(z + layout.clearance) for z in layout.cavity_floor],
            "rim_z": float(layout.phantom_top + layout.clearance),
            "blood_threshold_fraction": [float(v) for v in layout.blood_threshold_fraction]}


def _routes_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius, cavity_targets_z, rim_z,
                  blood_threshold_fraction):
    parts = _targets_parts(ops, observation, cavities, debris)
    tip = _part(observation, "own_tip", cavities, debris)
    levels = _part(observation, "blood", cavities, debris)
    centres = ops.constant(cavity_centres)  # (C, 2)
    targets = ops.concatenate([centres, ops.constant(cavity_targets_z)[:, None]])  # (C, 3)
    pending = (levels >= ops.constant(blood_threshold_fraction)) & (levels > 0.0)
    to_cavity, has_cavity = _nearest(ops, targets - tip[..., None, :], pending)

    mouth2 = float(cavity_mouth_radius) ** 2

    def inside(points):  # (..., 3) -> (..., C): which cavity mouths the point lies over
        return _squared(points[..., None, 0:2] - centres) < mouth2

    # Below the rim the tip is in a cavity or beside the phantom: every way out but into the same cavity is walled.
    below_rim = ops.positive_part(rim_z - tip[..., 2])
    tip_over = inside(tip)

    def climb(target, valid=None):
        walled = ~(tip_over & inside(target)).any(-1)
        return (below_rim * ops.as_float(walled if valid is None else walled & valid))[..., None]

    handoff = _part(observation, "handoff", cavities, debris)
    pin = tip + parts[0]
    return parts + [to_cavity, ops.as_float(has_cavity)[..., None], climb(tip + to_cavity, has_cavity),
                    climb(pin, parts[1][..., 0] > 0.5), climb(handoff)]


def suction_debris_routes(observation, *, cavities: int, debris: int, cavity_centres, cavity_mouth_radius,
                          cavity_targets_z, rim_z, blood_threshold_fraction):
    """``(..., obs_dim)`` -> ``(..., 21)``: :func:`suction_debris_targets`'s 14, then where to go next and whether
    a wall stands in the way (the env refuses a horizontal step into a wall, so a tip below a rim must rise before
    it can leave; measured: learned arms' mean actions push across the wall and stay there):

    - ``to_cavity`` (3): from the tip to the floor of the nearest cavity still above its clearing threshold (the
      scripted suction's target; zeros when every cavity is clear), ``has_cavity`` (1);
    - ``climb_to_cavity``, ``climb_to_pin``, ``climb_to_handoff`` (3): how far the tip lies below the rim (in a
      cavity, or beside the phantom) unless that target lies over the same cavity (0 above the rim, or when there is
      no such target). Measured: a grasper waiting beside the phantom pushed into its side for 1,000 steps.

    The geometry is the scene's, fixed (:func:`routes_geometry`; the exported policy keeps it in its
    ``policy.json``), not state: the actor still reads nothing but its own observation.
    """
    ops = _Ops(observation)
    return ops.concatenate(_routes_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius,
                                         cavity_targets_z, rim_z, blood_threshold_fraction))


def _cleared_pins_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius, cavity_targets_z,
                        rim_z, blood_threshold_fraction):
    parts = _routes_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius, cavity_targets_z,
                          rim_z, blood_threshold_fraction)
    tip = _part(observation, "own_tip", cavities, debris)
    levels = _part(observation, "blood", cavities, debris)
    centres = ops.constant(cavity_centres)
    slots = _slots(observation, cavities, debris)
    position = slots[..., layout.PIN_POSITION]
    home = ops.as_float(_squared(position[..., None, 0:2] - centres).argmin(-1)[..., None]
                        == ops.arange(cavities))  # (..., D, C)
    cleared = (levels < ops.constant(blood_threshold_fraction)) | (levels <= 0.0)  # (..., C)
    in_cleared = (home * ops.as_float(cleared)[..., None, :]).sum(-1) > 0.5  # (..., D)
    visible, held, delivered = _flags(slots)
    pending = visible & ~held & ~delivered & in_cleared
    to_pin, has_pin = _nearest(ops, position - tip[..., None, :], pending)
    # the climb toward it, as suction_debris_routes measures its own
    mouth2 = float(cavity_mouth_radius) ** 2
    target = tip + to_pin
    same = ((_squared(tip[..., None, 0:2] - centres) < mouth2) & (_squared(target[..., None, 0:2] - centres) < mouth2)
            ).any(-1)
    climb = ops.positive_part(rim_z - tip[..., 2]) * ops.as_float(~same & has_pin)
    return parts + [to_pin, ops.as_float(has_pin)[..., None], climb[..., None]]


def suction_debris_cleared_pins(observation, *, cavities: int, debris: int, cavity_centres, cavity_mouth_radius,
                                cavity_targets_z, rim_z, blood_threshold_fraction):
    """``(..., obs_dim)`` -> ``(..., 26)``: :func:`suction_debris_routes`'s 21, then the nearest pin to collect that
    lies in a cleared cavity (the only pins the scripted surgeon goes for: the others share a cavity with the working
    suction): ``to_clear_pin`` (3, zeros when there is none), ``has_clear_pin`` (1) and ``climb_to_clear_pin`` (1).
    Measured: a grasper drifting toward the revealed pins while the suction still worked there touched it for 128 of
    1,500 steps (return 1.75 against 14.5 for one that kept away), and learnt to keep away from every pin.
    """
    ops = _Ops(observation)
    return ops.concatenate(_cleared_pins_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius,
                                               cavity_targets_z, rim_z, blood_threshold_fraction))


#: :func:`suction_debris_cleared_pins_zoom`'s scale: 5 mm in the observation's normalised units (workspace range
#: 80 mm, tasks/suction_debris.toml), fixed as every feature set's definition is; tanh(offset / ZOOM) resolves the
#: last few millimetres and saturates beyond about a centimetre.
ZOOM = 0.005 / 0.08


def _cleared_pins_zoom_parts(ops, observation, *arguments):
    parts = _cleared_pins_parts(ops, observation, *arguments)
    to_clear_pin, carry = parts[-3], parts[3]
    return parts + [ops.tanh(to_clear_pin / ZOOM), ops.tanh(carry / ZOOM)]


def suction_debris_cleared_pins_zoom(observation, *, cavities: int, debris: int, cavity_centres,
                                     cavity_mouth_radius, cavity_targets_z, rim_z, blood_threshold_fraction):
    """``(..., obs_dim)`` -> ``(..., 32)``: :func:`suction_debris_cleared_pins`'s 26, then ``tanh(to_clear_pin /
    ZOOM)`` (3) and ``tanh(carry / ZOOM)`` (3): the same two offsets seen through a magnifier. Why: the grasp rule
    asks for the tip within 3 mm of a pin's axis (a grasp a few millimetres off the pin's centre, toward the hand-off
    side, can never be delivered) and delivery for the pin within 3 mm of the hand-off point, while the plain
    offsets span the whole workspace: after the actor's normalisation 3 mm is about a tenth of their spread, a
    detail a small tanh network resolves slowly. The zoomed copies give those millimetres the whole of a unit's
    range (multi-scale inputs); they are functions of the actor's own observation, as every feature here."""
    ops = _Ops(observation)
    return ops.concatenate(_cleared_pins_zoom_parts(ops, observation, cavities, debris, cavity_centres,
                                                    cavity_mouth_radius, cavity_targets_z, rim_z,
                                                    blood_threshold_fraction))


def _bleeding_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius, cavity_targets_z,
                    rim_z, blood_threshold_fraction):
    parts = _cleared_pins_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius,
                                cavity_targets_z, rim_z, blood_threshold_fraction)
    in_thresholds = _part(observation, "blood", cavities, debris) / ops.constant(blood_threshold_fraction)
    slots = _slots(observation, cavities, debris)
    visible, held, delivered = _flags(slots)
    left = ops.as_float(~delivered).sum(-1)
    holding_last = (left == 1.0) & (held & ~delivered).any(-1)
    hidden = (~visible & ~delivered).any(-1)
    to_pin, carry = parts[0], parts[3]  # the grasper picks revealed pins under blood too: any pin, not a cleared one's
    return parts + [ops.tanh(to_pin / ZOOM), ops.tanh(carry / ZOOM), ops.tanh(in_thresholds),
                    ops.tanh(10.0 * in_thresholds), (left / debris)[..., None], ops.as_float(holding_last)[..., None],
                    ops.as_float(hidden)[..., None]]


def suction_debris_bleeding(observation, *, cavities: int, debris: int, cavity_centres, cavity_mouth_radius,
                            cavity_targets_z, rim_z, blood_threshold_fraction):
    """``(..., obs_dim)`` -> ``(..., 39)``: :func:`suction_debris_cleared_pins`'s 26, then ``tanh(to_pin / ZOOM)``
    (3) and ``tanh(carry / ZOOM)`` (3) (the grasp's and the hand-off's millimetres, as
    :func:`suction_debris_cleared_pins_zoom` gives them, but toward any revealed pin: a revealed pin stays graspable
    under blood that has come back), and what a bleeding field's timing turns on: each cavity's blood in units of its clearing threshold through two magnifiers,
    ``tanh(level)`` and ``tanh(10 level)`` (2 + 2; the observation gives blood as a fraction of the start, where
    the threshold is about 0.06 and a tenth of it 0.006, below what a normalised tanh network resolves), the share
    of pins still to hand off (1), whether the pin held is the last (1) and whether any pin is still hidden (1).
    Measured: a clone of the sweeping experts on :func:`suction_debris_cleared_pins` alone fitted them to a loss of
    0.098 and finished 20 % of its validation episodes (docs/results.md, the bleeding field)."""
    ops = _Ops(observation)
    return ops.concatenate(_bleeding_parts(ops, observation, cavities, debris, cavity_centres, cavity_mouth_radius,
                                           cavity_targets_z, rim_z, blood_threshold_fraction))


def _pick_zoom_parts(ops, observation, tool_point_drop, zoom):
    # PSM Pick's observation as a policy reads its keys in order: achieved_goal (3), desired_goal (3), observation
    # (p~ 3, jaw 1, o~ 3).
    goal, tip, obj = observation[..., 3:6], observation[..., 6:9], observation[..., 10:13]
    jaws = ops.concatenate([tip[..., 0:2], tip[..., 2:3] - tool_point_drop])
    return [ops.tanh((obj - jaws) / zoom), ops.tanh((goal - obj) / zoom)]


def psm_pick_zoom(observation, *, tool_point_drop: float, zoom: float):
    """PSM Pick's ``(..., 13)`` observation (its keys in order) -> ``(..., 6)``: ``tanh((o~ - jaws~) / zoom)`` and
    ``tanh((g~ - o~) / zoom)``, the jaws' way to the object and the object's to the goal through a magnifier (``zoom``
    in units of rho; the jaws lie ``tool_point_drop`` below p~). Why: the grasp and the goal ask for millimetres
    (delta = 3 mm is 0.12 rho) of offsets that a tanh network reads as differences of positions spanning the whole
    workspace; with the plain observation one PPO seed of three learnt to carry in 2.5M steps (see the results
    page). These are functions of the policy's own observation."""
    ops = _Ops(observation)
    return ops.concatenate(_pick_zoom_parts(ops, observation, tool_point_drop, zoom))


#: Known feature sets and how many values each appends.
FEATURES = {"suction_debris_targets": 14, "suction_debris_routes": 21, "suction_debris_cleared_pins": 26,
            "suction_debris_cleared_pins_zoom": 32, "suction_debris_bleeding": 39, "psm_pick_zoom": 6}
_PARTS = {"suction_debris_targets": _targets_parts, "suction_debris_routes": _routes_parts,
          "suction_debris_cleared_pins": _cleared_pins_parts, "suction_debris_cleared_pins_zoom": _cleared_pins_zoom_parts,
          "suction_debris_bleeding": _bleeding_parts,
          "psm_pick_zoom": _pick_zoom_parts}
_SCENE_ARGUMENTS = ("cavities", "debris", "cavity_centres", "cavity_mouth_radius", "cavity_targets_z", "rim_z",
                    "blood_threshold_fraction")
#: The collaborative scene's feature sets (its ``observation_features`` option); the others are single-arm policies'.
SCENE_FEATURE_SETS = ("suction_debris_targets", "suction_debris_routes", "suction_debris_cleared_pins",
                      "suction_debris_cleared_pins_zoom", "suction_debris_bleeding")
#: The arguments each feature set takes, in the order its parts function takes them.
_ARGUMENTS = {"suction_debris_targets": _SCENE_ARGUMENTS[:2],
              **{name: _SCENE_ARGUMENTS for name in ("suction_debris_routes", "suction_debris_cleared_pins",
                                                     "suction_debris_cleared_pins_zoom", "suction_debris_bleeding")},
              "psm_pick_zoom": ("tool_point_drop", "zoom")}
#: Feature sets that carry the scene's geometry in their spec (:func:`routes_geometry`).
NEEDS_GEOMETRY = {"suction_debris_routes", "suction_debris_cleared_pins", "suction_debris_cleared_pins_zoom",
                  "suction_debris_bleeding"}


def observation_width(spec: dict) -> int | None:
    """The observation length a feature set reads (the collaborative scene's: tips, tool, blood, pin slots, hand-off),
    or None where the set does not fix it (a single-arm set)."""
    if spec.get("name") in SCENE_FEATURE_SETS:
        return layout.plain_width(layout.observation_layout(int(spec["cavities"]), int(spec["debris"]),
                                                            bool(spec.get("fluids", False))))
    return None


def check_spec(spec) -> None:
    """A feature set as a policy file keeps it, checked before any observation meets it: a known name, exactly its
    arguments, counts >= 1, and every geometry value finite, of one entry per cavity (a NaN centre once gave NaN
    actions, a wrong count numpy's own errors at the first step)."""
    if not isinstance(spec, dict):
        raise ValueError(f"a feature set is a table ({{'name': ..., arguments}}), got {spec!r}")
    name = spec.get("name")
    if name not in _PARTS:
        raise ValueError(f"unknown observation features {name!r} (known: {sorted(_PARTS)})")
    given, wanted = set(spec) - {"name"}, set(_ARGUMENTS[name])
    if name in SCENE_FEATURE_SETS and "fluids" in spec:  # (optional: a scene with fluids says so)
        if spec["fluids"] is not True:
            raise ValueError(f"observation features {name!r}: fluids is true where given, got {spec['fluids']!r}")
        given = given - {"fluids"}
    if given != wanted:
        raise ValueError(f"observation features {name!r} take the arguments {sorted(wanted)}"
                         + (f"; missing {sorted(wanted - given)}" if wanted - given else "")
                         + (f"; unknown {sorted(given - wanted)}" if given - wanted else ""))
    for key in ("cavities", "debris"):
        if key in spec and (type(spec[key]) is not int or spec[key] < 1):
            raise ValueError(f"observation features {name!r}: {key} must be an integer >= 1, got {spec[key]!r}")
    shapes = {"cavity_centres": (spec.get("cavities"), 2), "cavity_targets_z": (spec.get("cavities"),),
              "blood_threshold_fraction": (spec.get("cavities"),), "cavity_mouth_radius": (), "rim_z": (),
              "tool_point_drop": (), "zoom": ()}
    for key, shape in shapes.items():
        if key not in spec:
            continue
        value = spec[key]
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"observation features {name!r}: {key} must be numbers, got {value!r}") from None
        if isinstance(value, bool) or array.shape != shape or not np.all(np.isfinite(array)):
            raise ValueError(f"observation features {name!r}: {key} must be finite numbers of shape {shape} "
                             f"(one per cavity where it has an axis), got {value!r}")
    for key in ("cavity_mouth_radius", "zoom"):
        if key in spec and not spec[key] > 0:
            raise ValueError(f"observation features {name!r}: {key} must be > 0, got {spec[key]!r}")


def apply(spec: dict, observation):
    """``observation`` with the features ``spec`` names appended (``spec``: ``{"name": ..., **arguments}`` as a
    policy's ``policy.json`` keeps it under ``"features"``)."""
    name = spec.get("name")
    if name not in _PARTS:
        raise ValueError(f"unknown observation features {name!r} (known: {sorted(_PARTS)})")
    arguments = {k: v for k, v in spec.items() if k not in ("name", "fluids")}
    unknown = sorted(set(arguments) - set(_ARGUMENTS[name]))
    if unknown:
        raise ValueError(f"observation features {name!r}: unknown arguments {unknown}")
    ops = _Ops(observation)
    try:
        values = [arguments[key] for key in _ARGUMENTS[name]]
    except KeyError as missing:
        raise ValueError(f"observation features {name!r}: missing argument {missing}") from None
    return ops.concatenate([observation, *_PARTS[name](ops, observation, *values)])  # (one copy of the row)
