"""MAPPO / IPPO with everything on one device: the worlds, the policy, the rollout and the update.

The batched env runs where the learner runs (``batched_env(device=...)``: the step compiled by JAX, torch tensors in
and out; on a CPU, ``backend="numpy"`` keeps numpy's env, which is faster there), so a rollout of ``num_envs`` x
``rollout_steps`` steps never leaves the device until validation. It reads the configurations of the trainer of record
(:class:`~dvrl_marl.training.mappo_config.MappoConfig`, ``baselines/configs/*.toml``): the same models, the same
exported numpy policies, the same validation (the exported actors by their mean action, ``teams.VALIDATION_SEED``).
Read top to bottom: :func:`step_worlds` steps the worlds and :func:`value_rollout` values the steps (together
:func:`collect`; :class:`_ProcessCollector` steps them in a worker process instead), :func:`advantages` is GAE,
:func:`update` is PPO's clipped objective, :func:`export` and :func:`score` validate the actors (beside the learner,
in a worker process: :class:`Validations`), :func:`train` ties them together.

    python -m dvrl_marl.training.device_mappo baselines/configs/suction_debris_mappo.toml --device cuda --out runs/x

What it leaves out of the trainer of record (``dvrl_marl.training.mappo``), refused by name: partners in a seat,
pretraining from demonstrations and the critic's warm-up; it keeps no checkpoints (no resuming) and uses no Ray
collectors (a CPU's second core steps the worlds with ``collector="process"``).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dvrl_marl.envs import suction_debris
from dvrl_marl.envs.presets import scene_options
from dvrl_marl.envs.suction_debris import env_name
from dvrl_marl.training import teams
from dvrl_marl.training.mappo_config import MappoConfig, load_config
from dvrl_marl.training.models import (actor_arrays, bounds_loss, build_models, limit_threads, require_torch,
                                       switch_gaussian, update_norms, write_actor)

__all__ = ["train", "collect", "step_worlds", "value_rollout", "advantages", "update", "export", "score", "validate",
           "Rollout", "Steps"]

#: What this trainer does not do (the trainer of record does): the option, and the value that turns it off.
_NOT_HERE = {"surgeon": "none", "bc_expert": "", "init_policy": {}, "critic_warmup_steps": 0}


@dataclass
class Rollout:
    """``rollout_steps`` x ``num_envs`` transitions on the device: observations (T, N, A, d), states (T, N, S),
    actions (T, N, A, 4), their log-probabilities and values (T, N, A), rewards (T, N, A), and per world whether the
    step ended the episode (``done``) and by termination (``terminated``) (T, N); ``next_values`` (T, N, A): the value
    after each step (of the state the step ended on, also when the world was reset within it)."""

    observations: object
    states: object
    actions: object
    log_probs: object
    values: object
    rewards: object
    done: object
    terminated: object
    next_values: object


class _TorchView:
    """The numpy batched env with torch tensors in and out (a CPU learner's view of it; the device env is one)."""

    def __init__(self, env, torch):
        self.env, self.torch = env, torch
        self.possible_agents = env.possible_agents

    def _out(self, value):
        if isinstance(value, dict):
            return {key: self._out(item) for key, item in value.items()}
        return self.torch.from_numpy(np.asarray(value))

    def reset(self, seed=None):
        observations, infos = self.env.reset(seed=seed)
        return self._out(observations), infos

    def step(self, actions):
        observations, rewards, terminated, truncated, infos = self.env.step(
            {agent: value.cpu().numpy().astype(np.float64) for agent, value in actions.items()})
        agents = self.possible_agents
        info = infos[agents[0]]
        kept = {"is_success": self._out(info["is_success"])}
        if "final_state" in info:  # (worlds ended and were reset in this step: each agent's final observation)
            kept["final_state"] = self._out(info["final_state"])
            kept["final_observation"] = {agent: self._out(infos[agent]["final_observation"]) for agent in agents}
        return (self._out(observations), self._out(rewards), self._out(terminated), self._out(truncated),
                {agent: kept for agent in agents})

    def state(self):
        return self._out(self.env.state())

    def set_start_level(self, level):
        self.env.set_start_level(level)


def _stack(values: dict, agents, torch):
    return torch.stack([values[agent] for agent in agents], dim=1)


@dataclass
class Steps:
    """What stepping the worlds gives, before any value is computed: ``observations`` (T + 1, N, A, d) and ``states``
    (T + 1, N, S), each step's and, last, those after the last step; ``actions`` (T, N, A, 4), their ``log_probs`` and
    the ``rewards`` (T, N, A); per world ``done`` and ``terminated`` (T, N); the final observations (E, A, d) and
    states (E, S) of the E episodes that ended, at ``ended_at`` (E, 2: step, world); ``successes`` among them."""

    observations: object
    states: object
    actions: object
    log_probs: object
    rewards: object
    done: object
    terminated: object
    final_observations: object
    final_states: object
    ended_at: object
    successes: int


def step_worlds(env, head, distribution, agents, observations, state, steps: int, torch, device) -> Steps:
    """Step every world ``steps`` times with the actors' samples (no critic: :func:`value_rollout` values them)."""
    keys = ("observations", "states", "actions", "log_probs", "rewards", "done", "terminated")
    buffers = {key: [] for key in keys}
    finals, final_states, ended_at = [], [], []
    successes = torch.zeros((), dtype=torch.long, device=device)  # (summed on the device: no wait for it a step)
    for t in range(steps):
        with torch.no_grad():
            loc, scale = head(observations)
            policy = distribution(loc, scale)
            action = policy.sample()
        next_observations, rewards, terminated, truncated, infos = env.step(
            {agent: action[:, index] for index, agent in enumerate(agents)})
        agent = agents[0]
        infos = infos[agent]
        done = (terminated[agent] | truncated[agent]).to(device)
        rows = done.nonzero().squeeze(-1)  # (a step's one wait for a device: which worlds ended)
        if len(rows):  # the state each ended world's step ended on (a reset world's final state, not its new one)
            finals.append(_stack(infos["final_observation"], agents, torch).to(device, torch.float32)[rows])
            final_states.append(infos["final_state"].to(device, torch.float32)[rows])
            ended_at.append(torch.stack([torch.full_like(rows, t), rows], dim=1))
            successes += (infos["is_success"].to(device) & done).sum()
        for key, item in (("observations", observations), ("states", state), ("actions", action),
                          ("log_probs", policy.log_prob(action)),
                          ("rewards", _stack(rewards, agents, torch).to(device, torch.float32)), ("done", done),
                          ("terminated", terminated[agent].to(device))):
            buffers[key].append(item)
        observations = _stack(next_observations, agents, torch).to(device, torch.float32)
        state = env.state().to(device, torch.float32)
    buffers["observations"].append(observations)
    buffers["states"].append(state)
    stacked = {key: torch.stack(items) for key, items in buffers.items()}
    if finals:
        ending = (torch.cat(finals), torch.cat(final_states), torch.cat(ended_at))
    else:
        ending = (stacked["observations"][:0, 0], stacked["states"][:0, 0],
                  torch.zeros((0, 2), dtype=torch.long, device=device))
    return Steps(**stacked, final_observations=ending[0], final_states=ending[1], ended_at=ending[2],
                 successes=int(successes))


def value_rollout(steps: Steps, critic, torch) -> Rollout:
    """The critic's values of every step in one call, and after each step: the next step's value, or the final
    state's for a world that ended there."""
    with torch.no_grad():
        values = critic(steps.states, steps.observations)  # (T + 1, N, A)
        next_values = values[1:].clone()
        if len(steps.ended_at):
            ended = steps.ended_at.to(values.device)
            next_values[ended[:, 0], ended[:, 1]] = critic(steps.final_states, steps.final_observations)
    return Rollout(observations=steps.observations[:-1], states=steps.states[:-1], actions=steps.actions,
                   log_probs=steps.log_probs, values=values[:-1], rewards=steps.rewards, done=steps.done,
                   terminated=steps.terminated, next_values=next_values)


def collect(env, models, observations, state, steps: int, torch, device):
    """Step every world ``steps`` times with the actors' samples and value the steps. Returns the :class:`Rollout`,
    the last observations and state, and the episodes that ended: ``(successes, ended)``."""
    taken = step_worlds(env, models["head"], models["distribution"], models["agents"], observations, state, steps,
                        torch, device)
    return (value_rollout(taken, models["critic"], torch), taken.observations[-1], taken.states[-1],
            (taken.successes, len(taken.ended_at)))


class _ProcessCollector:
    """The worlds stepped in a worker process while the learner updates (on a CPU: the env on one core, the update on
    another). The worker holds the numpy env and a copy of the actors; each :meth:`submit` sends the actors' weights
    (and the start level) and asks for the next ``rollout_steps``, which :meth:`result` returns as :class:`Steps`. The
    learner submits the next rollout before it updates on the last, so each rollout is collected by the actors of
    one update before (PPO's ratio is taken against the log-probabilities the worker recorded)."""

    def __init__(self, config: MappoConfig, seed: int):
        import multiprocessing

        context = multiprocessing.get_context("spawn")  # (a fork of a process holding torch's threads is not safe)
        self.connection, theirs = context.Pipe()
        self.process = context.Process(target=_collector_main, args=(theirs, config, seed), daemon=True,
                                       name="dvrl-marl collector")
        self.process.start()
        theirs.close()

    def submit(self, head, level) -> None:
        self.connection.send(({key: value.detach().cpu().clone() for key, value in head.state_dict().items()}, level))

    def result(self) -> Steps:
        try:
            return self.connection.recv()
        except (EOFError, ConnectionResetError):
            raise RuntimeError(f"the collector process ended (exit code {self.process.exitcode}); its error is "
                               "printed above") from None

    def close(self) -> None:
        try:
            self.connection.send(None)
        except (BrokenPipeError, OSError):
            pass
        self.process.join(timeout=10)
        if self.process.is_alive():
            self.process.terminate()


def _received(connection):
    try:
        return connection.recv()
    except EOFError:  # (the learner is gone)
        return None


def _collector_main(connection, config: MappoConfig, seed: int) -> None:
    _worker_start()
    torch = require_torch()
    limit_threads(1)
    torch.manual_seed(seed)
    host = suction_debris.batched_env(num_envs=config.num_envs, **dict(config.env))
    env = _TorchView(host, torch)
    models = build_learner(config, host, torch.device("cpu"), torch)
    observations, _ = env.reset(seed=seed)
    observations = _stack(observations, models["agents"], torch).to(torch.float32)
    state = env.state().to(torch.float32)
    while (message := _received(connection)) is not None:
        weights, level = message
        models["head"].load_state_dict(weights)
        if level is not None:
            env.set_start_level(level)
        taken = step_worlds(env, models["head"], models["distribution"], models["agents"], observations, state,
                            config.rollout_steps, torch, torch.device("cpu"))
        observations, state = taken.observations[-1], taken.states[-1]
        connection.send(taken)
    connection.close()


def advantages(rollout: Rollout, gamma: float, lam: float, torch):
    """GAE (Schulman et al. 2016) backwards over the rollout: a terminated episode bootstraps nothing, a truncated
    one its final state's value; returns (advantages, returns), (T, N, A)."""
    steps = rollout.rewards.shape[0]
    out = torch.zeros_like(rollout.rewards)
    running = torch.zeros_like(rollout.rewards[0])
    for t in reversed(range(steps)):
        alive = (~rollout.terminated[t]).to(rollout.rewards.dtype)[:, None]
        delta = rollout.rewards[t] + gamma * alive * rollout.next_values[t] - rollout.values[t]
        carry = (~rollout.done[t]).to(rollout.rewards.dtype)[:, None]  # a new episode starts after a done step
        running = delta + gamma * lam * carry * running
        out[t] = running
    return out, out + rollout.values


def update(models, optimiser, rollout: Rollout, advantage, returns, config: MappoConfig, torch):
    """PPO's clipped objective over ``config.epochs`` passes of ``config.minibatches`` minibatches of worlds x steps;
    returns the mean losses."""
    head, critic, distribution = models["head"], models["critic"], models["distribution"]
    flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731  (T, N, ...) -> (T N, ...)
    observations, states, actions = flat(rollout.observations), flat(rollout.states), flat(rollout.actions)
    old_log_probs, advantage, returns = flat(rollout.log_probs), flat(advantage), flat(returns)
    count = observations.shape[0]
    size = max(1, count // config.minibatches)
    sums = {key: torch.zeros((), device=observations.device) for key in ("policy", "value", "entropy")}
    for _ in range(config.epochs):
        order = torch.randperm(count, device=observations.device)
        for start in range(0, size * config.minibatches, size):
            rows = order[start:start + size]
            # (index_select: a CPU's advanced indexing took 8x as long for these rows; 14 % of the update)
            take = lambda x: x.index_select(0, rows)  # noqa: E731
            seen = take(observations)
            loc, scale = head(seen)
            policy = distribution(loc, scale)
            ratio = torch.exp(policy.log_prob(take(actions)) - take(old_log_probs))
            gain = take(advantage)
            gain = (gain - gain.mean(0)) / (gain.std(0) + 1e-8)  # normalised per agent
            policy_loss = -torch.min(ratio * gain, ratio.clamp(1 - config.clip_epsilon, 1 + config.clip_epsilon)
                                     * gain).mean()
            value_loss = torch.nn.functional.smooth_l1_loss(critic(take(states), seen), take(returns))
            entropy = policy.entropy().mean()
            loss = policy_loss + config.value_coef * value_loss - config.entropy_coef * entropy
            if config.bounds_loss_coef > 0.0:  # the means kept inside the action box, where the noise explores
                loss = loss + config.bounds_loss_coef * bounds_loss(loc, config.tool_head)
            optimiser.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(models["parameters"], config.max_grad_norm)
            optimiser.step()
            for key, value in (("policy", policy_loss), ("value", value_loss), ("entropy", entropy)):
                sums[key] += value.detach()  # (on the device: no wait for it within the update)
    return {key: float(value) / (config.epochs * config.minibatches) for key, value in sums.items()}


def actors(models) -> dict:
    """The torch actors of ``models`` as numpy arrays, per agent (:func:`models.actor_arrays`: what :func:`export`
    writes)."""
    return {agent: actor_arrays(models["actor_net"], index, models["log_std"][index])
            for index, agent in enumerate(models["agents"])}


def export(arrays: dict, config: MappoConfig, folder: Path, seed: int, steps: int, env,
           trainer: str = "device_mappo") -> dict:
    """Export the actors given as numpy ``arrays`` per agent (:func:`actors`) as numpy policies into ``folder`` (one
    ``marl-<agent>`` folder each), recording ``trainer``; returns their paths."""
    folders = {}
    for agent, actor in arrays.items():
        folders[agent] = folder / f"marl-{agent}"
        write_actor(actor, folders[agent], name=f"marl-{agent}", agent=agent, tool_head=config.tool_head,
                    env_id=env_name(str(config.env.get("task", suction_debris.TASK))),
                    metadata={"training": {"config": config.name, "algorithm": config.algorithm, "seed": seed,
                                           "steps": steps, "trainer": trainer},
                              # the scene it learnt on, which evaluations make (dvrl-marl evaluate-team)
                              **({"preset": config.env["preset"]} if config.env.get("preset", "default") != "default"
                                 else {})},
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
    return teams.evaluate_team_batched(seats, episodes, seed=teams.VALIDATION_SEED, **scene_options(**env_options))


def validate(models, config: MappoConfig, out: Path, seed: int, steps: int, env) -> dict:
    """Export the actors into ``out/policies`` and score them there and then (:func:`score`)."""
    folders = export(actors(models), config, out / "policies", seed, steps, env)
    return score(folders, dict(config.env), config.eval_episodes, config.evaluate_with_noise)


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
                 trainer: str = "device_mappo"):
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
        """Export the actors given as numpy ``arrays`` per agent (:func:`actors`) and score them."""
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


def refuse_options(config: MappoConfig, trainer: str = "the device trainer") -> None:
    """Refuse, by name, the options of the trainer of record this trainer does not have."""
    for option, off in _NOT_HERE.items():
        if getattr(config, option) != off:
            raise ValueError(f"{config.name}: {option} = {getattr(config, option)!r} is the trainer of record's "
                             f"(python -m dvrl_marl.training.mappo); {trainer} takes none")


def new_run_folder(out_dir) -> Path:
    """``out_dir``, made; refused when it holds a run already."""
    out = Path(out_dir)
    if (out / "progress.csv").exists():
        raise ValueError(f"{out} holds a run already (progress.csv); another folder starts a new one")
    out.mkdir(parents=True, exist_ok=True)
    return out


def build_learner(config: MappoConfig, env, device, torch) -> dict:
    """The torch models of ``config`` for ``env`` on ``device``: the actors' head, the critic's values, the actors'
    network and normalisers, the log standard deviations, the parameters and the distribution class."""
    agents = list(env.possible_agents)
    obs_dim, state_dim = env.observation_space(agents[0]).shape[0], env.state_space.shape[0]
    actor, critic, actor_net, norms = build_models(config, agents, obs_dim, state_dim, 4,
                                                   feature_spec=env.feature_spec)
    from torchrl.modules import IndependentNormal

    head = actor.module[0].module  # the GaussianHead: (loc, scale) from the observations (..., A, d)
    critic_net = critic.module
    takes_observation = config.algorithm == "ippo" or config.critic_input == "state_and_observation"

    def value(state, observations):
        if config.algorithm == "ippo":
            return critic_net(observations).squeeze(-1)
        out = critic_net(state, observations) if takes_observation else critic_net(state)
        return out.squeeze(-1)

    head.to(device)
    critic_net.to(device)
    parameters = [p for p in list(head.parameters()) + list(critic_net.parameters()) if p.requires_grad]
    return {"agents": agents, "head": head, "critic": value, "critic_net": critic_net, "actor_net": actor_net,
            "norms": norms,
            "log_std": head.log_std, "parameters": parameters,
            "distribution": switch_gaussian() if config.tool_head == "switch" else IndependentNormal}


def train(config: MappoConfig, seed: int, out_dir, *, device: str = "cpu", backend: str | None = None,
          total_steps: int | None = None, stop_at: float | None = None, max_seconds: float | None = None,
          validate_beside: bool = True, collector: str = "inline", log=print) -> dict:
    """Train ``config`` with seed ``seed`` on ``device``; writes ``progress.csv`` (per validation: the steps its
    policies were exported at, their validation success, train success since the last row, env-steps/s up to the
    export, wall clock from the call to the result) and the policies last validated in ``out_dir/policies``; returns
    the last row. ``stop_at``: stop once a validation reaches this success (time to target); ``max_seconds``: stop at
    the first validation reported after this much wall clock. ``validate_beside``: score in a worker process while
    the learner steps on (:class:`Validations`); False scores in this process, the learner waiting.
    ``collector``: ``"inline"`` steps the worlds in this process between updates; ``"process"`` (numpy's env on a
    CPU) steps them in a worker process while the learner updates (:class:`_ProcessCollector`)."""
    torch = require_torch()
    if collector not in ("inline", "process"):
        raise ValueError(f"collector must be 'inline' or 'process', got {collector!r}")
    refuse_options(config)
    backend = backend or ("jax" if str(device).startswith("cuda") else "numpy")
    if backend not in ("numpy", "jax"):
        raise ValueError(f"backend must be 'numpy' or 'jax', got {backend!r}")
    if collector == "process" and (backend != "numpy" or str(device) != "cpu"):
        raise ValueError(f"collector='process' steps numpy's env for a learner on the CPU; got backend {backend!r} "
                         f"on {device!r} (on a GPU the worlds are the device's: collector='inline')")
    cores = os.cpu_count() or 2
    if config.torch_threads:
        limit_threads(int(config.torch_threads))
    elif collector == "process":  # (the worker's core is its own)
        limit_threads(max(1, cores - 1))
    # a CPU learner on every core gives one to a validation while it runs beside (both slow on an oversubscribed
    # machine); a learner on a GPU or with threads set keeps its threads
    found_threads = torch.get_num_threads()
    share_a_core = (not config.torch_threads and collector == "inline" and validate_beside and found_threads > 1
                    and str(device) == "cpu")
    began = time.perf_counter()
    device = torch.device(device)
    torch.manual_seed(seed)
    out = new_run_folder(out_dir)
    options = dict(config.env)
    if backend == "jax":
        env = suction_debris.batched_env(num_envs=config.num_envs, device=str(device), **options)
        host = env
    else:
        host = suction_debris.batched_env(num_envs=config.num_envs, **options)
        env = _TorchView(host, torch)
    models = build_learner(config, host, device, torch)
    optimiser = torch.optim.Adam(models["parameters"], lr=config.learning_rate)
    total = int(total_steps or config.total_steps)
    agents = models["agents"]
    if collector == "inline":
        observations, _ = env.reset(seed=seed)
        observations = _stack(observations, agents, torch).to(device, torch.float32)
        state = env.state().to(device, torch.float32)
    else:
        worker = _ProcessCollector(config, seed)
        worker.submit(models["head"], config.level(0.0))
    return_scale = _ReturnScale(len(agents), config.gamma, torch, device)
    progress = Progress(out, config, seed, began, stop_at=stop_at, max_seconds=max_seconds, log=log)
    done_steps, next_validation = 0, config.eval_every
    collect_seconds = 0.0
    validations = Validations(out, config, seed, beside=validate_beside)

    try:
        while done_steps < total:
            fraction = done_steps / total
            level = config.level(fraction)
            if level is not None:
                env.set_start_level(level)
            if config.final_std:
                with torch.no_grad():
                    models["log_std"].fill_(math.log(config.exploration_std(fraction)))
            if config.anneal_lr:
                for group in optimiser.param_groups:
                    group["lr"] = config.learning_rate_at(fraction)
            if share_a_core:
                threads = found_threads - 1 if validations.busy() else found_threads
                if torch.get_num_threads() != threads:
                    limit_threads(threads)
            start = time.perf_counter()
            if collector == "inline":
                rollout, observations, state, (won, finished) = collect(env, models, observations, state,
                                                                        config.rollout_steps, torch, device)
            else:  # the next rollout is asked for before this one is learnt from: the worker steps while we update
                taken = worker.result()
                if done_steps + config.num_envs * config.rollout_steps < total:
                    worker.submit(models["head"], config.level((done_steps + config.num_envs * config.rollout_steps)
                                                               / total))
                rollout, (won, finished) = value_rollout(taken, models["critic"], torch), (taken.successes,
                                                                                           len(taken.ended_at))
            collect_seconds += time.perf_counter() - start
            progress.count(won, finished)
            rollout.rewards = rollout.rewards / return_scale.update(rollout.rewards, rollout.done)
            advantage, returns = advantages(rollout, config.gamma, config.gae_lambda, torch)
            update(models, optimiser, rollout, advantage, returns, config, torch)
            # normalisers move after the update, as in the trainer of record
            update_norms(models["norms"], rollout.observations, rollout.states)
            done_steps += config.num_envs * config.rollout_steps
            finished_run = done_steps >= total
            if any(progress.report(*row) for row in validations.results(wait=finished_run)):
                break
            if not validations.busy() and (done_steps >= next_validation or finished_run):
                next_validation = done_steps + config.eval_every
                validations.start(actors(models), done_steps, time.perf_counter() - began, host)
                if (finished_run or not validate_beside) and any(
                        progress.report(*row) for row in validations.results(wait=True)):
                    break
    finally:
        validations.close()
        if collector == "process":
            worker.close()
        if share_a_core:  # (the caller's threads as this run found them)
            limit_threads(found_threads)
    progress.finish(device=str(device), backend=backend, collect_seconds=collect_seconds)
    return progress.last


class _ReturnScale:
    """Rewards divided by the running standard deviation of the discounted return, per agent (reward scaling)."""

    def __init__(self, agents: int, gamma: float, torch, device):
        self.torch, self.gamma = torch, gamma
        self.mean = torch.zeros(agents, dtype=torch.float64, device=device)
        self.var = torch.ones(agents, dtype=torch.float64, device=device)
        self.count = 1e-4
        self.discounted = None

    def update(self, rewards, done):
        torch = self.torch
        if self.discounted is None:
            self.discounted = torch.zeros_like(rewards[0], dtype=torch.float64)
        returns = []
        for t in range(rewards.shape[0]):
            self.discounted = self.discounted * self.gamma + rewards[t].double()
            returns.append(self.discounted)
            self.discounted = self.discounted * (~done[t]).double()[:, None]
        batch = torch.stack(returns).reshape(-1, rewards.shape[-1])
        mean, var, n = batch.mean(0), batch.var(0, unbiased=False), batch.shape[0]
        delta, total = mean - self.mean, self.count + n
        self.mean = self.mean + delta * n / total
        self.var = (self.var * self.count + var * n + delta**2 * self.count * n / total) / total
        self.count = total
        return torch.sqrt(self.var + 1e-8).to(rewards.dtype)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", help="a MAPPO/IPPO configuration (baselines/configs/*.toml)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--backend", choices=("numpy", "jax"), default=None, help="default: jax on a GPU, else numpy")
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--stop-at", type=float, default=None, help="stop once validation reaches this success")
    parser.add_argument("--collector", choices=("inline", "process"), default="inline",
                        help="process: numpy's worlds step in a worker process while the learner updates (a CPU)")
    args = parser.parse_args()
    train(load_config(args.config), args.seed, args.out, device=args.device, backend=args.backend,
          total_steps=args.steps, stop_at=args.stop_at, collector=args.collector)


if __name__ == "__main__":
    main()
