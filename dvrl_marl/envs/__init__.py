"""The environments: single-arm Gymnasium goal envs and the collaborative PettingZoo env (``suction_debris_v8``).

Only the current version of the collaborative scene imports; an earlier name raises an ``ImportError`` that names
the current one and the commit that reproduces the earlier version's records (PettingZoo's convention).
"""

import importlib.abc
import re
import sys

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.envs.psm_pick import PSMPickEnv
from dvrl_marl.envs.psm_reach import PSMReachEnv
from dvrl_marl.suction_debris.task import TASK

__all__ = ["PSMReachEnv", "PSMPickEnv", "suction_debris_v8", "CURRENT", "RECORDS_COMMIT"]

#: The current version of the collaborative scene.
CURRENT = TASK
#: The commit whose code reproduces the records of the versions before the current one (0.1.0, never released).
RECORDS_COMMIT = "36a42a0"
_REPLACED = re.compile(r"suction_debris_v(\d+)$")


def replaced_message(name: str) -> str:
    """What an old version's name says when it is imported."""
    return (f"{name} is no longer available: use {CURRENT} (from dvrl_marl.envs import {CURRENT}); the records of "
            f"{name} are reproduced by commit {RECORDS_COMMIT} (docs/migration.md maps every old name)")


class _ReplacedVersions(importlib.abc.MetaPathFinder):
    """Importing an earlier version of the scene (in any form) fails with :func:`replaced_message`."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.rpartition(".")
        if package == __name__ and _REPLACED.match(name) and name != CURRENT:
            raise ImportError(replaced_message(name), name=fullname)
        return None


if not any(isinstance(finder, _ReplacedVersions) for finder in sys.meta_path):
    sys.meta_path.insert(0, _ReplacedVersions())

