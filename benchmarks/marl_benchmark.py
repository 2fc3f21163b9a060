"""The multi-agent benchmark table of the collaborative task: libraries x algorithms x start levels x seeds.

One row per run, one command per row (each writes one JSON record; nothing is overwritten):

    python benchmarks/marl_benchmark.py run --library benchmarl --algorithm mappo --level easy --seed 0 --frames 2000000
    python benchmarks/marl_benchmark.py run --library dvrl-marl --algorithm mappo --level default --seed 0 --frames 4000000
    python benchmarks/marl_benchmark.py run --library rllib --algorithm ippo --level easy --seed 0 --frames 983040
    python benchmarks/marl_benchmark.py table            # the table (markdown), its JSON and the plot

Every run uses the same env options, the shipped BenchMARL task files
(``dvrl_marl/integrations/benchmarl_tasks/suction_debris_<level>.yaml``: ``suction_debris_v8``, the guided reward,
the observation features, the start level, a tool with a finite speed, the jaw a switch that holds a pin until the
hand-off). Records are named by scene: the version and any option that changes the scene itself (``SCENE_OPTIONS``:
``tool_speed``, ``jaw_command``, ``hold_until_handoff``), so that runs on different scenes are never pooled in one
cell. ``benchmarl`` runs BenchMARL's own algorithms with the shipped settings, each a YAML
of what it changes in BenchMARL's defaults (``benchmarl_tasks/experiment.yaml``: one policy per arm, 256 worlds, the
PPO settings of the configuration of record; ``mappo.yaml``, ``ippo.yaml``: a critic per arm; ``mlp.yaml``: 64 x 64;
or files of your own, ``--algorithm-file``, ``--model-file``, ``--experiment-file``), only the frame budget and the
evaluation interval set here; a record names its settings (``benchmarl_settings``) and its cell their hash.
``dvrl-marl`` runs this project's trainer with the configuration of record
(``baselines/configs/suction_debris_<algorithm>.toml``; the test figure is its final policies, as BenchMARL's), its
``[env]`` replaced by the same task file (its run folder keeps the ``config.toml`` it ran); at the easy
level its start-level schedule is off (every episode easy), at the default and irrigation levels it keeps it (its
curriculum, ending on the level's task; at the irrigation level its tool's command a Gaussian, not a switch, whose
"shut" would irrigate); BenchMARL's runs at those levels get the same schedule through a callback
(``StartLevelSchedule``, outside the algorithm). ``rllib`` runs RLlib's PPO with a policy and a critic per arm
(IPPO) as ``examples/rllib_suction_debris.py --guided`` does (the PPO settings of BenchMARL's shipped files, its
record's ``rllib_settings``; 2 env runners of 8 envs), on the PettingZoo env with the same options; its start level is
the task file's throughout (no schedule). Validation and test episodes are always at the record's level.

Reported as the MARL evaluation protocol asks (Gorsane et al. 2022): success on 100 held-out test episodes (seeds
``teams.EVAL_SEED`` on, the record's level) per run, with the deterministic policy (the mean action: what a robot
is driven by, and BenchMARL's evaluation) and, beside it, sampling its actions as in training (``_sampled``); per cell the interquartile mean over
seeds with a 95 % stratified-bootstrap interval (``rliable``), and frames and wall clock until the validation
success first reached 0.9 during training. Records: ``baselines/results/benchmark/*.json`` (one per run; the curve,
the final figures, the command, the machine), the aggregate ``table.json`` and ``benchmark.png``. A BenchMARL run whose
policy diverges (NaN actions, which the env refuses by name) is recorded with success 0 and ``final["diverged"]``:
a cell counts every seed it ran.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
import provenance  # noqa: E402

RESULTS = ROOT / "baselines" / "results" / "benchmark"
LIBRARIES = ("benchmarl", "dvrl-marl", "rllib")
#: RLlib's PPO with a policy and a critic per arm, each on its own observation: IPPO.
ALGORITHMS = {"benchmarl": ("mappo", "ippo", "masac"), "dvrl-marl": ("mappo", "ippo"), "rllib": ("ippo",)}
#: RLlib's sampling: env runners and envs per runner (on 2 cores about 880 env steps/s, against 300 for RLlib's
#: default of one env in the driver; examples/rllib_suction_debris.py).
RLLIB_ENV_RUNNERS, RLLIB_ENVS_PER_RUNNER = 2, 8
#: RLlib's validation episodes during training (BenchMARL's: experiment.yaml's evaluation_episodes).
RLLIB_EVAL_EPISODES = 20
LEVELS = ("easy", "default")
#: The levels a run may take: the table's, and the irrigation level (``preset="irrigation"``: its cells join the
#: table's, not its plot).
RUN_LEVELS = (*LEVELS, "irrigation")
TEST_EPISODES = 100
#: The start-level schedule of the default level's runs, both libraries (the configuration of record's
#: ``[curriculum] levels``): BenchMARL through :class:`dvrl_marl.integrations.benchmarl.StartLevelSchedule`.
CURRICULUM = ((0.0, 0.0), (0.3, 0.5), (1.0, 1.0))
TARGET = 0.9


def _task_options(level: str) -> dict:
    import yaml

    return yaml.safe_load((ROOT / "dvrl_marl" / "integrations" / "benchmarl_tasks" /
                           f"suction_debris_{level}.yaml").read_text())


#: Task-file options that change the scene itself (and ``state_observations``, what MAPPO's critic reads): a
#: record's scene is its version with these, and cells of different scenes are never pooled.
SCENE_OPTIONS = ("tool_speed", "jaw_command", "hold_until_handoff", "state_observations", "normalize_observations")


#: Records made on 0.1.0's suction_debris_v7 ran the scene suction_debris_v8 runs: the same rules, step for step
#: (tests/test_golden.py replays v7's trajectories on v8), so their cells are the current ones.
SAME_SCENE = {"suction_debris_v7": "suction_debris_v8"}
#: The docs page of the current cells.
DOCS_PAGE = ROOT / "docs" / "benchmark.md"


def _scene_option(key: str, value) -> str:
    """One scene option in a scene's name: ``tool_speed0.05``, ``jaw_command-switch``, ``hold_until_handoff`` (a
    flag that is on; off, its default, is left out)."""
    if isinstance(value, bool):
        return f"_{key}" if value else ""
    if isinstance(value, str):
        return f"_{key}-{value}"
    return f"_{key}{value:g}"


def _scene_of(options: dict) -> str:
    """The scene a run used: its version, and any scene option (a preset's included), e.g.
    ``suction_debris_v8_tool_speed0.05``."""
    from dvrl_marl.envs.suction_debris import TASK
    from dvrl_marl.suction_debris.presets import with_preset

    options = with_preset(options)
    task = SAME_SCENE.get(options.get("task", TASK), options.get("task", TASK))
    return task + "".join(_scene_option(key, options[key]) for key in SCENE_OPTIONS
                                               if key in options)


def _settings_label(settings: dict | None) -> str:
    """A short name of a BenchMARL run's settings (its overrides of BenchMARL's algorithm, model and experiment
    defaults, :func:`_benchmarl_settings`): ``""`` for none (the records written before they were named), else ``"settings"`` and 6 hex digits of their hash, so that runs of
    different settings are never pooled in one cell nor written over each other."""
    if not settings or not any(settings.values()):
        return ""
    digest = hashlib.sha1(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:6]
    return f"settings{digest}"


def _record_path(results: Path, library: str, algorithm: str, level: str, seed: int, options: dict,
                 settings: dict | None = None) -> Path:
    label = _settings_label(settings)
    return results / f"{library}_{algorithm}_{_scene_of(options)}_{level}{'_' + label if label else ''}_seed{seed}.json"


def _task_of(record: dict) -> str:
    """The scene a record ran on (see :func:`_scene_of`)."""
    return _scene_of(record["env_options"])


def _library_of(record: dict) -> str:
    """The library of a record's cell, with the label of its BenchMARL (or RLlib) settings where it has some."""
    label = _settings_label(record.get("benchmarl_settings") or record.get("rllib_settings"))
    return f"{record['library']} ({label})" if label else record["library"]


