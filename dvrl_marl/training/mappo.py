"""Multi-agent PPO (MAPPO and IPPO) for the collaborative env, on TorchRL, fed by the batched env.

``dvrl-marl train baselines/configs/suction_debris_mappo.toml`` runs it. The pieces:

- **Data**: :func:`suction_debris_v8.batched_env` with ``num_envs`` worlds, stepped ``rollout_steps`` times per
  iteration (autoreset off: the trainer resets ended worlds itself, at the scheduled start level). Worlds of training
  seed ``s`` are seeded from ``TRAIN_SEED_BASE * (s + 1)``; periodic evaluation (and the choice of the best
  checkpoint) uses the validation seeds ``teams.VALIDATION_SEED`` on, and reported figures the test seeds
  ``teams.EVAL_SEED`` on (``dvrl-marl evaluate-team``): three disjoint ranges.
- **Models**: one actor per agent (no parameter sharing: the two roles see the same layout but do different
  jobs) on its own observation, a Gaussian with a learnt state-independent standard deviation (the env clips to
  the action box; a tanh-squashed Gaussian saturated early and stalled in our runs);
  the critic is centralised on the env's ``state()`` for MAPPO (one value per agent) or one per agent on its own
  observation for IPPO. Running mean/std normalisation of observations and state is part of each network (and
  folded into the exported actor's first layer).
- **Loss**: TorchRL's ``ClipPPOLoss`` and ``GAE`` over the ``("agents", ...)`` keys, rewards scaled by a running
  standard deviation of the discounted return (per agent), a few epochs on large minibatches (Yu et al. 2022).
- **What makes the task learnable** is the env's, not the trainer's: ``[env] reward_type = "guided"``
  (:mod:`dvrl_marl.suction_debris.guidance`, potential-based: success is still the sparse rule), ``[env]
  observation_features`` (relative targets the actors read; the exported numpy policies compute them from the
  plain observation), ``[env] contact_penalty``, and ``[curriculum] levels``: a schedule of the env's start level
  (:mod:`dvrl_marl.suction_debris.start_levels`), the level at which ended worlds restart as the run progresses. Any library
  can use the same options; this trainer only schedules the level.
- **What the measurements of this trainer added** (``[model]`` and ``[ppo]`` options, off by default;
  ``baselines/README.md`` has the figures): ``tool_head = "switch"`` decides the valve / jaw as open or closed (a
  Bernoulli, :func:`dvrl_marl.training.models.switch_gaussian`; ``initial_tool_logit`` leans it at the start);
  ``critic_input = "state_and_observation"`` gives MAPPO's critic each agent's own observation beside the state
  (Yu et al. 2022's agent-specific global state; measured: the state-only critic left MAPPO at 0.5 where this one
  reached 1.00); ``final_std`` replaces the learnt exploration noise by a schedule; ``[ppo] bounds_loss_coef`` keeps
  the actors' means inside the action box (:func:`~dvrl_marl.training.models.bounds_loss`). The keys that held the
  task's shaping and curriculum before are refused, naming where each went (:data:`~dvrl_marl.training.mappo_config.RETIRED`).
- **Demonstrations** (``[pretrain]``, off by default; the partner-seat configurations only, reported apart from
  the runs from scratch): ``bc_expert = "scripted"`` clones the scripted expert of each learning seat into its actor
  before PPO (:mod:`dvrl_marl.training.pretrain`; the clone is evaluated at step 0 and keeps the observation scaling
  it was fitted with), and ``critic_warmup_steps`` lets the critic learn the clone's values before the actor moves.
- **Partners** (``[run] surgeon``): the seat that does not learn is filled by the scripted expert, a learned policy
  or a list of these (:class:`dvrl_marl.training.teams.Partners`: world ``i`` gets partner ``i % K`` in the
  demonstrations, the DAgger rounds, PPO and validation alike; learned partners act with their recorded noise).
  Measured: a grasper cloned beside the scripted suction alone deadlocked beside learned suctions.
- **Device**: ``device = "cuda"`` (or ``"auto"``) runs the update on a GPU; collection stays on CPU (numpy env), the
  collector acting with a CPU copy of the actor that each rollout refreshes.

A run folder holds ``config.toml``, ``progress.csv`` (one row per evaluation), TensorBoard logs (``tb/``),
``checkpoint.pt`` (``--resume`` continues from it: networks, optimiser, normalisers, counters, random streams;
episodes in flight restart), ``policies/<name>`` (the latest numpy-only actors, see :mod:`dvrl_marl.policies`) and
``policies_best/<name>`` (those of the best validation evaluation).
"""

