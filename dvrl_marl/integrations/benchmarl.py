"""BenchMARL task for the collaborative scene: ``pip install "dvrl-marl[benchmarl]"``.

```python
from benchmarl.experiment import Experiment
from dvrl_marl.integrations.benchmarl import algorithm_config, experiment_config, model_config, suction_debris_task

experiment = Experiment(task=suction_debris_task("easy"), algorithm_config=algorithm_config("mappo"),
                        model_config=model_config(), critic_model_config=model_config(), seed=0,
                        config=experiment_config())
experiment.run()
```

:class:`SuctionDebrisTask` is a BenchMARL ``TaskClass`` over the batched env's TorchRL form
(:class:`dvrl_marl.integrations.torchrl.SuctionDebrisTorchRLEnv`, vectorised: BenchMARL's ``n_envs_per_worker``
worlds in one env): both arms in one group ``"agents"``, continuous actions in [-1, 1], ``state`` for MAPPO's
centralised critic, and the share of ended episodes that succeeded logged as ``collection/success_rate``.
:func:`suction_debris_task` reads one of the shipped task files, one per start level
(``dvrl_marl/integrations/benchmarl_tasks/suction_debris_<level>.yaml``: the guided reward, the observation
features, the level, ``tool_speed`` so that a Gaussian policy's noise cannot flick the valve, and the jaw a switch
that holds a pin until the hand-off, ``jaw_command`` and ``hold_until_handoff``: a grasp is one decision), or a file
of your own (its keys: any of ``SuctionDebrisTorchRLEnv``'s keyword arguments).

The settings the benchmark runs ship beside them, each a YAML of what it changes in BenchMARL's own defaults:
:func:`experiment_config` (``benchmarl_tasks/experiment.yaml``: one policy per arm, 256 worlds, the PPO settings of
this project's configuration of record), :func:`algorithm_config` (``mappo.yaml``, ``ippo.yaml``: a critic per arm,
whose rewards differ; BenchMARL's own for the others) and :func:`model_config` (``mlp.yaml``: 64 x 64). Nothing
inside BenchMARL's algorithms is changed. :class:`SuccessCurve` records the evaluation's success rate;
:class:`StartLevelSchedule` drives the start level from outside the algorithm (a curriculum).
"""

from __future__ import annotations

import copy
from pathlib import Path

import time

try:
    from benchmarl.environments.common import TaskClass
    from benchmarl.experiment.callback import Callback
except ImportError as error:  # pragma: no cover - exercised where BenchMARL is missing
    raise ImportError('dvrl_marl.integrations.benchmarl needs BenchMARL: pip install "dvrl-marl[benchmarl]"') from error
from torchrl.data import Composite

from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv
from dvrl_marl.suction_debris.presets import with_preset
from dvrl_marl.suction_debris.start_levels import checked_schedule, scheduled_level

__all__ = ["SuctionDebrisTask", "SuccessCurve", "StartLevelSchedule", "suction_debris_task", "experiment_config",
           "algorithm_config", "model_config", "settings_overrides", "first_episode_success", "TASK_FILES", "LEVELS"]

#: The shipped task files.
TASK_FILES = Path(__file__).with_name("benchmarl_tasks")
LEVELS = ("easy", "default", "irrigation")


def _base(env):
    """The SuctionDebrisTorchRLEnv under BenchMARL's transforms."""
    while not isinstance(env, SuctionDebrisTorchRLEnv):
        env = env.base_env
    return env


