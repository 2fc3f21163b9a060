"""Behaviour cloning of the scripted experts into a MAPPO run's actors, before PPO takes over.

This is the demonstrations route of the partner-seat configurations (``[pretrain] bc_expert = "scripted"``): it is
off by default, and a run that uses it learns *from demonstrations*, so its figures are reported apart from the
"from scratch" ones. Why it exists: PPO alone never learnt the grasper's job beside the scripted suction (0 % in
every variant measured, ``baselines/README.md``), while a clone of the scripted surgeon succeeds most of the time;
PPO then fine-tunes the clone on the team's reward.

- :func:`record_expert` plays the scripted expert in each learning seat (the configuration's scripted partner in
  the other) over ``bc_episodes`` default-task episodes from training seeds, executing the expert's motion plus
  Gaussian noise of standard deviation ``bc_action_noise`` while labelling each state with the expert's own
  action (DART, Laskey et al. 2017: the clone sees how the expert recovers from the errors it will make).
- :func:`clone_actor` fits one agent's actor mean to those labels (squared error on the motion, clipped to the
  action box; with the switch tool head, cross-entropy of the open/closed logit), observation normaliser first.
- :func:`clone_experts` does both, then ``bc_dagger_rounds`` rounds of DAgger (the clone drives, the expert labels).
- :func:`start_from_policies` (``init_policy``) instead starts an actor from a policy already trained (a shipped
  one, or a run's export): fine-tuning it on another reward or beside other partners.
- The trainer then runs PPO with the actor frozen for ``critic_warmup_steps`` (only the critic learns: advantages
  from an untrained critic would push the clone off what it learnt before the critic knows its value).
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.suction_debris.layout import MOVE, TOOL
__all__ = ["record_expert", "clone_actor", "clone_experts", "start_from_policies"]


def record_expert(config, seed: int, *, act=None, round_index: int = 0) -> dict:
    """``{agent: (observations (M, obs_dim), expert actions (M, 4))}`` for each learning seat of ``config``, over
    ``bc_episodes`` default-task episodes. ``act(index, observations) -> actions``: who drives (a DAgger round: the
    clone acts, the expert labels what it visits); None: the expert with DART noise. ``round_index`` picks the
    episodes' seeds (each round its own)."""
    from dvrl_marl.envs import suction_debris
    from dvrl_marl.training import teams
    from dvrl_marl.training.mappo_config import TRAIN_SEED_BASE, partner

    episodes = int(config.bc_episodes)
    surgeon = partner(config, None, noise_from=TRAIN_SEED_BASE * (seed + 1) - 31 * (round_index + 1))
    env = suction_debris.batched_env(num_envs=episodes, surgeon=surgeon, surgeon_seat=config.surgeon_seat,
                                        autoreset_mode="disabled", **config.env)
    agents = list(env.possible_agents)
    experts = {agent: teams.seat(config.bc_expert, agent, env) for agent in agents}
    # seeds of their own: below the training worlds' (TRAIN_SEED_BASE * (seed + 1) on), far from evaluation's
    rng = np.random.default_rng([seed, 7, round_index])
    observations, _ = env.reset(seed=TRAIN_SEED_BASE * (seed + 1) - episodes * (round_index + 1))
    recorded = {agent: ([], []) for agent in agents}
    running = np.ones(episodes, dtype=bool)
    for _ in range(env.params.max_cycles):
        actions = {}
        for index, agent in enumerate(agents):
            label = np.asarray(experts[agent](observations[agent]), dtype=np.float64)
            recorded[agent][0].append(observations[agent][running].astype(np.float32))
            recorded[agent][1].append(label[running].astype(np.float32))
            if act is None:
                executed = label.copy()
                executed[:, MOVE] = np.clip(label[:, MOVE] + rng.normal(0.0, config.bc_action_noise, (episodes, 3)),
                                          -1.0, 1.0)
            else:
                executed = act(index, observations[agent], rng)
            actions[agent] = executed
        observations, _, terminations, truncations, _ = env.step(actions)
        running &= ~(terminations[agents[0]] | truncations[agents[0]])
        if not running.any():
            break
    env.close()
    return {agent: (np.concatenate(obs), np.concatenate(act)) for agent, (obs, act) in recorded.items()}


def clone_experts(config, seed: int, actor_net, agents) -> dict:
    """Record, clone, then ``bc_dagger_rounds`` DAgger rounds (Ross et al. 2011: the clone drives with the noise
    PPO will start from, the expert labels every state it visits, the clone is refitted on everything so far: the
    states where a clone gets stuck are the ones its expert never visited). Returns a summary for ``pretrain.json``."""
    import torch

    summary = {"expert": config.bc_expert, "episodes": int(config.bc_episodes), "action_noise": config.bc_action_noise,
               "epochs": int(config.bc_epochs), "dagger_rounds": int(config.bc_dagger_rounds), "agents": {}}
    std = float(config.initial_std)
    device = next(actor_net.parameters()).device

    def act(index, observations, rng):
        with torch.no_grad():
            x = torch.from_numpy(observations.astype(np.float32)).to(device)
            loc = actor_net.agent_forward(x, index).cpu().numpy()
        action = np.clip(loc + rng.normal(0.0, std, loc.shape), -1.0, 1.0).astype(np.float64)
        if config.tool_head == "switch":  # the logit's more likely side, as the exported policy acts
            action[:, TOOL] = np.where(loc[:, TOOL] > 0.0, 1.0, -1.0)
        return action

    data = record_expert(config, seed)
    for round_index in range(int(config.bc_dagger_rounds) + 1):
        if round_index:
            visited = record_expert(config, seed, act=act, round_index=round_index)
            data = {agent: (np.concatenate([data[agent][0], visited[agent][0]]),
                            np.concatenate([data[agent][1], visited[agent][1]])) for agent in agents}
        for index, agent in enumerate(agents):
            observations, labels = data[agent]
            loss = clone_actor(actor_net, index, observations, labels, tool_head=config.tool_head,
                               epochs=config.bc_epochs, learning_rate=config.bc_learning_rate, seed=seed,
                               update_norm=round_index == 0)
            summary["agents"][agent] = {"transitions": int(len(observations)), "final_loss": loss}
    return summary


