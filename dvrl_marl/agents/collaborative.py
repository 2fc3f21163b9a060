"""The collaborative scene's scripted experts (they live with the task: :mod:`dvrl_marl.suction_debris.scripted_team`)."""

from dvrl_marl.suction_debris.scripted_team import (KeepClearSuction, KeepClearSurgeon, ScriptedSuction,
                                                    ScriptedSurgeon, SweepingSuction, SweepingSurgeon, YieldingSuction)

__all__ = ["ScriptedSuction", "ScriptedSurgeon", "KeepClearSuction", "KeepClearSurgeon", "SweepingSuction",
           "SweepingSurgeon", "YieldingSuction"]
