"""Reproducible training runs from a configuration file, with evaluation, CSV logs, checkpoints and resume.

A configuration (``baselines/configs/*.toml``, one per environment x algorithm, in the spirit of
rl-baselines3-zoo's hyperparameter files)::

    [run]
    env_id = "dvrl_marl/PSMReach-v1"
    algorithm = "ddpg"          # ddpg | ddpg_bc | td3 | sac | tqc (off-policy, HER) | ppo (on-policy, no HER)
    total_timesteps = 20000
    eval_every = 2000           # environment steps between evaluations
    eval_episodes = 50
    demonstrations = 0          # expert episodes to seed the replay buffer (and, for ddpg_bc, the BC loss)
    action_noise = 0.2          # Gaussian exploration noise (DDPG/TD3)
    num_envs = 1                # ppo: worlds stepped together (the batched env)
    normalize_reward = false    # ppo: SB3's VecNormalize on the rewards (observations stay as the env gives them)
    observation_features = ""   # features the policy computes from its observation ("psm_pick_zoom" for Pick)
    [env]                       # keyword arguments of gym.make: the task trained and evaluated
    [train_env]                 # keyword arguments of the training env only (the learning options: start levels,
                                # the jaw's rule, the guided reward); evaluations run the task of [env] alone
    [her]                       # HerReplayBuffer keyword arguments
    [algorithm]                 # keyword arguments of the SB3 class
    [policy]                    # policy_kwargs

A run folder holds ``config.toml`` (what ran), ``progress.csv`` (one row per evaluation: timesteps, success rate,
mean final distance, wall time), SB3's ``train_log.csv``, ``checkpoint.zip`` + ``replay_buffer.pkl`` (PPO:
``vecnormalize.pkl`` when it normalises rewards; ``resume`` continues from them), ``final_model.zip`` and
``best_model.zip`` (the best evaluation) and ``demonstrations.npz`` when demonstrations were used.

A policy trained with ``jaw_command = "switch"`` in ``[train_env]`` is evaluated, and exported, sending its jaw
command as -1 or 1 by its sign (the switch's rule), so that the registered env's proportional jaw does what the
switch did.
"""

from __future__ import annotations

import csv
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import gymnasium as gym
import numpy as np

import dvrl_marl  # noqa: F401  (registers the environments)
from dvrl_marl.schemas import STRICT, Flag, NonNegative, NonNegativeInt, PositiveInt, Text
from dvrl_marl.training.demonstrations import (
    generate_demonstrations,
    observation_batch,
    save_demonstrations,
)
from dvrl_marl.training import trainers

__all__ = ["RunConfig", "load_config", "train", "evaluate_policy", "ALGORITHMS"]


def sb3_algorithms() -> dict:
    from stable_baselines3 import DDPG, PPO, SAC, TD3

    from dvrl_marl.training.bc import DDPGBC

    table = {"ddpg": DDPG, "ddpg_bc": DDPGBC, "td3": TD3, "sac": SAC, "ppo": PPO}
    try:
        from sb3_contrib import TQC

        table["tqc"] = TQC
    except ImportError:  # sb3-contrib is optional
        pass
    return table


ALGORITHMS = ("ddpg", "ddpg_bc", "td3", "sac", "tqc", "ppo")
#: The on-policy ones: a batched training env of ``num_envs`` worlds, no replay buffer, no HER.
ON_POLICY = ("ppo",)


