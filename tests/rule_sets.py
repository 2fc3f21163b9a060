"""The rule sets of the scene's history as keyword sets of ``suction_debris_v8`` (docs/deviations.md: the keyword
that gives each simple rule back), for tests that hold one rule against the one it replaced.

``v3_rules.parallel_env(...)`` is ``suction_debris_v8.parallel_env(blocked_moves="slide", held_pin_at_grip=False)``:
the rules 0.1.0 called suction_debris_v3 (commit 36a42a0), which the current scene still offers rule by rule.
"""

from __future__ import annotations

from pettingzoo.utils.conversions import parallel_to_aec

from dvrl_marl.envs import suction_debris_v8

_SIMPLE = dict(pins_fall=False, suction_reach=0.0, bleeding_onset_s=0.0, deliver_at_grip=False,
               pins_stay_on_phantom=False, blocked_moves="stop", held_pin_at_grip=False)
_STEPS = (
    dict(pins_fall=True, suction_reach=0.002, bleeding_onset_s=10.0),
    dict(deliver_at_grip=True, pins_stay_on_phantom=True),
    dict(blocked_moves="slide"),
    dict(held_pin_at_grip=True),
    dict(blocked_moves="climb"),
    dict(blocked_moves="climb_ahead"),
    dict(blocked_moves="settle"),
)


class RuleSet:
    """``parallel_env``, ``env``, ``raw_env`` and ``batched_env`` of ``suction_debris_v8`` with these rules (keywords
    given by the caller win)."""

    AGENTS = suction_debris_v8.AGENTS
    TASK = suction_debris_v8.TASK

    def __init__(self, name: str, rules: dict):
        self.__name__, self.rules = name, dict(rules)

    def parallel_env(self, **kwargs):
        return suction_debris_v8.parallel_env(**{**self.rules, **kwargs})

    raw_env = parallel_env

    def env(self, **kwargs):
        return parallel_to_aec(self.parallel_env(**kwargs))

    def batched_env(self, num_envs: int = 1, **kwargs):
        return suction_debris_v8.batched_env(num_envs, **{**self.rules, **kwargs})

    def __repr__(self):
        return self.__name__


def _rule_sets():
    rules, out = dict(_SIMPLE), {}
    out["v0_rules"] = RuleSet("v0_rules", rules)
    for index, step in enumerate(_STEPS, start=1):
        rules = {**rules, **step}
        out[f"v{index}_rules"] = RuleSet(f"v{index}_rules", rules)
    return out


globals().update(_rule_sets())
