"""A compiled trainer's run: its folder, ``progress.csv`` and the validations of its exported actors beside the learner.

The JAX trainer (:mod:`dvrl_marl.training.jax_mappo`) exports its actors as numpy policies (:func:`export`) every
``eval_every`` steps and scores them on the validation seeds (:func:`score`: what a user loads is what is scored), in a
worker process while the learner steps on (:class:`Validations`); :class:`Progress` writes one row per validation and
says when the run stops. Numpy only: the workers import neither JAX nor torch.
"""

from __future__ import annotations

import csv
import json
import os
import time
from pathlib import Path

from dvrl_marl.envs import suction_debris
from dvrl_marl.envs.suction_debris import env_name
from dvrl_marl.suction_debris.presets import evaluation_options
from dvrl_marl.training import teams
from dvrl_marl.training.mappo_config import MappoConfig, scene_metadata
from dvrl_marl.training.models import write_actor

__all__ = ["export", "score", "Validations", "Progress", "new_run_folder", "copy_policies"]


def export(arrays: dict, config: MappoConfig, folder: Path, seed: int, steps: int, env,
           trainer: str = "jax_mappo") -> dict:
    """Export the actors given as numpy ``arrays`` per agent (:func:`~dvrl_marl.training.jax_mappo.actors`) as numpy
    policies into ``folder`` (one ``marl-<agent>`` folder each), recording ``trainer``; returns their paths."""
    folders = {}
    for agent, actor in arrays.items():
        folders[agent] = folder / f"marl-{agent}"
        write_actor(actor, folders[agent], name=f"marl-{agent}", agent=agent, tool_head=config.tool_head,
                    env_id=env_name(str(config.env.get("task", suction_debris.TASK))),
                    metadata={"training": {"config": config.name, "algorithm": config.algorithm, "seed": seed,
                                           "steps": steps, "trainer": trainer},
                              **scene_metadata(config)},
                    input_scaling=None if env.observation_scaling is None
                    else env.observation_scaling.observation_affine(agent), feature_spec=env.feature_spec)
    return folders


def score(folders: dict, env_options: dict, episodes: int, with_noise: bool) -> dict:
    """The exported policies in ``folders`` scored on the validation seeds, by their mean action or, ``with_noise``,
    acting as they trained (seeded): what a user loads is what is scored. Numpy only (it runs beside the learner)."""
    from dvrl_marl import policies

    seats = {}
    for agent, folder in folders.items():
        seats[agent] = policies.load(folder)
        if with_noise:
            seats[agent] = seats[agent].with_noise(teams.noise_seed(agent, teams.VALIDATION_SEED))
    # the configured scene without its learning options (the exported policies compute their features and scaling)
    return teams.evaluate_team_batched(seats, episodes, seed=teams.VALIDATION_SEED, **evaluation_options(**env_options))


def _worker_start() -> None:
    """A worker's numpy on one BLAS thread (two, beside the learner on a 2-core machine, slow both), and its end with
    its learner's: a learner stopped by a signal leaves no worker behind."""
    import threading

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    threading.Thread(target=watch, daemon=True, name="dvrl-marl parent watch").start()
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(1, user_api="blas")


def _validation_worker_start() -> None:
    """A validation worker's start: :func:`_worker_start`, and the imports :func:`score` needs, done now (while the
    learner compiles and steps) rather than at the first validation (seconds, on a run that learns in a minute)."""
    _worker_start()
    from dvrl_marl import policies  # noqa: F401
    from dvrl_marl.envs import suction_debris_batched  # noqa: F401


class _Scored:
    """A validation scored in this process (``beside=False``): already ready."""

    def __init__(self, value):
        self.value = value

    def ready(self) -> bool:
        return True

    def get(self):
        return self.value


