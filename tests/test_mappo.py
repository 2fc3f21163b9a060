"""The multi-agent PPO trainer on a tiny budget: it runs, logs, checkpoints, resumes and exports numpy policies;
and the start-state options its curriculum uses."""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from rule_sets import v0_rules  # the hand-off judged at the pin's centre

from dvrl_marl.envs import suction_debris_v8

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from dvrl_marl import policies  # noqa: E402
from dvrl_marl.suction_debris import guidance  # noqa: E402
from dvrl_marl.suction_debris.presets import with_preset  # noqa: E402
from dvrl_marl.training import mappo, mappo_config, models  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

TINY = """
[run]
algorithm = "{algorithm}"
total_steps = 2048
num_envs = 32
rollout_steps = 16
eval_every = 1024
eval_episodes = 4
checkpoint_every = 1024
surgeon = "{surgeon}"
surgeon_seat = "{seat}"
[env]
reward_type = "guided"
max_cycles = 40
[env.guidance]
suction_route = 0.0
[ppo]
epochs = 2
minibatches = 2
[model]
hidden = [16, 16]
[curriculum]
levels = [[0.0, 0.0], [0.5, 1.0]]
"""


def _config(tmp_path, algorithm="mappo", surgeon="none", seat="grasper"):
    path = tmp_path / f"tiny_{algorithm}_{surgeon}_{seat}.toml"
    path.write_text(TINY.format(algorithm=algorithm, surgeon=surgeon, seat=seat))
    return path


def _rows(run):
    with (run / "progress.csv").open() as handle:
        return list(csv.DictReader(handle))


@pytest.mark.parametrize("algorithm", ["mappo", "ippo"])
@pytest.mark.slow
def test_trainer_runs_logs_checkpoints_and_exports(tmp_path, algorithm):
    run = tmp_path / "run"
    final = mappo.train(mappo.load_config(_config(tmp_path, algorithm)), 0, run, progress=False, log=lambda *_: None)
    assert final["steps"] == 2048
    rows = _rows(run)
    assert [int(r["steps"]) for r in rows] == [1024, 2048]
    assert all(0.0 <= float(r["success_rate"]) <= 1.0 for r in rows)
    assert (run / "checkpoint.pt").is_file() and (run / "config.toml").is_file()
    assert any((run / "tb").iterdir()), "no TensorBoard events written"
    assert json.loads((run / "result.json").read_text())["steps"] == 2048
    assert (run / "policies_best" / "marl-grasper" / "policy.npz").is_file()
    for agent in ("suction", "grasper"):
        policy = policies.load(run / "policies" / f"marl-{agent}")
        assert policy.spec["agent"] == agent and policy.spec["training"]["algorithm"] == algorithm
        observation = np.zeros(suction_debris_v8.parallel_env().observation_space(agent).shape)
        action = policy(observation)
        assert action.shape == (4,) and np.all(np.abs(action) <= 1.0)


