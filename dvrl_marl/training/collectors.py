"""Experience for the multi-agent trainer: rollouts of the batched collaborative env, here or on a Ray cluster.

A :class:`RolloutCollector` owns a share of the training worlds (a batched env made with the configuration's
``[env]`` options, restarting ended worlds at the scheduled start level) and a copy of the actors; :meth:`RolloutCollector.rollout` steps its worlds
``rollout_steps`` times with the actors' weights it is given and returns the arrays the learner needs. The
learner (:func:`dvrl_marl.training.mappo.train`) asks :class:`LocalCollectors` (one collector in its own process,
sharing its actor: nothing is copied) or :class:`RayCollectors` (``num_collectors`` Ray actors, spread over the
cluster's nodes, each stepping ``num_envs / num_collectors`` worlds; the learner stays where it is) for a batch;
both return the same arrays, so the update does not know where its data came from.

Fault tolerance on Ray: collectors are restarted when they die (``max_restarts``) and a rollout that was running
on one is retried on its replacement (``max_task_retries``); the replacement rebuilds its worlds from its first
seeds, and the learner's weights come with every rollout, so training goes on. The learner itself resumes from
its checkpoint (``--resume``).
"""

from __future__ import annotations

import os
import socket

import numpy as np

from dvrl_marl.suction_debris.layout import ACTION_WIDTH
from dvrl_marl.training.mappo_config import TRAIN_SEED_BASE, partner
from dvrl_marl.training.models import build_models, limit_threads, require_torch

__all__ = ["RolloutCollector", "LocalCollectors", "RayCollectors", "make_collectors", "split_worlds"]

#: Per-step arrays of a rollout, (T, worlds, ...), concatenated over collectors along the world axis.
ROLLOUT_ARRAYS = ("observation", "next_observation", "state", "next_state", "action", "log_prob", "reward",
                  "discounted_return", "done", "terminated")
ROLLOUT_STATS = ("episodes_ended", "successes", "debris_delivered", "blood_left_ml")


def split_worlds(num_envs: int, parts: int) -> list[int]:
    """``num_envs`` worlds in ``parts`` shares as equal as can be (the first ones one larger)."""
    if parts < 1 or parts > num_envs:
        raise ValueError(f"cannot split {num_envs} worlds among {parts} collectors (need 1 <= collectors <= worlds)")
    base, extra = divmod(num_envs, parts)
    return [base + (index < extra) for index in range(parts)]


