"""MAPPO / IPPO on JAX, the trainer of record for the collaborative scene: the worlds, the policy, the rollout and
the update compiled into one function per update.

One update cycle is one compiled function (the PureJaxRL way): ``jax.lax.scan`` steps the worlds with the actors'
samples (the env's :attr:`~dvrl_marl.envs.suction_debris_device.SuctionDebrisDeviceEnv.step_function`, the core's one
step), then the return scaling, GAE, the PPO epochs (optax's Adam) and the running normalisers run in the same program.
Python only sets each cycle's schedules (the start level, the learning rate, the exploration) and exports the actors
for validation (:mod:`dvrl_marl.training.run_progress`: beside the learner, in worker processes). Read top to bottom:
the networks (torch's layouts, so that the export writes them as they are), the distributions (the switch tool head),
the loss (:func:`minibatch_loss`: clipped objective, per-agent advantage normalisation, smooth-L1 value loss, bounds
loss, global gradient clipping), the reward scaling and GAE (:func:`scaled_rewards`, :func:`advantages`), the cycle
(:func:`make_cycle`) and the run (:func:`train`).

It reads the configurations of the TorchRL trainer (:class:`~dvrl_marl.training.mappo_config.MappoConfig`,
``baselines/configs/*.toml``); ``tests/test_jax_mappo.py`` holds a minibatch's loss and gradients, the reward scaling
and GAE equal to the same algorithm written in torch. What it leaves to the TorchRL trainer
(:mod:`dvrl_marl.training.mappo`), refused by name: partners in a seat, pretraining from demonstrations, warm starts
from torch policies and the critic's warm-up; checkpoints (``--resume``) and Ray collectors. Its random draws are
JAX's, so a seed's run is its own. The actors are written by the same numpy export
(:func:`~dvrl_marl.training.models.write_actor`) and scored by the same validation.

    dvrl-marl train suction_debris_mappo                                  # the default trainer of MAPPO/IPPO
    dvrl-marl train suction_debris_mappo_gpu --device cuda --validators 8
    python -m dvrl_marl.training.jax_mappo baselines/configs/suction_debris_mappo_gpu.toml --device cuda --out runs/x

Needs JAX and optax (``pip install "dvrl-marl[jax]"``; a GPU needs JAX's CUDA build), not torch.
"""

from __future__ import annotations

import argparse
import math
import os
import time
from pathlib import Path

import numpy as np

from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris.layout import ACTION_WIDTH, MOVE
from dvrl_marl.suction_debris.observation_scaling import MIN_SPREAD
from dvrl_marl.training import run_progress, trainers
from dvrl_marl.training.mappo_config import MappoConfig, load_config

__all__ = ["train", "compilation_cache", "init_params", "init_norms", "actor_loc", "critic_values", "minibatch_loss",
           "scaled_rewards", "advantages", "make_cycle", "start", "actors", "refuse_options", "TORCHRL_ONLY"]

#: JAX's float32 for the networks (the process runs with float64 on: the core's arrays are float64).
_F32 = "float32"


def _jax():
    try:
        import jax
        import optax  # noqa: F401
    except ImportError as error:
        raise ModuleNotFoundError(f"the JAX trainer needs jax and optax ({error.name} is missing): "
                                  'pip install "dvrl-marl[jax]"', name=error.name) from None
    jax.config.update("jax_enable_x64", True)
    return jax


# --- networks: torch's layouts (weight (out, in)), so that the export copies them as they are -------------------
def _linear(key, inputs: int, outputs: int) -> dict:
    """torch's ``nn.Linear`` initial distribution: weight and bias uniform within 1 / sqrt(inputs)."""
    import jax

    bound = 1.0 / math.sqrt(inputs)
    weight_key, bias_key = jax.random.split(key)
    return {"weight": jax.random.uniform(weight_key, (outputs, inputs), _F32, -bound, bound),
            "bias": jax.random.uniform(bias_key, (outputs,), _F32, -bound, bound)}


def _mlp_init(key, inputs: int, hidden, outputs: int) -> list:
    import jax

    sizes = [inputs, *[int(size) for size in hidden], outputs]
    keys = jax.random.split(key, len(sizes) - 1)
    return [_linear(k, a, b) for k, a, b in zip(keys, sizes[:-1], sizes[1:])]


