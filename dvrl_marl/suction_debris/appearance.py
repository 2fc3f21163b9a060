"""The endoscope's looks, drawn per world and episode (domain randomisation): the ranges an image observation's
colours, light, camera pose and noise are drawn from (``image_appearance``), one for training and one held out
beyond it, and how one world's look is drawn from its own stream's uniforms. :mod:`dvrl_marl.envs.endoscope` dresses
the scene in them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Appearance", "APPEARANCES", "QUANTITIES", "held_out_only"]


@dataclass(frozen=True)
class Appearance:
    """How far a world's look strays from the scene's, drawn per world and episode (domain randomisation): the most
    each quantity strays, and ``low`` the least (none for a training range; a held-out range starts where the
    training range ends, so that it lies outside it). Colour gains of the tissue and the blood (each channel times
    1 +/- the value) and of the instruments (one gain), the light's brightness (times 1 +/- the value) and direction
    (degrees about two axes), the endoscope's position (mm along each axis) and direction (degrees about two axes),
    and the image noise's standard deviation (of 255). ``scene_colours`` is the share of worlds that keep the scene's
    own colours while the rest of their look is drawn: with six gains drawn apart, a look with all of them near 1
    (the scene as a person sees it) would almost never be drawn."""

    colour: float
    light: float
    light_degrees: float
    camera_mm: float
    camera_degrees: float
    noise: float
    low: "Appearance | None" = None
    scene_colours: float = 0.0

    #: uniforms one world's look takes
    UNIFORMS = 32

    def draw(self, u: np.ndarray) -> dict:
        """One world's look from :attr:`UNIFORMS` uniforms in [0, 1): each magnitude uniform in [low, high], its
        sign another draw."""
        low = self.low or Appearance(0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
        at = iter(range(self.UNIFORMS))

        def signed(name, count=1):
            lo, hi = getattr(low, name), getattr(self, name)
            out = []
            for _ in range(count):
                magnitude, sign = lo + (hi - lo) * u[next(at)], u[next(at)]
                out.append(magnitude if sign >= 0.5 else -magnitude)
            return np.array(out)

        look = {"tissue": 1.0 + signed("colour", 3), "blood": 1.0 + signed("colour", 3),
                "instrument": 1.0 + signed("colour")[0], "light": 1.0 + signed("light")[0],
                "light_turn": np.radians(signed("light_degrees", 2)), "camera_shift": signed("camera_mm", 3) * 1e-3,
                "camera_turn": np.radians(signed("camera_degrees", 2)),
                "noise": low.noise + (self.noise - low.noise) * u[next(at)]}
        if u[next(at)] < self.scene_colours:
            look.update(tissue=np.ones(3), blood=np.ones(3), instrument=1.0)
        return look


#: The named ranges of ``image_appearance``: "train" (what a seat learns beside), "held_out" (outside it, to test on);
#: and below, each quantity held out alone.
APPEARANCES = {"train": Appearance(0.15, 0.2, 15.0, 3.0, 2.0, 4.0, scene_colours=0.25),
               "held_out": Appearance(0.3, 0.4, 30.0, 6.0, 4.0, 8.0,
                                      low=Appearance(0.15, 0.2, 15.0, 3.0, 2.0, 4.0))}

#: The quantities a range is made of, as :func:`held_out_only` names them: its fields.
QUANTITIES = {"colour": ("colour",), "light": ("light", "light_degrees"), "camera": ("camera_mm", "camera_degrees"),
              "noise": ("noise",)}


def held_out_only(*quantities: str) -> Appearance:
    """The training range with the named quantities (keys of :data:`QUANTITIES`) drawn from the held-out range
    instead: which of the held-out range's quantities, alone or together, a pixel policy fails on. No world keeps the
    scene's own colours."""
    unknown = [quantity for quantity in quantities if quantity not in QUANTITIES]
    if not quantities or unknown:
        raise ValueError(f"held_out_only: quantities must be among {sorted(QUANTITIES)}, got {list(quantities)!r}")
    train, held_out = APPEARANCES["train"], APPEARANCES["held_out"]
    fields = {name for quantity in quantities for name in QUANTITIES[quantity]}
    low = Appearance(**{name: getattr(held_out.low, name) if name in fields else 0.0
                        for names in QUANTITIES.values() for name in names})
    return Appearance(**{**vars(train), **{name: getattr(held_out, name) for name in fields}, "low": low,
                         "scene_colours": 0.0})


#: "held_out_colour", "held_out_light", "held_out_camera", "held_out_noise": one quantity held out at a time.
APPEARANCES.update({f"held_out_{quantity}": held_out_only(quantity) for quantity in QUANTITIES})