class SuctionDebrisTask(TaskClass):
    """The collaborative task as a BenchMARL ``TaskClass`` (see the module documentation); ``config``: keyword
    arguments of :class:`SuctionDebrisTorchRLEnv`."""

    def get_env_fun(self, num_envs, continuous_actions, seed, device):
        config = copy.deepcopy(self.config)
        return lambda: SuctionDebrisTorchRLEnv(num_envs=num_envs, device=device, seed=seed, **config)

    def supports_continuous_actions(self) -> bool:
        return True

    def supports_discrete_actions(self) -> bool:
        return False

    def max_steps(self, env) -> int:
        return int(_base(env).batched.params.max_cycles)

    def has_render(self, env) -> bool:
        return False  # (rendering every evaluation is slow; render a policy with dvrl-marl's own tools)

    def group_map(self, env) -> dict:
        return _base(env).group_map

    # BenchMARL's specs are a single world's (the env's batch dimension removed)
    def observation_spec(self, env) -> Composite:
        spec = env.full_observation_spec_unbatched.clone()
        for key in ("state", "is_success"):
            del spec[key]
        return spec

    def info_spec(self, env):
        return None

    def state_spec(self, env) -> Composite:
        return Composite({"state": env.full_observation_spec_unbatched["state"].clone()})

    def action_spec(self, env) -> Composite:
        return env.full_action_spec_unbatched.clone()

    def action_mask_spec(self, env):
        return None

    @staticmethod
    def env_name() -> str:
        return "dvrl_marl"

    @staticmethod
    def log_info(batch) -> dict:
        done = batch.get(("next", "done"))
        ended = float(done.sum())
        if not ended:
            return {}
        return {"collection/success_rate": float((batch.get(("next", "is_success")) & done).sum()) / ended}


def first_episode_success(rollout) -> bool:
    """Whether one world's rollout (a tensordict of its steps, BenchMARL's evaluation or ``env.rollout``) completed
    the task in its first episode (a vectorised rollout restarts worlds that end)."""
    done = rollout.get(("next", "done")).reshape(-1)
    if not bool(done.any()):
        return False
    first = int(done.nonzero()[0])
    return bool(rollout.get(("next", "is_success")).reshape(-1)[first])


class SuccessCurve(Callback):
    """A BenchMARL callback: after each evaluation, the share of its episodes that completed the task, logged as
    ``eval/success_rate`` and kept in :attr:`points` (frames, wall seconds since the callback was made, success)."""

    def __init__(self):
        super().__init__()
        self.points: list[dict] = []
        self.started = time.perf_counter()

    def on_evaluation_end(self, rollouts):
        success = sum(first_episode_success(r) for r in rollouts) / max(len(rollouts), 1)
        frames = int(self.experiment.total_frames)
        self.points.append({"frames": frames, "wall_seconds": time.perf_counter() - self.started,
                            "success_rate": float(success)})
        self.experiment.logger.log({"eval/success_rate": float(success)}, step=self.experiment.n_iters_performed)


class StartLevelSchedule(Callback):
    """A BenchMARL callback that drives the env's start level (:mod:`dvrl_marl.suction_debris.start_levels`) as a
    piecewise-linear schedule over the run, ``levels = [(progress, level), ...]`` (progress: the share of
    ``max_n_frames`` collected): after each collected batch the training worlds' next episodes start at the scheduled
    level. The same curriculum as this project's trainer (``[curriculum] levels``), from outside the algorithm; the
    evaluation env keeps the task file's level.
    """

    def __init__(self, levels=((0.0, 0.0), (0.3, 0.5), (1.0, 1.0))):
        super().__init__()
        self.levels = checked_schedule(levels, "StartLevelSchedule")
        if not self.levels:
            raise ValueError("StartLevelSchedule: an empty schedule (give at least one (progress, level) pair)")
        self.applied: list[tuple[int, float]] = []  # (frames, level) each time the level was set

    def level(self, progress: float) -> float:
        return scheduled_level(self.levels, progress)

    def _apply(self):
        experiment = self.experiment
        frames = int(getattr(experiment, "total_frames", 0))
        level = self.level(frames / max(int(experiment.config.max_n_frames or 1), 1))
        _base(experiment.collector.env).set_start_level(level)
        self.applied.append((frames, level))

    def on_setup(self):
        self._apply()

    def on_batch_collected(self, batch):
        self._apply()


def _overridden(config, path: Path, overrides: dict, what: str):
    """``config`` (a BenchMARL config dataclass) with the values of the YAML file ``path`` (None or a missing
    shipped file: none), then ``overrides``; an unknown key is a ``ValueError`` naming it and the file."""
    from_file = settings_overrides(path) if path is not None else {}
    for key, value in {**from_file, **overrides}.items():
        if not hasattr(config, key):
            raise ValueError(f"{'overrides' if key in overrides else path}: {key}: not a BenchMARL {what} setting")
        setattr(config, key, value)
    return config


