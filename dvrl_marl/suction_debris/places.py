"""Where the collaborative scene's arms wait: the suction's parking place and the surgeon's waiting place.

Both are scene facts shared by the scripted experts (:mod:`dvrl_marl.suction_debris.scripted_team`) and the env's guided
reward (:mod:`dvrl_marl.suction_debris.guidance`), which leads a learning arm to the same places. Heights are metres above the
phantom's top (normalised units are scene-specific), converted with the workspace range.
"""

from __future__ import annotations

import numpy as np

__all__ = ["SAFE_HEIGHT", "PARK_HEIGHT", "park_height", "suction_parking_place", "surgeon_waiting_place"]

#: Above the phantom's top while travelling between cavities (m).
SAFE_HEIGHT = 0.010
#: Above the phantom's top where an arm waits out of the other's way (m).
PARK_HEIGHT = 0.030


def park_height(layout, workspace_range: float) -> float:
    """The parking height, normalised (``layout``: the env's :class:`SceneLayout`)."""
    return layout.phantom_top + PARK_HEIGHT / workspace_range


def suction_parking_place(layout, workspace_range: float) -> np.ndarray:
    """Normalised: above the suction's RCM, 5 mm toward the phantom, at the parking height."""
    base = np.asarray(layout.base_positions["suction"][:2])
    return np.array([base[0] + 0.005 / workspace_range, base[1], park_height(layout, workspace_range)])


def surgeon_waiting_place(layout, workspace_range: float, base=None) -> np.ndarray:
    """Normalised: beside the grasper's RCM (``base``, x~ y~; default the layout's), toward the assistant, at the
    parking height."""
    base = np.asarray(layout.base_positions["grasper"][:2] if base is None else base)
    return np.array([base[0] - 0.015 / workspace_range, base[1] + 0.02 / workspace_range,
                     park_height(layout, workspace_range)])