@pytest.mark.slow
def test_exported_policy_is_numpy_only(tmp_path):
    run = tmp_path / "run"
    mappo.train(mappo.load_config(_config(tmp_path)), 0, run, progress=False, log=lambda *_: None)
    code = ("import sys, numpy as np\n"
            "sys.modules['torch'] = None; sys.modules['torchrl'] = None\n"
            "from dvrl_marl import policies\n"
            f"p = policies.load({str(run / 'policies' / 'marl-grasper')!r})\n"
            "print(p(np.zeros(30)).shape)\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "(4,)"


def test_export_matches_the_torch_actor(tmp_path):
    """The numpy policy (normalisation folded into the first layer) acts as the actor's mean, clipped."""
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    config = mappo.load_config(_config(tmp_path))
    actor, _, actor_net, norms = models.build_models(config, ["suction", "grasper"], 30, 31, 4)
    rng = np.random.default_rng(0)
    norms["observation"].update(torch.from_numpy(rng.normal(0.3, 2.0, (500, 2, 30))))
    for net in actor_net.nets:  # make the head matter
        torch.nn.init.normal_(net[-1].weight, std=0.5)
    observations = rng.normal(0.3, 2.0, (20, 2, 30))
    td = TensorDict({"agents": TensorDict({"observation": torch.from_numpy(observations).float()},
                                          batch_size=[20, 2])}, batch_size=[20])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = np.clip(actor(td)["agents", "action"].numpy(), -1.0, 1.0)
    for index, agent in enumerate(["suction", "grasper"]):
        folder = mappo.export_actor(actor_net, index, tmp_path / agent, name=agent, agent=agent, metadata={})
        np.testing.assert_allclose(policies.load(folder)(observations[:, index]), expected[:, index], atol=2e-5)



@settings(max_examples=12, deadline=None)
@example(batches=[(1, 26.0, 0.5)], seed=0)  # (a float32 mean of 26 holds it to about 1e-6)
@given(batches=st.lists(st.tuples(st.integers(1, 40), st.floats(-1e3, 1e3), st.floats(1e-3, 1e2)), min_size=1,
                        max_size=5), seed=st.integers(0, 2**16))
def test_the_normalisers_hold_the_statistics_of_everything_they_saw(tmp_path_factory, batches, seed):
    """Batch after batch (float32, as a rollout gives them; any offset and spread), the running mean and variance
    are those of a float64 merge of every batch (Chan et al.) from the prior (mean 0, variance 1, count 1e-4), within
    float32's precision, the actor's and the critic's observation normalisers alike; ``observation=False`` leaves
    the actor's as it was (a clone keeps its input scaling)."""
    from dataclasses import replace

    config = replace(mappo.load_config(_config(tmp_path_factory.mktemp("config"))),
                     critic_input="state_and_observation")
    _, _, _, norms = models.build_models(config, ["suction", "grasper"], 6, 5, 4)
    _, _, _, kept = models.build_models(config, ["suction", "grasper"], 6, 5, 4)
    rng = np.random.default_rng(seed)
    expected = {key: (torch.zeros(d, dtype=torch.float64), torch.ones(d, dtype=torch.float64), 1e-4)
                for key, d in (("observation", 6), ("state", 5))}
    for rows, centre, spread in batches:
        observations = torch.from_numpy(rng.normal(centre, spread, (rows, 3, 2, 6))).float()
        state = torch.from_numpy(rng.normal(-centre, spread, (rows, 3, 5))).float()
        models.update_norms(norms, observations, state)
        models.update_norms(kept, observations, state, observation=False)
        for key, x in (("observation", observations.double().reshape(-1, 6)), ("state", state.double().reshape(-1, 5))):
            mean, var, count = expected[key]
            n, delta = x.shape[0], x.mean(0) - mean
            total = count + n
            expected[key] = (mean + delta * n / total,
                             (var * count + x.var(0, unbiased=False) * n + delta**2 * count * n / total) / total, total)
    for key, truth in (("observation", "observation"), ("critic_observation", "observation"), ("state", "state")):
        mean, var, count = expected[truth]
        offset = 1e-6 * mean.abs()  # (a float32 row holds its offset to 6e-8 of it)
        assert torch.all((norms[key].mean - mean).abs() <= 1e-5 * var.sqrt() + offset + 1e-12), key
        assert torch.all((norms[key].var.sqrt() - var.sqrt()).abs() <= 1e-4 * var.sqrt() + offset + 1e-12), key
        assert float(norms[key].count) == pytest.approx(count)
    assert torch.equal(kept["observation"].mean, torch.zeros(6, dtype=torch.float64))
    assert torch.equal(kept["critic_observation"].var, norms["critic_observation"].var)

def test_export_folds_the_envs_observation_normalisation(tmp_path):
    """An actor trained on ``normalize_observations``' inputs exports a policy that reads the scene's units (what the
    surgeon seat and the benchmark's test episodes give it): its actions on a plain observation are the torch
    actor's on that observation normalised."""
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    config = mappo.load_config(_config(tmp_path))
    actor, _, actor_net, norms = models.build_models(config, ["suction", "grasper"], 30, 31, 4)
    rng = np.random.default_rng(1)
    norms["observation"].update(torch.from_numpy(rng.normal(0.0, 1.0, (500, 2, 30))))
    for net in actor_net.nets:
        torch.nn.init.normal_(net[-1].weight, std=0.5)
    centre, spread = rng.normal(0.0, 0.3, (2, 30)), rng.uniform(0.01, 0.5, (2, 30))
    plain = rng.normal(0.0, 0.3, (20, 2, 30))
    normalized = (plain - centre) / spread
    td = TensorDict({"agents": TensorDict({"observation": torch.from_numpy(normalized).float()},
                                          batch_size=[20, 2])}, batch_size=[20])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = np.clip(actor(td)["agents", "action"].numpy(), -1.0, 1.0)
    for index, agent in enumerate(["suction", "grasper"]):
        folder = mappo.export_actor(actor_net, index, tmp_path / agent, name=agent, agent=agent, metadata={},
                                    input_scaling=(centre[index], spread[index]))
        np.testing.assert_allclose(policies.load(folder)(plain[:, index]), expected[:, index], atol=5e-5)


def test_training_on_normalized_observations_exports_policies_that_read_the_scenes_units(tmp_path, monkeypatch):
    """With ``normalize_observations`` in [env] the trainer hands each agent's map to the export (and validates the
    exported policies on the plain env, as the seat and the benchmark's test episodes run them)."""
    from dvrl_marl.suction_debris.observation_scaling import ObservationScaling

    path = _config(tmp_path)
    path.write_text(path.read_text().replace('reward_type = "guided"', 'reward_type = "guided"\nnormalize_observations = true'))
    config = mappo.load_config(path)
    handed = {}
    real_export = mappo.export_actor

    def export(*args, agent, input_scaling=None, **kwargs):
        handed[agent] = input_scaling
        return real_export(*args, agent=agent, input_scaling=input_scaling, **kwargs)

    monkeypatch.setattr(mappo, "export_actor", export)
    mappo.train(config, 0, tmp_path / "run", total_steps=1024, progress=False, log=lambda *_: None)
    env = suction_debris_v8.batched_env(num_envs=1, max_cycles=40, normalize_observations=True)
    assert isinstance(env.observation_scaling, ObservationScaling)
    for agent in ("suction", "grasper"):
        for mine, expected in zip(handed[agent], env.observation_scaling.observation_affine(agent)):
            np.testing.assert_array_equal(mine, expected)

def test_resume_continues_from_the_checkpoint(tmp_path):
    config = mappo.load_config(_config(tmp_path))
    run = tmp_path / "run"
    mappo.train(config, 0, run, total_steps=1024, progress=False, log=lambda *_: None)
    first = torch.load(run / "checkpoint.pt", weights_only=False)
    assert first["steps"] == 1024
    messages = []
    final = mappo.train(config, 0, run, total_steps=2048, resume=True, progress=False, log=messages.append)
    assert any("resumed" in m and "1024" in m for m in messages)
    assert final["steps"] == 2048
    rows = _rows(run)
    assert [int(r["steps"]) for r in rows] == [1024, 2048]  # the log continues, nothing repeated
    # wall-clock is the run's, across sessions: the resumed row counts the first session's seconds too
    assert float(rows[1]["wall_seconds"]) > first["wall_seconds"] > 0
    second = torch.load(run / "checkpoint.pt", weights_only=False)
    changed = [not torch.equal(first["loss_module"][k], second["loss_module"][k]) for k in first["loss_module"]]
    assert any(changed), "resumed training did not update the networks"


def test_partner_seat_runs(tmp_path):
    """Suction learns beside the scripted surgeon; the grasper beside the scripted suction."""
    for seat, learner in (("grasper", "suction"), ("suction", "grasper")):
        run = tmp_path / seat
        mappo.train(mappo.load_config(_config(tmp_path, surgeon="scripted", seat=seat)), 0, run, total_steps=1024,
                    progress=False, log=lambda *_: None)
        assert sorted(p.name for p in (run / "policies").iterdir()) == [f"marl-{learner}"]


@pytest.mark.extended
def test_cli_train_mappo(tmp_path):
    config = _config(tmp_path)
    result = subprocess.run([sys.executable, "-m", "dvrl_marl.cli", "train", str(config), "--trainer", "torchrl",
                             "--out", str(tmp_path / "r"), "--steps", "1024", "--no-progress", "--export",
                             str(tmp_path / "exported")],
                            capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert "success" in result.stdout
    assert (tmp_path / "exported" / "marl-suction" / "policy.npz").is_file()


@pytest.mark.parametrize("text, message", [
    ("[run]\nalgorithm = 'mappo'\nbogus = 1\n", "[run] bogus: unknown key"),
    ("[run]\nalgorithm = 'sarsa'\n", "[run] algorithm: must be one of"),
    ("[nonsense]\nx = 1\n", "unknown table [nonsense]"),
    ("[run]\nalgorithm = 'mappo'\nnum_envs = 0\n", "[run] num_envs: must be >= 1"),
    ("[run\n", "not valid TOML"),
    ("[pretrain]\nbc_expert = 'human'\n", "[pretrain] bc_expert: must be one of"),
    ("[pretrain]\nbc_expert = 'scripted'\nbc_episodes = 0\n", "[pretrain] bc_episodes: must be >= 1"),
    ("[pretrain]\nbc_expert = 'scripted'\nbc_action_noise = -0.1\n", "[pretrain] bc_action_noise: must be >= 0"),
    ("[pretrain]\nbc_expert = 'scripted'\nbc_dagger_rounds = -1\n", "[pretrain] bc_dagger_rounds: must be >= 0"),
    ("[pretrain]\ncritic_warmup_steps = -5\n", "[pretrain] critic_warmup_steps: must be >= 0"),
    ("[pretrain]\nbc_expert = 'scripted'\ninit_policy = { suction = 'marl-suction' }\n", "init_policy and bc_expert"),
    ("[run]\nsurgeon = 'scripted'\n[pretrain]\ninit_policy = { grasper = 'marl-grasper' }\n", "the partner's seat"),
    ("[pretrain]\ninit_policy = { suction = 'marl-grasper' }\n", "trained for the 'grasper' seat"),
    ("[pretrain]\ninit_policy = { suction = 'no-such-policy' }\n", "init_policy suction = 'no-such-policy'"),
    ("[pretrain]\ninit_policy = { assistant = 'marl-suction' }\n", "[pretrain] init_policy.assistant"),
    ("[run]\nsurgeon = 'in-the-way'\nsurgeon_seat = 'suction'\n", "fill the LND seat ('grasper')"),
    ("[pretrain]\nbc_expert = 'yielding'\n", "the suction must be the only learning seat"),
    ("[curriculum]\nlevels = [[0.0, 1.5]]\n", "[curriculum] levels[0][1]: must be <= 1"),
    ("[curriculum]\nlevels = [[0.5, 0.0], [0.2, 1.0]]\n", "[curriculum] levels: the progress points must increase"),
    ("[shaping]\noff_centre_grasps = 1.0\n", "[shaping] shaping: retired when the env took it over (now the env's guided reward"),
    ("[curriculum]\nreceding_starts = 0.3\n", "[curriculum] receding_starts: retired when the env took it over (now the env's start levels"),
    ("[model]\nobservation_features = \"suction_debris_routes\"\n", "commit ea6d143"),
    ("[model]\nheld_tool_logit = { grasper = -8.0 }\n", "commit c59ae5f"),
    ("[model]\nheld_tool_logit = { grasper = -8.0 }\n[curriculum]\nreceding_starts = 0.3\n", "commit ea6d143"),
    ("[env]\nreward_type = \"guided\"\n[env.guidance]\nhold_bonus = -1.0\n", "hold_bonus"),
    ("[run]\nsurgeon = []\n", "non-empty list"),
    ("[run]\nsurgeon = 3\n", "[run] surgeon"),
    ("[run]\nsurgeon = ['none', 'scripted']\n", "cannot be one of several"),
    ("[run]\nsurgeon = ['scripted', 'no-such-policy']\nsurgeon_seat = 'suction'\n",
     "surgeon 'no-such-policy' cannot fill the 'suction' seat"),
    ("[run]\nsurgeon = 'marl-grasper'\nsurgeon_seat = 'suction'\n", "trained for the 'grasper' seat"),
    ("[ppo]\ngamma = 2.0\n", "[ppo] gamma: must be <= 1, got 2.0"),
    ("[ppo]\nclip_epsilon = -0.2\n", "[ppo] clip_epsilon: must be > 0"),
    ("[ppo]\nmax_grad_norm = -1\n", "[ppo] max_grad_norm: must be > 0"),
    ("[run]\ncheckpoint_every = 0\n", "[run] checkpoint_every: must be >= 1"),
    ("[ppo]\nlearning_rate = '3e-4'\n", "[ppo] learning_rate: must be a number, got '3e-4'"),
    ("[model]\ngamma = 0.9\n", "[model] gamma: unknown key (it belongs in [ppo])"),
    ("[run]\ngamma = 0.9\n[ppo]\ngamma = 0.8\n", "[ppo] gamma: set twice (also in [run])"),
    ("[env]\npins_fal = true\n", "[env] suction_debris_v8() got an unexpected keyword argument 'pins_fal'"),
    ("[env]\nbleeding_ml_s = -0.3\n", "[env] suction_debris_v8: bleeding_ml_s: must be >= 0"),
    ("[model]\nhidden = [64, 0]\n", "[model] hidden[1]: must be >= 1"),
    ("[model]\ninitial_tool_logit = { assistant = 1.0 }\n", "[model] initial_tool_logit.assistant"),
    ("[run]\nextends = 'missing.toml'\n", "[run] extends = 'missing.toml': no such file"),
    ("[run]\nextends = 'bad.toml'\n", "comes back to a file of its own chain (bad.toml -> bad.toml)"),
    ("[run]\nextends = 3\n", "[run] extends: a configuration file's name"),
])
def test_bad_configuration_names_file_and_key(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ValueError) as error:
        mappo.load_config(path)
    assert str(path) in str(error.value) and message in str(error.value)


def test_curriculum_schedules_the_envs_start_level():
    config = mappo.MappoConfig(levels=[(0.0, 0.0), (0.3, 0.5), (1.0, 1.0)])
    assert config.level(0.0) == 0.0 and config.level(0.15) == pytest.approx(0.25)
    assert config.level(0.3) == 0.5 and config.level(0.65) == pytest.approx(0.75) and config.level(1.0) == 1.0
    assert mappo.MappoConfig().level(0.5) is None  # no schedule: the env's own start_level


def test_grasp_path_shaping_is_continuous_through_the_grasp():
    """Env potential + trainer potential changes by less than the sensor range x weight when the jaw closes on a pin."""
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled", blood_ml=[0.0, 0.0])
    env.reset(seed=3)
    core = env.core
    pin = core.debris_position[0, 0] + np.array([0.0, 0.0, 0.002])
    env.reset(seed=3, options={"tip_positions": {"grasper": pin[None]}})  # same seed: same pins
    grasp = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"])
    before = grasp.potential(env.state())
    _, rewards, *_ = env.step({"suction": np.zeros((1, 4)), "grasper": np.array([[0.0, 0.0, 0.0, -1.0]])})
    assert core.holding[0] == 0
    total = rewards["grasper"][0] + grasp.potential(env.state())[0] - before[0]
    # +2 for the first lift; the shaping terms move by at most 10 x (3 mm + 2 mm).
    assert abs(total - 2.0) < 0.06
    assert rewards["grasper"][0] < 1.3  # the env alone charges the grasp (what the trainer's term repairs)


@pytest.mark.parametrize("over_rims, park", [(False, False), (True, False), (False, True)])
def test_suction_route_shaping_is_continuous_when_a_cavity_clears(over_rims, park):
    """Env potential + trainer potential: clearing a cavity earns the removal and ``clear_bonus``, not the env's
    drop of 10 x the distance to the other cavity."""
    blood_threshold = suction_debris_v8.SuctionDebrisParams.from_task().blood_threshold_ml
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled",
                                        blood_ml=[blood_threshold + 0.02, 8.0])
    env.reset(seed=1)
    cavities = env.core.cavities
    surface = env.core.surface_z[0, 0]
    tip = np.array([[cavities.centre_x[0], cavities.centre_y[0], max(surface - 0.0005, cavities.floor_z[0] + 0.0012)]])
    env.set_tip_positions({"suction": tip})
    route = guidance.SuctionRouteShaping(env, 10.0, ["suction", "grasper"], clear_bonus=2.0, over_rims=over_rims,
                                        park=park)
    blood = env.core.info()["blood_remaining_per_cavity"]
    before = route.potential(env.state(), blood)
    _, rewards, *_ = env.step({"suction": np.array([[0.0, 0.0, 0.0, 1.0]]), "grasper": np.zeros((1, 4))})
    after_blood = env.core.info()["blood_remaining_per_cavity"]
    assert after_blood[0, 0] < blood_threshold <= blood[0, 0], "the step did not clear the cavity"
    removed = blood[0, 0] - after_blood[0, 0]
    total = rewards["suction"][0] + route.potential(env.state(), after_blood)[0] - before[0]
    assert rewards["suction"][0] < -0.3  # the env alone charges the clearing
    # with the route: the removal and the bonus (the tip did not move); around the rims the route from a tip a few
    # millimetres above A's floor differs from the one through the floor by twice that height
    assert abs(total - (removed + 2.0)) < (0.06 if over_rims else 0.03)
    # nothing pending: both cleared, and no route left (or the way to the parking place)
    to_park = np.linalg.norm(route.park - env.core.arms["suction"].tip_world()[0]) if park else 0.0
    assert route.potential(env.state(), np.zeros((1, 2)))[0] == pytest.approx(4.0 - 10.0 * to_park)


def test_route_to_park_leads_out_of_the_way_and_favours_the_far_cavity_first():
    """With the park leg the cleared suction's potential rises toward its parking place (the scripted expert's), and
    the shortest route visits the cavity farther from the suction's side first, as the expert does."""
    from dvrl_marl.agents.collaborative import ScriptedSuction

    env = suction_debris_v8.batched_env(num_envs=1, autoreset_mode="disabled")
    env.reset(seed=0)
    route = guidance.SuctionRouteShaping(env, 10.0, ["suction", "grasper"], park=True)
    expert = ScriptedSuction.for_env(env)
    np.testing.assert_allclose(route.park, np.asarray(expert.park) * env.workspace_range
                               + np.asarray(env.params.workspace_centre))
    state = env.state()
    tip = env.state_layout["suction_tip"]
    cleared = np.zeros((1, 2))
    start = route.potential(state, cleared)[0]
    toward = state.copy()
    toward[:, tip] += (expert.park - state[0, tip]) * 0.5  # halfway to the park (normalised coordinates)
    assert route.potential(toward, cleared)[0] > start
    # from a point midway between the cavities, both full: the route's order is the expert's (far cavity first)
    floors = route.floors
    middle = state.copy()
    middle[:, tip] = ((floors[0] + floors[1]) / 2 + [0.0, 0.0, 0.01] - env.params.workspace_centre) / env.workspace_range
    full = np.full((1, 2), 8.0)
    lengths = {order: sum(np.linalg.norm(b - a) for a, b in zip(
        [middle[0, tip] * env.workspace_range + env.params.workspace_centre] + [floors[k] for k in order],
        [floors[k] for k in order] + [route.park])) for order in [(0, 1), (1, 0)]}
    far_first = tuple(expert.order)
    assert lengths[far_first] < lengths[far_first[::-1]]
    # the trainer's potential replaces the env's (10 x the distance to the nearest cavity) by 10 x that route
    nearest = np.linalg.norm(middle[0, tip] * env.workspace_range + env.params.workspace_centre - floors[0])
    assert -route.potential(middle, full)[0] == pytest.approx(10.0 * (lengths[far_first] - nearest), rel=1e-9)


# --- start-state options of the batched env ------------------------------------------------------------------
def test_tip_positions_and_debris_count_options():
    env = suction_debris_v8.batched_env(num_envs=3, autoreset_mode="disabled")
    env.reset(seed=0)
    tips = np.array([[0.02, 0.0, 0.05], [0.03, 0.005, 0.06], [0.04, -0.005, 0.055]])
    mask = np.array([True, False, True])
    before = env.core.arms["grasper"].tip_world()[1].copy()
    env.reset(options={"reset_mask": mask, "tip_positions": {"grasper": tips}, "debris_count": [1, 3, 2]})
    grasper = env.core.arms["grasper"].tip_world()
    np.testing.assert_allclose(grasper[[0, 2]], tips[[0, 2]], atol=1e-12)
    np.testing.assert_allclose(grasper[1], before)  # not reset, untouched
    layout = env.state_layout["debris"]
    delivered = env.state()[:, layout][:, 5::6]
    np.testing.assert_array_equal(delivered, [[0, 1, 1], [0, 0, 0], [0, 0, 1]])


@pytest.mark.parametrize("options, message", [
    ({"tip_positions": {"grasper": np.full((2, 3), 5.0)}}, "outside the workspace box"),
    ({"tip_positions": {"grasper": np.array([[0.03, 0.0, 0.0]] * 2)}}, "below the surface"),
    ({"tip_positions": {"surgeon": np.zeros((2, 3))}}, "unknown agent 'surgeon'"),
    ({"tip_positions": {"grasper": np.zeros((3, 3))}}, "one row per world"),
    ({"tip_positions": {"grasper": np.full((2, 3), np.nan)}}, "must be finite"),
    ({"debris_count": [4, 1]}, "debris_count must be integers in 0..3"),
    ({"debris_count": [1.5, 1]}, "debris_count must be integers"),
])
def test_start_state_options_reject_bad_values(options, message):
    env = suction_debris_v8.batched_env(num_envs=2, autoreset_mode="disabled")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        env.reset(options=options)


def test_colliding_tip_positions_are_refused():
    env = suction_debris_v8.batched_env(num_envs=1, autoreset_mode="disabled")
    env.reset(seed=0)
    suction_tip = env.core.arms["suction"].tip_world()
    with pytest.raises(ValueError, match="intersect"):  # (the same seed: the same episode, the same suction tip)
        env.reset(seed=0, options={"tip_positions": {"grasper": suction_tip}})


def test_set_tip_positions_keeps_the_drawn_episode():
    env = suction_debris_v8.batched_env(num_envs=2, autoreset_mode="disabled", blood_ml=[0.0, 0.0])
    env.reset(seed=4)
    pins = env.core.debris_position.copy()
    blood = env.core.remaining_ml.copy()
    target = pins[:, 0] + np.array([0.0, 0.0, 0.0015])
    env.set_tip_positions({"grasper": target}, worlds=[1])
    np.testing.assert_allclose(env.core.arms["grasper"].tip_world()[1], target[1], atol=1e-12)
    np.testing.assert_array_equal(env.core.debris_position, pins)
    np.testing.assert_array_equal(env.core.remaining_ml, blood)
    with pytest.raises(ValueError, match="one row per world"):
        env.set_tip_positions({"grasper": target[:1]}, worlds=[1])


def test_hold_bonus_charges_a_drop():
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled", blood_ml=[0.0, 0.0])
    env.reset(seed=3)
    env.set_tip_positions({"grasper": env.core.debris_position[:1, 0] + np.array([0.0, 0.0, 0.0015])})
    grasp = guidance.GraspPathShaping(env, 0.0, ["suction", "grasper"], hold_bonus=1.0)
    still = np.zeros((1, 4))
    values = [grasp.potential(env.state())[0]]
    for jaw in (-1.0, -1.0, 1.0):  # grasp, hold, release
        env.step({"suction": still, "grasper": np.array([[0.0, 0.0, 0.0, jaw]])})
        values.append(grasp.potential(env.state())[0])
    assert values == [0.0, 1.0, 1.0, 0.0]


def test_demo_runs_the_marl_team(tmp_path, monkeypatch):
    """``dvrl-marl demo --team marl`` seats the exported multi-agent policies (here from a tiny run)."""
    from dvrl_marl import demo

    run = tmp_path / "run"
    mappo.train(mappo.load_config(_config(tmp_path)), 0, run, total_steps=1024, progress=False, log=lambda *_: None)
    if demo.MARL_SEATS["suction"] != "marl-suction":
        shutil.copytree(run / "policies" / "marl-suction", run / "policies" / demo.MARL_SEATS["suction"])
    monkeypatch.setattr(policies, "shipped_dir", lambda: run / "policies")
    assert set(demo.MARL_SEATS.values()) <= set(policies.available())
    metrics = demo.run_demo(team="marl", out=tmp_path / "demo", max_cycles=30, video=False, progress=False)
    assert metrics["team"] == "marl" and metrics["pipeline"] == "marl" and metrics["steps"] == 30
    with pytest.raises(ValueError, match="pipeline applies"):
        demo.run_demo(team="marl", pipeline="learned_team", out=tmp_path / "d2", video=False, progress=False)


def test_demo_without_shipped_marl_policies_names_them(tmp_path, monkeypatch):
    from dvrl_marl import demo

    monkeypatch.setattr(policies, "shipped_dir", lambda: tmp_path)
    with pytest.raises(FileNotFoundError, match="marl-suction and marl-grasper"):
        demo.run_demo(team="marl", out=tmp_path / "demo", max_cycles=10, video=False, progress=False)
    with pytest.raises(FileNotFoundError, match="seats the multi-agent policies marl-suction; marl-suction is not"):
        demo.run_demo(team="marl", surgeon="scripted", out=tmp_path / "demo", max_cycles=10, video=False,
                      progress=False)


def test_run_folder_configuration_reads_back(tmp_path):
    """The config.toml a run writes is a configuration the trainer accepts, defaults (None) included."""
    config = mappo.load_config(_config(tmp_path))
    assert config.levels == [(0.0, 0.0), (0.5, 1.0)] and config.env["guidance"] == {"suction_route": 0.0}
    path = tmp_path / "written.toml"
    path.write_text(mappo.config_toml(config))
    again = mappo.load_config(path)
    assert {k: v for k, v in vars(again).items() if k != "name"} == {k: v for k, v in vars(config).items() if k != "name"}


def test_the_benchmarks_easy_task_file_reads_back_from_a_run_folder_and_none_is_refused_by_name(tmp_path):
    """The easy level's options (the task's own time limit: easy_episode_steps 0) survive config.toml; an env option
    of None, which TOML cannot hold, is refused by name rather than written as a file the trainer cannot read."""
    import yaml

    from dvrl_marl.integrations import __file__ as integrations

    config = mappo.load_config(_config(tmp_path))
    config.env = yaml.safe_load((Path(integrations).parent / "benchmarl_tasks" / "suction_debris_easy.yaml").read_text())
    path = tmp_path / "written.toml"
    path.write_text(mappo.config_toml(config))
    named = {"preset": config.env["preset"]} if config.env.get("preset", "default") != "default" else {}
    assert mappo.load_config(path).env == {**named, **with_preset(config.env)}  # (the preset's name kept)
    config.env = {**config.env, "easy_episode_steps": None}
    with pytest.raises(ValueError, match="easy_episode_steps"):
        mappo.config_toml(config)


def test_refused_placement_moves_no_tip():
    env = suction_debris_v8.batched_env(num_envs=1, autoreset_mode="disabled")
    env.reset(seed=0)
    before = {agent: env.core.arms[agent].tip_world().copy() for agent in ("suction", "grasper")}
    with pytest.raises(ValueError, match="outside the workspace box"):
        env.set_tip_positions({"suction": np.array([[-0.03, 0.0, 0.05]]), "grasper": np.full((1, 3), 5.0)})
    for agent, tip in before.items():
        np.testing.assert_array_equal(env.core.arms[agent].tip_world(), tip)


def test_over_rims_distances_go_around_the_phantom():
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled")
    env.reset(seed=0)
    rims = guidance.OverRims(env)
    cavities = env.core.cavities
    floor_a = np.array([cavities.centre_x[0], cavities.centre_y[0], cavities.floor_z[0] + 0.001])
    floor_b = np.array([cavities.centre_x[1], cavities.centre_y[1], cavities.floor_z[1] + 0.001])
    inside_a = floor_a + np.array([0.005, 0.0, 0.004])
    # within one cavity: the straight line
    assert rims.distance(inside_a, floor_a) == pytest.approx(np.linalg.norm(inside_a - floor_a))
    # between cavities: up to the top (+ margin), across, down: longer than the straight line through the phantom
    height = cavities.phantom.top_z + 0.002
    expected = (height - inside_a[2]) + np.hypot(*(floor_b - inside_a)[:2]) + (height - floor_b[2])
    assert rims.distance(inside_a, floor_b) == pytest.approx(expected)
    assert rims.distance(inside_a, floor_b) > np.linalg.norm(floor_b - inside_a)
    # a tip stuck on A's rim, pushing toward B's floor: climbing is progress, pushing down into the rim is not
    on_rim = np.array([-0.0099, -0.0008, 0.028])
    assert rims.distance(on_rim + [0, 0, 0.001], floor_b) < rims.distance(on_rim, floor_b)
    assert rims.distance(on_rim + [0.001, 0, -0.001], floor_b) > rims.distance(on_rim + [0, 0, 0.001], floor_b)
    # beside the phantom, below its top (its side is a wall): up, across, down into the cavity
    phantom = cavities.phantom
    beside = np.array([phantom.centre_x - phantom.half_x - 0.004, 0.0, phantom.top_z - 0.02])
    assert rims.region(beside) == guidance.OverRims.BESIDE and rims.region(beside + [0, 0, 0.03]) == -1
    expected = (height - beside[2]) + np.hypot(*(floor_a - beside)[:2]) + (height - floor_a[2])
    assert rims.distance(beside, floor_a) == pytest.approx(expected)
    above = np.array([0.0, 0.03, phantom.top_z + 0.01])  # over the top, outside the cavities: straight lines
    over_a = floor_a + [0.0, 0.0, 0.02]  # over cavity A, above the top: nothing to climb
    assert rims.distance(above, over_a) == pytest.approx(np.linalg.norm(over_a - above))
    assert rims.distance(above, beside + [0.0, 0.0, 0.03]) == pytest.approx(
        np.linalg.norm(beside + [0.0, 0.0, 0.03] - above))
    # batched: (N, K, 3) against (N, 1, 3)
    starts = np.stack([inside_a, floor_b])[None]
    np.testing.assert_allclose(rims.distance(starts, floor_a[None, None]),
                               [[rims.distance(inside_a, floor_a), rims.distance(floor_b, floor_a)]])
    # a point along that way splits its length, and the way starts and ends where it says (up first, from A's floor)
    for fraction in (0.0, 0.1, 0.5, 0.9, 1.0):
        point = rims.point_along(inside_a, floor_b, fraction)
        assert rims.distance(inside_a, point) + rims.distance(point, floor_b) == pytest.approx(
            rims.distance(inside_a, floor_b), abs=1e-9)
        assert rims.distance(inside_a, point) == pytest.approx(fraction * rims.distance(inside_a, floor_b), abs=1e-9)
    np.testing.assert_allclose(rims.point_along(inside_a, floor_b, 0.01)[:2], inside_a[:2])
    np.testing.assert_allclose(rims.point_along(inside_a, floor_a, 0.5), (inside_a + floor_a) / 2)


@pytest.mark.parametrize("over_rims", [False, True])
def test_grasp_path_shaping_over_rims_is_continuous_through_the_grasp(over_rims):
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled", blood_ml=[0.0, 0.0])
    env.reset(seed=3)
    pin = env.core.debris_position[0, 0] + np.array([0.0, 0.0, 0.002])
    env.reset(seed=3, options={"tip_positions": {"grasper": pin[None]}})
    grasp = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=over_rims)
    before = grasp.potential(env.state())
    _, rewards, *_ = env.step({"suction": np.zeros((1, 4)), "grasper": np.array([[0.0, 0.0, 0.0, -1.0]])})
    total = rewards["grasper"][0] + grasp.potential(env.state())[0] - before[0]
    assert abs(total - 2.0) < 0.06
    if over_rims:  # while holding, the carry is measured around the rim: more than the env's straight line
        assert grasp.potential(env.state())[0] < 0.0