def _mlp(layers: list, x):
    import jax.numpy as jnp

    for layer in layers[:-1]:
        x = jnp.tanh(x @ layer["weight"].T + layer["bias"])
    return x @ layers[-1]["weight"].T + layers[-1]["bias"]


def init_params(key, config: MappoConfig, agents, obs_dim: int, state_dim: int, action_dim: int = ACTION_WIDTH) -> dict:
    """The actors (one network per agent; the last layer scaled by 0.01, its bias zero but the switch tool's initial
    logit), the log standard deviations (A, action_dim) and the critics, as :func:`models.build_models` makes them."""
    import jax
    import jax.numpy as jnp

    actor_key, critic_key = jax.random.split(key)
    actors = []
    for index, agent in enumerate(agents):
        layers = _mlp_init(jax.random.fold_in(actor_key, index), obs_dim, config.hidden, action_dim)
        bias = jnp.zeros(action_dim, _F32)
        if config.tool_head == "switch":
            bias = bias.at[-1].set(float(config.initial_tool_logit.get(agent, 0.0)))
        layers[-1] = {"weight": layers[-1]["weight"] * 0.01, "bias": bias}
        actors.append(layers)
    if config.algorithm == "mappo" and config.critic_input == "state":
        critic = _mlp_init(critic_key, state_dim, config.hidden, len(agents))
    else:  # one value network per agent: the state and its observation (MAPPO), or its observation alone (IPPO)
        inputs = obs_dim + (state_dim if config.algorithm == "mappo" else 0)
        critic = [_mlp_init(jax.random.fold_in(critic_key, index), inputs, config.hidden, 1)
                  for index in range(len(agents))]
    log_std = jnp.full((len(agents), action_dim), math.log(config.initial_std), _F32)
    return {"actors": actors, "log_std": log_std, "critic": critic}


def init_norms(config: MappoConfig, obs_dim: int, state_dim: int) -> dict:
    """The running normalisers (float64 mean, variance, count) of the actors' observations, the critic's
    observations and the state, as :func:`models.build_models` keeps them."""
    import jax.numpy as jnp

    def norm(size):
        return {"mean": jnp.zeros(size), "var": jnp.ones(size), "count": jnp.asarray(1e-4)}

    norms = {"observation": norm(obs_dim)}
    if config.algorithm == "ippo" or config.critic_input == "state_and_observation":
        norms["critic_observation"] = norm(obs_dim)
    if config.algorithm == "mappo":
        norms["state"] = norm(state_dim)
    return norms


def _normalised(norm: dict, x):
    import jax.numpy as jnp

    std = jnp.maximum(jnp.sqrt(norm["var"]), MIN_SPREAD)
    return (x - norm["mean"].astype(_F32)) / std.astype(_F32)


def actor_loc(params: dict, norms: dict, observations):
    """The actors' outputs (..., A, 4) on their observations (..., A, d): the Gaussian's means (the switch tool's
    logit last)."""
    import jax.numpy as jnp

    x = _normalised(norms["observation"], observations)
    return jnp.stack([_mlp(layers, x[..., index, :]) for index, layers in enumerate(params["actors"])], axis=-2)


def critic_values(params: dict, norms: dict, config: MappoConfig, states, observations):
    """The values (..., A) of the states (..., S) and the agents' observations (..., A, d)."""
    import jax.numpy as jnp

    if config.algorithm == "mappo" and config.critic_input == "state":
        return _mlp(params["critic"], _normalised(norms["state"], states))
    seen = _normalised(norms["critic_observation"], observations)
    values = []
    for index, layers in enumerate(params["critic"]):
        x = seen[..., index, :]
        if config.algorithm == "mappo":
            x = jnp.concatenate([_normalised(norms["state"], states), x], axis=-1)
        values.append(_mlp(layers, x)[..., 0])
    return jnp.stack(values, axis=-1)