class RolloutCollector:
    """Steps ``num_envs`` training worlds (see the module documentation).

    ``first_world``: this share's offset among all training worlds (its worlds are seeded after the ones before
    it); ``steps_done`` and ``progress`` (the fraction of the run done) say where the run stands (resets are seeded
    from it and the first episodes start at that progress's level); ``rng_state`` restores the random stream of a
    checkpoint (episode cuts); ``actor`` shares the learner's actor module (local collection) instead of
    building a copy that rollouts load weights into.
    """

    def __init__(self, config, seed: int, *, index: int = 0, num_envs: int | None = None, first_world: int = 0,
                 steps_done: int = 0, progress: float = 0.0, rng_state=None, actor=None,
                 torch_threads: int | None = None):
        from dvrl_marl.envs import suction_debris

        torch = require_torch()
        if torch_threads:
            limit_threads(int(torch_threads))
        if actor is None:  # a collector of its own (a Ray actor): its own sampling stream too
            torch.manual_seed(int(np.random.SeedSequence([seed, index, steps_done]).generate_state(1)[0]))
        self.config, self.index = config, int(index)
        surgeon = partner(config, None, noise_from=TRAIN_SEED_BASE * (seed + 1) + 104_729 * (index + 1))
        self.env = suction_debris.batched_env(num_envs=int(num_envs or config.num_envs), surgeon=surgeon,
                                                 surgeon_seat=config.surgeon_seat, autoreset_mode="disabled",
                                                 **config.env)
        env, n = self.env, self.env.num_envs
        self.agents = list(env.possible_agents)
        obs_dim, state_dim = env.observation_space(self.agents[0]).shape[0], env.state_space.shape[0]
        self.actor = actor if actor is not None else build_models(
            config, self.agents, obs_dim, state_dim, 4, feature_spec=env.feature_spec)[0]
        self.rng = np.random.default_rng(seed if index == 0 else [seed, index])
        if rng_state is not None:
            self.rng.bit_generator.state = rng_state
        self.observations, _ = env.reset(seed=TRAIN_SEED_BASE * (seed + 1) + steps_done + first_world,
                                         options=self._level_option(progress))
        self.state = env.state()
        self.discounted = np.zeros((n, len(self.agents)))
        # Worlds that start together stay in step for a whole episode (1,500 steps, ~50 rollouts of the same phase);
        # the first episode of each world is cut at a random length (a time limit, bootstrapped like the env's own).
        self.episode_step = np.zeros(n, dtype=np.int64)
        self.first_cut = self.rng.integers(1, env.params.max_cycles + 1, n)
        horizon, count = config.rollout_steps, len(self.agents)
        self.buffers = {
            "observation": np.zeros((horizon, n, count, obs_dim), dtype=np.float32),
            "state": np.zeros((horizon, n, state_dim), dtype=np.float32),
            "action": np.zeros((horizon, n, count, ACTION_WIDTH), dtype=np.float32),
            "log_prob": np.zeros((horizon, n, count), dtype=np.float32),
            "reward": np.zeros((horizon, n, count), dtype=np.float32),
            "discounted_return": np.zeros((horizon, n, count), dtype=np.float64),
            "done": np.zeros((horizon, n), dtype=bool),
            "terminated": np.zeros((horizon, n), dtype=bool),
        }
        self.buffers["next_observation"] = np.zeros_like(self.buffers["observation"])
        self.buffers["next_state"] = np.zeros_like(self.buffers["state"])

    def _level_option(self, progress: float) -> dict:
        """The reset option of the scheduled start level at ``progress`` ({} without a schedule)."""
        level = self.config.level(progress)
        return {} if level is None else {"level": level}

    def rollout(self, actor_state=None, progress: float = 0.0) -> dict:
        """Step every world ``rollout_steps`` times sampling from the actors (``actor_state``: the learner's
        ``actor.state_dict()``, loaded first); the per-step arrays (:data:`ROLLOUT_ARRAYS`) and episode counts."""
        torch = require_torch()
        from tensordict import TensorDict
        from torchrl.envs.utils import ExplorationType, set_exploration_type

        if actor_state is not None:
            self.actor.load_state_dict(actor_state)
        config, env, agents = self.config, self.env, self.agents
        buffers, n, count = self.buffers, env.num_envs, len(self.agents)
        stats = dict.fromkeys(ROLLOUT_STATS, 0.0)
        # sampling from the policy: TorchRL's actors act deterministically unless told otherwise
        with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
            for t in range(config.rollout_steps):
                obs = np.stack([self.observations[a] for a in agents], axis=1)
                buffers["observation"][t] = obs
                buffers["state"][t] = self.state
                td = TensorDict({"agents": TensorDict({"observation": torch.from_numpy(buffers["observation"][t])},
                                                      batch_size=[n, count])}, batch_size=[n])
                self.actor(td)
                action = td["agents", "action"].numpy()
                buffers["action"][t] = action
                buffers["log_prob"][t] = td["agents", "action_log_prob"].numpy()
                self.observations, rewards, terminations, truncations, infos = env.step(
                    {a: action[:, i].astype(np.float64) for i, a in enumerate(agents)})
                self.state = env.state()
                buffers["next_observation"][t] = np.stack([self.observations[a] for a in agents], axis=1)
                buffers["next_state"][t] = self.state
                reward = np.stack([rewards[a] for a in agents], axis=1)
                terminated, truncated = terminations[agents[0]], truncations[agents[0]]
                self.episode_step += 1
                truncated = truncated | (self.episode_step == self.first_cut)
                self.first_cut[self.episode_step >= self.first_cut] = 0  # see first_cut
                done = terminated | truncated
                self.episode_step[done] = 0
                self.discounted = self.discounted * config.gamma + reward
                buffers["discounted_return"][t] = self.discounted
                self.discounted[done] = 0.0
                buffers["reward"][t] = reward
                buffers["done"][t], buffers["terminated"][t] = done, terminated
                if done.any():
                    info = infos[agents[0]]
                    stats["episodes_ended"] += int(done.sum())
                    stats["successes"] += int((done & info["is_success"]).sum())
                    # (an easy start's debris out of play count as delivered)
                    stats["debris_delivered"] += float(info["debris_delivered"][done].sum())
                    stats["blood_left_ml"] += float(info["blood_remaining"][done].sum())
                    self.observations, _ = env.reset(options={"reset_mask": done, **self._level_option(progress)})
                    self.state = env.state()
        return {**buffers, "stats": stats}

    def rng_state(self) -> dict:
        """The collector's random stream (episode cuts), for the learner's checkpoint."""
        return self.rng.bit_generator.state

    def where(self) -> dict:
        """Which machine and process this collector runs in (and its Ray node, when on Ray)."""
        node = None
        try:
            import ray

            if ray.is_initialized():
                node = ray.get_runtime_context().get_node_id()
        except ImportError:
            pass
        return {"index": self.index, "host": socket.gethostname(), "pid": os.getpid(), "node_id": node,
                "worlds": self.env.num_envs}

    def close(self) -> None:
        self.env.close()