def _benchmarl_settings(algorithm: str, algorithm_file: str | None, model_file: str | None,
                        experiment_file: str | None = None) -> dict:
    """What a BenchMARL run changes in BenchMARL's defaults: in its algorithm's and its model's, the shipped files
    (``benchmarl_tasks/<algorithm>.yaml``, ``mlp.yaml``) or the ones given; in its experiment's, the shipped
    ``experiment.yaml`` and then the file given."""
    folder = ROOT / "dvrl_marl" / "integrations" / "benchmarl_tasks"
    for given in (algorithm_file, model_file, experiment_file):
        if given is not None and not Path(given).is_file():
            raise SystemExit(f"{given}: no such settings file")
    from dvrl_marl.integrations.benchmarl import settings_overrides

    return {"algorithm": settings_overrides(algorithm_file or folder / f"{algorithm}.yaml"),
            "model": settings_overrides(model_file or folder / "mlp.yaml"),
            "experiment": {**settings_overrides(folder / "experiment.yaml"),
                           **(settings_overrides(experiment_file) if experiment_file else {})}}


def _machine_of(runs: list[dict]) -> str:
    """The machine(s) a cell's runs took their wall clock on, in words."""
    kinds = sorted({f"{run['machine']['cpus']} cores, Python {run['machine']['python']}" for run in runs})
    return " / ".join(kinds)