# --- the policy's distribution: independent Normals, or the motion's Normals and a Bernoulli tool (switch) ----------
def _log_prob(loc, log_std, action, switch: bool):
    import jax
    import jax.numpy as jnp

    motion = slice(None, -1) if switch else slice(None)
    std = jnp.exp(log_std)
    normal = (-0.5 * ((action[..., motion] - loc[..., motion]) / std[..., motion]) ** 2 - log_std[..., motion]
              - 0.5 * math.log(2.0 * math.pi)).sum(-1)
    if not switch:
        return normal
    opened = (action[..., -1] > 0.0).astype(loc.dtype)
    logit = loc[..., -1]
    return normal + opened * jax.nn.log_sigmoid(logit) + (1.0 - opened) * jax.nn.log_sigmoid(-logit)


def _entropy(loc, log_std, switch: bool):
    import jax
    import jax.numpy as jnp

    motion = slice(None, -1) if switch else slice(None)
    normal = jnp.broadcast_to(0.5 + 0.5 * math.log(2.0 * math.pi) + log_std[..., motion],
                              loc[..., motion].shape).sum(-1)
    if not switch:
        return normal
    logit = loc[..., -1]
    probability = jax.nn.sigmoid(logit)
    return normal - probability * jax.nn.log_sigmoid(logit) - (1.0 - probability) * jax.nn.log_sigmoid(-logit)


def _sample(key, loc, log_std, switch: bool):
    import jax
    import jax.numpy as jnp

    motion_key, tool_key = jax.random.split(key)
    action = loc + jnp.exp(log_std) * jax.random.normal(motion_key, loc.shape, loc.dtype)
    if not switch:
        return action
    opened = jax.random.bernoulli(tool_key, jax.nn.sigmoid(loc[..., -1]))
    return action.at[..., -1].set(jnp.where(opened, 1.0, -1.0).astype(loc.dtype))


# --- the loss -------------------------------------------------------------------------------------------------
def minibatch_loss(params: dict, norms: dict, config: MappoConfig, batch: dict):
    """PPO's loss on a minibatch (rows of ``observations`` (B, A, d), ``states`` (B, S), ``actions`` (B, A, 4),
    ``log_probs``, ``advantages`` and ``returns`` (B, A)): the clipped objective on advantages normalised per agent,
    the smooth-L1 value loss, the entropy bonus and the bounds loss; returns ``(loss, (policy loss, value loss,
    entropy))``."""
    import jax.numpy as jnp

    switch = config.tool_head == "switch"
    loc = actor_loc(params, norms, batch["observations"])
    log_std = params["log_std"]
    if config.final_std:  # a schedule, not learnt: no gradient (nor a share of the clipped norm), as in torch
        import jax

        log_std = jax.lax.stop_gradient(log_std)
    log_std = jnp.broadcast_to(log_std, loc.shape)
    ratio = jnp.exp(_log_prob(loc, log_std, batch["actions"], switch) - batch["log_probs"])
    gain = batch["advantages"]
    gain = (gain - gain.mean(0)) / (gain.std(0, ddof=1) + 1e-8)  # normalised per agent
    clipped = jnp.clip(ratio, 1.0 - config.clip_epsilon, 1.0 + config.clip_epsilon)
    policy_loss = -jnp.minimum(ratio * gain, clipped * gain).mean()
    error = critic_values(params, norms, config, batch["states"], batch["observations"]) - batch["returns"]
    value_loss = jnp.where(jnp.abs(error) < 1.0, 0.5 * error**2, jnp.abs(error) - 0.5).mean()  # smooth L1
    entropy = _entropy(loc, log_std, switch).mean()
    loss = policy_loss + config.value_coef * value_loss - config.entropy_coef * entropy
    if config.bounds_loss_coef > 0.0:  # the means kept inside the action box (models.bounds_loss)
        motion = loc[..., MOVE] if switch else loc
        loss = loss + config.bounds_loss_coef * (jnp.maximum(jnp.abs(motion) - 1.0, 0.0) ** 2).sum(-1).mean()
    return loss, (policy_loss, value_loss, entropy)


def optimiser(config: MappoConfig):
    """Adam after clipping the gradients' global norm (torch's ``clip_grad_norm_``), its learning rate set per
    cycle."""
    import optax

    return optax.inject_hyperparams(lambda learning_rate: optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm), optax.adam(learning_rate)))(
        learning_rate=config.learning_rate)