@dataclass
class RunConfig:
    """A goal-env run's settings; the annotations are the configuration's schema (pydantic checks every value)."""

    __pydantic_config__ = STRICT

    name: Text
    env_id: Text
    algorithm: Literal[ALGORITHMS]
    total_timesteps: PositiveInt
    eval_every: PositiveInt = 2000
    eval_episodes: PositiveInt = 50
    demonstrations: NonNegativeInt = 0
    action_noise: NonNegative = 0.0
    num_envs: PositiveInt = 1
    normalize_reward: Flag = False
    observation_features: Literal["", "psm_pick_zoom"] = ""
    env: dict[Text, Any] = field(default_factory=dict)  # gym.make keyword arguments (the env checks them)
    train_env: dict[Text, Any] = field(default_factory=dict)  # the training env's only (learning options)
    her: dict[Text, Any] = field(default_factory=dict)  # HerReplayBuffer's (SB3 checks them)
    algorithm_kwargs: dict[Text, Any] = field(default_factory=dict)
    policy: dict[Text, Any] = field(default_factory=dict)
    source: Text = ""

    def validate(self) -> "RunConfig":
        if self.env_id not in gym.registry:
            raise ValueError(f"config {self.name}: unknown env_id {self.env_id!r}")
        on_policy = self.algorithm in ON_POLICY
        if on_policy and (self.her or self.demonstrations or self.action_noise):
            raise ValueError(f"config {self.name}: {self.algorithm} takes no [her], demonstrations or action_noise "
                             "(an on-policy learner explores by its own Gaussian and keeps no replay buffer)")
        if not on_policy and (self.num_envs != 1 or self.normalize_reward):
            raise ValueError(f"config {self.name}: num_envs and normalize_reward are for ppo; {self.algorithm} "
                             "learns from one env through HER's replay buffer")
        if self.observation_features == "psm_pick_zoom" and "Pick" not in self.env_id:
            raise ValueError(f"config {self.name}: observation_features 'psm_pick_zoom' reads PSM Pick's observation; "
                             f"{self.env_id} is not a Pick env")
        overlap = sorted(set(self.env) & set(self.train_env))
        if overlap:
            raise ValueError(f"config {self.name}: {overlap} in both [env] and [train_env]; a key lives in one "
                             "([env]: the task trained and evaluated; [train_env]: the training env's only)")
        return self

    def feature_spec(self) -> dict | None:
        """The spec of the features the policy computes (what its ``policy.json`` records), or None."""
        if not self.observation_features:
            return None
        from dvrl_marl.suction_debris import features

        return features.pick_spec(gym.make(self.env_id, **self.env))

    def policy_kwargs(self) -> dict:
        """[policy], with the features extractor that appends ``observation_features`` when one is named."""
        spec = self.feature_spec()
        if spec is None:
            return dict(self.policy)
        from dvrl_marl.training.sb3_features import ObservationFeatures

        return {**self.policy, "features_extractor_class": ObservationFeatures,
                "features_extractor_kwargs": {"spec": spec}}

    @property
    def switch_dimensions(self) -> list[int]:
        """Action dimensions learnt as a switch (the jaw, with ``jaw_command = "switch"`` in [train_env])."""
        return [3] if self.train_env.get("jaw_command") == "switch" else []

    def export_metadata(self) -> dict:
        """What an exported policy of this run records so that it acts as evaluated: its switch dimensions and the
        features it computes (each only when there are any)."""
        out = {"switch_dimensions": self.switch_dimensions, "features": self.feature_spec()}
        return {key: value for key, value in out.items() if value}


_RUN_KEYS = ("env_id", "algorithm", "total_timesteps", "eval_every", "eval_episodes", "demonstrations", "action_noise",
             "num_envs", "normalize_reward", "observation_features")
_TABLES = ("run", "env", "train_env", "her", "algorithm", "policy")


