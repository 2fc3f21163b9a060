"""The JAX trainer's algorithm written in torch (the oracle ``test_jax_mappo.py`` holds it to): the same networks
(:func:`dvrl_marl.training.models.build_models`), the clipped objective, GAE and the reward scaling, computed
eagerly on the same weights and data. Test code: no trainer runs it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from dvrl_marl.suction_debris.layout import ACTION_WIDTH
from dvrl_marl.training.mappo_config import MappoConfig
from dvrl_marl.training.models import actor_arrays, bounds_loss, build_models, switch_gaussian


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


def build_learner(config: MappoConfig, env, device) -> dict:
    """The torch models of ``config`` for ``env`` on ``device``: the actors' head, the critic's values, the actors'
    network and normalisers, the log standard deviations, the parameters and the distribution class."""
    agents = list(env.possible_agents)
    obs_dim, state_dim = env.observation_space(agents[0]).shape[0], env.state_space.shape[0]
    actor, critic, actor_net, norms = build_models(config, agents, obs_dim, state_dim, ACTION_WIDTH,
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


def advantages(rollout: Rollout, gamma: float, lam: float):
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


def update(models, optimiser, rollout: Rollout, advantage, returns, config: MappoConfig):
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


class ReturnScale:
    """Rewards divided by the running standard deviation of the discounted return, per agent (reward scaling)."""

    def __init__(self, agents: int, gamma: float, device):
        self.gamma = gamma
        self.mean = torch.zeros(agents, dtype=torch.float64, device=device)
        self.var = torch.ones(agents, dtype=torch.float64, device=device)
        self.count = 1e-4
        self.discounted = None

    def update(self, rewards, done):
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


def load_into_torch(params: dict, norms: dict, models: dict, *, critic: bool = False) -> None:
    """Copy the actors, their log standard deviations and the actors' normaliser (``critic``: the critic and its
    normalisers too) into the torch ``models`` of :func:`build_learner` (the torch learner on the same weights)."""
    def copy_net(net, layers):
        for linear, layer in zip([m for m in net if hasattr(m, "weight")], layers):
            linear.weight.copy_(torch.from_numpy(np.array(layer["weight"], dtype=np.float32)))
            linear.bias.copy_(torch.from_numpy(np.array(layer["bias"], dtype=np.float32)))

    def copy_norm(module, norm):
        for name in ("mean", "var", "count"):
            getattr(module, name).copy_(torch.as_tensor(np.array(norm[name])))

    actor_net = models["actor_net"]
    with torch.no_grad():
        for net, layers in zip(actor_net.nets, params["actors"]):
            copy_net(net, layers)
        models["log_std"].copy_(torch.from_numpy(np.array(params["log_std"], dtype=np.float32)))
        copy_norm(actor_net.norm, norms["observation"])
        if not critic:
            return
        critic_net = models["critic_net"]
        if hasattr(critic_net, "net"):  # MAPPO's critic on the state alone
            copy_net(critic_net.net, params["critic"])
        else:  # one network per agent: on the state and the observation, or (IPPO) the observation
            per_agent = getattr(critic_net, "observation", critic_net)
            for net, layers in zip(per_agent.nets, params["critic"]):
                copy_net(net, layers)
            copy_norm(per_agent.norm, norms["critic_observation"])
        if "state" in norms:
            copy_norm(critic_net.norm, norms["state"])