def _first_reaching(curve: list[dict], key: str):
    return next((point[key] for point in curve if point["success_rate"] >= TARGET), None)


# --- BenchMARL ----------------------------------------------------------------------------------------------------
def run_benchmarl(algorithm: str, level: str, seed: int, frames: int, worlds: int, eval_every: int, folder: Path,
                  options: dict, batch_frames: int = 0, test_episodes: int = TEST_EPISODES,
                  settings: dict | None = None):
    import torch
    from benchmarl.experiment import Experiment
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    from dvrl_marl.integrations.benchmarl import (StartLevelSchedule, SuccessCurve, algorithm_config,
                                                  experiment_config, first_episode_success, model_config,
                                                  suction_debris_task)
    from dvrl_marl.training import teams

    torch.set_num_threads(1)
    started = time.perf_counter()
    curve = SuccessCurve()
    settings = settings or {}
    config = experiment_config(**settings.get("experiment", {}))  # BenchMARL's defaults, the shipped overrides
    config.max_n_frames = int(frames)
    config.on_policy_n_envs_per_worker = config.off_policy_n_envs_per_worker = int(worlds)
    if batch_frames:
        config.on_policy_collected_frames_per_batch = config.off_policy_collected_frames_per_batch = int(batch_frames)
        config.on_policy_minibatch_size = min(config.on_policy_minibatch_size, int(batch_frames))
    config.evaluation_interval = int(eval_every)
    config.save_folder = str(folder)
    config.checkpoint_at_end = False
    # BenchMARL's defaults with exactly the overrides the record names (read once, in command_run)
    algorithm_settings = algorithm_config(algorithm, shipped=False, **settings.get("algorithm", {}))
    task = suction_debris_task(level, **options)  # the options the record names
    experiment = Experiment(task=task, algorithm_config=algorithm_settings,
                            model_config=model_config(shipped=False, **settings.get("model", {})),
                            critic_model_config=model_config(shipped=False, **settings.get("model", {})),
                            seed=seed, config=config,
                            callbacks=[curve] + ([StartLevelSchedule(CURRICULUM)] if level != "easy" else []))
    try:
        experiment.run()
    except ValueError as error:  # its policy's actions became NaN, which the env refuses by name: it diverged
        if "NaN" not in str(error):
            raise
        # a run that did not learn: recorded as such (success 0), so that a cell counts every seed it ran
        return curve.points, {"episodes": test_episodes, "success_rate": 0.0, "success_rate_sampled": 0.0,
                              "diverged": f"at {int(experiment.total_frames):,} frames: {error}"[:300]}, \
            time.perf_counter() - started, int(experiment.total_frames)
    wall = time.perf_counter() - started
    # the final policy and its env options, for a look at its failures (benchmarks/mean_action_failures.py)
    torch.save(experiment.policy, folder / "policy.pt")
    (folder / "env_options.json").write_text(json.dumps(options, indent=2) + "\n")
    test_env = task.get_env_fun(num_envs=test_episodes, continuous_actions=True, seed=teams.EVAL_SEED,
                                device="cpu")()
    final = {"episodes": test_episodes}
    for key, exploration in (("success_rate", ExplorationType.DETERMINISTIC),
                             ("success_rate_sampled", ExplorationType.RANDOM)):
        test_env.set_seed(teams.EVAL_SEED)
        with torch.no_grad(), set_exploration_type(exploration):
            rollout = test_env.rollout(max_steps=task.max_steps(test_env), policy=experiment.policy,
                                       break_when_any_done=False)
        final[key] = float(np.mean([first_episode_success(r) for r in rollout.unbind(0)]))
    return curve.points, final, wall, int(experiment.total_frames)


