"""The shipped multi-agent policies (``marl-*``): numpy only, and they do the task they were trained for.

The figures of record (100 held-out seeds, three training seeds) are in ``baselines/README.md``; here a smaller
held-out sample shows that the shipped policy solves its seat, as a scripted expert's test shows for the expert.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from dvrl_marl import policies
from dvrl_marl.training import teams

pytestmark = pytest.mark.slow  # whole episodes of seats beside their partners (CI runs them)


@pytest.mark.parametrize("name, agent, feature_set", [
    ("marl-suction", "suction", "suction_debris_routes"),
    ("marl-suction-yielding", "suction", "suction_debris_routes"),
    ("marl-grasper", "grasper", "suction_debris_cleared_pins"),
    ("marl-suction-bleeding", "suction", "suction_debris_bleeding"),
    ("marl-grasper-bleeding", "grasper", "suction_debris_bleeding"),
])
def test_shipped_marl_policy_loads_with_numpy_alone(name, agent, feature_set):
    assert name in policies.available()
    code = ("import sys; sys.modules['torch'] = None; sys.modules['torchrl'] = None\n"
            "import numpy as np\n"
            "from dvrl_marl import policies\n"
            f"p = policies.load({name!r})\n"
            "print(p.spec['agent'], p.spec['features']['name'], p(np.zeros(30)).shape)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == [agent, feature_set, "(4,)"]


def test_marl_suction_clears_the_field_beside_the_scripted_surgeon():
    """With the noise it trained with (as evaluated and as the demo runs it), on held-out seeds."""
    result = teams.evaluate_team_batched(teams.seats("marl-suction", "scripted", noise_from=teams.EVAL_SEED),
                                         episodes=30, seed=teams.EVAL_SEED)
    assert result["success_rate"] >= 0.9, result["success_rate"]
    assert result["mean_contact_steps"] < 20.0
    # and its mean action (the policy called plainly) still clears blood: the learned routes, not the noise, do that
    plain = teams.evaluate_team_batched(teams.seats("marl-suction", "scripted"), episodes=30, seed=teams.EVAL_SEED)
    assert plain["mean_blood_removed_ml"] > 12.0


@pytest.mark.extended
def test_the_yielding_suction_waits_for_a_surgeon_in_its_way_and_finishes_beside_the_others():
    """By its default call (the mean action), on held-out seeds: beside the held-out surgeons that rest in its way
    (they wait longer than any it met in training) it finishes without pushing, where the scripted suction pushes
    for about 180 steps an episode; beside the scripted surgeon and a person-like one it is as the script."""
    from dvrl_marl.agents.partners import zoo_partner
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.parallel_env()
    seat = teams.seat("marl-suction-yielding", "suction")
    results = teams.evaluate_beside("suction", seat, {"in-the-way": zoo_partner("in-the-way", "grasper", env),
                                                      "scripted": teams.seat("scripted", "grasper"),
                                                      "person": zoo_partner("person", "grasper", env)},
                                    episodes=16, max_cycles=6000)
    in_the_way = results.pop("in-the-way")
    assert in_the_way["success_rate"] == 1.0 and in_the_way["mean_contact_steps"] <= 5.0, in_the_way
    for partner, result in results.items():
        assert result["success_rate"] == 1.0 and result["mean_contact_steps"] == 0.0, (partner, result)


@pytest.mark.extended
def test_the_bleeding_team_finishes_where_the_keep_clear_team_runs_out_of_steps():
    """By their default call (the mean action), on held-out seeds of the task's own 1,500 steps: the sweeping experts
    cloned finish a bleeding field the keep-clear scripted team mostly leaves unfinished, without a contact."""
    team = teams.seats("marl-suction-bleeding", "marl-grasper-bleeding")
    slow = teams.evaluate_team_batched(team, episodes=16, bleeding_ml_s=0.1)
    assert slow["success_rate"] >= 0.85 and slow["mean_contact_steps"] == 0.0, slow
    fast = teams.evaluate_team_batched(team, episodes=16, bleeding_ml_s=0.3)
    keep_clear = teams.evaluate_team_batched(teams.seats("keep-clear", "keep-clear"), episodes=16, bleeding_ml_s=0.3)
    assert fast["success_rate"] >= 0.4 and fast["success_rate"] > keep_clear["success_rate"], (fast, keep_clear)
    assert fast["mean_contact_steps"] == 0.0


def test_marl_grasper_collects_every_pin_beside_the_scripted_suction():
    """Cloned from the scripted surgeon (DAgger, beside scripted and learned suctions) and fine-tuned by MAPPO; with
    its noise, on held-out seeds."""
    result = teams.evaluate_team_batched(teams.seats("scripted", "marl-grasper", noise_from=teams.EVAL_SEED),
                                         episodes=30, seed=teams.EVAL_SEED)
    assert result["success_rate"] >= 0.9, result["success_rate"]
    assert result["mean_contact_steps"] < 20.0


def test_the_learned_team_works_together():
    """Both shipped learned seats, acting as they trained, on held-out seeds (the grasper trained beside a population
    of suctions, marl-suction among them; cross-play with suctions it never met is in baselines/README.md)."""
    result = teams.evaluate_team_batched(teams.seats("marl-suction", "marl-grasper", noise_from=teams.EVAL_SEED),
                                         episodes=30, seed=teams.EVAL_SEED)
    assert result["success_rate"] >= 0.85, result["success_rate"]
    assert result["mean_debris_delivered"] > 2.7


def test_the_demo_runs_the_whole_learned_team(tmp_path):
    from dvrl_marl import demo

    metrics = demo.run_demo(team="marl", surgeon="learned", out=tmp_path / "demo", video=False, progress=False)
    assert metrics["team"] == "marl" and metrics["surgeon"] == "learned"
    assert metrics["success"], metrics
    assert metrics["debris_delivered"] == metrics["debris_total"]


def test_the_demo_seats_the_learned_suction_beside_the_scripted_surgeon(tmp_path):
    from dvrl_marl import demo

    metrics = demo.run_demo(team="marl", surgeon="scripted", out=tmp_path / "demo", video=False, progress=False)
    assert metrics["team"] == "marl" and metrics["surgeon"] == "scripted"
    assert metrics["success"], metrics  # the whole episode (suction_debris_v8): cleared and delivered
    assert metrics["debris_delivered"] == metrics["debris_total"] and metrics["steps"] < metrics["max_cycles"]


def test_a_shipped_learned_policy_refuses_the_other_seat():
    with pytest.raises(ValueError, match="trained for the 'suction' seat"):
        teams.seat("marl-suction", "grasper")



def test_the_pixel_suction_loads_with_numpy_alone_and_reads_the_endoscope():
    code = ("import sys; sys.modules['torch'] = None; sys.modules['torchrl'] = None\n"
            "import numpy as np\n"
            "from dvrl_marl import policies\n"
            "p = policies.load('marl-suction-pixels')\n"
            "seen = {'observation': np.zeros((2, 30)), 'image': np.zeros((2, 64, 64, 3), np.uint8),\n"
            "        'image_right': np.zeros((2, 64, 64, 3), np.uint8)}\n"
            "print(p.spec['agent'], p.image_options['image_size'], p(seen).shape)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["suction", "64", "(2,", "4)"]
    with pytest.raises(ValueError, match="sees the endoscope"):
        policies.load("marl-suction-pixels")(np.zeros(30))


@pytest.mark.parametrize("look", [None, pytest.param("train", marks=pytest.mark.extended),
                                  pytest.param("held_out", marks=pytest.mark.extended)])
def test_the_pixel_suction_clears_the_field_from_the_endoscope_beside_the_scripted_surgeon(look):
    """By its default call, reading only the endoscope's image and its own tip and valve, on held-out seeds of the
    task's 1,500 steps: the scene's own look (as a person's view draws it), looks of the training range and looks
    outside it."""
    options = {} if look is None else {"image_appearance": look}
    team = {"suction": teams.seat("marl-suction-pixels", "suction"), "grasper": teams.seat("scripted", "grasper")}
    result = teams.evaluate_team_batched(team, episodes=8, **options)
    assert result["success_rate"] >= 0.85 and result["mean_contact_steps"] <= 2.0, result


def test_the_irrigation_team_clears_a_clotted_field_by_irrigating():
    """Learnt from scratch on the irrigation level (the compiled trainer with a cost on wasted saline, seed 3 of
    five); by its mean action on held-out seeds, numpy alone: it irrigates (saline used), finishes, never overflows
    a cavity and records the scene it learnt on."""
    from dvrl_marl.envs import suction_debris_v8

    for name in ("marl-suction-irrigation", "marl-grasper-irrigation"):
        assert name in policies.available() and policies.load(name).spec["features"]["fluids"] is True
    scene = suction_debris_v8.parallel_env(preset="irrigation")
    result = teams.evaluate_team_batched(teams.seats("marl-suction-irrigation", "marl-grasper-irrigation", env=scene),
                                         episodes=16, preset="irrigation")
    assert result["success_rate"] >= 0.85, result["success_rate"]
    assert result["mean_saline_used_ml"] > 4.0 and result["overflowed_episodes"] == 0.0
    assert policies.load("marl-suction-irrigation").spec["preset"] == "irrigation"
