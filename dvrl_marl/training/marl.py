"""Multi-agent training on the collaborative env through PettingZoo tooling: SB3 PPO via SuperSuit.

Both arms share one PPO policy (parameter sharing): SuperSuit pads the agents' spaces to a common shape (they are
already equal here), appends a one-hot agent indicator to each observation, and turns the parallel env into an
SB3 vector env in which every agent is one slot. With ``surgeon="scripted"`` only the suction arm learns, the
scripted surgeon being part of the environment.

Configuration (``baselines/configs/suction_debris_ppo*.toml``)::

    [run]
    total_timesteps = 200000    # agent steps (each parallel step counts once per learning agent)
    n_envs = 4
    eval_episodes = 10
    surgeon = "none"            # or "scripted"
    [env]                       # suction_debris_v8.parallel_env keyword arguments
    [algorithm]                 # PPO keyword arguments
    [policy]                    # policy_kwargs
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from dvrl_marl.envs import suction_debris
from dvrl_marl.training import trainers

__all__ = ["make_vec_env", "train_ppo", "TeamPolicy", "evaluate_team"]


def make_vec_env(n_envs: int = 4, surgeon: str | None = None, **env_kwargs):
    """An SB3-compatible vector env over the collaborative env's learning agents (see
    :func:`dvrl_marl.integrations.sb3.make_collaborative_vec_env`)."""
    from dvrl_marl.integrations.sb3 import make_collaborative_vec_env

    return make_collaborative_vec_env(n_envs, surgeon=surgeon, **env_kwargs)


class TeamPolicy:
    """A shared PPO policy acting for every learning agent of a parallel env (adds the agent indicator)."""

    def __init__(self, model, agents):
        self.model = model
        self.agents = list(agents)
        # SuperSuit writes the indicator at the observation space's upper bound rather than 1.
        self.indicator_value = float(model.observation_space.high[-1])

    def __call__(self, observations: dict) -> dict:
        actions = {}
        for index, agent in enumerate(self.agents):
            obs = observations[agent]
            if len(self.agents) > 1:
                indicator = np.zeros(len(self.agents))
                indicator[index] = self.indicator_value
                obs = np.concatenate([obs, indicator])
            actions[agent], _ = self.model.predict(obs, deterministic=True)
        return actions


def evaluate_team(act, episodes: int, seed: int = 5_000_000, surgeon=None, on_reset=None, **env_kwargs) -> dict:
    """Success rate, mean steps, blood removed and instrument contacts; ``act(observations) -> actions dict``.

    ``on_reset()`` is called at each episode start (e.g. to reset pipelines' stage state).
    """
    env = suction_debris.parallel_env(surgeon=surgeon, **env_kwargs)
    successes, steps, removed, contacts = 0, [], [], []
    for episode in range(episodes):
        observations, _ = env.reset(seed=seed + episode)
        if on_reset is not None:
            on_reset()
        count = touching = 0
        while env.agents:
            observations, _, _, _, infos = env.step(act(observations))
            info = next(iter(infos.values()))
            count += 1
            touching += bool(info["collision"])
        successes += bool(info["is_success"])
        steps.append(count)
        removed.append(sum(env.blood.removed_ml))
        contacts.append(touching)
    return {"success_rate": successes / episodes, "mean_steps": float(np.mean(steps)),
            "mean_blood_removed_ml": float(np.mean(removed)), "mean_contacts": float(np.mean(contacts)),
            "episodes": episodes}


def _checked(path, table: dict):
    """The configuration checked against its schema (:class:`dvrl_marl.schemas.Sb3PpoRun`; ``[env]`` by the scene
    itself; ``[algorithm]`` and ``[policy]`` by SB3): ``([run], [env])``."""
    from dvrl_marl.schemas import Sb3PpoRun, validated

    for name, content in table.items():
        if name not in ("run", "env", "algorithm", "policy") or not isinstance(content, dict):
            raise ValueError(f"{path}: unknown table [{name}] (known: run, env, algorithm, policy)")
    run = validated(Sb3PpoRun, table.get("run", {}), str(path), table="run")
    env_kwargs = dict(table.get("env", {}))
    try:
        suction_debris.parallel_env(**env_kwargs).close()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: [env] {error}") from None
    return run, env_kwargs


def train_ppo(config_path, seed: int, out_dir, total_timesteps: int | None = None,
              eval_episodes: int | None = None, tensorboard: bool = False) -> dict:
    """Train PPO on the collaborative env from a configuration; writes the model and ``result.json``."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.logger import configure

    from dvrl_marl.training.runner import log_formats

    formats = log_formats(tensorboard)
    config_path = Path(config_path)
    from dvrl_marl.files import read_toml

    table = read_toml(config_path)
    run, env_kwargs = _checked(config_path, table)
    surgeon = None if run.surgeon == "none" else run.surgeon
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.toml").write_text(config_path.read_text())
    vec = make_vec_env(run.n_envs, surgeon=surgeon, **env_kwargs)
    model = PPO("MlpPolicy", vec, seed=seed, verbose=0, policy_kwargs=table.get("policy", {}),
                **table.get("algorithm", {}))
    model.set_logger(configure(str(out_dir / "sb3_log"), formats))
    start = time.perf_counter()
    model.learn(int(total_timesteps or run.total_timesteps))
    model.save(out_dir / "final_model.zip")
    vec.close()
    agents = [a for a in suction_debris.AGENTS if surgeon is None or a != "grasper"]
    episodes = int(eval_episodes or run.eval_episodes)
    result = evaluate_team(TeamPolicy(model, agents), episodes, surgeon=surgeon, **env_kwargs)
    result.update({"config": config_path.stem, "seed": seed, "timesteps": int(model.num_timesteps),
                   "wall_seconds": time.perf_counter() - start})
    (out_dir / "result.json").write_text(json.dumps(result, indent=2) + "\n")
    return result


def train_from_request(request, run_table: dict) -> int:
    """``dvrl-marl train`` with a collaborative PPO configuration (SB3, one policy shared by both arms)."""
    name = Path(request.config).stem
    out = request.out_folder(name)
    result = train_ppo(request.config, request.seed, out, total_timesteps=request.steps,
                       tensorboard=request.tensorboard)
    print(f"{name} seed {request.seed}: {result}; run folder {out}")
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="sb3-team", algorithms=("ppo", None), goal_env=False, run=train_from_request,
    takes=frozenset({"steps", "tensorboard"}), needs=("stable_baselines3", "supersuit"),
    install='pip install "dvrl-marl[train]"',
    summary="the collaborative scene's two arms as one shared SB3 PPO policy (SuperSuit)"))