def test_grasp_shaping_waits_at_the_surgeon_home_when_there_is_nothing_to_collect():
    from dvrl_marl.agents.collaborative import ScriptedSurgeon

    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled")
    env.reset(seed=0)  # full cavities: no pin in view
    grasp = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True, home=True)
    home = np.asarray(ScriptedSurgeon.for_env(env).home) * env.workspace_range + np.asarray(env.params.workspace_centre)
    np.testing.assert_allclose(grasp.home, home)
    state = env.state()
    tip = env.state_layout["grasper_tip"]
    start = state[0, tip] * env.workspace_range + env.params.workspace_centre
    assert grasp.potential(state)[0] == pytest.approx(-10.0 * guidance.OverRims(env).distance(start, home))
    closer = state.copy()
    closer[:, tip] = ((start + home) / 2 - env.params.workspace_centre) / env.workspace_range
    assert grasp.potential(closer)[0] > grasp.potential(state)[0]
    # with a pin in view the way home no longer counts
    with_pin = state.copy()
    first = env.state_layout["debris"].start
    with_pin[:, first + 3] = 1.0
    without_home = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True)
    assert grasp.potential(with_pin)[0] == pytest.approx(without_home.potential(with_pin)[0])


def test_grasp_shaping_collects_only_pins_in_cleared_cavities():
    """cleared_only: a pin showing where blood is still above the threshold is not a target (the env's pull toward
    it is cancelled: env + trainer potential is the way home); once its cavity is clear it is."""
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled")
    env.reset(seed=0)
    grasp = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True, home=True, cleared_only=True)
    plain = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True, home=True)
    layout = env.state_layout
    state = env.state()
    first = layout["debris"].start
    state[:, first + 3] = 1.0  # pin 0 in view ...
    pin = state[0, first:first + 3] * env.workspace_range + env.params.workspace_centre
    cavity = int(np.argmin(np.hypot(env.core.cavities.centre_x - pin[0], env.core.cavities.centre_y - pin[1])))
    tip = state[0, layout["grasper_tip"]] * env.workspace_range + env.params.workspace_centre
    env_potential = -10.0 * np.linalg.norm(tip - pin)
    way_home = guidance.OverRims(env).distance(tip, grasp.home)
    # ... its cavity full: not a target; the sum of both potentials is the way home, as with no pin at all
    assert env_potential + grasp.potential(state)[0] == pytest.approx(-10.0 * way_home)
    assert plain.potential(state)[0] != pytest.approx(grasp.potential(state)[0])
    # ... its cavity cleared: the target, exactly as without the rule
    state[0, layout["blood"].start + cavity] = 0.0
    assert grasp.potential(state)[0] == pytest.approx(plain.potential(state)[0])