def load_config(path) -> RunConfig:
    """Read a run configuration from a TOML file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no configuration file {path}")
    from dvrl_marl.files import extended_chain, read_extended_toml

    # A variant of another configuration (e.g. the same run on a newer env version) holds what differs:
    # [run] extends, followed key by key; the run folder keeps every file of the chain.
    chain = extended_chain(path)
    text = "".join((f"\n# --- {link.name} ---\n" if index else "") + link.read_text()
                   for index, link in enumerate(chain))
    table = read_extended_toml(path)
    run = dict(table.get("run", {}))
    unknown = [name for name in table if name not in _TABLES or not isinstance(table[name], dict)]
    if unknown:
        raise ValueError(f"{path}: unknown table [{unknown[0]}] (known: {', '.join(_TABLES)})")
    for key in run:
        if key not in _RUN_KEYS:
            raise ValueError(f"{path}: [run] {key}: unknown key (a typo?); known: {', '.join(_RUN_KEYS)}")
    from dvrl_marl.schemas import validated

    values = {"name": path.stem, "env": table.get("env", {}), "train_env": table.get("train_env", {}),
              "her": table.get("her", {}), "algorithm_kwargs": table.get("algorithm", {}),
              "policy": table.get("policy", {}), "source": text, **run}
    tables = {**{key: "run" for key in run}, "env": "env", "train_env": "train_env", "her": "her",
              "algorithm_kwargs": "algorithm", "policy": "policy"}
    return validated(RunConfig, values, str(path), tables=tables).validate()


def evaluate_policy(policy, env_id: str, episodes: int, seed: int = 1_000_000, env_kwargs: dict | None = None,
                    video_path=None) -> dict:
    """Success rate and mean final distance over seeded episodes; ``policy(observation_dict) -> action``."""
    render_mode = "rgb_array" if video_path else None
    env = gym.make(env_id, render_mode=render_mode, **(env_kwargs or {}))
    successes, distances, frames = 0, [], []
    for episode in range(episodes):
        obs, _ = env.reset(seed=seed + episode)
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(policy(obs))
            done = terminated or truncated
            if video_path and episode < 3:
                frames.append(env.render())
        successes += bool(info["is_success"])
        unwrapped = env.unwrapped
        distances.append(unwrapped.workspace_range * float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])))
    env.close()
    if video_path:
        from dvrl_marl.video import write_video

        write_video(video_path, frames, fps=env.metadata["render_fps"])
    return {"success_rate": successes / episodes, "mean_final_distance": float(np.mean(distances)),
            "episodes": episodes}


def _sb3_policy(model, switch_dimensions=()):
    """The model's deterministic action; ``switch_dimensions`` sent as -1 or 1 by their sign (as exported)."""
    switches = list(switch_dimensions)

    def act(observation):
        action, _ = model.predict(observation, deterministic=True)
        if switches:
            action = np.array(action)
            action[switches] = np.where(action[switches] > 0.0, 1.0, -1.0)
        return action

    return act


def _seed_buffer_with_demonstrations(model, demos: dict) -> None:
    observations = observation_batch(demos)
    next_observations = observation_batch(demos, "next_")
    episodes = demos["episode"]
    for i in range(len(episodes)):
        last = i + 1 == len(episodes) or episodes[i + 1] != episodes[i]
        model.replay_buffer.add(
            {k: v[i:i + 1] for k, v in observations.items()},
            {k: v[i:i + 1] for k, v in next_observations.items()},
            demos["action"][i:i + 1], np.array([demos["reward"][i]]), np.array([last]),
            [{"TimeLimit.truncated": bool(last)}],
        )


def _training_env(config: RunConfig, seed: int):
    """Off-policy: one env (SB3's Monitor around it). On-policy: ``num_envs`` worlds of the batched env, seeded
    ``seed``, their rewards normalised on request. Both with [env] and [train_env]."""
    if config.algorithm not in ON_POLICY:
        from stable_baselines3.common.monitor import Monitor

        return Monitor(gym.make(config.env_id, **config.env, **config.train_env))
    from dvrl_marl.integrations.sb3 import make_sb3_vec_env

    venv = make_sb3_vec_env(config.env_id, num_envs=config.num_envs, seed=seed, **config.env, **config.train_env)
    if config.normalize_reward:
        from stable_baselines3.common.vec_env import VecNormalize

        venv = VecNormalize(venv, norm_obs=False, norm_reward=True,
                            gamma=float(config.algorithm_kwargs.get("gamma", 0.99)))
    return venv


def _build_model(config: RunConfig, env, seed: int):
    from stable_baselines3 import HerReplayBuffer
    from stable_baselines3.common.noise import NormalActionNoise

    cls = sb3_algorithms().get(config.algorithm)
    if cls is None:
        raise ValueError(f"algorithm {config.algorithm!r} needs sb3-contrib (pip install sb3-contrib)")
    kwargs = dict(config.algorithm_kwargs)
    if config.algorithm in ON_POLICY:
        return cls("MultiInputPolicy", env, policy_kwargs=config.policy_kwargs(), seed=seed, verbose=0, **kwargs)
    if "train_freq" in kwargs and isinstance(kwargs["train_freq"], list):
        kwargs["train_freq"] = tuple(kwargs["train_freq"])
    if config.action_noise > 0:
        dim = env.action_space.shape[0]
        kwargs["action_noise"] = NormalActionNoise(np.zeros(dim), config.action_noise * np.ones(dim))
    return cls(
        "MultiInputPolicy", env, replay_buffer_class=HerReplayBuffer, replay_buffer_kwargs=dict(config.her),
        policy_kwargs=config.policy_kwargs(), seed=seed, verbose=0,
        **kwargs,
    )