def _merged(norm: dict, x) -> dict:
    """``norm`` with the batch ``x`` (..., k) merged in (Chan et al.: moments in float32, merged in float64)."""
    import jax.numpy as jnp

    x = x.reshape(-1, x.shape[-1])
    mean = x.mean(0)
    var = ((x - mean) ** 2).mean(0)
    mean, var, n = mean.astype(jnp.float64), var.astype(jnp.float64), x.shape[0]
    delta, total = mean - norm["mean"], norm["count"] + n
    return {"mean": norm["mean"] + delta * n / total,
            "var": (norm["var"] * norm["count"] + var * n + delta**2 * norm["count"] * n / total) / total,
            "count": total}


def scaled_rewards(rewards, done, scale: dict, gamma: float):
    """Rewards (T, N, A) divided by the running standard deviation of the discounted return, per agent (the device
    trainer's reward scaling); ``scale``: the running moments and each world's discounted return so far. Returns the
    scaled rewards and the new ``scale``."""
    _jax()  # (float64 on: the running moments are float64)
    import jax.numpy as jnp
    from jax import lax

    def body(discounted, item):
        reward, ended = item
        discounted = discounted * gamma + reward.astype(jnp.float64)
        return discounted * (~ended)[:, None], discounted

    discounted, returns = lax.scan(body, scale["discounted"].astype(jnp.float64), (rewards, done))
    batch = returns.reshape(-1, rewards.shape[-1])
    mean, var, n = batch.mean(0), batch.var(0), batch.shape[0]
    delta, total = mean - scale["mean"], scale["count"] + n
    scale = {"mean": scale["mean"] + delta * n / total,
             "var": (scale["var"] * scale["count"] + var * n + delta**2 * scale["count"] * n / total) / total,
             "count": total, "discounted": discounted}
    return rewards / jnp.sqrt(scale["var"] + 1e-8).astype(rewards.dtype), scale


def advantages(rewards, values, next_values, terminated, done, gamma: float, lam: float):
    """GAE backwards over (T, N, A): a terminated episode bootstraps nothing, a truncated one its final state's
    value (``next_values``); returns (advantages, returns)."""
    _jax()  # (float64 on: the running moments are float64)
    import jax.numpy as jnp
    from jax import lax

    def body(running, item):
        reward, value, next_value, ended_by_termination, ended = item
        alive = (~ended_by_termination).astype(reward.dtype)[:, None]
        delta = reward + gamma * alive * next_value - value
        running = delta + gamma * lam * (~ended).astype(reward.dtype)[:, None] * running
        return running, running

    _, advantage = lax.scan(body, jnp.zeros_like(rewards[0]), (rewards, values, next_values, terminated, done),
                            reverse=True)
    return advantage, advantage + values


