"""Multi-agent PPO on the collaborative env with RLlib (new API stack): one policy per arm, or one shared.

    pip install "dvrl-marl[rllib]"
    python examples/rllib_suction_debris.py --iterations 50              # a policy per arm, on this machine
    python examples/rllib_suction_debris.py --shared --env-runners 2     # one policy for both arms, 2 env runners
    python examples/rllib_suction_debris.py --address auto               # on the Ray cluster this machine joined
    python examples/rllib_suction_debris.py --iterations 1 --video rllib.mp4   # and a video of the learned team
    python examples/rllib_suction_debris.py --guided --level easy --iterations 120 --env-runners 2 \
        --envs-per-runner 8 --test-episodes 100   # the env's learning options: learns the easy level (20 minutes)

``--guided`` turns on the env's options that made the task learnable, the benchmark's (``preset="benchmark"``:
``reward_type="guided"``, the observation features the learned seats read, ``dvrl_marl.suction_debris.guidance``; the slow
tool ``tool_speed=0.1``, the jaw a switch that holds a pin until the hand-off, ``dvrl_marl.core.tools``), and the
PPO settings BenchMARL's MAPPO learns it with (:func:`benchmark_ppo_settings`); ``--level`` its start level
(``easy`` ... ``default``, ``dvrl_marl.suction_debris.start_levels``); the trained team is then tested on ``--test-episodes``
held-out episodes at that level, by the mean action.

The env is registered with RLlib as ``dvrl_marl/suction_debris-v8`` (``dvrl_marl.integrations.rllib``; its
wrapper renders, RLlib's own does not) and steps the PettingZoo parallel env unmodified: on 2 cores about 300
steps/s with RLlib's defaults, 750-900 with ``--env-runners 2 --envs-per-runner 8``. For speed, the project's own
trainer (``dvrl-marl train``, MAPPO on the batched env, optionally on Ray) is the way; this recipe is for people whose
stack is RLlib.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path


#: ``--guided``: the benchmark's env options (its task files, dvrl_marl/integrations/benchmarl_tasks/, but for the
#: start level): ``preset="benchmark"``, the guided reward and features of the configuration of record, and the slow
#: tool and the jaw as a switch that holds a pin until the hand-off (RLlib's PPO explores the jaw and the valve with a
#: Gaussian, which an instant tool reads as a threshold and a held pin's jaw as a chance to drop it:
#: dvrl_marl.core.tools).
GUIDED = {"preset": "benchmark"}


def env_options(*, guided: bool = False, level: str = "default", max_cycles: int = 1500) -> dict:
    """The env's keyword arguments for this recipe (with ``guided``, the benchmark's task file of ``level``: at the
    easy level its episodes keep the task's time limit, ``easy_episode_steps=0``, as the benchmark's)."""
    easy = {"easy_episode_steps": 0} if guided and level == "easy" else {}
    return {**(GUIDED if guided else {"reward_type": "dense"}), "start_level": level, **easy, "max_cycles": max_cycles}


def benchmark_ppo_settings() -> dict:
    """``--guided``: the benchmark's PPO settings in RLlib's terms, read from the shipped BenchMARL files
    (``dvrl_marl/integrations/benchmarl_tasks/``: ``experiment.yaml``'s learning rate, gradient clip, batch, minibatch
    and epochs, ``mappo.yaml``'s GAE lambda and entropy bonus, ``mlp.yaml``'s width), so that RLlib's PPO learns with
    what BenchMARL's MAPPO learnt with. Where RLlib's defaults differ from BenchMARL's PPO: its policy and value share
    their layers (the value's loss then dominates a policy whose returns run to 20 per episode), its lambda is 1.0, it
    adds a KL penalty and clips the value loss at 10, and its PPO clip is 0.3; here they are BenchMARL's (separate
    networks, lambda 0.95, no KL term, no value-loss clip, clip 0.2)."""
    import yaml

    import dvrl_marl

    tasks = Path(dvrl_marl.__file__).parent / "integrations" / "benchmarl_tasks"
    experiment, mappo, mlp = (yaml.safe_load((tasks / f"{name}.yaml").read_text())
                              for name in ("experiment", "mappo", "mlp"))
    return {"train_batch": experiment["on_policy_collected_frames_per_batch"],
            "minibatch": experiment["on_policy_minibatch_size"], "epochs": experiment["on_policy_n_minibatch_iters"],
            "lr": experiment["lr"], "grad_clip": experiment["clip_grad_val"], "gamma": experiment["gamma"],
            "lambda_": mappo["lmbda"], "entropy_coeff": mappo["entropy_coef"], "hidden": list(mlp["num_cells"]),
            "clip_param": 0.2, "use_kl_loss": False, "vf_clip_param": float("inf"), "vf_share_layers": False}


#: The recipe's PPO settings without ``--guided`` (RLlib's own defaults but for these).
PLAIN_PPO = {"train_batch": 4000, "minibatch": 500, "epochs": 5, "lr": 3e-4, "gamma": 0.99}


def build_config(*, shared: bool = False, env_runners: int = 0, envs_per_runner: int = 1, max_cycles: int = 1500,
                 reward_type: str = "dense", seed: int = 0, options: dict | None = None, ppo: dict | None = None):
    """The PPOConfig of this recipe (``options``: the env's keyword arguments, else ``reward_type`` and
    ``max_cycles``; ``ppo``: PPO settings, :data:`PLAIN_PPO`'s keys or :func:`benchmark_ppo_settings`')."""
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.rllib.core.rl_module.default_model_config import DefaultModelConfig

    from dvrl_marl.integrations.rllib import policy_per_agent, register_suction_debris, shared_policy

    ppo = dict(ppo or PLAIN_PPO)
    hidden, share = ppo.pop("hidden", None), ppo.pop("vf_share_layers", None)
    batch, minibatch, epochs = ppo.pop("train_batch"), ppo.pop("minibatch"), ppo.pop("epochs")
    model = {**({"fcnet_hiddens": hidden} if hidden else {}), **({"vf_share_layers": share} if share is not None else {})}
    name = register_suction_debris()
    config = (PPOConfig()
              .environment(name, env_config=options or {"reward_type": reward_type, "max_cycles": max_cycles})
              .multi_agent(**(shared_policy() if shared else policy_per_agent()))
              .env_runners(num_env_runners=env_runners, num_envs_per_env_runner=envs_per_runner)
              .training(train_batch_size=batch, minibatch_size=minibatch, num_epochs=epochs, **ppo)
              .debugging(seed=seed))
    if model:
        config = config.rl_module(model_config=DefaultModelConfig(**model))
    return config


def learned_team(algo, *, shared: bool, noise_seed=None) -> dict:
    """The trained team as seats: per arm, a callable from observations ``(N, obs_dim)`` to actions ``(N, 4)``, the
    distributions' means (what drives a robot), or with ``noise_seed(agent)`` a seed per arm, actions sampled from them
    as in training."""
    import numpy as np
    import torch

    from dvrl_marl.integrations.rllib import AGENTS

    def seat(agent):
        module = algo.get_module("shared" if shared else agent)
        rng = np.random.default_rng(noise_seed(agent)) if noise_seed else None

        def act(observations):
            with torch.no_grad():
                output = module.forward_inference({"obs": torch.as_tensor(np.asarray(observations),
                                                                          dtype=torch.float32)})
            mean, log_std = np.split(output["action_dist_inputs"].numpy(), 2, axis=-1)  # RLlib's diagonal Gaussian
            if rng is not None:
                mean = mean + np.exp(log_std) * rng.standard_normal(mean.shape)
            return np.clip(mean, -1.0, 1.0)

        return act

    return {agent: seat(agent) for agent in AGENTS}


def score_team(algo, *, shared: bool, episodes: int, options: dict, seed: int | None = None,
              sampled: bool = False) -> dict:
    """``episodes`` held-out episodes of the trained team at once (``dvrl_marl.training.teams``: the test seeds every
    benchmark row is scored on, batched), by the mean action or ``sampled``; ``options``: the env's keyword arguments
    it trained with (the observation features among them)."""
    from dvrl_marl.training import teams

    seed = teams.EVAL_SEED if seed is None else seed
    noise = (lambda agent: teams.noise_seed(agent, seed)) if sampled else None
    return teams.evaluate_team_batched(learned_team(algo, shared=shared, noise_seed=noise), episodes, seed=seed,
                                       **options)


def roll_out(algo, *, shared: bool, seed: int = 900_000_000, max_cycles: int = 1500, video: str | None = None,
             options: dict | None = None) -> dict:
    """One episode of the trained team (deterministic actions: the distributions' means), optionally filmed;
    ``options``: the env's keyword arguments it trained with (the observation features among them)."""
    import numpy as np

    from dvrl_marl.envs import suction_debris_v8

    team = learned_team(algo, shared=shared)
    options = {k: v for k, v in (options or {"max_cycles": max_cycles}).items() if k != "reward_type"}
    env = suction_debris_v8.parallel_env(render_mode="rgb_array" if video else None, **options)
    observations, _ = env.reset(seed=seed)
    frames, steps, info = [], 0, {}
    while env.agents:
        actions = {agent: team[agent](observation[None])[0] for agent, observation in observations.items()}
        observations, _, _, _, infos = env.step(actions)
        info = next(iter(infos.values()))
        steps += 1
        if video and steps % 2 == 0:
            frames.append(env.render())
    env.close()
    if video:
        import imageio.v3 as iio

        iio.imwrite(video, np.stack(frames), fps=25)
    return {"steps": steps, "success": bool(info.get("is_success")), "blood_left_ml": info.get("blood_remaining")}


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                     formatter_class=argparse.ArgumentDefaultsHelpFormatter)  # --help shows defaults
    parser.add_argument("--iterations", type=int, default=50, help="training iterations")
    parser.add_argument("--shared", action="store_true", help="one policy for both arms")
    parser.add_argument("--env-runners", type=int, default=0, help="RLlib env runners (0: sample in the driver)")
    parser.add_argument("--envs-per-runner", type=int, default=1,
                        help="envs each env runner steps together (RLlib batches their policy calls)")
    parser.add_argument("--train-batch", type=int, help="env steps per iteration (default: 4000; --guided: 8192)")
    parser.add_argument("--minibatch", type=int, help="PPO minibatch size (default: 500; --guided: 2048)")
    parser.add_argument("--epochs", type=int, help="PPO epochs per iteration (default: 5)")
    parser.add_argument("--max-cycles", type=int, default=1500, help="steps before an episode is cut")
    parser.add_argument("--address", help="Ray cluster address (none: a Ray instance of this process)")
    parser.add_argument("--checkpoint", help="save the algorithm here at the end")
    parser.add_argument("--video", help="film one episode of the trained team to this MP4")
    parser.add_argument("--seed", type=int, default=0, help="seed of the run")
    parser.add_argument("--guided", action="store_true", help="the env's guided reward and observation features")
    parser.add_argument("--level", default="default", choices=("easy", "default"), help="the env's start level")
    parser.add_argument("--test-episodes", type=int, default=1, help="held-out episodes the trained team plays")
    args = parser.parse_args(argv)
    if args.iterations < 0 or args.test_episodes < 1 or args.envs_per_runner < 1:
        parser.error("--iterations must be >= 0, --test-episodes and --envs-per-runner >= 1")
    sizes = {"train_batch": args.train_batch, "minibatch": args.minibatch, "epochs": args.epochs}
    if any(value is not None and value < 1 for value in sizes.values()):
        parser.error("--train-batch, --minibatch and --epochs must be >= 1")
    ppo = {**(benchmark_ppo_settings() if args.guided else PLAIN_PPO),
           **{key: value for key, value in sizes.items() if value is not None}}

    from dvrl_marl.integrations.rllib import init_ray, train

    init_ray(args.address)
    options = env_options(guided=args.guided, level=args.level, max_cycles=args.max_cycles)
    config = build_config(shared=args.shared, env_runners=args.env_runners, envs_per_runner=args.envs_per_runner,
                          max_cycles=args.max_cycles, seed=args.seed, options=options, ppo=ppo)
    algo = config.build_algo()
    result = train(algo, args.iterations, log=lambda line: print(line, flush=True))
    summary = {"iterations": args.iterations,
               "env_steps": int(result.get("num_env_steps_sampled_lifetime", 0)),
               "policies": sorted(algo.config.policies)}
    if args.checkpoint:
        summary["checkpoint"] = str(algo.save(str(Path(args.checkpoint).resolve())).checkpoint.path)
    summary["episode"] = roll_out(algo, shared=args.shared, max_cycles=args.max_cycles, video=args.video,
                                  options=options)
    test = score_team(algo, shared=args.shared, episodes=args.test_episodes, options=options)
    summary["test"] = {"episodes": args.test_episodes, "level": args.level, "guided": args.guided,
                       "success_rate": test["success_rate"]}
    print(json.dumps(summary))
    algo.stop()
    return summary


if __name__ == "__main__":
    main()
