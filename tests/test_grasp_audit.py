"""baselines/grasp_audit.py: the counts it reports are the grasper's, read from its own observation."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

from dvrl_marl.agents.collaborative import ScriptedSurgeon
from dvrl_marl.envs import suction_debris_v8


def _audit_module():
    path = Path(__file__).resolve().parents[1] / "baselines" / "grasp_audit.py"
    spec = importlib.util.spec_from_file_location("grasp_audit", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_scripted_surgeon_grasps_every_pin_by_its_centre():
    result = _audit_module().audit("scripted", "scripted", episodes=3, seed=900_000_000, noise=False)
    assert result["success_rate"] == 1.0 and result["mean_grasps"] == 3.0 and result["mean_debris_delivered"] == 3.0
    assert result["undeliverable_grasp_fraction"] == 0.0 and result["mean_drops"] == 0.0
    assert result["episodes_by_debris_delivered"] == [0, 0, 0, 3]
    sides = result["pins_by_cavity"]
    assert sides["near"]["pins"] + sides["far"]["pins"] == 9
    for side in sides.values():
        assert side["grasped"] == side["delivered"] == side["pins"]


@pytest.mark.slow
def test_a_grasper_that_opens_mid_carry_is_counted_dropping():
    """The scripted surgeon with its jaw forced open for one step in every 20 while it carries: drops are counted,
    and the pins it lets go of are not delivered on those steps."""
    surgeon = ScriptedSurgeon.for_env(suction_debris_v8.parallel_env())
    steps = {"n": 0}

    def clumsy(observations):
        actions = np.asarray(surgeon.act(observations), dtype=np.float64)
        steps["n"] += 1
        if steps["n"] % 20 == 0:
            actions[:, 3] = 1.0
        return actions

    result = _audit_module().audit("scripted", clumsy, episodes=2, seed=900_000_000, noise=False)
    assert result["mean_drops"] > 0.0
    assert result["mean_grasps"] > result["mean_debris_delivered"]
