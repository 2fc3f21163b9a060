"""BenchMARL on the collaborative task (dvrl_marl.integrations.benchmarl): the task's specs and groups, and a short
run of BenchMARL's own MAPPO, IPPO and MASAC with our task files. CI runs these in an environment with BenchMARL
(``.ci/run``); elsewhere they skip, saying so."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import json
from pathlib import Path

import pytest

pytest.importorskip("benchmarl", reason='BenchMARL is not installed (pip install "dvrl-marl[benchmarl]")')

from dvrl_marl.integrations.benchmarl import LEVELS, SuctionDebrisTask, suction_debris_task  # noqa: E402
from dvrl_marl.suction_debris.presets import PRESETS  # noqa: E402


@pytest.mark.parametrize("level", LEVELS)
def test_shipped_levels_build_the_task_with_groups_specs_and_state(level):
    task = suction_debris_task(level)
    assert isinstance(task, SuctionDebrisTask) and task.config["reward_type"] == "guided"
    env = task.get_env_fun(num_envs=3, continuous_actions=True, seed=0, device="cpu")()
    assert task.group_map(env) == {"agents": ["suction", "grasper"]}
    assert task.observation_spec(env)["agents", "observation"].shape[0] == 2  # one world's: (agents, obs_dim)
    assert "state" in task.state_spec(env).keys() and "state" not in task.observation_spec(env).keys()
    assert task.action_spec(env)["agents", "action"].shape == (2, 4)
    assert task.max_steps(env) == (PRESETS["irrigation"]["max_cycles"] if level == "irrigation" else 1500)
    assert env.batched.levels.tolist() == [0.0 if level == "easy" else 1.0] * 3


def test_bad_task_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="neither a level"):
        suction_debris_task("hard")
    bad = tmp_path / "bad.yaml"
    bad.write_text("start_level: 3\n")
    with pytest.raises(ValueError, match="bad.yaml.*level must lie in"):
        suction_debris_task(str(bad))


@pytest.mark.parametrize("algorithm", ["mappo", "ippo", "masac"])
def test_a_short_benchmarl_run_trains_and_writes_its_json(tmp_path, algorithm):
    from benchmarl.algorithms import IppoConfig, MappoConfig, MasacConfig
    from benchmarl.experiment import Experiment, ExperimentConfig
    from benchmarl.models.mlp import MlpConfig

    config = ExperimentConfig.get_from_yaml()
    config.max_n_frames = 1_200
    config.on_policy_collected_frames_per_batch = config.off_policy_collected_frames_per_batch = 600
    config.on_policy_n_envs_per_worker = config.off_policy_n_envs_per_worker = 4
    config.on_policy_n_minibatch_iters, config.on_policy_minibatch_size = 1, 300
    config.off_policy_n_optimizer_steps, config.off_policy_train_batch_size = 2, 64
    config.evaluation_interval, config.evaluation_episodes = 600, 2
    config.loggers, config.render, config.save_folder = ["csv"], False, str(tmp_path)
    algorithm_config = {"mappo": MappoConfig, "ippo": IppoConfig, "masac": MasacConfig}[algorithm].get_from_yaml()
    task = suction_debris_task("easy", max_cycles=60)
    experiment = Experiment(task=task, algorithm_config=algorithm_config, model_config=MlpConfig.get_from_yaml(),
                            critic_model_config=MlpConfig.get_from_yaml(), seed=0, config=config)
    experiment.run()
    assert experiment.total_frames >= 1_200
    results = list(tmp_path.rglob("*.json"))
    assert results, "BenchMARL wrote no JSON of results"
    data = json.loads(results[0].read_text())
    assert "dvrl_marl" in json.dumps(data)


def test_start_level_schedule_drives_the_training_worlds_level(tmp_path):
    from benchmarl.algorithms import MappoConfig
    from benchmarl.experiment import Experiment
    from benchmarl.models.mlp import MlpConfig

    from dvrl_marl.integrations.benchmarl import StartLevelSchedule, SuccessCurve, experiment_config

    with pytest.raises(ValueError, match="progress increasing"):
        StartLevelSchedule([(0.5, 0.0), (0.2, 1.0)])
    schedule = StartLevelSchedule([(0.0, 0.0), (1.0, 1.0)])
    assert schedule.level(0.25) == pytest.approx(0.25)
    curve = SuccessCurve()
    config = experiment_config(max_n_frames=1_200, on_policy_collected_frames_per_batch=600,
                               on_policy_n_envs_per_worker=4, on_policy_minibatch_size=300,
                               on_policy_n_minibatch_iters=1, evaluation_interval=600, evaluation_episodes=2,
                               save_folder=str(tmp_path))
    experiment = Experiment(task=suction_debris_task("default", max_cycles=60), algorithm_config=MappoConfig.get_from_yaml(),
                            model_config=MlpConfig.get_from_yaml(), critic_model_config=MlpConfig.get_from_yaml(),
                            seed=0, config=config, callbacks=[schedule, curve])
    experiment.run()
    # set at the start (level 0), after the first batch (half-way: 0.5) and the second (the default task)
    assert [level for _, level in schedule.applied] == [0.0, 0.5, 1.0]
    assert len(curve.points) >= 1 and all(0.0 <= p["success_rate"] <= 1.0 for p in curve.points)
    with pytest.raises(ValueError, match="not a BenchMARL experiment setting"):
        experiment_config(learning_rate=1e-3)


def test_shipped_settings_change_only_what_their_files_say(tmp_path):
    """The algorithm's and the model's settings: BenchMARL's defaults, then the shipped files, then overrides."""
    from benchmarl.algorithms import IppoConfig, MappoConfig, MasacConfig
    from benchmarl.models.mlp import MlpConfig

    from dvrl_marl.integrations.benchmarl import algorithm_config, model_config, settings_overrides

    for name, stock in (("mappo", MappoConfig), ("ippo", IppoConfig)):
        shipped = algorithm_config(name)
        assert shipped.share_param_critic is False and shipped.lmbda == 0.95  # one critic per arm
        assert algorithm_config(name, shipped=False) == stock.get_from_yaml()
        changed = {key for key, value in vars(shipped).items() if value != getattr(stock.get_from_yaml(), key)}
        assert changed == set(settings_overrides(Path(__file__).parents[1] / "dvrl_marl" / "integrations" /
                                                 "benchmarl_tasks" / f"{name}.yaml"))
    assert algorithm_config("mappo").entropy_coef == 0.001 and algorithm_config("ippo").entropy_coef == 0.0
    assert algorithm_config("masac") == MasacConfig.get_from_yaml()  # no shipped file: BenchMARL's own
    assert algorithm_config("mappo", lmbda=0.8).lmbda == 0.8
    assert model_config().num_cells == [64, 64] and model_config(shipped=False) == MlpConfig.get_from_yaml()
    own = tmp_path / "mine.yaml"
    own.write_text("entropy_coef: 0.01\n")
    mine = algorithm_config("mappo", path=own)
    assert mine.entropy_coef == 0.01 and mine.share_param_critic is True  # the file given, not the shipped one
    with pytest.raises(ValueError, match="mine.yaml: num_cells: not a BenchMARL mappo setting"):
        own.write_text("num_cells: [8]\n")
        algorithm_config("mappo", path=own)
    with pytest.raises(ValueError, match="'ppo': not one of"):
        algorithm_config("ppo")
    with pytest.raises(ValueError, match="no such file"):
        model_config(path=tmp_path / "missing.yaml")
    with pytest.raises(ValueError, match="holds a mapping"):
        own.write_text("- 64\n")
        model_config(path=own)
    with pytest.raises(ValueError, match="overrides: width: not a BenchMARL MLP model setting"):
        model_config(width=3)