def test_trainer_runs_with_the_switch_head_the_envs_hold_and_zoomed_features(tmp_path):
    """The switch head, the env's grasp options (a held pin kept until the hand-off: what the retired
    held_tool_logit prior did) and the zoomed feature set through a whole tiny run: the exported grasper computes the
    features from the plain observation and decides its jaw as a sign; the retired key is refused naming its commit."""
    text = TINY.format(algorithm="ippo", surgeon="none", seat="grasper").replace(
        "hidden = [16, 16]\n", 'hidden = [16, 16]\ntool_head = "switch"\n'
                        'initial_tool_logit = { suction = 3.0, grasper = 0.0 }\n').replace(
        "max_cycles = 40\n", 'max_cycles = 40\nobservation_features = "suction_debris_cleared_pins_zoom"\n'
                           'jaw_command = "switch"\nhold_until_handoff = true\n')
    path = tmp_path / "hold_zoom.toml"
    path.write_text(text)
    config = mappo.load_config(path)
    assert config.env["hold_until_handoff"] is True
    run = tmp_path / "run"
    mappo.train(config, 0, run, progress=False, log=lambda *_: None)
    grasper = policies.load(run / "policies" / "marl-grasper")
    assert grasper.spec["features"]["name"] == "suction_debris_cleared_pins_zoom"
    assert grasper.spec["layer_sizes"][1:3] == [16, 16]  # the network alone: no unit of a prior
    assert grasper(np.zeros(30))[3] in (-1.0, 1.0)
    assert mappo.load_config(run / "config.toml").env["hold_until_handoff"] is True
    retired = tmp_path / "held_prior.toml"
    retired.write_text(text.replace('tool_head = "switch"\n', 'tool_head = "switch"\nheld_tool_logit = { grasper = -10.0 }\n'))
    with pytest.raises(ValueError, match=r"\[model\] held_tool_logit: retired when the env took it over \(now the env's option: "
                                         r"\[env\] hold_until_handoff = true.*reproducible from commit c59ae5f"):
        mappo.load_config(retired)


