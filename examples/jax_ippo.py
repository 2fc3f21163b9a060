"""IPPO on ``suction_debris_v8.jax_env`` in one compiled function, read top to bottom (PureJaxRL's way): collect with
``lax.scan`` over ``jit(vmap(env.step))``, advantages by GAE, a clipped PPO update per agent. Each agent has its own
Gaussian actor and critic on its own observation (independent PPO).

    python examples/jax_ippo.py --worlds 512 --updates 200      # pip install "dvrl-marl[jax]"

A short run shows the loop, not a trained team: the scene's sparse reward needs the configuration of record's
shaping and curriculum (``dvrl-marl train suction_debris_mappo_large_batch --trainer jax``) to learn.
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import optax

from dvrl_marl.envs import suction_debris_v8


def mlp(key, sizes):
    keys = jax.random.split(key, len(sizes) - 1)
    return [(jax.random.normal(k, (a, b)) * jnp.sqrt(1.0 / a), jnp.zeros(b)) for k, a, b in zip(keys, sizes, sizes[1:])]


def forward(layers, x):
    for weight, bias in layers[:-1]:
        x = jnp.tanh(x @ weight + bias)
    weight, bias = layers[-1]
    return x @ weight + bias


def make_train(worlds: int, rollout: int, updates: int, seed: int, **env_options):
    env = suction_debris_v8.jax_env(**env_options)
    agents, obs_dim = env.agents, env.observation_space(env.agents[0]).shape[0]
    step, reset = jax.vmap(env.step), jax.vmap(env.reset)
    optimiser = optax.chain(optax.clip_by_global_norm(0.5), optax.adam(3e-4))

    def init(key):
        keys = jax.random.split(key, 2 * len(agents))
        return {agent: {"actor": mlp(keys[2 * i], [obs_dim, 64, 64, 4]), "critic": mlp(keys[2 * i + 1], [obs_dim, 64, 64, 1]),
                        "log_std": jnp.full(4, -0.5)} for i, agent in enumerate(agents)}

    def log_prob(params, obs, action):
        mean, log_std = forward(params["actor"], obs), params["log_std"]
        return (-0.5 * ((action - mean) / jnp.exp(log_std)) ** 2 - log_std - 0.5 * jnp.log(2 * jnp.pi)).sum(-1)

    def loss(params, batch):  # one agent's clipped PPO loss
        ratio = jnp.exp(log_prob(params, batch["obs"], batch["action"]) - batch["log_prob"])
        advantage = (batch["advantage"] - batch["advantage"].mean()) / (batch["advantage"].std() + 1e-8)
        policy = -jnp.minimum(ratio * advantage, jnp.clip(ratio, 0.8, 1.2) * advantage).mean()
        value = ((forward(params["critic"], batch["obs"])[..., 0] - batch["return"]) ** 2).mean()
        return policy + 0.5 * value

    def gae(rewards, values, dones, last_value, gamma=0.99, lam=0.95):
        def back(carry, x):
            advantage, next_value = carry
            reward, value, done = x
            delta = reward + gamma * next_value * (1 - done) - value
            advantage = delta + gamma * lam * (1 - done) * advantage
            return (advantage, value), advantage
        _, advantages = jax.lax.scan(back, (jnp.zeros_like(last_value), last_value), (rewards, values, dones), reverse=True)
        return advantages

    def update(carry, _):
        params, opt_state, obs, states, key = carry

        def collect(carry, _):  # one step of every world
            obs, states, key = carry
            key, *keys = jax.random.split(key, len(agents) + 1)
            actions = {agent: forward(params[agent]["actor"], obs[agent])
                       + jnp.exp(params[agent]["log_std"]) * jax.random.normal(k, (worlds, 4)) for agent, k in zip(agents, keys)}
            next_obs, states, rewards, dones, _ = step(jax.random.split(key, worlds), states, actions)
            record = {agent: {"obs": obs[agent], "action": actions[agent], "reward": rewards[agent],
                              "done": dones["__all__"].astype(jnp.float64),
                              "log_prob": log_prob(params[agent], obs[agent], actions[agent]),
                              "value": forward(params[agent]["critic"], obs[agent])[..., 0]} for agent in agents}
            return (next_obs, states, key), record

        (obs, states, key), trace = jax.lax.scan(collect, (obs, states, key), None, rollout)
        batches = {}
        for agent in agents:  # advantages and returns, then one batch of every world's steps
            t = trace[agent]
            advantages = gae(t["reward"], t["value"], t["done"], forward(params[agent]["critic"], obs[agent])[..., 0])
            batches[agent] = {"obs": t["obs"].reshape(-1, obs_dim), "action": t["action"].reshape(-1, 4),
                              "log_prob": t["log_prob"].reshape(-1), "advantage": advantages.reshape(-1),
                              "return": (advantages + t["value"]).reshape(-1)}
        grads = {agent: jax.grad(loss)(params[agent], batches[agent]) for agent in agents}
        changes, opt_state = optimiser.update(grads, opt_state, params)
        params = optax.apply_updates(params, changes)
        mean_reward = jnp.mean(jnp.stack([trace[agent]["reward"].mean() for agent in agents]))
        return (params, opt_state, obs, states, key), mean_reward

    @jax.jit
    def train():
        key = jax.random.key(seed)
        key, init_key, reset_key = jax.random.split(key, 3)
        params = init(init_key)
        obs, states = reset(jax.random.split(reset_key, worlds))
        carry, rewards = jax.lax.scan(update, (params, optimiser.init(params), obs, states, key), None, updates)
        return carry[0], rewards

    return train


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    parser.add_argument("--worlds", type=int, default=512)
    parser.add_argument("--rollout", type=int, default=32)
    parser.add_argument("--updates", type=int, default=200)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--preset", default="benchmark")
    args = parser.parse_args(argv)
    params, rewards = make_train(args.worlds, args.rollout, args.updates, args.seed, preset=args.preset)()
    print(f"{args.updates} updates of {args.worlds} worlds x {args.rollout} steps; mean reward per step, first "
          f"{float(rewards[0]):.4f}, last {float(rewards[-1]):.4f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