# --- one update cycle, compiled -------------------------------------------------------------------------------
def make_cycle(env, config: MappoConfig):
    """The update cycle as one function of the carry ``(world state, observations, global state, params, norms,
    optimiser state, return scale, key)``, the cycle's learning rate and log standard deviation (None: learnt):
    ``rollout_steps`` steps of every world, the return scaling, GAE, ``epochs`` x ``minibatches`` PPO steps, the
    normalisers. Returns the new carry and the cycle's figures (successes, episodes ended, mean losses)."""
    jax = _jax()
    import jax.numpy as jnp
    from jax import lax

    step = env.step_function
    agents = list(env.possible_agents)
    switch = config.tool_head == "switch"
    tx = optimiser(config)

    def stacked(values: dict):
        return jnp.stack([values[agent] for agent in agents], axis=1).astype(_F32)

    def rollout(carry, params, norms, key):
        def body(inner, step_key):
            world, observations, state = inner
            loc = actor_loc(params, norms, observations)
            log_std = jnp.broadcast_to(params["log_std"], loc.shape)
            action = _sample(step_key, loc, log_std, switch)
            world, next_observations, rewards, terminated, truncated, infos = step(
                world, {agent: action[:, index].astype(jnp.float64) for index, agent in enumerate(agents)})
            done = terminated | truncated
            # the value after the step: of the state it ended on (also for a world reset within it)
            next_value = critic_values(params, norms, config, infos["final_state"].astype(_F32),
                                       stacked(infos["final_observation"]))
            record = {"observations": observations, "states": state, "actions": action,
                      "log_probs": _log_prob(loc, log_std, action, switch),
                      "values": critic_values(params, norms, config, state, observations),
                      "next_values": next_value, "rewards": stacked(rewards), "done": done,
                      "terminated": terminated, "won": infos["is_success"] & done}
            return (world, stacked(next_observations), infos["state"].astype(_F32)), record

        return lax.scan(body, carry, jax.random.split(key, config.rollout_steps))

    def update(params, norms, opt_state, batch, key):
        count = batch["log_probs"].shape[0]
        size = max(1, count // config.minibatches)
        gradient = jax.value_and_grad(minibatch_loss, has_aux=True)

        def minibatch(inner, rows):
            params, opt_state = inner
            taken = {name: value[rows] for name, value in batch.items()}
            (_, parts), grads = gradient(params, norms, config, taken)
            updates, opt_state = tx.update(grads, opt_state, params)
            return (jax.tree_util.tree_map(lambda p, u: p + u, params, updates), opt_state), jnp.stack(parts)

        def epoch(inner, epoch_key):
            order = jax.random.permutation(epoch_key, count)[:size * config.minibatches]
            return lax.scan(minibatch, inner, order.reshape(config.minibatches, size))

        (params, opt_state), parts = lax.scan(epoch, (params, opt_state), jax.random.split(key, config.epochs))
        return params, opt_state, parts.reshape(-1, 3).mean(0)

    def cycle(carry, learning_rate, log_std):
        world, observations, state, params, norms, opt_state, scale, key = carry
        key, rollout_key, update_key = jax.random.split(key, 3)
        if log_std is not None:  # a schedule, not learnt (minibatch_loss stops its gradient: Adam leaves it)
            params = {**params, "log_std": jnp.broadcast_to(log_std, params["log_std"].shape).astype(_F32)}
        (world, observations, state), record = rollout((world, observations, state), params, norms, rollout_key)
        rewards, scale = scaled_rewards(record["rewards"], record["done"], scale, config.gamma)
        advantage, returns = advantages(rewards, record["values"], record["next_values"], record["terminated"],
                                        record["done"], config.gamma, config.gae_lambda)
        flat = lambda x: x.reshape(-1, *x.shape[2:])  # noqa: E731  (T, N, ...) -> (T N, ...)
        batch = {"observations": flat(record["observations"]), "states": flat(record["states"]),
                 "actions": flat(record["actions"]), "log_probs": flat(record["log_probs"]),
                 "advantages": flat(advantage), "returns": flat(returns)}
        opt_state.hyperparams["learning_rate"] = learning_rate
        params, opt_state, losses = update(params, norms, opt_state, batch, update_key)
        # the normalisers move after the update (the update reads the ones its rollout was taken with)
        norms = {name: _merged(norm, record["states"] if name == "state" else record["observations"])
                 for name, norm in norms.items()}
        figures = {"successes": record["won"].sum(), "ended": record["done"].sum(), "losses": losses}
        return (world, observations, state, params, norms, opt_state, scale, key), figures

    return cycle


# --- the export: numpy arrays, as the torch trainers' actors give them ------------------------------------------
def actors(params: dict, norms: dict, agents) -> dict:
    """The actors as numpy arrays per agent (:func:`models.actor_arrays`'s form: ``layers``, the normaliser's
    ``mean`` and ``std``, ``log_std``), what :func:`run_progress.export` writes; no torch."""
    mean = np.array(norms["observation"]["mean"], dtype=np.float64)
    std = np.maximum(np.sqrt(np.array(norms["observation"]["var"], dtype=np.float64)), MIN_SPREAD)
    log_std = np.array(params["log_std"])
    return {agent: {"layers": [(np.array(layer["weight"]), np.array(layer["bias"])) for layer in layers],
                    "mean": mean, "std": std, "log_std": log_std[index]}
            for index, (agent, layers) in enumerate(zip(agents, params["actors"]))}


# --- the run --------------------------------------------------------------------------------------------------
def start(env, config: MappoConfig, seed: int) -> tuple:
    """The first carry of :func:`make_cycle`'s cycle: every world reset with ``seed``, the networks initialised from
    it, the optimiser, the normalisers and the reward scaling at their start, on the env's device."""
    jax = _jax()
    import jax.numpy as jnp

    agents = list(env.possible_agents)
    obs_dim, state_dim = env.observation_space(agents[0]).shape[0], env.state_space.shape[0]
    observations, _ = env.reset(seed=seed)
    key, init_key = jax.random.split(jax.random.PRNGKey(seed))
    params = init_params(init_key, config, agents, obs_dim, state_dim)
    scale = {"mean": jnp.zeros(len(agents)), "var": jnp.ones(len(agents)), "count": jnp.asarray(1e-4),
             "discounted": jnp.zeros((config.num_envs, len(agents)))}
    observations = jnp.stack([observations[agent] for agent in agents], axis=1).astype(_F32)
    carry = (env.world_state, observations, env.state().astype(_F32), params, init_norms(config, obs_dim, state_dim),
             optimiser(config).init(params), scale, key)
    return jax.device_put(carry, env.device)


def compilation_cache(folder="auto") -> str | None:
    """Keep compiled cycles in JAX's persistent compilation cache: ``folder``, or with ``"auto"`` the one this process
    set already, else ``$XDG_CACHE_HOME/dvrl_marl/jax`` (``~/.cache``); None or ``""`` keeps none. Why: a cycle takes
    about 30 s to compile on a GPU, half of a run that learns in a minute; a second run of the same configuration and
    size on the same machine loads it. Returns the folder in use."""
    jax = _jax()
    if folder == "auto":
        folder = jax.config.jax_compilation_cache_dir or str(
            Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dvrl_marl" / "jax")
    if folder:
        jax.config.update("jax_compilation_cache_dir", str(folder))
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return folder or None


#: What this trainer does not do (the TorchRL trainer does): the option, and the value that turns it off.
TORCHRL_ONLY = {"surgeon": "none", "bc_expert": "", "init_policy": {}, "critic_warmup_steps": 0}


def torchrl_only(config: MappoConfig) -> str | None:
    """The first option ``config`` sets that only the TorchRL trainer has, said by name (None: none)."""
    for option, off in TORCHRL_ONLY.items():
        if getattr(config, option) != off:
            return f"{option} = {getattr(config, option)!r} is the TorchRL trainer's"
    return None


def refuse_options(config: MappoConfig) -> None:
    """Refuse, by name, the options of the TorchRL trainer this one does not have."""
    why = torchrl_only(config)
    if why is not None:
        raise ValueError(f"{config.name}: {why} (dvrl-marl train --trainer torchrl); the JAX trainer takes none")


def train(config: MappoConfig, seed: int, out_dir, *, device: str = "cpu", total_steps: int | None = None,
          stop_at: float | None = None, max_seconds: float | None = None, validate_beside: bool = True,
          validators: int = 1, cache="auto", log=print) -> dict:
    """Train ``config`` with seed ``seed``, the worlds and the learner on ``device`` (JAX's ``"cpu"`` or
    ``"cuda"``); writes ``progress.csv`` (one row per validation), ``result.json`` and the policies last validated
    (``policies/marl-<agent>``), and returns the last row. ``validators``: validations scored at once, each in a
    worker process of its own (each falls due every ``eval_every`` steps; on a machine of many cores several keep up
    with a fast learner).
    ``cache``: where compiled cycles are kept (:func:`compilation_cache`; None keeps none)."""
    jax = _jax()
    compilation_cache(cache)
    refuse_options(config)
    began = time.perf_counter()
    out = run_progress.new_run_folder(out_dir)
    env = suction_debris.batched_env(num_envs=config.num_envs, device=device, arrays="jax", check_actions=False,
                                        **dict(config.env))
    carry = list(start(env, config, seed))
    cycle = jax.jit(make_cycle(env, config), donate_argnums=(0,))
    learnt_std = not config.final_std
    total = int(total_steps or config.total_steps)
    progress = run_progress.Progress(out, config, seed, began, stop_at=stop_at, max_seconds=max_seconds, log=log)
    validations = run_progress.Validations(out, config, seed, beside=validate_beside, workers=validators,
                                           trainer="jax_mappo")
    done_steps, next_validation, batch = 0, config.eval_every, config.num_envs * config.rollout_steps
    tally = (0, 0)  # training episodes completed and ended since the last validation (summed on the device)
    try:
        while done_steps < total:
            fraction = done_steps / total
            level = config.level(fraction)
            if level is not None:
                env.set_start_level(level)
            carry[0] = env.world_state
            log_std = None if learnt_std else np.float32(math.log(config.exploration_std(fraction)))
            carry, figures = cycle(tuple(carry), np.float32(config.learning_rate_at(fraction)), log_std)
            carry = list(carry)
            env.world_state = carry[0]
            tally = (tally[0] + figures["successes"], tally[1] + figures["ended"])
            done_steps += batch
            finished = done_steps >= total
            if not validations.busy() and (done_steps >= next_validation or finished):
                next_validation = done_steps + config.eval_every
                losses = np.asarray(figures["losses"])  # (the host waits for this cycle here, once per validation)
                if not np.all(np.isfinite(losses)):
                    raise FloatingPointError(f"{config.name} seed {seed} @ {done_steps:,d} steps: the losses are "
                                             f"not finite (policy, value, entropy: {losses.tolist()})")
                progress.count(int(tally[0]), int(tally[1]))
                tally = (0, 0)
                validations.start(actors(carry[3], carry[4], env.possible_agents), done_steps,
                                  time.perf_counter() - began, env)
            reported = validations.results(wait=finished or not validate_beside)
            if any(progress.report(*row) for row in reported):
                break
    finally:
        validations.close()
    progress.finish(device=str(env.device), backend="jax")
    return progress.last


def _device_of(config: MappoConfig) -> str:
    """The configuration's ``device`` as JAX's: ``"auto"`` is a GPU where JAX has one, else the CPU."""
    if config.device != "auto":
        return config.device
    return "cuda" if any(device.platform == "gpu" for device in _jax().devices()) else "cpu"


def train_from_request(request: trainers.TrainRequest, run_table: dict) -> int:
    """``dvrl-marl train`` with this trainer: ``--device`` (else the configuration's), ``--validators``,
    ``--steps``, ``--export``."""
    config = load_config(request.config)
    out = request.out_folder(config.name)
    final = train(config, request.seed, out, device=request.device or _device_of(config), total_steps=request.steps,
                  validators=request.validators or 1)
    print(f"{config.name} seed {request.seed}: validation success {final['success_rate']:.2f} after "
          f"{final['steps']:,d} steps; policies in {out / 'policies'}; run folder {out}")
    run_progress.copy_policies(out, request.export)
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="jax", algorithms=("mappo", "ippo"), run=train_from_request, rank=0,
    cannot=lambda run_table, path: torchrl_only(load_config(path)),
    takes=frozenset({"steps", "export", "device", "validators"}), needs=("jax", "optax"),
    install='pip install "dvrl-marl[jax]"',
    summary="MAPPO/IPPO, each update cycle compiled whole by JAX (the default; CPU or GPU)"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("config", help="a MAPPO/IPPO configuration (baselines/configs/*.toml)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--device", default="cpu", help="JAX's device: cpu, cuda or cuda:<index>")
    parser.add_argument("--steps", type=int, default=None)
    parser.add_argument("--stop-at", type=float, default=None, help="stop once validation reaches this success")
    parser.add_argument("--max-seconds", type=float, default=None, help="stop at the first validation after this long")
    parser.add_argument("--validators", type=int, default=1, help="validations scored at once (worker processes)")
    parser.add_argument("--cache", default="auto", help="JAX's compilation cache folder (auto: ~/.cache/dvrl_marl/jax "
                        "unless JAX has one; '' keeps none)")
    args = parser.parse_args()
    train(load_config(args.config), args.seed, args.out, device=args.device, total_steps=args.steps,
          stop_at=args.stop_at, max_seconds=args.max_seconds, validators=args.validators,
          cache=args.cache)


if __name__ == "__main__":
    main()
