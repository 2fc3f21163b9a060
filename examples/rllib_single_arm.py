"""PPO on a single-arm env (Reach, Pick) with RLlib (new API stack), each env runner stepping a vector of envs.

    pip install "dvrl-marl[rllib]"
    python examples/rllib_single_arm.py --iterations 30                          # PSMReachDense-v1, 8 envs a runner
    python examples/rllib_single_arm.py --env dvrl_marl/PSMPickDense-v1 --env-runners 2 --envs-per-runner 16
    python examples/rllib_single_arm.py --iterations 1 --video reach.mp4         # and a video of one episode

The env is registered with RLlib with its ``Dict`` observation flattened (``dvrl_marl.integrations.rllib``;
RLlib's default models read flat vectors); RLlib vectorises it with Gymnasium's vector API
(``num_envs_per_env_runner``). The dense variants suit PPO; the sparse ones (the paper's) want HER, which RLlib does
not have: for those, Stable-Baselines3 + HER (``dvrl-marl train baselines/configs/reach_lnd_ddpg_her.toml``).
"""

from __future__ import annotations

import argparse
import json


def build_config(env_id: str = "dvrl_marl/PSMReachDense-v1", *, env_runners: int = 0, envs_per_runner: int = 8,
                 train_batch: int = 4000, minibatch: int = 500, epochs: int = 10, seed: int = 0):
    """The PPOConfig of this recipe."""
    from ray.rllib.algorithms.ppo import PPOConfig

    from dvrl_marl.integrations.rllib import register_single_arm

    name = register_single_arm(env_id)
    return (PPOConfig()
            .environment(name)
            .env_runners(num_env_runners=env_runners, num_envs_per_env_runner=envs_per_runner)
            .training(train_batch_size=train_batch, minibatch_size=minibatch, num_epochs=epochs, gamma=0.95, lr=3e-4)
            .debugging(seed=seed))


def evaluate(algo, env_id: str, episodes: int = 20, seed: int = 1_000_000, video: str | None = None) -> dict:
    """Success rate of the trained policy (the Gaussian's mean) over seeded episodes; the first one filmed."""
    import gymnasium as gym
    import numpy as np
    import torch

    import dvrl_marl  # noqa: F401  (registration)

    module = algo.get_module()
    successes, frames = 0, []
    for episode in range(episodes):
        env = gym.wrappers.FlattenObservation(
            gym.make(env_id, render_mode="rgb_array" if video and episode == 0 else None))
        observation, _ = env.reset(seed=seed + episode)
        done, info = False, {}
        while not done:
            output = module.forward_inference({"obs": torch.as_tensor(observation[None], dtype=torch.float32)})
            size = env.action_space.shape[0]
            action = np.clip(output["action_dist_inputs"][0, :size].detach().numpy(), -1.0, 1.0)
            observation, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            if video and episode == 0:
                frames.append(env.render())
        successes += bool(info.get("is_success"))
        env.close()
    if video:
        import imageio.v3 as iio

        iio.imwrite(video, np.stack(frames), fps=10)
    return {"episodes": episodes, "success_rate": successes / episodes}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # --help shows defaults
    parser.add_argument("--env", default="dvrl_marl/PSMReachDense-v1", help="a single-arm env id")
    parser.add_argument("--iterations", type=int, default=30, help="training iterations")
    parser.add_argument("--env-runners", type=int, default=0, help="RLlib env runners (0: sample in the driver)")
    parser.add_argument("--envs-per-runner", type=int, default=8, help="envs each runner steps as one vector")
    parser.add_argument("--train-batch", type=int, default=4000, help="env steps per iteration")
    parser.add_argument("--minibatch", type=int, default=500, help="PPO minibatch size")
    parser.add_argument("--epochs", type=int, default=10, help="PPO epochs per iteration")
    parser.add_argument("--episodes", type=int, default=20, help="evaluation episodes at the end")
    parser.add_argument("--address", help="Ray cluster address (none: a Ray instance of this process)")
    parser.add_argument("--video", help="film the first evaluation episode to this MP4")
    parser.add_argument("--seed", type=int, default=0, help="seed of the run")
    args = parser.parse_args(argv)

    from dvrl_marl.integrations.rllib import init_ray, train

    init_ray(args.address)
    algo = build_config(args.env, env_runners=args.env_runners, envs_per_runner=args.envs_per_runner,
                        train_batch=args.train_batch, minibatch=args.minibatch, epochs=args.epochs,
                        seed=args.seed).build_algo()
    result = train(algo, args.iterations, log=lambda line: print(line, flush=True))
    summary = {"env": args.env, "iterations": args.iterations,
               "env_steps": int(result.get("num_env_steps_sampled_lifetime", 0)),
               **evaluate(algo, args.env, args.episodes, video=args.video)}
    print(json.dumps(summary))
    algo.stop()
    return summary


if __name__ == "__main__":
    main()