def clone_actor(actor_net, index: int, observations: np.ndarray, actions: np.ndarray, *, tool_head: str,
                epochs: int, learning_rate: float, batch_size: int = 4096, seed: int = 0,
                update_norm: bool = True) -> float:
    """Fit agent ``index``'s actor mean to ``actions`` on ``observations`` (see the module documentation); with
    ``update_norm`` updates the actors' observation normaliser with these observations first. Returns the last
    epoch's mean loss."""
    import torch
    from torch.nn import functional

    device = next(actor_net.parameters()).device
    x = torch.from_numpy(np.ascontiguousarray(observations)).to(device)
    y = torch.from_numpy(np.ascontiguousarray(actions)).to(device)
    if update_norm:
        with torch.no_grad():
            actor_net.norm.update(x)
    network = actor_net.nets[index]
    optimiser = torch.optim.Adam(network.parameters(), lr=learning_rate)
    generator = torch.Generator().manual_seed(seed)
    count = x.shape[0]
    steps_per_epoch = max(count // batch_size, 1)
    schedule = torch.optim.lr_scheduler.LambdaLR(  # annealed to 0: a sharp fit where the expert switches
        optimiser, lambda step: max(1.0 - step / (epochs * steps_per_epoch), 0.0))
    last = float("nan")
    for _ in range(int(epochs)):
        order = torch.randperm(count, generator=generator).to(device)
        total = 0.0
        for step in range(steps_per_epoch):
            chosen = order[step * batch_size:(step + 1) * batch_size]
            loc = actor_net.agent_forward(x[chosen], index)
            target = y[chosen]
            if tool_head == "switch":
                loss = ((loc[:, MOVE] - target[:, MOVE].clamp(-1.0, 1.0)) ** 2).sum(-1).mean()
                loss = loss + functional.binary_cross_entropy_with_logits(loc[:, TOOL], (target[:, TOOL] > 0.0).float())
            else:
                loss = ((loc - target.clamp(-1.0, 1.0)) ** 2).sum(-1).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            schedule.step()
            total += float(loss.detach())
        last = total / steps_per_epoch
    return last


def start_from_policies(config, actor_net, agents, feature_spec) -> dict:
    """Load ``config.init_policy``'s policies into their agents' actors: the exported layers (the input scaling
    folded into the first) become the networks' weights, the shared observation normaliser the identity (and, as
    for a clone, it is not refitted), the switch tool's logit unscaled. The network, its activations and the
    observation features must be the run's. Returns a summary for ``pretrain.json``."""
    import torch

    from dvrl_marl import policies
    from dvrl_marl.training.models import SWITCH_EXPORT_GAIN

    for agent in config.init_policy:
        if agent not in agents:
            raise ValueError(f"init_policy: {agent!r} is not a learning seat of this run ({agents})")
    with torch.no_grad():
        actor_net.norm.mean.zero_()
        actor_net.norm.var.fill_(1.0)
    summary = {"started_from": dict(config.init_policy)}
    for agent, name in config.init_policy.items():
        policy = policies.load(name)
        spec, net = policy.spec, actor_net.nets[agents.index(agent)]
        linears = [module for module in net if hasattr(module, "weight")]
        sizes = [int(linears[0].weight.shape[1])] + [int(module.weight.shape[0]) for module in linears]
        if list(spec["layer_sizes"]) != sizes or spec["activations"] != ["tanh"] * (len(sizes) - 2) + ["clip"]:
            raise ValueError(f"init_policy {agent} = {name!r}: layers {spec['layer_sizes']} ({spec['activations']}) "
                             f"are not this run's {sizes} (tanh, clipped output): set [model] hidden to match")
        if (spec.get("features") or None) != (feature_spec or None):
            raise ValueError(f"init_policy {agent} = {name!r}: its observation features "
                             f"{(spec.get('features') or {}).get('name')!r} are not this run's "
                             f"{(feature_spec or {}).get('name')!r} ([env] observation_features)")
        switch = (spec.get("exploration") or {}).get("tool_head") == "switch" or 3 in spec.get("switch_dimensions", ())
        if switch != (config.tool_head == "switch"):
            raise ValueError(f"init_policy {agent} = {name!r}: its tool is {'a switch' if switch else 'Gaussian'}, "
                             f"this run's tool_head is {config.tool_head!r}")
        with torch.no_grad():
            for index, module in enumerate(linears):
                weight, bias = (torch.tensor(np.array(value), dtype=module.weight.dtype)
                                for value in policy.weights[index])
                if index == len(linears) - 1 and switch:  # the export scaled the logit into a sign
                    weight[-1] /= SWITCH_EXPORT_GAIN
                    bias[-1] /= SWITCH_EXPORT_GAIN
                module.weight.copy_(weight)
                module.bias.copy_(bias)
    return summary