def test_mappo_critic_on_the_agent_specific_state_trains_and_resumes(tmp_path):
    """critic_input = "state_and_observation": each agent's value from the state and its own observation (and
    features); a tiny run trains, its checkpoint resumes, and the critic's inputs reach the value."""
    text = TINY.format(algorithm="mappo", surgeon="none", seat="grasper").replace(
        "hidden = [16, 16]\n", 'hidden = [16, 16]\ncritic_input = "state_and_observation"\n').replace(
        "max_cycles = 40\n", 'max_cycles = 40\nobservation_features = "suction_debris_cleared_pins_zoom"\n')
    path = tmp_path / "agent_specific.toml"
    path.write_text(text)
    config = mappo.load_config(path)
    run = tmp_path / "run"
    mappo.train(config, 0, run, total_steps=1024, progress=False, log=lambda *_: None)
    final = mappo.train(config, 0, run, total_steps=2048, resume=True, progress=False, log=lambda *_: None)
    assert final["steps"] == 2048
    _, critic, _, norms = models.build_models(config, ["suction", "grasper"], 30, 33, 4)
    assert set(norms) == {"observation", "state", "critic_observation"}
    from tensordict import TensorDict

    observation = torch.zeros(5, 2, 30)
    td = TensorDict({"state": torch.zeros(5, 33), "agents": TensorDict({"observation": observation},
                                                                        batch_size=[5, 2])}, batch_size=[5])
    with torch.no_grad():
        before = critic(td)["agents", "state_value"].clone()
        td["agents", "observation"][:, 1, 0] = 1.0  # the grasper's own tip moves: only its value changes
        after = critic(td)["agents", "state_value"]
    assert before.shape == (5, 2, 1)
    assert torch.equal(before[:, 0], after[:, 0]) and not torch.equal(before[:, 1], after[:, 1])