class Validations:
    """Validations beside the learner: each exports the actors at once and scores them in a worker process (another
    core, or the host's CPU while the learner holds the GPU), up to ``workers`` at a time; the learner steps on
    meanwhile. A validation falls due every ``eval_every`` steps and waits while ``workers`` are in flight; results
    come back in the order the validations started. The policies last reported are kept in ``out/policies``. A run
    that stops early (its target met) stops the validations still in flight rather than wait for them."""

    def __init__(self, out: Path, config: MappoConfig, seed: int, beside: bool, workers: int = 1,
                 trainer: str = "jax_mappo"):
        if int(workers) < 1:
            raise ValueError(f"workers must be at least 1, got {workers!r}")
        self.out, self.config, self.seed, self.workers = out, config, seed, int(workers)
        self.trainer = trainer
        self.pending = []  # (steps, wall seconds at export, folder, its result to come), oldest first
        self.pool = None
        if beside:
            import multiprocessing

            # spawn: a fork of a process holding torch's threads (or CUDA) is not safe; the workers start now
            self.pool = multiprocessing.get_context("spawn").Pool(self.workers, initializer=_validation_worker_start)

    def busy(self) -> bool:
        """Whether as many validations as workers are in flight."""
        return len(self.pending) >= self.workers

    def start(self, arrays: dict, steps: int, wall: float, env) -> None:
        """Export the actors given as numpy ``arrays`` per agent (:func:`~dvrl_marl.training.jax_mappo.actors`) and
        score them."""
        folder = self.out / "validating" / str(steps)
        folders = export(arrays, self.config, folder, self.seed, steps, env, self.trainer)
        job = (folders, dict(self.config.env), self.config.eval_episodes, self.config.evaluate_with_noise)
        result = _Scored(score(*job)) if self.pool is None else self.pool.apply_async(score, job)
        self.pending.append((steps, wall, folder, result))

    def results(self, wait: bool = False) -> list:
        """``(steps, wall seconds at export, result)`` of each validation that has reported, in the order they
        started (``wait``: of every one in flight)."""
        import shutil

        reported = []
        while self.pending and (wait or self.pending[0][3].ready()):
            steps, wall, folder, result = self.pending.pop(0)
            result = result.get()
            shutil.rmtree(self.out / "policies", ignore_errors=True)
            folder.rename(self.out / "policies")
            reported.append((steps, wall, result))
        return reported

    def close(self) -> None:
        """Stop the workers: those still scoring are stopped (the run ended without their results)."""
        if self.pool is not None:
            if self.pending:
                self.pool.terminate()
            else:
                self.pool.close()
            self.pool.join()
        import shutil

        shutil.rmtree(self.out / "validating", ignore_errors=True)


class Progress:
    """A run's ``progress.csv``, one row per validation (the steps its policies were exported at, their validation
    success, train success since the last row, env-steps/s up to the export, wall clock from the run's start to the
    result), its log line, and ``result.json`` at the end; :meth:`report` says whether the run stops there."""

    COLUMNS = ("steps", "success_rate", "blood_removed_ml", "contact_steps", "train_success", "env_steps_per_s",
               "wall_seconds")

    def __init__(self, out: Path, config: MappoConfig, seed: int, began: float, *, stop_at=None, max_seconds=None,
                 log=print):
        self.out, self.config, self.seed, self.began = out, config, seed, began
        self.stop_at, self.max_seconds, self.log = stop_at, max_seconds, log
        self.file = out / "progress.csv"
        self.file.write_text(",".join(self.COLUMNS) + "\n")
        self.successes = self.ended = 0
        self.last = {}

    def count(self, successes: int, ended: int) -> None:
        """Training episodes that ended, and how many of them completed the task."""
        self.successes += int(successes)
        self.ended += int(ended)

    def report(self, steps: int, wall: float, result: dict) -> bool:
        self.last = last = {"steps": steps, "success_rate": result["success_rate"],
                            "blood_removed_ml": result["mean_blood_removed_ml"],
                            "contact_steps": result["mean_contact_steps"],
                            "train_success": self.successes / max(self.ended, 1), "env_steps_per_s": steps / wall,
                            "wall_seconds": time.perf_counter() - self.began}
        with self.file.open("a", newline="") as handle:
            csv.writer(handle).writerow([last[column] for column in self.COLUMNS])
        self.log(f"{self.config.name} seed {self.seed} @ {steps:,d} steps: validation {result['success_rate']:.2f}, "
                 f"train {last['train_success']:.2f}, {last['env_steps_per_s']:,.0f} env-steps/s, "
                 f"{last['wall_seconds']:.0f} s")
        self.successes = self.ended = 0
        return (self.stop_at is not None and result["success_rate"] >= self.stop_at) or (
            self.max_seconds is not None and last["wall_seconds"] >= self.max_seconds)

    def finish(self, **extra) -> None:
        (self.out / "result.json").write_text(json.dumps({"config": self.config.name, "seed": self.seed, **extra,
                                                          **self.last}, indent=2) + "\n")


def new_run_folder(out_dir) -> Path:
    """``out_dir``, made; refused when it holds a run already."""
    out = Path(out_dir)
    if (out / "progress.csv").exists():
        raise ValueError(f"{out} holds a run already (progress.csv); another folder starts a new one")
    out.mkdir(parents=True, exist_ok=True)
    return out


def copy_policies(out: Path, export) -> None:
    """``--export``: a multi-agent run's policies (``out/policies``) copied to ``export`` (nothing without one)."""
    if export:
        import shutil

        shutil.copytree(out / "policies", export, dirs_exist_ok=True)
        print(f"exported the policies to {export}")