# --- this project's trainer ---------------------------------------------------------------------------------------
def run_dvrl_marl(algorithm: str, level: str, seed: int, frames: int, eval_every: int, folder: Path, options: dict,
                  test_episodes: int = TEST_EPISODES, eval_episodes: int | None = None):
    import csv

    from dvrl_marl import policies
    from dvrl_marl.training import mappo, teams

    config = mappo.load_config(ROOT / "baselines" / "configs" / f"suction_debris_{algorithm}.toml")
    config.env = dict(options)
    if level == "easy":
        config.levels = []  # every episode easy (the task file's start level)
    if level == "irrigation":  # the valve has three states: a switch's "shut" (-1) would irrigate
        config.tool_head = "gaussian"
    config.eval_every = config.checkpoint_every = int(eval_every)
    config.evaluate_with_noise = False  # validation as BenchMARL's: the deterministic policy
    if eval_episodes:
        config.eval_episodes = int(eval_episodes)
    finished = folder / "result.json"
    if finished.is_file():  # trained already (its record not written yet): evaluate it
        result = json.loads(finished.read_text())
    else:
        result = mappo.train(config, seed, folder, total_steps=int(frames), progress=False, tensorboard=False,
                             log=lambda *_: None)
    with (folder / "progress.csv").open() as handle:
        curve = [{"frames": int(float(row["steps"])), "wall_seconds": float(row["wall_seconds"]),
                  "success_rate": float(row["success_rate"])} for row in csv.DictReader(handle)]
    wall = curve[-1]["wall_seconds"]  # the training's own clock (the test episodes below are not training)
    # the final policies, as BenchMARL's experiment.policy (the best validation checkpoint stays in policies_best/)
    team = {agent: policies.load(folder / "policies" / f"marl-{agent}") for agent in ("suction", "grasper")}
    # (the exported policies compute their features and normalisation from the plain observation)
    options = {k: v for k, v in config.env.items()
               if k not in ("reward_type", "observation_features", "normalize_observations")}
    final = teams.evaluate_team_batched(team, test_episodes, seed=teams.EVAL_SEED, **options)
    sampled = teams.evaluate_team_batched({agent: policy.with_noise(teams.noise_seed(agent, teams.EVAL_SEED))
                                           for agent, policy in team.items()}, test_episodes, seed=teams.EVAL_SEED,
                                          **options)
    return curve, {"success_rate": float(final["success_rate"]), "episodes": test_episodes,
                   "success_rate_sampled": float(sampled["success_rate"]),
                   "validation_best": float(result.get("success_rate", float("nan")))}, wall, int(frames)