@pytest.mark.parametrize("path", sorted((ROOT / "baselines" / "results" / "marl").glob("*.toml")), ids=lambda p: p.stem)
def test_every_recorded_configuration_before_the_env_options_names_its_commit(path):
    """Records that used the trainer's own shaping and curriculum (retired when the env took it over) are refused, naming the
    commit that reproduces them; the others still load."""
    import tomllib

    table = tomllib.loads(path.read_text())
    retired = [key for name, content in table.items() if name != "env" for key in content
               if key in mappo_config.RETIRED] + (["shaping"] if "shaping" in table else [])
    if retired:  # the oldest commit that reads every retired key the record has
        commit = ("ea6d143" if any(key not in mappo_config.RETIRED_AT for key in retired)
                  else mappo_config.RETIRED_AT[retired[0]])
        with pytest.raises(ValueError, match=f"reproducible from commit {commit}"):
            mappo.load_config(path)
    else:
        mappo.load_config(path)


@pytest.mark.parametrize("path", sorted(p for pattern in ("suction_debris_mappo*.toml", "suction_debris_ippo*.toml")
                                       for p in (ROOT / "baselines" / "configs").glob(pattern)), ids=lambda p: p.stem)
def test_every_shipped_multi_agent_configuration_loads(path):
    config = mappo.load_config(path)
    assert config.name == path.stem and config.algorithm in mappo.ALGORITHMS


