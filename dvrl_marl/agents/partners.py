"""Partners that act like people: the scripted experts late, slow, smooth, shaky and hesitant, in seeded profiles.

A learned seat that only ever met the fast, exact scripted partner fails beside a person (the project's measured
person in the surgeon seat: about 200 ms late, 60 % of the script's speed, a smooth approach, a little motor noise,
short pauses). :class:`PersonLikePartner` puts such a person in either seat: it wraps the seat's scripted expert and

- sees the scene ``reaction_steps`` steps late (20 ms each);
- approaches smoothly: the expert's proportional gain times ``approach`` (1: the script's jump to within a step);
- moves at ``speed`` of the full step, with Gaussian ``motor_noise`` on each motion axis;
- now and then (``pause_probability`` per step) stops for ``pause_steps`` steps, its tool as it was.

Profiles are drawn from ranges with a seed (:func:`draw_profiles`): :data:`TRAINING_RANGES` for the partners a
trainer may use, and the held-out zoo :data:`HELD_OUT`, whose kinds lie outside those ranges (later, slower,
shakier, more hesitant) and are never used in training; :data:`PERSON` is the measured person, a reference inside
the training ranges. :func:`zoo_partner` builds a kind's members (four profiles, a share of the worlds each).
Every partner takes one observation ``(d,)`` or a batch ``(N, d)``, keeps per-world state, and starts over on
:meth:`PersonLikePartner.reset`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dvrl_marl.agents.population import Partners, draw_within
from dvrl_marl.suction_debris.layout import ACTION_WIDTH, MOVE, TOOL

__all__ = ["Partners", "Profile", "PersonLikePartner", "TRAINING_RANGES", "HELD_OUT", "PERSON", "draw_profiles", "zoo_partner",
           "training_partners", "ZOO_SEED", "TRAINING_SEED"]


@dataclass(frozen=True)
class Profile:
    """How a person-like partner acts (see the module documentation); steps are 20 ms control steps."""

    reaction_steps: int = 0
    speed: float = 1.0
    approach: float = 1.0
    motor_noise: float = 0.0
    pause_probability: float = 0.0
    pause_steps: int = 0

    def __post_init__(self):
        for name in ("reaction_steps", "pause_steps"):  # counts of steps: whole numbers (1.5 is no step count)
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"Profile: {name} must be a whole number of steps, got {value!r}")
        if not (self.reaction_steps >= 0 and 0.0 < self.speed <= 1.0 and 0.0 < self.approach <= 1.0
                and self.motor_noise >= 0.0 and 0.0 <= self.pause_probability < 1.0 and self.pause_steps >= 0):
            raise ValueError(f"Profile: a value is out of range: {self}")


#: The ranges a trainer's partners may be drawn from (uniform; the integers inclusive).
TRAINING_RANGES = {"reaction_steps": (0, 15), "speed": (0.4, 1.0), "approach": (0.08, 1.0),
                   "motor_noise": (0.0, 0.15), "pause_probability": (0.0, 0.004), "pause_steps": (10, 50)}
#: The measured person in the surgeon seat (the project's reference notes): a reference, inside TRAINING_RANGES.
PERSON = {"reaction_steps": (10, 10), "speed": (0.6, 0.6), "approach": (0.1, 0.1), "motor_noise": (0.05, 0.05),
          "pause_probability": (0.002, 0.002), "pause_steps": (25, 25)}
#: The held-out zoo: each kind leaves TRAINING_RANGES in one way (its other values lie inside them).
HELD_OUT = {
    "late": {**PERSON, "reaction_steps": (17, 22), "approach": (0.06, 0.08)},  # 340-440 ms late
    "slow": {**PERSON, "speed": (0.25, 0.35)},
    "shaky": {**PERSON, "motor_noise": (0.16, 0.2)},  # (0.22 and up: the scripted seat fails beside it too)
    "hesitant": {**PERSON, "pause_probability": (0.006, 0.01), "pause_steps": (60, 100)},
}
#: The held-out members are drawn from this seed (one stream per kind and seat): documented and reproducible.
ZOO_SEED = 424_242
#: A trainer's person-like partners are drawn from TRAINING_RANGES with this seed (apart from ZOO_SEED's streams).
TRAINING_SEED = 77_000


def draw_profiles(ranges: dict, count: int, seed: int) -> list[Profile]:
    """``count`` profiles drawn uniformly from ``ranges`` (integers inclusive), reproducibly from ``seed``."""
    rng = np.random.default_rng(seed)
    return [draw_within(Profile, ranges, rng) for _ in range(count)]


class PersonLikePartner:
    """The scripted expert of ``agent``'s seat acting with ``profile``'s imperfections (module documentation).
    ``env``: the scene it plays in (its layout); ``seed``: the noise and pauses."""

    def __init__(self, agent: str, env, profile: Profile, seed: int = 0):
        from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

        if agent not in ("suction", "grasper"):
            raise ValueError(f"PersonLikePartner: agent must be 'suction' or 'grasper', got {agent!r}")
        if not isinstance(profile, Profile):
            raise ValueError(f"PersonLikePartner: profile must be a Profile, got {type(profile).__name__}")
        self.agent, self.profile, self.seed = agent, profile, int(seed)
        self.expert = (ScriptedSuction if agent == "suction" else ScriptedSurgeon).for_env(env)
        self.expert.gain = self.expert.gain * profile.approach  # a smooth approach: a smaller proportional gain
        self._seen = None
        self.reset()

    def reset(self, worlds=None) -> None:
        """Forget what it saw and start its noise again: in every world (``worlds`` None), or in those worlds of a
        batch only (their episodes restarted; the other worlds go on as they were). Each world has its own state and
        its own noise stream seeded ``seed``, so world i of a batch acts as this partner does in one env."""
        if worlds is None or self._seen is None:
            self._seen = None  # (reaction_steps + 1, N, d) ring of observations, made at the next call
            self._rngs, self._steps, self._paused, self._tool, self._fresh = [], None, None, None, None
            return
        worlds = np.arange(len(self._steps))[worlds] if np.asarray(worlds).dtype == bool else np.asarray(worlds)
        for world in np.atleast_1d(worlds):
            self._rngs[world] = np.random.default_rng(self.seed)
        self._steps[worlds], self._paused[worlds], self._fresh[worlds] = 0, 0, True
        self._tool[worlds] = np.nan

    def _start(self, batch: np.ndarray) -> None:
        n, depth = len(batch), self.profile.reaction_steps + 1
        self._seen = np.repeat(batch[None], depth, axis=0)
        self._rngs = [np.random.default_rng(self.seed) for _ in range(n)]
        self._steps, self._paused = np.zeros(n, dtype=np.int64), np.zeros(n, dtype=np.int64)
        self._tool, self._fresh = np.full(n, np.nan), np.zeros(n, dtype=bool)

    def __call__(self, observation) -> np.ndarray:
        observations = np.asarray(observation, dtype=np.float64)
        single = observations.ndim == 1
        batch = observations[None] if single else observations
        n = len(batch)
        depth = self.profile.reaction_steps + 1
        if self._seen is None or self._seen.shape[1] != n:
            self._start(batch)  # until it has seen more, the first view
        if self._fresh.any():  # worlds restarted: their first view fills what they have seen
            self._seen[:, self._fresh] = batch[self._fresh]
            self._fresh[:] = False
        rows = np.arange(n)
        self._seen[self._steps % depth, rows] = batch
        seen = self._seen[(self._steps + 1) % depth, rows]  # what it saw reaction_steps ago, world by world
        self._steps += 1
        actions = np.asarray(self.expert(seen), dtype=np.float64).reshape(n, ACTION_WIDTH).copy()
        actions[:, MOVE] *= self.profile.speed
        if self.profile.motor_noise > 0.0:
            actions[:, MOVE] += np.stack([rng.normal(0.0, self.profile.motor_noise, 3) for rng in self._rngs])
        if self.profile.pause_probability > 0.0:
            draws = np.array([rng.random() for rng in self._rngs])
            starting = (self._paused == 0) & (draws < self.profile.pause_probability)
            self._paused[starting] = self.profile.pause_steps
            pausing = self._paused > 0
            actions[pausing, :3] = 0.0
            held = pausing & ~np.isnan(self._tool)
            actions[held, 3] = self._tool[held]
            self._paused[pausing] -= 1
        np.clip(actions, -1.0, 1.0, out=actions)
        self._tool = actions[:, TOOL].copy()
        return actions[0].astype(np.float32) if single else actions

    def __repr__(self) -> str:
        return f"PersonLikePartner({self.agent!r}, {self.profile})"


def zoo_partner(kind: str, agent: str, env, members: int = 4):
    """A held-out kind (:data:`HELD_OUT`, ``"person"``, or ``"in-the-way"``: the LND seat's obstructing surgeons,
    :mod:`dvrl_marl.agents.in_the_way`) in ``agent``'s seat: ``members`` profiles drawn from its ranges with
    :data:`ZOO_SEED`, a share of the worlds each (:class:`Partners`)."""
    if agent not in ("suction", "grasper"):
        raise ValueError(f"zoo_partner: agent must be 'suction' or 'grasper', got {agent!r}")
    if kind == "in-the-way":
        from dvrl_marl.agents.in_the_way import held_out_obstructors

        return held_out_obstructors(agent, env, members)
    ranges = PERSON if kind == "person" else HELD_OUT.get(kind)
    if ranges is None:
        raise ValueError(f"unknown partner kind {kind!r}; held out: {sorted(HELD_OUT)}, 'in-the-way' or 'person'")
    stream = ZOO_SEED + 1000 * (sorted(HELD_OUT).index(kind) + 1 if kind in HELD_OUT else 0) + (agent == "grasper")
    profiles = draw_profiles(ranges, members, stream)
    partners = [PersonLikePartner(agent, env, profile, seed=stream + index) for index, profile in enumerate(profiles)]
    return Partners(partners, [f"{kind}-{index}" for index in range(members)])


def training_partners(agent: str, env, members: int = 8):
    """The person-like partners a trainer may use in ``agent``'s seat (the seat name ``"person-like"`` of
    :func:`dvrl_marl.training.teams.seat`): ``members`` profiles from :data:`TRAINING_RANGES`, drawn with
    :data:`TRAINING_SEED`, a share of the worlds each."""
    if agent not in ("suction", "grasper"):
        raise ValueError(f"training_partners: agent must be 'suction' or 'grasper', got {agent!r}")
    stream = TRAINING_SEED + (agent == "grasper")
    profiles = draw_profiles(TRAINING_RANGES, members, stream)
    partners = [PersonLikePartner(agent, env, profile, seed=stream + 100 * (index + 1))
                for index, profile in enumerate(profiles)]
    return Partners(partners, [f"person-like-{index}" for index in range(members)])