def experiment_config(path=None, **overrides):
    """BenchMARL's ``ExperimentConfig``: its own defaults, then the shipped overrides for this task
    (``benchmarl_tasks/experiment.yaml``: the record's PPO settings, 256 worlds per batch) or those of ``path``,
    then ``overrides``. An unknown key is a ``ValueError`` naming it."""
    from benchmarl.experiment import ExperimentConfig

    path = Path(path) if path is not None else TASK_FILES / "experiment.yaml"
    if not path.is_file():
        raise ValueError(f"BenchMARL experiment settings {str(path)!r}: no such file")
    return _overridden(ExperimentConfig.get_from_yaml(), path, overrides, "experiment")


def algorithm_config(name: str, path=None, shipped: bool = True, **overrides):
    """BenchMARL's config of the algorithm ``name`` (``"mappo"``, ``"ippo"``, ``"masac"``, ...): its own defaults,
    then the shipped overrides for this task where there are some (``benchmarl_tasks/<name>.yaml``; none with
    ``shipped=False``) or those of ``path``, then ``overrides``. Settings only: nothing inside the algorithm
    changes. An unknown key is a ``ValueError`` naming it."""
    from benchmarl.algorithms import algorithm_config_registry

    if name not in algorithm_config_registry:
        raise ValueError(f"BenchMARL algorithm {name!r}: not one of {', '.join(sorted(algorithm_config_registry))}")
    if path is not None and not Path(path).is_file():
        raise ValueError(f"BenchMARL {name} settings {str(path)!r}: no such file")
    path = Path(path) if path is not None else TASK_FILES / f"{name}.yaml" if shipped else None
    return _overridden(algorithm_config_registry[name].get_from_yaml(), path, overrides, f"{name}")


def model_config(path=None, shipped: bool = True, **overrides):
    """BenchMARL's ``MlpConfig`` (the policies' and critics' network): its own defaults, then the shipped
    overrides for this task (``benchmarl_tasks/mlp.yaml``; none with ``shipped=False``) or those of ``path``,
    then ``overrides``."""
    from benchmarl.models.mlp import MlpConfig

    if path is not None and not Path(path).is_file():
        raise ValueError(f"BenchMARL model settings {str(path)!r}: no such file")
    path = Path(path) if path is not None else TASK_FILES / "mlp.yaml" if shipped else None
    return _overridden(MlpConfig.get_from_yaml(), path, overrides, "MLP model")


def settings_overrides(path) -> dict:
    """The values a settings file (an algorithm's, the model's) overrides, as written (``{}`` for no file)."""
    import yaml

    path = Path(path)
    if not path.is_file():
        return {}
    values = yaml.safe_load(path.read_text()) or {}
    if not isinstance(values, dict):
        raise ValueError(f"{path}: a settings file holds a mapping of settings, got {type(values).__name__}")
    return dict(values)


def suction_debris_task(level_or_file: str = "default", **overrides) -> SuctionDebrisTask:
    """The task from a shipped level (``"easy"``, ``"default"``, ``"irrigation"``) or a YAML file of keyword arguments; ``overrides``
    replace the file's values. Checked by building one world: a bad key or value is a ``ValueError`` naming it."""
    import yaml

    path = TASK_FILES / f"suction_debris_{level_or_file}.yaml" if level_or_file in LEVELS else Path(level_or_file)
    if not path.is_file():
        raise ValueError(f"BenchMARL task {level_or_file!r}: neither a level ({', '.join(LEVELS)}) nor a file")
    config = yaml.safe_load(path.read_text()) or {}
    if not isinstance(config, dict):
        raise ValueError(f"{path}: a task file holds keyword arguments (a mapping), got {type(config).__name__}")
    config.update(overrides)
    try:
        config = with_preset(config, str(path))  # the preset's options spelt out: the task says what it runs
        SuctionDebrisTorchRLEnv(num_envs=1, **config).batched.close()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: {error}") from None
    name = path.stem if level_or_file not in LEVELS else f"suction_debris_{level_or_file}"
    return SuctionDebrisTask(name=name, config=config)