def test_a_configuration_that_extends_the_record_holds_only_what_differs(tmp_path):
    """``[run] extends``: the record's settings, key by key overridden by the file's own (the large-batch retuning
    among the shipped ones); a chain through another file; the name is the file's."""
    record = mappo.load_config(ROOT / "baselines" / "configs" / "suction_debris_mappo.toml")
    large = mappo.load_config(ROOT / "baselines" / "configs" / "suction_debris_mappo_large_batch.toml")
    assert (large.num_envs, large.epochs, large.minibatches, large.learning_rate) == (512, 2, 8, 0.0003)
    assert (large.env, large.levels, large.hidden, large.gamma) == (record.env, record.levels, record.hidden,
                                                                     record.gamma)
    (tmp_path / "base.toml").write_text((ROOT / "baselines" / "configs" / "suction_debris_mappo.toml").read_text())
    (tmp_path / "middle.toml").write_text("[run]\nextends = 'base.toml'\nnum_envs = 8\n[ppo]\nepochs = 2\n")
    (tmp_path / "leaf.toml").write_text("[run]\nextends = 'middle.toml'\n[ppo]\nepochs = 3\n[env]\ncontact_penalty = 0.5\n")
    leaf = mappo.load_config(tmp_path / "leaf.toml")
    assert (leaf.name, leaf.num_envs, leaf.epochs, leaf.minibatches) == ("leaf", 8, 3, record.minibatches)
    assert leaf.env == {**record.env, "contact_penalty": 0.5}
    (tmp_path / "base.toml").write_text("[run]\nextends = 'leaf.toml'\n")
    with pytest.raises(ValueError, match=r"comes back to a file of its own chain \(leaf.toml -> middle.toml -> base.toml"):
        mappo.load_config(tmp_path / "leaf.toml")


def _pin_along_x(seeds=range(40)):
    """A seed whose first pin lies within 25 degrees of the x axis (a grasp at its +x end holds it 11+ mm short)."""
    for seed in seeds:
        env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled",
                                            blood_ml=[0.0, 0.0])
        env.reset(seed=seed)
        if abs(np.cos(env.core.debris_yaw[0, 0])) > np.cos(np.radians(25)):
            return seed
    raise AssertionError("no pin along x in the seeds tried")


@pytest.mark.slow
def test_centred_grasps_charge_a_grasp_that_can_never_be_delivered():
    """A pin taken by its +x end is held so far behind the tip that the tip would have to leave the workspace to
    bring it onto the hand-off point: the scripted carry never delivers it, while the same pin taken by its centre
    is delivered. ``centred`` shaping charges the first at the grasp (the hold bonus gone, the distance beyond the
    workspace counted) and not the second."""
    from dvrl_marl.agents.collaborative import ScriptedSurgeon

    seed = _pin_along_x()
    gains, delivered = {}, {}
    for grip in ("centre", "end"):
        env = v0_rules.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled",
                                            blood_ml=[0.0, 0.0])
        env.reset(seed=seed)
        core = env.core
        pin = core.debris_position[0, 0].copy()
        axis = np.array([np.cos(core.debris_yaw[0, 0]), np.sin(core.debris_yaw[0, 0]), 0.0]) * 0.0125
        place = pin if grip == "centre" else pin + (axis if axis[0] > 0 else -axis)  # the centre or the +x end
        env.reset(seed=seed, options={"tip_positions": {"grasper": (place + [0.0, 0.0, 0.0015])[None]}})
        shapings = {"centred": guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], hold_bonus=1.0,
                                                        over_rims=True, centred=True),
                    "plain": guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], hold_bonus=1.0,
                                                      over_rims=True)}
        still = np.zeros((1, 4))
        before = {name: s.potential(env.state())[0] for name, s in shapings.items()}
        observations, rewards, *_ = env.step({"suction": still, "grasper": np.array([[0.0, 0.0, 0.0, -1.0]])})
        assert core.holding[0] == 0
        gains[grip] = {name: rewards["grasper"][0] + s.potential(env.state())[0] - before[name]
                       for name, s in shapings.items()}
        surgeon = ScriptedSurgeon.for_env(env)  # the carry: the pin (not the tip) toward the hand-off point
        delivered[grip] = False
        for _ in range(600):
            observations, _, _, _, infos = env.step({"suction": still, "grasper": surgeon.act(observations["grasper"])})
            delivered[grip] |= bool(infos["grasper"]["debris_delivered"][0])
        if grip == "end":
            assert core.holding[0] == 0  # still held, at the workspace's face, more than 3 mm short
    assert delivered == {"centre": True, "end": False}
    # without the rule both grasps earn the same; with it the end grasp loses its hold bonus and more
    assert gains["end"]["plain"] == pytest.approx(gains["centre"]["plain"], abs=0.3)
    assert gains["centre"]["centred"] == pytest.approx(gains["centre"]["plain"], abs=0.2)
    assert gains["end"]["centred"] < gains["centre"]["centred"] - 1.5