def _merge(results: list[dict]) -> dict:
    if len(results) == 1:
        return results[0]
    merged = {key: np.concatenate([r[key] for r in results], axis=1) for key in ROLLOUT_ARRAYS}
    merged["stats"] = {key: sum(r["stats"][key] for r in results) for key in ROLLOUT_STATS}
    return merged


class LocalCollectors:
    """One collector in the learner's process, acting with the learner's own actor module (``shared``), or with a
    CPU copy of it that each rollout loads the learner's weights into (a learner on a GPU)."""

    def __init__(self, collector: RolloutCollector, shared: bool = True):
        self.collector = collector
        self.shared = shared
        self.count = 1

    def collect(self, actor_state, progress: float = 0.0) -> dict:
        if self.shared:  # the actor is the learner's: its weights are current
            return self.collector.rollout(None, progress)
        return self.collector.rollout({key: value.detach().cpu() for key, value in actor_state.items()}, progress)

    def rng_states(self) -> list:
        return [self.collector.rng_state()]

    def where(self) -> list[dict]:
        return [self.collector.where()]

    def close(self) -> None:
        self.collector.close()


class RayCollectors:
    """``num_collectors`` collectors as Ray actors, spread over the cluster's nodes (see the module documentation).

    ``address``: ``"auto"`` (the cluster this machine belongs to, started with ``ray start``), ``"host:port"`` or
    ``"ray://host:10001"``, or ``None`` for a Ray instance of this process. Each collector asks Ray for
    ``cpus_per_collector`` CPUs and runs torch on that many threads.
    """

    def __init__(self, config, seed: int, *, address: str | None, num_collectors: int, steps_done: int = 0,
                 progress: float = 0.0, rng_states=None, cpus_per_collector: float = 1.0,
                 max_restarts: int = -1):
        try:
            import ray
        except ImportError as error:
            raise ModuleNotFoundError('collecting on Ray needs Ray: pip install "dvrl-marl[ray]"',
                                      name="ray") from error
        self._ray = ray
        if not ray.is_initialized():
            if address is None:  # a Ray instance of this process: no dashboard to serve
                ray.init(include_dashboard=False, log_to_driver=False)
            else:
                ray.init(address=address, log_to_driver=False)
        shares = split_worlds(config.num_envs, num_collectors)
        remote = ray.remote(num_cpus=cpus_per_collector, max_restarts=max_restarts, max_task_retries=-1)(
            RolloutCollector)
        if rng_states is not None and len(rng_states) != num_collectors:
            rng_states = None  # a checkpoint of another number of collectors: fresh streams
        self.actors, first = [], 0
        for index, share in enumerate(shares):
            self.actors.append(remote.options(scheduling_strategy="SPREAD", name=None).remote(
                config, seed, index=index, num_envs=share, first_world=first, steps_done=steps_done,
                progress=progress, rng_state=None if rng_states is None else rng_states[index],
                torch_threads=max(1, int(cpus_per_collector))))
            first += share
        self.count = num_collectors

    def collect(self, actor_state, progress: float = 0.0) -> dict:
        ray = self._ray
        weights = ray.put({key: value.detach().cpu() for key, value in actor_state.items()})
        results = ray.get([actor.rollout.remote(weights, progress) for actor in self.actors])
        if len(results) == 1:  # Ray returns read-only views of its object store; the learner's tensors want their own
            results[0] = {key: np.array(value) if key in ROLLOUT_ARRAYS else value for key, value in results[0].items()}
        return _merge(results)

    def rng_states(self) -> list:
        return self._ray.get([actor.rng_state.remote() for actor in self.actors])

    def where(self) -> list[dict]:
        return self._ray.get([actor.where.remote() for actor in self.actors])

    def close(self) -> None:
        for actor in self.actors:
            self._ray.kill(actor, no_restart=True)
        self.actors = []


def make_collectors(config, seed: int, *, actor, steps_done: int, progress: float = 0.0,
                    rng_states=None, ray_address: str | None = None, num_collectors: int = 0):
    """:class:`RayCollectors` when ``ray_address`` or ``num_collectors`` asks for Ray, else :class:`LocalCollectors`."""
    if ray_address is None and not num_collectors:
        collector = RolloutCollector(config, seed, steps_done=steps_done, progress=progress, actor=actor,
                                     rng_state=None if not rng_states else rng_states[0])
        return LocalCollectors(collector, shared=actor is not None)
    return RayCollectors(config, seed, address=None if ray_address in (None, "local") else ray_address,
                         num_collectors=max(1, int(num_collectors or 1)), steps_done=steps_done,
                         progress=progress, rng_states=rng_states)
