"""Demonstrations as Minari datasets (the Farama standard for offline RL): record a seat, load it, replay it.

```python
from dvrl_marl import datasets
from dvrl_marl.agents import ScriptedSurgeon

dataset = datasets.record("dvrl_marl/surgeon-scripted-v1", "scripted", episodes=20, seed=0)   # the LND seat
observations, actions = datasets.transitions("dvrl_marl/surgeon-scripted-v1")                # for cloning
device = datasets.replay_device("dvrl_marl/surgeon-scripted-v1", episode=3)                   # a teleop device
```

Each episode is one seat of ``suction_debris_v8`` as the Gymnasium env ``dvrl_marl/SurgeonSeat-v8`` (the partner
inside it) sees it: observations, actions, rewards, terminations, truncations and infos (``is_success``,
``blood_remaining``, ``debris_delivered``, ``collision`` and the partner's action), with the env spec (id and
keyword arguments) and each episode's seed, so ``replay`` plays an episode back exactly. Minari keeps datasets
under ``~/.minari/datasets`` unless ``MINARI_DATASETS_PATH`` says otherwise. Needs ``pip install "dvrl-marl[data]"``
(Minari with its HDF5 storage; recording does not need Minari's JAX extra). Files recorded with
:class:`~dvrl_marl.teleop.Recorder` (``.npz``) convert with :func:`from_recording`.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.suction_debris import layout
from dvrl_marl.suction_debris.task import TASK

__all__ = ["record", "record_episodes", "transitions", "replay", "replay_device", "from_recording", "EpisodeRecorder",
           "save_episodes", "next_free_id", "SEAT_ENV_ID"]

#: The Gymnasium env every dataset here is recorded from.
SEAT_ENV_ID = "dvrl_marl/SurgeonSeat-v8"
_INFO_KEYS = ("is_success", "blood_remaining", "debris_delivered", "collision", "partner_action")


def _minari():
    try:
        import minari
    except ImportError as error:  # the optional extra
        raise ModuleNotFoundError('datasets need Minari: pip install "dvrl-marl[data]"', name="minari") from error
    return minari


def _seat_env(env_kwargs: dict | None):
    import gymnasium as gym

    import dvrl_marl  # noqa: F401  (registration)

    return gym.make(SEAT_ENV_ID, **(env_kwargs or {}))


def _seat_policy(policy, env):
    """``"scripted"`` (the seat's expert), a shipped policy name or folder, or a callable / teleop device."""
    if isinstance(policy, str):
        if policy == "scripted":
            from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

            scene = env.unwrapped.scene
            return (ScriptedSurgeon if env.unwrapped.seat == "grasper" else ScriptedSuction).for_env(scene)
        from dvrl_marl import policies

        return policies.load(policy)
    return policy


def record_episodes(policy, episodes: int, *, seed: int = 0, env_kwargs: dict | None = None,
                    action_noise: float = 0.0):
    """Run ``episodes`` seeded episodes (``seed``, ``seed + 1``...) of the seat with ``policy``; Minari episode
    buffers. A device (``.action``) or any ``policy(observation) -> action`` fills the seat.

    ``action_noise`` (DART, Laskey et al. 2017): the seat executes the policy's motion plus Gaussian noise of this
    spread (the jaw as the policy says), so the data shows the policy recovering from small errors; each step's
    ``infos["expert_action"]`` is what the policy itself asked for, the label a clone learns."""
    _minari()

    env = _seat_env(env_kwargs)
    act = _seat_policy(policy, env)
    noise = np.random.default_rng(seed)
    buffers = []
    for episode in range(int(episodes)):
        observation, info = env.reset(seed=seed + episode)
        if hasattr(act, "reset"):
            act.reset()
        recorder = EpisodeRecorder(episode, seed + episode, observation, info)
        done = False
        while not done:
            wanted = np.asarray(act.action(observation) if hasattr(act, "action") else act(observation),
                                dtype=np.float32)
            action = wanted.copy()
            if action_noise > 0.0:
                action[:3] = np.clip(action[:3] + noise.normal(0.0, action_noise, 3), -1.0, 1.0)
            observation, reward, terminated, truncated, info = env.step(action)
            recorder.step(action, observation, reward, terminated, truncated, info, expert_action=wanted)
            done = terminated or truncated
        buffers.append(recorder.buffer())
    env.close()
    return buffers, env


class EpisodeRecorder:
    """One episode of the seat, step by step, as a Minari episode buffer: what :func:`record_episodes` and the
    browser seat (:mod:`dvrl_marl.teleop.session`) write. ``extra_info`` names further per-step info keys to keep
    (each step's info must then hold them; the reset's value is taken from ``info`` or False)."""

    def __init__(self, episode_id: int, seed: int, observation, info: dict, extra_info: tuple[str, ...] = ()):
        self.episode_id, self.seed = int(episode_id), int(seed)
        self._keys = _INFO_KEYS + tuple(extra_info)
        self.observations, self.actions, self.rewards = [np.array(observation)], [], []
        self.terminations, self.truncations = [], []
        self.infos = {key: [info.get(key, False)] for key in self._keys}
        self.infos["expert_action"] = [np.zeros(layout.ACTION_WIDTH, dtype=np.float32)]

    def __len__(self) -> int:
        return len(self.actions)

    def step(self, action, observation, reward, terminated, truncated, info: dict, expert_action=None) -> None:
        """One step: the action executed and what the env returned; ``expert_action`` is the label a clone learns
        (the action itself when not given)."""
        action = np.asarray(action, dtype=np.float32)
        self.observations.append(np.array(observation))
        self.actions.append(action)
        self.rewards.append(float(reward))
        self.terminations.append(bool(terminated))
        self.truncations.append(bool(truncated))
        for key in self._keys:
            self.infos[key].append(info[key])
        self.infos["expert_action"].append(action if expert_action is None else np.asarray(expert_action, np.float32))

    def buffer(self, stopped: bool = False):
        """The episode as a Minari ``EpisodeBuffer``; ``stopped``: it ended before the env said so (a person stopped
        recording or reset), recorded as a truncation at its last step."""
        from minari.data_collector.episode_buffer import EpisodeBuffer

        if not self.actions:
            raise ValueError("an episode needs at least one step to be recorded")
        truncations = list(self.truncations)
        if stopped and not (self.terminations[-1] or truncations[-1]):
            truncations[-1] = True
        return EpisodeBuffer(id=self.episode_id, seed=self.seed, observations=list(self.observations),
                             actions=list(self.actions), rewards=list(self.rewards),
                             terminations=list(self.terminations), truncations=truncations,
                             infos={key: np.asarray(values) for key, values in self.infos.items()})


def save_episodes(dataset_id: str, buffers, env, *, description: str, algorithm_name: str):
    """Write episode buffers recorded in ``env`` (made with ``gym.make``, so its spec can be replayed) as the
    Minari dataset ``dataset_id``."""
    minari = _minari()
    _check_id(dataset_id)
    if dataset_id in minari.list_local_datasets():
        raise ValueError(f"a Minari dataset {dataset_id!r} exists already; delete it first (minari.delete_dataset)")
    return minari.create_dataset_from_buffers(
        dataset_id, list(buffers), env=env.spec, eval_env=env.spec, algorithm_name=algorithm_name,
        author="dvrl-marl", author_email="dvrl-marl@users.noreply.github.com",
        code_permalink="https://github.com/dvrl-marl/dvrl-marl", description=description)


def next_free_id(dataset_id: str) -> str:
    """``dataset_id`` if no local dataset has it, else the same name at the first free version (``-v2``, ``-v3``...).

    A version is taken when Minari lists it or when anything lies at its path: a damaged dataset folder (an
    interrupted write, a hand-edited metadata file) is not listed by Minari, yet writing there fails, and a person's
    recording must never be lost to it."""
    minari = _minari()
    _check_id(dataset_id)
    from minari.dataset.minari_dataset import gen_dataset_id, parse_dataset_id
    from minari.storage.datasets_root_dir import get_dataset_path

    namespace, name, version = parse_dataset_id(dataset_id)
    taken = set(minari.list_local_datasets())
    version = 1 if version is None else int(version)
    while (gen_dataset_id(namespace, name, version) in taken
           or get_dataset_path(gen_dataset_id(namespace, name, version)).exists()):
        version += 1
    return gen_dataset_id(namespace, name, version)


def record(dataset_id: str, policy, episodes: int = 20, *, seed: int = 0, env_kwargs: dict | None = None,
           description: str | None = None, algorithm_name: str | None = None, action_noise: float = 0.0):
    """Record ``episodes`` episodes of ``policy`` in the surgeon seat as the Minari dataset ``dataset_id``
    (``namespace/name-vN``); returns the dataset. An existing dataset of that id is an error (delete it with
    ``minari.delete_dataset``)."""
    _check_id(dataset_id)
    if dataset_id in _minari().list_local_datasets():  # before the episodes are run, not after
        raise ValueError(f"a Minari dataset {dataset_id!r} exists already; delete it first (minari.delete_dataset)")
    buffers, env = record_episodes(policy, episodes, seed=seed, env_kwargs=env_kwargs, action_noise=action_noise)
    name = policy if isinstance(policy, str) else type(policy).__name__
    return save_episodes(dataset_id, buffers, env, algorithm_name=algorithm_name or f"dvrl-marl {name}",
                         description=description or (f"{episodes} episodes of {name} in the surgeon seat of "
                                                     f"{TASK} (seeds {seed}..{seed + episodes - 1}, "
                                                     f"action noise {action_noise})"))


def _check_id(dataset_id: str) -> None:
    """Refuse a malformed id before anything is written (Minari would leave a folder that breaks its own listing)."""
    from minari.dataset.minari_dataset import parse_dataset_id

    try:
        parse_dataset_id(dataset_id)
    except ValueError as error:
        raise ValueError(f"dataset id {dataset_id!r} is not of the form (namespace/)name-vN, e.g. "
                         f"'dvrl_marl/surgeon-scripted-v1'") from error


def _dataset(dataset):
    return _minari().load_dataset(dataset) if isinstance(dataset, str) else dataset


def transitions(dataset, successful_only: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Every (observation, label) pair of a dataset (an id or a loaded dataset), for behaviour cloning: the label
    is what the recorded policy asked for (``infos["expert_action"]``, which differs from the executed action when
    it was recorded with ``action_noise``)."""
    observations, actions = [], []
    for episode in _dataset(dataset).iterate_episodes():
        if successful_only and not bool(np.asarray(episode.infos["is_success"])[-1]):
            continue
        observations.append(np.asarray(episode.observations)[:-1])
        labels = episode.infos.get("expert_action") if episode.infos else None
        actions.append(np.asarray(labels)[1:] if labels is not None else np.asarray(episode.actions))
    if not observations:
        raise ValueError("the dataset has no episodes to learn from")
    return np.concatenate(observations), np.concatenate(actions).astype(np.float32)


def _episode(dataset, index: int):
    dataset = _dataset(dataset)
    total = int(dataset.total_episodes)
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or not 0 <= index < total:
        raise ValueError(f"episode must be an episode's index in [0, {total}) of {dataset.spec.dataset_id!r}, "
                         f"got {index!r}")
    episodes = list(dataset.iterate_episodes([int(index)]))
    if not episodes:
        raise ValueError(f"the dataset has no episode {index}")
    return dataset, episodes[0]


def replay_device(dataset, episode: int = 0):
    """A :class:`~dvrl_marl.teleop.ReplayDevice` that plays one episode's actions."""
    from dvrl_marl.teleop import ReplayDevice

    return ReplayDevice(np.asarray(_episode(dataset, episode)[1].actions, dtype=np.float32))


def replay(dataset, episode: int = 0) -> dict:
    """Play one episode back in the env it was recorded in (same env arguments, same seed) and compare: the
    largest observation difference and whether the outcome matches."""
    import dvrl_marl  # noqa: F401  (the env the dataset names must be registered)

    dataset, data = _episode(dataset, episode)
    env = dataset.recover_environment()
    seed = next(iter(dataset.storage.get_episode_metadata([episode]))).get("seed")
    observation, _ = env.reset(seed=None if seed is None else int(seed))
    recorded = np.asarray(data.observations)
    worst = float(np.max(np.abs(observation - recorded[0])))
    for step, action in enumerate(np.asarray(data.actions)):
        observation, _, terminated, truncated, info = env.step(action)
        worst = max(worst, float(np.max(np.abs(observation - recorded[step + 1]))))
    env.close()
    return {"max_observation_difference": worst, "success": bool(info["is_success"]),
            "recorded_success": bool(np.asarray(data.infos["is_success"])[-1]), "steps": len(data.actions)}


def from_recording(dataset_id: str, paths, *, seeds=None, env_kwargs: dict | None = None):
    """Convert demonstration files (``teleop.Recorder`` / ``save_demonstration``, one episode each) into a Minari
    dataset by replaying their actions in the surgeon seat (seeded with ``seeds``, one per file, or the seed the
    file's metadata names)."""
    from dvrl_marl.teleop import ReplayDevice, load_demonstration

    _check_id(dataset_id)
    buffers, env = [], None
    for index, path in enumerate(paths):
        _, actions, metadata = load_demonstration(path)
        seed = int(seeds[index] if seeds is not None else metadata.get("seed", index))
        episode_buffers, env = record_episodes(ReplayDevice(actions), 1, seed=seed, env_kwargs=env_kwargs)
        buffers.append(episode_buffers[0].__class__(**{**episode_buffers[0].__dict__, "id": index}))
    return save_episodes(dataset_id, buffers, env, algorithm_name="dvrl-marl recording",
                         description=f"{len(buffers)} recorded episodes converted from demonstration files")