def test_centred_grasps_approach_a_pin_from_above():
    """``centred``: at the same distance from a pin's centre, a tip above it is nearer in potential than one beside
    it at its height (a tip coming along the floor would close on the pin's end)."""
    env = suction_debris_v8.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled", blood_ml=[0.0, 0.0])
    env.reset(seed=3)
    pin = env.core.debris_position[0, 0].copy()
    yaw = env.core.debris_yaw[0, 0]
    across = np.array([-np.sin(yaw), np.cos(yaw), 0.0])  # horizontal, across the pin's axis
    centred = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True, centred=True)
    plain = guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], over_rims=True)
    totals = {}
    for name, place in (("above", pin + [0.0, 0.0, 0.006]), ("beside", pin + 0.006 * across)):
        env.set_tip_positions({"grasper": place[None]})
        tip = env.core.arms["grasper"].tip_world()[0]
        np.testing.assert_allclose(tip, place, atol=1e-6)
        state = env.state()
        env_potential = -10.0 * np.linalg.norm(tip - pin)
        totals[name] = (env_potential + plain.potential(state)[0], env_potential + centred.potential(state)[0])
    plain_preference = totals["above"][0] - totals["beside"][0]
    centred_preference = totals["above"][1] - totals["beside"][1]
    assert centred_preference > max(plain_preference, 0.0) + 0.05


def test_off_centre_grasps_charge_a_grasp_in_proportion_to_its_distance_from_the_pins_centre():
    """``off_centre``: a pin taken at its centre costs nothing more than with ``centred`` alone; taken 3 mm and 6 mm
    along its axis toward an end (both deliverable in principle) it costs in proportion, at the grasp."""
    seed = _pin_along_x()
    gains = {}
    for along in (0.0, 0.003, 0.006):
        env = v0_rules.batched_env(num_envs=1, reward_type="dense", autoreset_mode="disabled",
                                            blood_ml=[0.0, 0.0])
        env.reset(seed=seed)
        core = env.core
        pin = core.debris_position[0, 0].copy()
        axis = np.array([np.cos(core.debris_yaw[0, 0]), np.sin(core.debris_yaw[0, 0]), 0.0])
        place = pin + along * (axis if axis[0] > 0 else -axis)
        env.reset(seed=seed, options={"tip_positions": {"grasper": (place + [0.0, 0.0, 0.0015])[None]}})
        shapings = {weight: guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], hold_bonus=1.0,
                                                     over_rims=True, centred=True, off_centre=weight)
                    for weight in (0.0, 20.0)}
        before = {w: s.potential(env.state())[0] for w, s in shapings.items()}
        env.step({"suction": np.zeros((1, 4)), "grasper": np.array([[0.0, 0.0, 0.0, -1.0]])})
        assert core.holding[0] == 0
        after = {w: s.potential(env.state())[0] for w, s in shapings.items()}
        gains[along] = {w: after[w] - before[w] for w in shapings}
    charge = {along: gains[along][0.0] - gains[along][20.0] for along in gains}
    assert charge[0.0] == pytest.approx(0.0, abs=0.02)
    assert charge[0.003] == pytest.approx(10.0 * 20.0 * 0.003, rel=0.15)
    assert charge[0.006] == pytest.approx(2.0 * charge[0.003], rel=0.15)
    with pytest.raises(ValueError, match="off_centre"):
        guidance.GraspPathShaping(env, 10.0, ["suction", "grasper"], off_centre=-1.0)


def test_the_trainer_runs_on_suction_debris_v8(tmp_path):
    # The scene a person uses (hand-off at the grip, dropped pins kept in view) is a task option of the trainer's env.
    path = tmp_path / "tiny_v2.toml"
    path.write_text(TINY.format(algorithm="mappo", surgeon="none", seat="grasper").replace(
        '[env]\n', '[env]\ntask = "suction_debris_v8"\n'))
    config = mappo.load_config(path)
    assert config.env["task"] == "suction_debris_v8"
    run = tmp_path / "run"
    final = mappo.train(config, 0, run, progress=False, log=lambda *_: None)
    assert final["steps"] == 2048
    assert suction_debris_v8.batched_env(num_envs=1, **config.env).params.deliver_at_grip


def test_the_best_checkpoint_prefers_success_then_fewer_contacts_then_blood():
    def result(success, contacts, blood):
        return {"success_rate": success, "mean_contact_steps": contacts, "mean_blood_removed_ml": blood}

    assert mappo._rank(result(0.9, 50.0, 10.0)) > mappo._rank(result(0.8, 0.0, 15.0))  # success first
    assert mappo._rank(result(0.9, 0.0, 14.0)) > mappo._rank(result(0.9, 5.0, 15.0))  # a seat that waits
    assert mappo._rank(result(0.9, 0.0, 15.0)) > mappo._rank(result(0.9, 0.0, 14.0))


def test_a_seeds_run_is_reproduced_bit_for_bit(tmp_path):
    """The trainer of record, run twice from one seed on one machine with one set of library versions, exports the
    same policies to the last bit (what docs/results.md promises of a figure; across machines it does not)."""
    config = mappo.load_config(_config(tmp_path))
    exported = []
    for run in ("first", "second"):
        mappo.train(config, 3, tmp_path / run, total_steps=2048, progress=False, log=lambda *_: None)
        exported.append(tmp_path / run / "policies")
    for agent in ("suction", "grasper"):
        first, second = (np.load(folder / f"marl-{agent}" / "policy.npz") for folder in exported)
        assert first.files == second.files
        for name in first.files:
            np.testing.assert_array_equal(first[name], second[name], err_msg=f"marl-{agent} {name}")
