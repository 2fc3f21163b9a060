"""The JAX trainer's figures (dvrl_marl.training.jax_mappo): env-steps/s end to end (collection, update, validation)
and the wall clock from process start to a validation success (the mean action, the exported policies), on one
device.

A MAPPO configuration (``--config``; default the record's, ``baselines/configs/suction_debris_mappo.toml``;
``suction_debris_mappo_large_batch.toml`` is its retuning for a large batch on a CPU), any of its settings replaced
by the options given (``--worlds`` beyond the configuration's keeps the curriculum at least 1,000 updates long),
validated by the mean action (the record validates with its exploration noise), stopped at ``--target`` validation
success or after ``--seconds`` (the clock runs from process start, imports and validations included); then the last
policies are tested by their mean action on ``--test-episodes`` held-out seeds. One JSON line per run goes to
``--json`` (the device probe reads it).

    python benchmarks/device_training.py --device cpu --config baselines/configs/suction_debris_mappo_large_batch.toml
    python benchmarks/device_training.py --device cuda --worlds 4096 --validators 4 \
        --config baselines/configs/suction_debris_mappo_large_batch.toml

(Rows with ``"what": "device_trainer"`` in ``benchmarks/results`` were made by the torch device trainer, retired.)
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import replace
from pathlib import Path

STARTED = time.perf_counter()  # (process start, imports included, as the target counts it)

HERE = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--config", type=Path, default=HERE / "baselines" / "configs" / "suction_debris_mappo.toml",
                        help="a MAPPO configuration (default: the record's; suction_debris_mappo_large_batch.toml is "
                             "its retuning for a large batch on a CPU)")
    parser.add_argument("--worlds", type=int, default=None, help="default: the configuration's")
    parser.add_argument("--rollout", type=int, default=None, help="steps per world per update (default: the "
                        "configuration's)")
    parser.add_argument("--eval-every", type=int, default=None, help="env steps between validations (default: the "
                        "configuration's)")
    parser.add_argument("--target", type=float, default=0.9)
    parser.add_argument("--seconds", type=float, default=180.0)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--test-episodes", type=int, default=100, help="held-out test episodes of the last policies")
    parser.add_argument("--epochs", type=int, default=None, help="PPO epochs per rollout (default: the "
                        "configuration's)")
    parser.add_argument("--minibatches", type=int, default=None, help="minibatches per epoch (default: the "
                        "configuration's)")
    parser.add_argument("--learning-rate", type=float, default=None, help="default: the configuration's")
    parser.add_argument("--total-steps", type=int, default=None,
                        help="the run's length, which paces the curriculum (default: the configuration's; with "
                             "--worlds, that or 1,000 batches, whichever is more)")
    parser.add_argument("--validators", type=int, default=1, help="validations scored at once")
    parser.add_argument("--cache", default="", help="the JAX trainer's compilation cache folder (default none: a "
                        "fresh machine's compile is timed; 'auto': the trainer's own default)")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    from dvrl_marl.training import jax_mappo
    from dvrl_marl.training.mappo_config import load_config

    config = load_config(args.config)
    # validated by the mean action (the record's validation acts with its noise)
    config = replace(config, torch_threads=0, evaluate_with_noise=False)
    for field, value in (("num_envs", args.worlds), ("rollout_steps", args.rollout), ("eval_every", args.eval_every),
                         ("epochs", args.epochs), ("minibatches", args.minibatches),
                         ("learning_rate", args.learning_rate)):
        if value is not None:
            config = replace(config, **{field: value})
    batch = config.num_envs * config.rollout_steps
    # a larger batch than the configuration's keeps its curriculum at least 1,000 updates long
    config = replace(config, total_steps=args.total_steps or (max(config.total_steps, 1000 * batch) if args.worlds
                                                              else config.total_steps))
    with tempfile.TemporaryDirectory() as folder:
        before_training = time.perf_counter() - STARTED  # (imports and configuration)
        last = jax_mappo.train(config, args.seed, Path(folder) / "run", device=args.device, stop_at=args.target,
                               max_seconds=args.seconds, validators=args.validators, cache=args.cache or None)
        # the clock stops at the result of the validation that ended the run (not when the validations still in
        # flight have finished: the run waits for them before it returns)
        seconds = before_training + last.get("wall_seconds", time.perf_counter() - STARTED - before_training)
        test = _test(Path(folder) / "run" / "policies", config, args.test_episodes) if args.test_episodes else None
    import jax

    name = jax.devices("gpu")[0].device_kind if args.device.startswith("cuda") else args.device
    row = {"what": "jax_trainer", "config": config.name, "device": name, "worlds": config.num_envs,
           "rollout": config.rollout_steps, "eval_every": config.eval_every, "collector": "compiled",
           "validators": args.validators,
           "cache": args.cache,
           "epochs": config.epochs, "minibatches": config.minibatches, "learning_rate": config.learning_rate,
           "total_steps": config.total_steps,
           "seed": args.seed, "steps": last.get("steps"), "validation_success": last.get("success_rate"),
           "env_steps_per_s": last.get("env_steps_per_s"), "reached_target": (last.get("success_rate") or 0.0)
           >= args.target, "seconds_from_process_start": seconds, "test_success": test,
           "test_episodes": args.test_episodes}
    print(json.dumps(row), flush=True)
    if args.json:
        with open(args.json, "a") as handle:
            handle.write(json.dumps(row) + "\n")


def _test(folder: Path, config, episodes: int) -> float:
    """The exported policies' success by their mean action on the held-out test seeds (``teams.EVAL_SEED``)."""
    from dvrl_marl import policies
    from dvrl_marl.suction_debris.presets import evaluation_options
    from dvrl_marl.training import teams

    seats = {agent: policies.load(folder / f"marl-{agent}") for agent in ("suction", "grasper")}
    return float(teams.evaluate_team_batched(seats, episodes, seed=teams.EVAL_SEED,
                                             **evaluation_options(**config.env))["success_rate"])


if __name__ == "__main__":
    main()