# --- RLlib --------------------------------------------------------------------------------------------------------
def _rllib_recipe():
    """examples/rllib_suction_debris.py: the RLlib recipe a user runs (its PPO settings, its team as seats)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("rllib_suction_debris", ROOT / "examples" / "rllib_suction_debris.py")
    recipe = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(recipe)
    return recipe


def _rllib_settings(ppo: dict) -> dict:
    """What an RLlib run sets (``ppo``: the recipe's ``--guided`` PPO settings; its sampling), JSON-safe (an unclipped
    value loss, ``inf``, as a string)."""
    return {"ppo": {k: (str(v) if isinstance(v, float) and not np.isfinite(v) else v) for k, v in ppo.items()},
            "env_runners": RLLIB_ENV_RUNNERS, "envs_per_runner": RLLIB_ENVS_PER_RUNNER}


def run_rllib(level: str, seed: int, frames: int, eval_every: int, folder: Path, options: dict, ppo: dict,
              test_episodes: int = TEST_EPISODES, eval_episodes: int | None = None):
    """RLlib's PPO, a policy per arm, as examples/rllib_suction_debris.py --guided runs it (``ppo``: the benchmark's PPO
    settings, its ``benchmark_ppo_settings()``), for ``frames`` env steps; validation every ``eval_every`` (the mean action, ``teams.VALIDATION_SEED`` on; its time
    is not training's), the test as every row's."""
    from dvrl_marl.integrations.rllib import init_ray
    from dvrl_marl.training import teams

    recipe = _rllib_recipe()
    init_ray(None)
    algo = recipe.build_config(env_runners=RLLIB_ENV_RUNNERS, envs_per_runner=RLLIB_ENVS_PER_RUNNER, seed=seed,
                               options=dict(options), ppo=ppo).build_algo()
    curve, done, wall, next_eval = [], 0, 0.0, int(eval_every)
    while done < frames:
        start = time.perf_counter()
        done = int(algo.train().get("num_env_steps_sampled_lifetime", 0))
        wall += time.perf_counter() - start
        if done >= next_eval or done >= frames:
            validation = recipe.score_team(algo, shared=False, episodes=eval_episodes or RLLIB_EVAL_EPISODES,
                                          options=options, seed=teams.VALIDATION_SEED)
            curve.append({"frames": done, "wall_seconds": wall, "success_rate": float(validation["success_rate"])})
            print(f"{done:,} frames, {wall / 60:.1f} min: validation {validation['success_rate']:.2f}", flush=True)
            next_eval = (done // int(eval_every) + 1) * int(eval_every)
    algo.save(str((folder / "checkpoint").resolve()))
    final = recipe.score_team(algo, shared=False, episodes=test_episodes, options=options)
    sampled = recipe.score_team(algo, shared=False, episodes=test_episodes, options=options, sampled=True)
    algo.stop()
    return curve, {"success_rate": float(final["success_rate"]), "episodes": test_episodes,
                   "success_rate_sampled": float(sampled["success_rate"]),
                   "validation_best": max(point["success_rate"] for point in curve)}, wall, done


def command_run(args) -> int:
    code = provenance.code_state()  # (as the run starts: what it imports and trains)
    results = Path(args.results)
    options = _task_options(args.level)  # read once: the record says what ran, whatever the file says later
    ppo = _rllib_recipe().benchmark_ppo_settings() if args.library == "rllib" else None  # read once, as the options
    if ppo is not None and args.batch_frames:  # (a smaller batch, named in the record's settings)
        ppo.update(train_batch=int(args.batch_frames), minibatch=min(int(ppo["minibatch"]), int(args.batch_frames)))
    settings = (_benchmarl_settings(args.algorithm, args.algorithm_file, args.model_file, args.experiment_file)
                if args.library == "benchmarl" else _rllib_settings(ppo) if args.library == "rllib"
                else None)  # read once, as the options
    record = _record_path(results, args.library, args.algorithm, args.level, args.seed, options, settings)
    if record.exists():
        print(f"{record} exists: a run is recorded once (delete it to run again)", file=sys.stderr)
        return 2
    if args.algorithm not in ALGORITHMS[args.library]:
        print(f"--algorithm: {args.library} runs {', '.join(ALGORITHMS[args.library])}", file=sys.stderr)
        return 2
    folder = results / "runs" / record.stem
    if folder.exists() and not (args.library == "dvrl-marl" and (folder / "result.json").is_file()):
        print(f"{folder} exists: delete it, or the record of that run", file=sys.stderr)
        return 2
    folder.mkdir(parents=True, exist_ok=True)
    if args.library == "benchmarl":
        curve, final, wall, frames = run_benchmarl(args.algorithm, args.level, args.seed, args.frames, args.worlds,
                                                   args.eval_every, folder, options, args.batch_frames,
                                                   args.test_episodes, settings)
    elif args.library == "rllib":
        curve, final, wall, frames = run_rllib(args.level, args.seed, args.frames, args.eval_every, folder, options,
                                               ppo, args.test_episodes, args.eval_episodes)
    else:
        curve, final, wall, frames = run_dvrl_marl(args.algorithm, args.level, args.seed, args.frames,
                                                   args.eval_every, folder, options, args.test_episodes,
                                                   args.eval_episodes)
    out = {"library": args.library, "algorithm": args.algorithm, "level": args.level, "seed": args.seed,
           "frames": frames, "wall_seconds": wall, "final": final, "curve": curve,
           "frames_to_target": _first_reaching(curve, "frames"), "wall_to_target": _first_reaching(curve, "wall_seconds"),
           "target": TARGET, "env_options": options,
           **({f"{args.library}_settings": settings} if settings is not None else {}),
           "curriculum": [list(point) for point in CURRICULUM] if args.level != "easy" else None,
           "command": "python benchmarks/marl_benchmark.py " + " ".join(sys.argv[1:]),
           "machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
           "code": code}  # (what a rerun must match to give this figure bit for bit)
    record.write_text(json.dumps(out, indent=2) + "\n")
    print(f"{record.name}: test success {final['success_rate']:.2f}, {frames:,} frames, {wall / 60:.1f} min, "
          f"to {TARGET:.0%}: {out['frames_to_target']} frames")
    return 0


# --- the table ----------------------------------------------------------------------------------------------------
def aggregate(records: list[dict], reps: int = 2000) -> list[dict]:
    """Per (library, algorithm, level): IQM of the test success over seeds with a 95 % stratified-bootstrap
    interval (rliable), and the median frames / wall clock to the target over the seeds that reached it."""
    from rliable import library as rly
    from rliable import metrics

    cells = {}
    for record in records:
        cells.setdefault((_task_of(record), _library_of(record), record["algorithm"], record["level"]), []).append(record)
    rows = []
    for (task, library, algorithm, level), runs in sorted(cells.items()):
        def iqm(key):
            # rliable resamples from numpy's global stream: seeded per cell, so a cell's interval is the same
            # whatever other cells the table holds
            np.random.seed(0)
            scores = np.array([[run["final"][key]] for run in runs if key in run["final"]])  # (seeds, 1 task)
            point, interval = rly.get_interval_estimates({"x": scores},
                                                         lambda s: np.array([metrics.aggregate_iqm(s)]), reps=reps)
            return float(point["x"][0]), [float(interval["x"][0][0]), float(interval["x"][1][0])]

        iqm_success, ci95 = iqm("success_rate")
        with_sampled = sum("success_rate_sampled" in run["final"] for run in runs)  # (the first records had none)
        sampled = iqm("success_rate_sampled") if with_sampled else None
        reached = [run for run in runs if run["frames_to_target"] is not None]
        rows.append({"task": task, "library": library, "algorithm": algorithm, "level": level, "seeds": len(runs),
                     "machine": _machine_of(runs),
                     "iqm_success": iqm_success, "ci95": ci95,
                     "iqm_success_sampled": None if sampled is None else sampled[0], "seeds_sampled": with_sampled,
                     "ci95_sampled": None if sampled is None else sampled[1],
                     "seed_success": [run["final"]["success_rate"] for run in runs],
                     "seed_diverged": [bool(run["final"].get("diverged")) for run in runs],
                     "frames": int(np.median([run["frames"] for run in runs])),
                     "wall_minutes": float(np.median([run["wall_seconds"] for run in runs]) / 60),
                     "reached_target": f"{len(reached)}/{len(runs)}",
                     "frames_to_target": (int(np.median([r["frames_to_target"] for r in reached])) if reached
                                          else None),
                     "minutes_to_target": (float(np.median([r["wall_to_target"] for r in reached]) / 60) if reached
                                           else None)})
    return rows


#: The records in marl-eval's JSON form (https://github.com/instadeepai/marl-eval: the form BenchMARL and JaxMARL
#: report in), written by ``table`` beside table.json, one file per level (``marl_eval_<level>.json``), for others to
#: plot with their tools.
MARL_EVAL = "marl_eval_{}.json"


def marl_eval_json(records: list[dict]) -> dict:
    """``{level: {scene: {level: {"<library> <ALGORITHM>": {"seed_N": {"step_i": {"step_count", "success_rate"},
    ..., "absolute_metrics": {...}}}}}}}``, as marl-eval's checks ask (``DiagnoseData``): per scene one task (the
    level), so every algorithm is in every task; the same number of steps in every run, the validations nearest the
    coarsest run's (each with its own frame count); the held-out test by the mean action as the absolute metric (the
    metrics must be the steps' own: the sampled test is table.json's). Each metric is one value (a share of
    episodes)."""
    cells: dict = {}
    for record in records:
        cells.setdefault((record["level"], _task_of(record)), []).append(record)
    out: dict = {}
    for (level, scene), runs in sorted(cells.items()):
        coarsest = min(runs, key=lambda r: len(r["curve"]))["curve"]
        grid = [point["frames"] for point in coarsest]
        for record in sorted(runs, key=lambda r: (_library_of(r), r["algorithm"], r["seed"])):
            points = [min(record["curve"], key=lambda point: abs(point["frames"] - frames)) for frames in grid]
            run = {f"step_{index}": {"step_count": int(point["frames"]), "success_rate": [float(point["success_rate"])]}
                   for index, point in enumerate(points)}
            run["absolute_metrics"] = {"success_rate": [float(record["final"]["success_rate"])]}
            algorithm = f"{_library_of(record)} {record['algorithm'].upper()}"
            out.setdefault(level, {}).setdefault(scene, {}).setdefault(level, {}).setdefault(algorithm, {})[
                f"seed_{record['seed']}"] = run
    return out


def current_scene() -> str:
    """The scene of the benchmark's cells: ``suction_debris_v8`` with ``preset="benchmark"``'s scene options."""
    return _scene_of({"preset": "benchmark"})


#: The docs page's count of the records its table aggregates: the next regeneration may not write a page of fewer.
RECORDS_MARK = "<!-- records aggregated: {} -->"


def records_on_page(page: Path) -> int:
    """How many records the docs page says its table aggregates (0 for a page without the mark, or none)."""
    import re

    found = re.search(RECORDS_MARK.format(r"(\d+)"), page.read_text()) if page.is_file() else None
    return int(found.group(1)) if found else 0


def command_table(args) -> int:
    results = Path(args.results)
    records = [json.loads(path.read_text()) for path in sorted(results.glob("*_seed*.json"))]
    if not records:
        print(f"no records in {results}", file=sys.stderr)
        return 2
    # The docs page is the shipped records' page: written from the shipped folder, or to a page given by name, never
    # from another folder by default (a test's folder of three records once wrote the published page empty).
    docs = (DOCS_PAGE if results.resolve() == RESULTS.resolve() else None) if args.docs is None else (
        Path(args.docs) if args.docs else None)
    scene = current_scene()
    current_records = [record for record in records if _task_of(record) == scene]
    if docs is not None:
        before = records_on_page(docs)
        if not current_records:
            print(f"{results}: no record of the current scene {scene}; {docs} was left as it was", file=sys.stderr)
            return 2
        if len(current_records) < before and not args.allow_fewer:
            print(f"{results}: {len(current_records)} records of the current scene {scene}, where {docs} aggregates "
                  f"{before}; it was left as it was (--allow-fewer writes it with the records found)", file=sys.stderr)
            return 2
    rows = aggregate(records)
    for level, data in marl_eval_json(records).items():
        (results / MARL_EVAL.format(level)).write_text(json.dumps(data, indent=1) + "\n")
    (results / "table.json").write_text(json.dumps({"target": TARGET, "test_episodes": TEST_EPISODES, "rows": rows},
                                                   indent=2) + "\n")
    print("\n".join(_markdown_table(rows)))
    _plot(rows, results / "benchmark.png")
    if docs is not None:
        current = [row for row in rows if row["task"] == scene]
        _plot(current, docs.with_suffix(".png"))
        docs.write_text(_docs_page(current, docs.with_suffix(".png").name, len(current_records)))
    return 0


def _markdown_table(rows: list[dict], with_scene: bool = True) -> list[str]:
    """The cells as a markdown table; ``with_scene=False`` leaves the scene's column out (a page of one scene)."""
    lines = ["| scene | library | algorithm | level | seeds | IQM success, mean action [95 % CI] | per seed | IQM success, "
             "sampled [95 % CI] | frames | minutes | machine | validation reached 0.9 | frames to 0.9 | minutes to 0.9 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in rows:
        low, high = row["ci95"]
        to_frames = f"{row['frames_to_target']:,}" if row["frames_to_target"] is not None else "-"
        to_minutes = f"{row['minutes_to_target']:.0f}" if row["minutes_to_target"] is not None else "-"
        lines.append(
            f"| {row['task']} | {row['library']} | {row['algorithm'].upper()} | {row['level']} | {row['seeds']} | "
            f"{row['iqm_success']:.2f} [{low:.2f}, {high:.2f}] | "
            f"{', '.join(f'{s:.2f}' + (' (diverged)' if d else '') for s, d in zip(row['seed_success'], row['seed_diverged']))} | "
            + (f"{row['iqm_success_sampled']:.2f} [{row['ci95_sampled'][0]:.2f}, {row['ci95_sampled'][1]:.2f}]"
               + (f" (n={row['seeds_sampled']})" if row["seeds_sampled"] != row["seeds"] else "") + " | "
               if row["iqm_success_sampled"] is not None else "- | ") +
            f"{row['frames']:,} | {row['wall_minutes']:.0f} | {row['machine']} | {row['reached_target']} | {to_frames} | "
            f"{to_minutes} |")
    if not with_scene:
        lines = ["|" + line.split("|", 2)[2] for line in lines]
    return lines


def _docs_page(rows: list[dict], plot: str, records: int) -> str:
    """The documentation's benchmark page: the current scene's cells (``preset="benchmark"``), the scene named once
    above them."""
    return "\n".join([
        "# Benchmark", "",
        "Generated by `python benchmarks/marl_benchmark.py table` from the records in `baselines/results/benchmark/`;",
        "do not edit. Both arms learnt from scratch on `suction_debris_v8` with `preset=\"benchmark\"` (the scene's",
        "name below spells the preset's scene options out; records made on 0.1.0's last version with the same",
        "options ran this scene step for step). Success on 100 held-out test episodes per run at the run's level, by",
        "the policies' mean action (what a robot is driven by) and sampled as in training; per cell the interquartile",
        "mean over seeds with a 95 % stratified-bootstrap interval (`rliable`). The irrigation level's rows ran",
        "`preset=\"irrigation\"`: the same scene options on a clotted field, the Suction & Irrigation valve signed",
        "(`dvrl_marl/integrations/benchmarl_tasks/suction_debris_irrigation.yaml`). One row per run:", "",
        "    python benchmarks/marl_benchmark.py run --library dvrl-marl --algorithm mappo --level default --seed N \\",
        "        --frames 4000000 --eval-every 1000000",
        "    python benchmarks/marl_benchmark.py run --library benchmarl --algorithm mappo --level default --seed N \\",
        "        --frames 3932160 --eval-every 491520 [--algorithm-file baselines/configs/benchmarl_mappo_entropy.yaml]",
        "    python benchmarks/marl_benchmark.py run --library benchmarl --algorithm mappo --level irrigation --seed N \\",
        "        --frames 15728640 --eval-every 1966080 [--algorithm-file baselines/configs/benchmarl_mappo_irrigation.yaml]",
        "    python benchmarks/marl_benchmark.py run --library rllib --algorithm ippo --level easy --seed N \\",
        "        --frames 983040 --eval-every 245760", "",
        "Cells of every earlier scene, and how each change was found: [history](history.md).", "",
        f"Scene: `{current_scene()}` ({records} records).", "",
        *_markdown_table(rows, with_scene=False), "",
        RECORDS_MARK.format(records), "",
        f"![IQM test success per library, algorithm and level]({plot})", ""])


def _short_scene(scene: str) -> str:
    """A scene's name for the plot's labels: ``v7 tool0.1 jaw-switch hold state`` (the table keeps the whole name)."""
    short = scene.removeprefix("suction_debris_")
    for option, name in (("_tool_speed", " tool"), ("_jaw_command-", " jaw-"), ("_hold_until_handoff", " hold"),
                         ("_state_observations", " state"), ("_normalize_observations", " normalized")):
        short = short.replace(option, name)
    return short


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    height = 1.2 + 0.55 * max(sum(row["level"] == level for row in rows) for level in LEVELS)
    fig, axes = plt.subplots(1, len(LEVELS), figsize=(5.5 * len(LEVELS), height), sharex=True)
    for axis, level in zip(np.atleast_1d(axes), LEVELS):
        chosen = [row for row in rows if row["level"] == level]
        labels = [f"{row['library']} {row['algorithm'].upper()}\n{_short_scene(row['task'])} (n={row['seeds']})"
                  for row in chosen]
        y = np.arange(len(chosen))
        for offset, key, interval, colour, name in ((0.2, "iqm_success", "ci95", "#4c72b0", "mean action"),
                                                    (-0.2, "iqm_success_sampled", "ci95_sampled", "#dd8452",
                                                     "sampled")):
            present = [i for i, row in enumerate(chosen) if row.get(key) is not None]
            if not present:
                continue
            points = np.array([chosen[i][key] for i in present])
            errors = np.array([[chosen[i][key] - chosen[i][interval][0], chosen[i][interval][1] - chosen[i][key]]
                               for i in present]).T
            axis.barh(y[present] + offset, points, height=0.38, xerr=errors, color=colour, capsize=3, label=name)
        axis.set_yticks(y, labels, fontsize=8)
        axis.set_xlim(0, 1)
        axis.axvline(TARGET, color="grey", linestyle=":")
        axis.set_title(f"{level} level: IQM test success, 95 % CI")
        axis.legend(fontsize=7, loc="lower right")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="one run: writes one JSON record")
    run.add_argument("--library", choices=LIBRARIES, required=True)
    run.add_argument("--algorithm", choices=sorted({a for v in ALGORITHMS.values() for a in v}), required=True)
    run.add_argument("--level", choices=RUN_LEVELS, required=True)
    run.add_argument("--seed", type=int, required=True)
    run.add_argument("--frames", type=int, default=2_000_000, help="env steps of all worlds (default %(default)s)")
    run.add_argument("--worlds", type=int, default=256, help="BenchMARL: worlds per batch (default %(default)s)")
    run.add_argument("--batch-frames", type=int, default=0,
                     help="BenchMARL, RLlib: frames per collected batch (0: the shipped experiment.yaml's)")
    run.add_argument("--eval-every", type=int, default=245_760, help="frames between validations (default %(default)s)")
    run.add_argument("--test-episodes", type=int, default=TEST_EPISODES, help="held-out test episodes (default %(default)s)")
    run.add_argument("--eval-episodes", type=int, default=0,
                     help="dvrl-marl, rllib: validation episodes (0: the configuration's; RLlib's: 20)")
    run.add_argument("--algorithm-file", default=None,
                     help="BenchMARL: a YAML of the algorithm's settings to change (default: the shipped "
                          "benchmarl_tasks/<algorithm>.yaml, where there is one)")
    run.add_argument("--model-file", default=None,
                     help="BenchMARL: a YAML of the MLP's settings to change (default: the shipped benchmarl_tasks/mlp.yaml)")
    run.add_argument("--experiment-file", default=None,
                     help="BenchMARL: a YAML of experiment settings to change beyond the shipped experiment.yaml")
    run.add_argument("--results", default=str(RESULTS))
    table = sub.add_parser("table", help="the table of the records, its JSON and plot")
    table.add_argument("--results", default=str(RESULTS))
    table.add_argument("--docs", default=None, help="also write the current scene's cells to this page (default: "
                       "docs/benchmark.md when --results is the shipped records' folder, else none; '': none)")
    table.add_argument("--allow-fewer", action="store_true",
                       help="write the docs page even from fewer records than it aggregates now")
    args = parser.parse_args(argv)
    if args.command == "run" and (args.frames < 1 or args.worlds < 1 or args.seed < 0 or args.test_episodes < 1
                                  or args.eval_episodes < 0 or args.batch_frames < 0 or args.eval_every < 1):
        parser.error("--frames, --worlds, --test-episodes, --eval-every must be >= 1; --seed, --eval-episodes, "
                     "--batch-frames >= 0")
    return command_run(args) if args.command == "run" else command_table(args)


if __name__ == "__main__":
    sys.exit(main())
