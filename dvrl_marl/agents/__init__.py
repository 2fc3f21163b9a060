"""Scripted experts, one per task (Meta-World style): callables ``policy(observation) -> action``."""

from dvrl_marl.agents.collaborative import (KeepClearSuction, KeepClearSurgeon, ScriptedSuction, ScriptedSurgeon,
                                            SweepingSuction, SweepingSurgeon)
from dvrl_marl.agents.experts import PickExpert, ReachExpert

__all__ = ["ReachExpert", "PickExpert", "ScriptedSuction", "ScriptedSurgeon", "KeepClearSuction", "KeepClearSurgeon",
           "SweepingSuction", "SweepingSurgeon"]