from __future__ import annotations

import csv
import math
import json
import shutil
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from dvrl_marl.envs import suction_debris
from dvrl_marl.envs.suction_debris import TASK, env_name
from dvrl_marl.suction_debris.presets import evaluation_options
from dvrl_marl.training import run_progress, teams, trainers
from dvrl_marl.training.mappo_config import (ALGORITHMS, CRITIC_INPUTS, TABLE_KEYS, TOOL_HEADS, TRAIN_SEED_BASE,
                                             MappoConfig, config_toml, demonstrations, load_config, partner, partners,
                                             scene_metadata)
from dvrl_marl.training.models import (bounds_loss, build_models, export_actor, learner_device,
                                       limit_threads, require_torch, update_norms)
from dvrl_marl.training.teams import evaluate_team_batched

__all__ = ["MappoConfig", "load_config", "train", "export_actor", "load_checkpoint", "TRAIN_SEED_BASE", "ALGORITHMS",
           "TOOL_HEADS", "CRITIC_INPUTS", "TABLE_KEYS"]


def train(config: MappoConfig, seed: int, out_dir, *, total_steps: int | None = None, resume: bool = False,
          progress: bool = True, tensorboard: bool = True, log=print, ray_address: str | None = None,
          num_collectors: int = 0, on_iteration=None) -> dict:
    """Train (or resume) a run; returns the last evaluation row. Exports the actors to ``out_dir/policies``.

    ``ray_address`` / ``num_collectors``: collect experience on Ray actors (:mod:`dvrl_marl.training.collectors`;
    ``ray_address="auto"`` joins the cluster this machine belongs to, ``None`` with ``num_collectors`` starts Ray in
    this process); otherwise here. ``on_iteration(iteration, collectors)`` runs after each update (monitoring,
    tests)."""
    torch = require_torch()
    from tensordict import TensorDict
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from dvrl_marl.training.collectors import make_collectors

    if config.torch_threads:
        limit_threads(int(config.torch_threads))
    device = learner_device(config)
    out = Path(out_dir)
    total = int(total_steps or config.total_steps)
    surgeon = None if config.surgeon == "none" else "scripted"  # (who fills the seat does not change the spaces)
    # The learner's view of the env (spaces, layout for the partner in evaluation): one world.
    env = suction_debris.batched_env(num_envs=1, surgeon=surgeon, surgeon_seat=config.surgeon_seat,
                                        autoreset_mode="disabled", **config.env)
    agents = list(env.possible_agents)
    n, horizon, count = config.num_envs, config.rollout_steps, len(agents)
    obs_dim = env.observation_space(agents[0]).shape[0]
    state_dim = env.state_space.shape[0]
    torch.manual_seed(seed)
    actor, critic, actor_net, norms = build_models(config, agents, obs_dim, state_dim, 4,
                                                   feature_spec=env.feature_spec)

    def easy_share(progress: float) -> float:
        """The share of resets the start level draws easy (1 - level; the progress file's easy_fraction)."""
        level = config.level(progress)
        return 1.0 - (float(env.levels[0]) if level is None else level)

    actor.to(device)
    critic.to(device)
    actor_head = actor.module[0].module  # the GaussianHead (its log_std)
    loss_module = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=config.clip_epsilon,
                              entropy_coeff=config.entropy_coef, critic_coeff=config.value_coef,
                              normalize_advantage=True, normalize_advantage_exclude_dims=(-2,),
                              loss_critic_type="smooth_l1")
    loss_module.set_keys(reward=("agents", "reward"), action=("agents", "action"),
                         sample_log_prob=("agents", "action_log_prob"), value=("agents", "state_value"),
                         done=("agents", "done"), terminated=("agents", "terminated"))
    loss_module.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.gae_lambda)
    optimiser = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate)
    # running variance of the discounted return, per agent: rewards are divided by its square root (reward scaling)
    return_var_state = {"mean": np.zeros(count), "var": np.ones(count), "count": 1e-4}
    steps_done, iteration, rng_states, seconds_before = 0, 0, None, 0.0
    checkpoint = out / "checkpoint.pt"
    if resume:
        saved = load_checkpoint(checkpoint, device)
        try:
            loss_module.load_state_dict(saved["loss_module"])
            optimiser.load_state_dict(saved["optimiser"])
        except (KeyError, RuntimeError, ValueError) as error:  # another configuration's networks, or a damaged file
            raise ValueError(f"{checkpoint}: its networks do not fit this configuration ({error}); resume it with "
                             "the configuration it was trained with") from None
        return_var_state = {key: np.asarray(value, dtype=np.float64) if key != "count" else float(value)
                            for key, value in saved["return_var"].items()}
        steps_done, iteration = saved["steps"], saved["iteration"]
        rng_states = saved.get("collector_rng") or [saved["rng"]]  # (checkpoints before collectors kept one stream)
        torch.set_rng_state(saved["torch_rng"].cpu())
        seconds_before = float(saved.get("wall_seconds", 0.0))  # the run's cost counts every session it took
        if steps_done >= total:  # nothing to do: the records stay as they are
            log(f"{out}: the run is finished ({steps_done:,d} steps done, {total:,d} asked); nothing was changed. "
                "Pass a larger --steps to extend it.")
            env.close()
            return _finished_result(out, steps_done)
        log(f"resumed {out} at {steps_done} steps")
    elif (out / "checkpoint.pt").exists() or (out / "progress.csv").exists():
        env.close()
        raise ValueError(f"{out} holds a run already (checkpoint.pt / progress.csv): --resume continues it; another "
                         "--out starts a new one. Nothing was overwritten.")
    out.mkdir(parents=True, exist_ok=True)  # (only now: a refused resume leaves no folder behind)
    (out / "config.toml").write_text(config_toml(config))
    writer = None
    if tensorboard:
        try:
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(out / "tb"))
        except ImportError:
            log("tensorboard is not installed: no TensorBoard logs")
    collectors = make_collectors(config, seed, actor=actor if device.type == "cpu" else None, steps_done=steps_done,
                                 progress=steps_done / total,
                                 rng_states=rng_states,
                                 ray_address=ray_address, num_collectors=num_collectors)
    if collectors.count > 1 or ray_address is not None or num_collectors:
        spread = collectors.where()
        log(f"collecting on Ray: {len(spread)} collectors on {len({w['node_id'] for w in spread})} node(s), "
            f"{'/'.join(str(w['worlds']) for w in spread)} worlds")
    progress_file = out / "progress.csv"
    if not (resume and progress_file.is_file()):
        progress_file.write_text("steps,success_rate,blood_removed_ml,median_steps,contact_steps,easy_fraction,"
                                 "episode_success,wall_seconds\n")
    start = time.perf_counter() - seconds_before
    next_eval = (steps_done // config.eval_every + 1) * config.eval_every
    next_checkpoint = (steps_done // config.checkpoint_every + 1) * config.checkpoint_every
    episodes_ended = successes = 0
    delivered_sum = blood_left_sum = 0.0
    best = (-1.0, -math.inf, -1.0)  # the best validation's rank (see _rank)
    if resume and (out / "best.json").is_file():
        recorded = json.loads((out / "best.json").read_text())
        best = tuple(recorded) if len(recorded) == 3 else (recorded[0], -math.inf, recorded[1])  # (older runs)
    last = {}

    def evaluate(steps: int, easy: float, episode_success: float) -> dict:
        """Validation of the current actors (with the scripted partner, if any): a progress row, the best
        checkpoint's policies, TensorBoard and the log."""
        nonlocal best
        seats = _learned_seats(actor_net, agents, out, config, seed, steps, actor_head.log_std,
                               env.observation_scaling)
        if surgeon is not None:
            seats[config.surgeon_seat] = partner(config, env, noise_from=teams.VALIDATION_SEED)
        result = evaluate_team_batched(seats, config.eval_episodes, seed=teams.VALIDATION_SEED,
                                       **_eval_kwargs(config))
        if _rank(result) > best:
            best = _rank(result)
            shutil.copytree(out / "policies", out / "policies_best", dirs_exist_ok=True)
            (out / "best.json").write_text(json.dumps(list(best)))
        row = {"steps": steps, "success_rate": result["success_rate"],
               "blood_removed_ml": result["mean_blood_removed_ml"],
               "median_steps": result["median_steps_to_completion"], "contact_steps": result["mean_contact_steps"],
               "easy_fraction": easy, "episode_success": episode_success, "wall_seconds": time.perf_counter() - start}
        with progress_file.open("a", newline="") as handle:
            csv.writer(handle).writerow([row[k] for k in ("steps", "success_rate", "blood_removed_ml", "median_steps",
                                                          "contact_steps", "easy_fraction", "episode_success",
                                                          "wall_seconds")])
        if writer is not None:
            writer.add_scalar("eval/success_rate", result["success_rate"], steps)
            writer.add_scalar("eval/blood_removed_ml", result["mean_blood_removed_ml"], steps)
            writer.add_scalar("eval/contact_steps", result["mean_contact_steps"], steps)
        log(f"{config.name} seed {seed} @ {steps:,d} steps: success {result['success_rate']:.2f}, "
            f"blood removed {result['mean_blood_removed_ml']:.1f} ml, "
            f"debris delivered {result['mean_debris_delivered']:.2f}, "
            f"contacts {result['mean_contact_steps']:.1f}, {time.perf_counter() - start:.0f} s")
        return row

    if config.bc_expert and steps_done == 0:  # demonstrations first (dvrl_marl.training.pretrain)
        from dvrl_marl.training import pretrain

        began = time.perf_counter()
        summary = pretrain.clone_experts(config, seed, actor_net, agents)
        summary["wall_seconds"] = time.perf_counter() - began
        (out / "pretrain.json").write_text(json.dumps(summary, indent=2) + "\n")
        fitted = ", ".join(f"{agent}: {value['transitions']:,d} transitions, loss {value['final_loss']:.4f}"
                           for agent, value in summary["agents"].items())
        log(f"{config.name} seed {seed}: cloned the {config.bc_expert} expert ({fitted}) in "
            f"{summary['wall_seconds']:.0f} s")
        last = evaluate(0, easy_share(0.0), 0.0)  # what the clone does before PPO
    elif config.init_policy and steps_done == 0:  # fine-tuning a policy already trained
        from dvrl_marl.training import pretrain

        summary = pretrain.start_from_policies(config, actor_net, agents, env.feature_spec)
        (out / "pretrain.json").write_text(json.dumps(summary, indent=2) + "\n")
        log(f"{config.name} seed {seed}: actors start from {summary['started_from']}")
        last = evaluate(0, easy_share(0.0), 0.0)  # what the policy does before PPO
    # Where the time goes (benchmarks/ray_scaling.py reads it from result.json): collecting vs. updating.
    timing = {"collect_seconds": 0.0, "learn_seconds": 0.0, "steps": 0, "collectors": collectors.count}
    try:
        while steps_done < total:
            easy = easy_share(steps_done / total)
            if config.final_std:  # the scheduled exploration noise (the same in collection and in the update)
                with torch.no_grad():
                    actor_head.log_std.fill_(math.log(config.exploration_std(steps_done / total)))
            # --- collect ---
            began = time.perf_counter()
            # (a CPU copy when the learner is elsewhere)
            batch = collectors.collect(actor.state_dict(), steps_done / total)
            timing["collect_seconds"] += time.perf_counter() - began
            began = time.perf_counter()
            for discounted in batch["discounted_return"]:  # step by step, as the returns grew
                _update_running(return_var_state, discounted)
            episodes_ended += batch["stats"]["episodes_ended"]
            successes += batch["stats"]["successes"]
            delivered_sum += batch["stats"]["debris_delivered"]
            blood_left_sum += batch["stats"]["blood_left_ml"]
            obs_buf, next_obs_buf = batch["observation"], batch["next_observation"]
            state_buf, next_state_buf = batch["state"], batch["next_state"]
            action_buf, logp_buf, reward_buf = batch["action"], batch["log_prob"], batch["reward"]
            done_buf, term_buf = batch["done"], batch["terminated"]
            steps_done += n * horizon
            iteration += 1
            # --- learn ---
            if config.anneal_lr:
                for group in optimiser.param_groups:
                    group["lr"] = config.learning_rate_at((steps_done - n * horizon) / total)
            scale = np.sqrt(return_var_state["var"] + 1e-8).astype(np.float32)

            def swap(x):  # (T, N, ...) -> (N, T, ...)
                return torch.from_numpy(np.ascontiguousarray(np.swapaxes(x, 0, 1))).to(device)

            done_t = swap(done_buf)[..., None, None].expand(n, horizon, count, 1)
            term_t = swap(term_buf)[..., None, None].expand(n, horizon, count, 1)
            data = TensorDict({
                "agents": TensorDict({"observation": swap(obs_buf), "action": swap(action_buf),
                                      "action_log_prob": swap(logp_buf)}, batch_size=[n, horizon, count]),
                "state": swap(state_buf),
                "next": TensorDict({
                    "agents": TensorDict({"observation": swap(next_obs_buf),
                                          "reward": swap(reward_buf / scale)[..., None],
                                          "done": done_t.clone(), "terminated": term_t.clone()},
                                         batch_size=[n, horizon, count]),
                    "state": swap(next_state_buf)}, batch_size=[n, horizon]),
            }, batch_size=[n, horizon])
            with torch.no_grad():
                loss_module.value_estimator(data, params=loss_module.critic_network_params,
                                            target_params=loss_module.target_critic_network_params)
            flat = data.reshape(-1)
            size = flat.shape[0] // config.minibatches
            sums = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0, "clip_fraction": 0.0,
                    "kl_approx": 0.0, "explained_variance": 0.0, "entropy": 0.0}
            for _ in range(config.epochs):
                order = torch.randperm(flat.shape[0])
                for m in range(config.minibatches):
                    batch = flat[order[m * size:(m + 1) * size]]
                    losses = loss_module(batch)
                    total_loss = losses["loss_objective"] + losses["loss_critic"] + losses.get("loss_entropy", 0.0)
                    if config.bounds_loss_coef > 0.0:
                        bounds = config.bounds_loss_coef * bounds_loss(actor_net(batch["agents", "observation"]),
                                                                       config.tool_head)
                        total_loss = total_loss + bounds
                        sums["loss_bounds"] = sums.get("loss_bounds", 0.0) + float(bounds.detach())
                    if steps_done <= config.critic_warmup_steps:  # the actor frozen while the critic learns
                        total_loss = losses["loss_critic"]
                    optimiser.zero_grad()
                    total_loss.backward()
                    torch.nn.utils.clip_grad_norm_(loss_module.parameters(), config.max_grad_norm)
                    optimiser.step()
                    for key in sums:
                        if key in losses.keys():
                            sums[key] += float(losses[key].detach().float().mean())
            # Normalisers move after the update, so the update sees the statistics the rollout was collected with.
            observed = torch.from_numpy(obs_buf).to(device)
            # A clone keeps the input scaling it was fitted with (refitting it to the rollouts took one from 0.88
            # success to 0.00 while its weights were frozen).
            update_norms(norms, observed, torch.from_numpy(state_buf).to(device),
                         observation=not (config.bc_expert or config.init_policy))
            if writer is not None:
                updates = config.epochs * config.minibatches
                for key, value in sums.items():
                    writer.add_scalar(f"train/{key}", value / updates, steps_done)
                writer.add_scalar("train/reward_mean", float(reward_buf.mean()), steps_done)
                writer.add_scalar("train/easy_fraction", easy, steps_done)
                for i, agent in enumerate(agents):
                    writer.add_scalar(f"train/reward_{agent}", float(reward_buf[..., i].mean()), steps_done)
                if episodes_ended:
                    writer.add_scalar("train/episode_success", successes / episodes_ended, steps_done)
                    writer.add_scalar("train/debris_delivered", delivered_sum / episodes_ended, steps_done)
                    writer.add_scalar("train/blood_left_ml", blood_left_sum / episodes_ended, steps_done)
            if progress:
                rate = (steps_done) / max(time.perf_counter() - start, 1e-9)
                print(f"\r{config.name} seed {seed}: {steps_done:>11,d}/{total:,d} steps "
                      f"({100 * steps_done / total:5.1f} %), {rate:,.0f} steps/s, easy {easy:.2f}, "
                      f"train success {successes / max(episodes_ended, 1):.2f}", end="", file=sys.stderr, flush=True)
            timing["learn_seconds"] += time.perf_counter() - began
            timing["steps"] += n * horizon
            final = steps_done >= total
            if steps_done >= next_eval or final:
                next_eval += config.eval_every
                if progress:
                    print(file=sys.stderr)
                last = evaluate(steps_done, easy, successes / max(episodes_ended, 1))
                episodes_ended = successes = 0
                delivered_sum = blood_left_sum = 0.0
            if steps_done >= next_checkpoint or final:
                next_checkpoint += config.checkpoint_every
                tmp = checkpoint.with_suffix(".tmp")
                # Plain values and tensors only: the file loads with torch.load(weights_only=True), which runs no
                # code from it.
                return_var = {"mean": return_var_state["mean"].tolist(), "var": return_var_state["var"].tolist(),
                              "count": float(return_var_state["count"])}
                torch.save({"loss_module": loss_module.state_dict(), "optimiser": optimiser.state_dict(),
                            "return_var": return_var, "steps": steps_done, "iteration": iteration,
                            "collector_rng": collectors.rng_states(), "torch_rng": torch.get_rng_state(),
                            "wall_seconds": time.perf_counter() - start, "config": asdict(config)}, tmp)
                tmp.replace(checkpoint)  # atomic: an interruption never leaves a half-written checkpoint
            if on_iteration is not None:
                on_iteration(iteration, collectors)
    finally:
        collectors.close()
    if writer is not None:
        writer.close()
    env.close()
    (out / "result.json").write_text(json.dumps({"config": config.name, "seed": seed, **last, "timing": timing},
                                                indent=2) + "\n")
    return last



def _rank(result: dict) -> tuple:
    """How validations compare: success first; at equal success fewer instrument-contact steps (a seat that waits
    beats one that pushes), then more blood removed."""
    return (result["success_rate"], -result["mean_contact_steps"], result["mean_blood_removed_ml"])


def _finished_result(out: Path, steps_done: int) -> dict:
    """The last evaluation of a finished run, from its records (result.json, else progress.csv's last row)."""
    result = out / "result.json"
    if result.is_file():
        return json.loads(result.read_text())
    progress = out / "progress.csv"
    rows = list(csv.DictReader(progress.open())) if progress.is_file() else []
    last = {key: float(value) for key, value in rows[-1].items()} if rows else {"success_rate": float("nan")}
    return {**last, "steps": steps_done}



def load_checkpoint(path, device="cpu") -> dict:
    """A run's ``checkpoint.pt``, read with ``torch.load(weights_only=True)``: tensors and plain values only, so a
    crafted file cannot run code (the earliest checkpoints' numpy arrays are allowed by name, nothing else). A
    missing, damaged or foreign file is a ``ValueError`` naming it."""
    torch = require_torch()
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no checkpoint to resume from (a mistyped --out, or a run that never reached its "
                         "first checkpoint); nothing was started or overwritten")
    numpy_arrays = [np.ndarray, np.dtype, getattr(np, "_core", getattr(np, "core", None)).multiarray._reconstruct]
    numpy_arrays += [getattr(np.dtypes, name) for name in ("Float64DType", "Float32DType", "Int64DType", "BoolDType")
                     if hasattr(np, "dtypes")]
    try:
        with torch.serialization.safe_globals(numpy_arrays):
            saved = torch.load(path, weights_only=True, map_location=device)
    except Exception as error:  # noqa: BLE001  (UnpicklingError, RuntimeError, EOFError...: all say "not readable")
        reason = str(error).strip().splitlines()[-1] if str(error).strip() else type(error).__name__
        raise ValueError(f"{path}: not a checkpoint this trainer can read ({type(error).__name__}: "
                         f"{reason[:300]}); it is loaded as weights only, so a file that would run code is refused")
    missing = [key for key in ("loss_module", "optimiser", "return_var", "steps", "iteration", "torch_rng")
               if not isinstance(saved, dict) or key not in saved]
    if missing:
        raise ValueError(f"{path}: not a dvrl-marl MAPPO checkpoint (missing {missing})")
    return saved



def _update_running(stats: dict, x: np.ndarray) -> None:
    batch_mean, batch_var, count = x.mean(axis=0), x.var(axis=0), x.shape[0]
    delta, total = batch_mean - stats["mean"], stats["count"] + count
    stats["mean"] = stats["mean"] + delta * count / total
    stats["var"] = (stats["var"] * stats["count"] + batch_var * count + delta**2 * stats["count"] * count / total) / total
    stats["count"] = total



def _eval_kwargs(config: MappoConfig) -> dict:
    """The scene validation runs: the configured one without its learning options (the exported policies compute
    their observation features and normalisation from the plain observation), at the configured start level (a
    fixed ``start_level`` is the task being learnt; the ``[curriculum]`` schedule is not)."""
    return evaluation_options(**config.env)



def _learned_seats(actor_net, agents, out: Path, config: MappoConfig, seed: int, steps: int, log_std=None,
                   scaling=None) -> dict:
    """Export the current actors and load them back as numpy policies (what users get is what is evaluated);
    with ``evaluate_with_noise`` they act with their exploration noise (seeded), as ``evaluate-team --noise``."""
    from dvrl_marl import policies

    seats = {}
    for index, agent in enumerate(agents):
        folder = out / "policies" / f"marl-{agent}"
        export_actor(actor_net, index, folder, name=f"marl-{agent}", agent=agent, tool_head=config.tool_head,
                     env_id=env_name(str(config.env.get("task", TASK))),
                     metadata={"training": {"config": config.name, "algorithm": config.algorithm, "seed": seed,
                                            "steps": steps, "partners": partners(config),
                                            **demonstrations(config)}, **scene_metadata(config)},
                     log_std=None if log_std is None else log_std[index],
                     input_scaling=None if scaling is None else scaling.observation_affine(agent))
        seats[agent] = policies.load(folder)
        if config.evaluate_with_noise:
            seats[agent] = seats[agent].with_noise(teams.noise_seed(agent, teams.VALIDATION_SEED))
    return seats


def train_from_request(request: trainers.TrainRequest, run_table: dict) -> int:
    """``dvrl-marl train`` with this trainer: ``--steps``, ``--resume``, ``--ray-address``, ``--num-collectors``,
    ``--export`` (TensorBoard logs are always written, ``--tensorboard`` or not)."""
    config = load_config(request.config)
    out = request.out_folder(config.name)
    final = train(config, request.seed, out, total_steps=request.steps, resume=request.resume,
                  progress=request.progress, ray_address=request.ray_address,
                  num_collectors=request.num_collectors or 0)
    print(f"{config.name} seed {request.seed}: success {final['success_rate']:.2f} after {final['steps']:,d} steps; "
          f"policies in {out / 'policies'}; run folder {out}")
    run_progress.copy_policies(out, request.export)
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="torchrl", algorithms=ALGORITHMS, run=train_from_request, rank=1,
    takes=frozenset({"steps", "export", "resume", "tensorboard", "ray_address", "num_collectors"}),
    needs=("torch", "torchrl"), install='pip install "dvrl-marl[torchrl]"',
    summary="MAPPO/IPPO on TorchRL: checkpoints (--resume), Ray collectors, partners in a seat, pretraining"))