def train(config: RunConfig, seed: int, out_dir, *, total_timesteps: int | None = None, progress: bool = True,
          resume: bool = False, tensorboard: bool = False) -> list[dict]:
    """Train ``config`` with ``seed`` into ``out_dir``; returns the evaluation history."""
    from dvrl_marl.training.bc import DDPGBC

    from stable_baselines3.common.callbacks import BaseCallback
    from stable_baselines3.common.logger import configure

    formats = log_formats(tensorboard)  # before any work: a missing package fails at once
    out_dir = Path(out_dir)
    on_policy = config.algorithm in ON_POLICY
    checkpoint, buffer_path = out_dir / "checkpoint.zip", out_dir / "replay_buffer.pkl"
    # What a resume needs beside the model: the replay buffer (off-policy), the reward statistics (PPO's, if kept)
    state_path = (out_dir / "vecnormalize.pkl" if config.normalize_reward else None) if on_policy else buffer_path
    progress_csv = out_dir / "progress.csv"
    if resume and not (checkpoint.is_file() and (state_path is None or state_path.is_file())):
        raise ValueError(f"{out_dir}: no checkpoint.zip (and {state_path.name if state_path else 'nothing else'}) to "
                         "resume from (a mistyped --out, or a run that never reached its first evaluation); nothing "
                         "was started or overwritten")
    if not resume and (checkpoint.exists() or progress_csv.exists()):
        raise ValueError(f"{out_dir} holds a run already (checkpoint.zip / progress.csv): --resume continues it; "
                         "another --out starts a new one. Nothing was overwritten.")
    out_dir.mkdir(parents=True, exist_ok=True)
    total = int(total_timesteps or config.total_timesteps)
    env = _training_env(config, seed)
    history: list[dict] = []
    if resume:
        if on_policy and config.normalize_reward:
            from stable_baselines3.common.vec_env import VecNormalize

            env = VecNormalize.load(str(state_path), env.venv)
        model = sb3_algorithms()[config.algorithm].load(checkpoint, env=env)
        if not on_policy:
            model.load_replay_buffer(buffer_path)
        if progress_csv.is_file():
            with progress_csv.open() as handle:
                history = [{k: float(v) for k, v in row.items()} for row in csv.DictReader(handle)]
        if isinstance(model, DDPGBC) and (out_dir / "demonstrations.npz").is_file():
            from dvrl_marl.training.demonstrations import load_demonstrations

            demos = load_demonstrations(out_dir / "demonstrations.npz")
            model.set_demonstrations(observation_batch(demos), demos["action"])
    else:
        (out_dir / "config.toml").write_text(config.source or "")
        model = _build_model(config, env, seed)
        if config.demonstrations:
            demos = generate_demonstrations(config.env_id, config.demonstrations, seed=10_000 * (seed + 1),
                                            env_kwargs=config.env)
            save_demonstrations(demos, out_dir / "demonstrations.npz")
            _seed_buffer_with_demonstrations(model, demos)
            if isinstance(model, DDPGBC):
                model.set_demonstrations(observation_batch(demos), demos["action"])
        if progress_csv.exists():
            progress_csv.unlink()
    if resume and model.num_timesteps >= total and history:  # finished: its records stay as they are
        print(f"{out_dir}: the run is finished ({model.num_timesteps:,d} steps done, {total:,d} asked); nothing was "
              "changed. Pass a larger --steps to extend it.")
        env.close()
        return history
    model.set_logger(configure(str(out_dir / "sb3_log"), formats))

    start = time.perf_counter()
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=total, initial=model.num_timesteps, desc=config.name, unit="step", dynamic_ncols=True,
                   mininterval=0.5, disable=None)

    def evaluate_and_checkpoint():
        result = evaluate_policy(_sb3_policy(model, config.switch_dimensions), config.env_id, config.eval_episodes,
                                 env_kwargs=config.env)
        row = {"timesteps": model.num_timesteps, "success_rate": result["success_rate"],
               "mean_final_distance": result["mean_final_distance"], "wall_seconds": time.perf_counter() - start}
        history.append(row)
        # Evaluation figures beside SB3's training ones (CSV and TensorBoard), as EvalCallback does.
        model.logger.record("eval/success_rate", row["success_rate"])
        model.logger.record("eval/mean_final_distance", row["mean_final_distance"])
        model.logger.dump(model.num_timesteps)
        new_file = not progress_csv.exists()
        with progress_csv.open("a", newline="") as handle:
            writer = csv.DictWriter(handle, fieldnames=list(row))
            if new_file:
                writer.writeheader()
            writer.writerow(row)
        model.save(checkpoint)
        if not on_policy:
            model.save_replay_buffer(buffer_path)
        elif state_path is not None:
            model.get_env().save(str(state_path))
        if result["success_rate"] >= max(r["success_rate"] for r in history):
            model.save(out_dir / "best_model.zip")  # the evaluation-selected policy (EvalCallback's convention)
        if bar is not None:
            bar.set_postfix(success=f"{result['success_rate']:.2f}")

    next_evaluation = [(model.num_timesteps // config.eval_every + 1) * config.eval_every]

    class _Callback(BaseCallback):
        def _on_step(self) -> bool:
            if bar is not None:
                bar.update(self.model.num_timesteps - bar.n)
            if self.model.num_timesteps >= next_evaluation[0]:  # (a batched env passes it num_envs steps at a time)
                evaluate_and_checkpoint()
                next_evaluation[0] = (self.model.num_timesteps // config.eval_every + 1) * config.eval_every
            return True

    remaining = total - model.num_timesteps
    if remaining > 0:
        model.learn(remaining, callback=_Callback(), reset_num_timesteps=not resume, progress_bar=False)
    if not history or history[-1]["timesteps"] != model.num_timesteps:
        evaluate_and_checkpoint()
    if bar is not None:
        bar.close()
    shutil.copyfile(checkpoint, out_dir / "final_model.zip")
    return history


def load_final_model(config: RunConfig, out_dir):
    """A finished run's ``final_model.zip``, for export: off-policy models are loaded beside an env of the config (SB3's
    HER buffer will not load without one) with a replay buffer of one transition (an export reads the actor alone)."""
    cls = sb3_algorithms()[config.algorithm]
    path = Path(out_dir) / "final_model.zip"
    if config.algorithm in ON_POLICY:
        return cls.load(path)
    env = gym.make(config.env_id, **config.env, **config.train_env)
    return cls.load(path, env=env, custom_objects={"buffer_size": 1, "learning_starts": 0})


def log_formats(tensorboard: bool) -> list[str]:
    """SB3 logger formats: CSV always, TensorBoard on request (a clear error if it is not installed)."""
    if tensorboard:
        try:
            import tensorboard as _  # noqa: F401
        except ImportError:
            raise ImportError("TensorBoard logs need the tensorboard package: pip install 'dvrl-marl[train]'") from None
        return ["csv", "tensorboard"]
    return ["csv"]


def train_from_request(request, run_table: dict) -> int:
    """``dvrl-marl train`` with a goal env's configuration (``[run] env_id``; ``--export``: the final policy)."""
    config = load_config(request.config)
    out = request.out_folder(config.name)
    history = train(config, request.seed, out, total_timesteps=request.steps, progress=request.progress,
                    resume=request.resume, tensorboard=request.tensorboard)
    final = history[-1]
    print(f"{config.name} seed {request.seed}: success {final['success_rate']:.2f} after {int(final['timesteps'])} "
          f"steps; run folder {out}")
    if request.export:
        from dvrl_marl.training.export import export_policy

        model = load_final_model(config, out)
        export_policy(model, request.export, name=Path(request.export).name, env_id=config.env_id,
                      **config.export_metadata(),
                      training={"config": config.name, "seed": request.seed, "timesteps": int(final["timesteps"]),
                                "success_rate": final["success_rate"]})
        print(f"exported the policy to {request.export}")
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="sb3", algorithms=ALGORITHMS, goal_env=True, run=train_from_request,
    takes=frozenset({"steps", "export", "resume", "tensorboard"}), needs=("stable_baselines3", "sb3_contrib"),
    install='pip install "dvrl-marl[train]"',
    summary="a Gymnasium goal env (PSM Reach, PSM Pick) with SB3: DDPG + HER, TD3, SAC, TQC, PPO"))
