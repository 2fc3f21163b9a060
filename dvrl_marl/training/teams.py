"""Teams on the collaborative env: fill each seat with a learned, scripted or composed policy and measure them.

Numpy only (no torch): the shipped multi-agent policies are evaluated as users get them.

```python
from dvrl_marl.training import teams
result = teams.evaluate_team_batched(teams.seats("marl-suction", "marl-grasper"), episodes=100)
beside = teams.evaluate_beside("suction", teams.seat("marl-suction", "suction"),
                               {name: teams.seat(name, "grasper") for name in ("scripted", "pipeline")})
matrix = teams.cross_play(["marl-suction", "scripted"], ["marl-grasper", "scripted", "pipeline"])
```

A seat is named by ``"scripted"`` (the built-in expert), ``"keep-clear"`` and ``"sweeping"`` (the cooperative
experts for a bleeding field), ``"yielding"`` (the suction seat only: the scripted suction that holds its place rather
than push into the other instrument), ``"person-like"`` (eight person-like partners drawn from the training ranges,
:mod:`dvrl_marl.agents.partners`), ``"in-the-way"`` (the LND seat only: eight surgeons that rest over the suction's
route until it has waited near them, :mod:`dvrl_marl.agents.in_the_way`), ``"pipeline"`` (the ``learned_team``
pipeline: the single-arm Reach and Pick policies composed, one pipeline per world), a shipped policy name
(:func:`dvrl_marl.policies.available`) or a policy folder.
"""

from __future__ import annotations

import numpy as np

from dvrl_marl.agents.partners import Partners
from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris.rules import FLUID_FIGURES

__all__ = ["evaluate_team_batched", "evaluate_beside", "seat", "seats", "partner", "Partners", "cross_play",
           "EVAL_SEED", "VALIDATION_SEED"]

#: Reported evaluations use seeds EVAL_SEED, EVAL_SEED + 1, ...: no training world ever draws them.
EVAL_SEED = 900_000_000
#: Trainers evaluate during training (and pick their best checkpoint) on seeds from here: a validation range kept
#: apart from EVAL_SEED's, so a reported figure never comes from the seeds a checkpoint was selected on.
VALIDATION_SEED = 800_000_000


class _PerWorld:
    """One stateful single-env policy (a pipeline) per world of a batch."""

    def __init__(self, make):
        self.make, self.policies = make, None

    def __call__(self, observations: np.ndarray) -> np.ndarray:
        if self.policies is None or len(self.policies) != len(observations):
            self.policies = [self.make() for _ in range(len(observations))]
        return np.stack([np.asarray(p(o), dtype=np.float64) for p, o in zip(self.policies, observations)])

    def reset(self, worlds=None) -> None:
        """New episodes: every world's policy made again (``worlds`` None), or those worlds' only."""
        if worlds is None or self.policies is None:
            self.policies = None
            return
        for world in np.flatnonzero(worlds) if np.asarray(worlds).dtype == bool else np.atleast_1d(worlds):
            self.policies[world] = self.make()


def noise_seed(agent: str, seed: int) -> int:
    """The seed of a learned seat's exploration noise in an evaluation starting at ``seed`` (one per seat)."""
    return int(seed) * 2 + suction_debris.AGENTS.index(agent)


def seat(name, agent: str, env=None, noise_from: int | None = None):
    """A callable on observations ``(N, obs_dim)`` -> ``(N, 4)`` for ``agent`` (see the module documentation).
    ``noise_from``: a learned policy acts with its exploration noise, seeded from this evaluation seed."""
    from dvrl_marl import policies
    from dvrl_marl.agents.collaborative import (KeepClearSuction, KeepClearSurgeon, ScriptedSuction, ScriptedSurgeon,
                                                SweepingSuction, SweepingSurgeon, YieldingSuction)

    if agent not in suction_debris.AGENTS:
        raise ValueError(f"unknown seat {agent!r}; seats are {list(suction_debris.AGENTS)}")
    if callable(name):
        return name
    env = env or suction_debris.parallel_env()
    if name == "scripted":
        return (ScriptedSuction if agent == "suction" else ScriptedSurgeon).for_env(env)
    if name == "keep-clear":  # the cooperative experts for a bleeding field
        return (KeepClearSuction if agent == "suction" else KeepClearSurgeon).for_env(env)
    if name == "sweeping":  # the bleeding field's experts that clear once and sweep at the last hand-off
        return (SweepingSuction if agent == "suction" else SweepingSurgeon).for_env(env)
    if name == "yielding":  # the scripted suction that holds its place rather than push into the other instrument
        if agent != "suction":
            raise ValueError(f"'yielding' is a suction seat (YieldingSuction), not {agent!r}")
        return YieldingSuction.for_env(env)
    if name == "person-like":  # the scripted expert as people act: late, slow, smooth, shaky, hesitant (seeded)
        from dvrl_marl.agents.partners import training_partners

        return training_partners(agent, env)
    if name == "in-the-way":  # surgeons that rest over the suction's route until it has waited near them
        from dvrl_marl.agents.in_the_way import training_obstructors

        return training_obstructors(agent, env)
    if name == "pipeline":
        from dvrl_marl.pipeline import ArmPipeline, load_pipeline

        plan = load_pipeline("learned_team")[agent]
        return _PerWorld(lambda: ArmPipeline(plan, agent, env))  # (env: its layout, an irrigating scene's included)
    policy = policies.load(name)
    trained_for = policy.spec.get("agent")
    if trained_for is not None and trained_for != agent:
        raise ValueError(f"policy {name!r} was trained for the {trained_for!r} seat, not {agent!r}")
    if noise_from is not None:
        return policy.with_noise(noise_seed(agent, noise_from))
    return policy


def partner(spec, agent: str, env=None, noise_from: int | None = None):
    """The filler of a trainer's partner seat ``agent``: None for ``"none"``; a seat name (see :func:`seat`); or a
    list of them (:class:`Partners`, a share of the worlds each). Learned partners that record their exploration
    noise act with it (seeded from ``noise_from``, one stream per partner): the partner a trainee meets varies as a
    person's hand does."""
    if spec is None or spec == "none":
        return None
    names = [spec] if isinstance(spec, str) else list(spec)
    members = []
    for index, name in enumerate(names):
        member = seat(name, agent, env)
        spec_of = getattr(member, "spec", None)
        if noise_from is not None and spec_of is not None and (spec_of.get("exploration") or {}).get("std"):
            member = member.with_noise(noise_seed(agent, int(noise_from) + 7919 * index))
        members.append(member)
    return members[0] if isinstance(spec, str) else Partners(members, names)


def seats(suction, grasper, noise_from: int | None = None, env=None) -> dict:
    """Both seats (:func:`seat`); ``env``: the scene they are made for (a scripted seat reads its layout: an
    irrigating scene's experts irrigate), the default scene's parallel env if None."""
    return {"suction": seat(suction, "suction", env, noise_from=noise_from),
            "grasper": seat(grasper, "grasper", env, noise_from=noise_from)}


def evaluate_team_batched(team: dict, episodes: int = 100, seed: int = EVAL_SEED, **env_kwargs) -> dict:
    """Play ``episodes`` episodes at once (world j seeded ``seed + j``) with ``team[agent]`` callables on
    observations ``(N, obs_dim)`` returning ``(N, 4)``.

    A seat with ``image_options`` (a pixel policy) gets its observation dict, images included, from an env made with
    those options (``image_appearance`` among ``env_kwargs`` sets their look); the other seats get the vector.

    Returns success rate, blood removed, debris delivered, median steps to completion (over successes),
    instrument-contact steps per episode and, per seat, the tip's path (mm per episode) and the mean absolute change
    of its action between steps (how smoothly it moved; a real PSM is servoed through IK at 50 Hz), with the
    per-episode outcomes (success, steps, contact steps).
    """
    return _summary(_play(team, episodes, seed, env_kwargs), np.arange(episodes), seed)


def evaluate_beside(agent: str, policy, partners: dict, episodes: int = 100, seed: int = EVAL_SEED,
                    **env_kwargs) -> dict:
    """``policy`` in ``agent``'s seat beside each of ``partners`` (``{name: policy}`` in the other seat), in one batch
    of ``episodes`` worlds per partner: partner k of K plays worlds k, k + K, k + 2K... (world j seeded ``seed + j``).
    One batch steps several partners' episodes for about the price of one partner's (a step's cost hardly grows with
    its worlds). Returns ``{name: evaluate_team_batched's figures over that partner's worlds}``, each with its
    ``seeds``."""
    other = {"suction": "grasper", "grasper": "suction"}.get(agent)
    if other is None:
        raise ValueError(f"evaluate_beside: agent must be 'suction' or 'grasper', got {agent!r}")
    if not partners:
        raise ValueError("evaluate_beside: no partner given")
    names = list(partners)
    team = {agent: policy, other: Partners(list(partners.values()), names)}
    played = _play(team, episodes * len(names), seed, env_kwargs)
    results = {}
    for k, name in enumerate(names):
        worlds = np.arange(k, episodes * len(names), len(names))
        results[name] = {**_summary(played, worlds, seed), "seeds": (seed + worlds).tolist()}
    return results


def _play(team: dict, episodes: int, seed: int, env_kwargs: dict) -> dict:
    """Every world's episode played to its end: per-world outcomes (arrays of ``episodes`` rows)."""
    # No reward is read here: the sparse one costs nothing, where a preset's guided one computes its potentials (and
    # the guided terms' settings go with it).
    env_kwargs = {**{k: v for k, v in env_kwargs.items() if k != "guidance"}, "reward_type": "sparse"}
    # A seat that sees the endoscope (a pixel policy) names the image options it needs; the others read the vector.
    seeing = {agent: getattr(policy, "image_options", None) for agent, policy in team.items()}
    seeing = {agent: options for agent, options in seeing.items() if options}
    for options in seeing.values():
        clash = {k: (env_kwargs[k], v) for k, v in options.items() if k in env_kwargs and env_kwargs[k] != v}
        if clash:
            raise ValueError(f"evaluate_team_batched: a pixel seat needs {options}, the evaluation asks {clash}")
        env_kwargs.update(options)
    if not seeing and "image_appearance" in env_kwargs:
        raise ValueError("evaluate_team_batched: image_appearance given, but no seat sees the endoscope")
    env = suction_debris.batched_env(num_envs=episodes, autoreset_mode="disabled", **env_kwargs)
    missing = set(env.possible_agents) - set(team)
    if missing:
        raise ValueError(f"evaluate_team_batched: no policy for seat(s) {sorted(missing)}")
    observations, infos = env.reset(seed=seed)
    for policy in team.values():  # a seat that keeps state (a pipeline, a person-like partner) starts its episodes
        getattr(policy, "reset", lambda: None)()
    first = env.agents[0]
    initial = infos[first]["blood_remaining"].copy()
    done = np.zeros(episodes, dtype=bool)
    success = np.zeros(episodes, dtype=bool)
    steps = np.zeros(episodes, dtype=np.int64)
    contacts = np.zeros(episodes, dtype=np.int64)
    remaining = initial.copy()
    delivered = np.zeros(episodes)
    tip = env.observation_layout["own_tip"]
    scaling = env.observation_scaling  # normalize_observations: the team reads it, the paths are the scene's

    def tip_of(agent, observation):
        observation = observation["observation"] if isinstance(observation, dict) else observation
        return (observation if scaling is None else scaling.plain_observation(agent, observation))[:, tip]

    def seen_by(agent, observation):
        return observation if agent in seeing or not isinstance(observation, dict) else observation["observation"]

    path = {agent: np.zeros(episodes) for agent in env.agents}
    change = {agent: np.zeros(episodes) for agent in env.agents}
    last = {}
    fluids: dict = {}
    while not done.all():
        actions = {agent: np.asarray(team[agent](seen_by(agent, observations[agent])), dtype=np.float64)
                   for agent in env.agents}
        before = {agent: tip_of(agent, observations[agent]) for agent in env.agents}
        observations, _, terminations, truncations, infos = env.step(actions)
        info = infos[first]
        live = ~done
        for agent in env.agents:
            path[agent] += live * np.linalg.norm(tip_of(agent, observations[agent]) - before[agent], axis=1)
            if agent in last:
                change[agent] += live * np.abs(actions[agent] - last[agent]).mean(axis=1)
            last[agent] = actions[agent]
        steps += live
        contacts += live & info["collision"]
        remaining = np.where(live, info["blood_remaining"], remaining)
        delivered = np.where(live, info["debris_delivered"], delivered)
        success |= live & info["is_success"]
        for key in FLUID_FIGURES:  # a scene with fluids: each figure as the episode left it
            if key in info:
                fluids.setdefault(key, np.zeros(episodes))[live] = np.asarray(info[key], dtype=np.float64)[live]
        done |= terminations[first] | truncations[first]
    env.close()
    return {"success": success, "steps": steps, "contacts": contacts, "initial": initial, "remaining": remaining,
            "fluids": fluids,
            "delivered": delivered, "path_mm": {agent: 1000.0 * env.workspace_range * value
                                                for agent, value in path.items()},
            "action_change": {agent: value / np.maximum(steps - 1, 1) for agent, value in change.items()}}


def _summary(played: dict, worlds: np.ndarray, seed: int) -> dict:
    """evaluate_team_batched's figures over ``worlds`` (indices) of what :func:`_play` played."""
    success, steps, contacts = played["success"][worlds], played["steps"][worlds], played["contacts"][worlds]
    remaining = played["remaining"][worlds]
    return {"episodes": len(worlds), "seed": seed, "success_rate": float(success.mean()),
            "mean_blood_removed_ml": float((played["initial"][worlds] - remaining).mean()),  # net of any bleeding
            "mean_blood_left_ml": float(remaining.mean()),
            "mean_debris_delivered": float(played["delivered"][worlds].mean()),
            "median_steps_to_completion": float(np.median(steps[success])) if success.any() else None,
            "mean_contact_steps": float(contacts.mean()),
            "mean_tip_path_mm": {agent: float(value[worlds].mean()) for agent, value in played["path_mm"].items()},
            "mean_action_change": {agent: float(value[worlds].mean())
                                   for agent, value in played["action_change"].items()},
            "success": success.tolist(), "steps": steps.tolist(), "contact_steps": contacts.tolist(),
            **_fluid_summary(played, worlds)}


def _fluid_summary(played: dict, worlds: np.ndarray) -> dict:
    """Blood left as a share of the start, saline used and wasted, overflows (share of episodes with one, events and
    seconds per episode): for a scene with fluids only."""
    fluids = played.get("fluids") or {}
    if not fluids:
        return {}
    start = played["initial"][worlds]
    left = played["remaining"][worlds] / np.where(start > 0.0, start, 1.0)
    return {"mean_blood_left_share": float(left.mean()), "max_blood_left_share": float(left.max()),
            "mean_clot_left_ml": float(fluids["clot_remaining"][worlds].mean()),
            "mean_saline_used_ml": float(fluids["saline_used_ml"][worlds].mean()),
            "mean_saline_wasted_ml": float(fluids["saline_wasted_ml"][worlds].mean()),
            "overflowed_episodes": float((fluids["overflow_events"][worlds] > 0).mean()),
            "mean_overflow_events": float(fluids["overflow_events"][worlds].mean()),
            "mean_overflow_s": float(fluids["overflow_s"][worlds].mean()),
            "saline_used_ml": fluids["saline_used_ml"][worlds].tolist()}


def cross_play(suctions, graspers, episodes: int = 100, seed: int = EVAL_SEED, noise: bool = False,
               **env_kwargs) -> list[dict]:
    """Every suction with every grasper: one row per pair (names as given, figures of evaluate_team_batched).
    ``noise``: learned policies act with their exploration noise (seeded from ``seed``)."""
    rows = []
    for suction in suctions:
        for grasper in graspers:
            result = evaluate_team_batched(seats(suction, grasper, noise_from=seed if noise else None), episodes,
                                           seed, **env_kwargs)
            rows.append({"suction": str(suction), "grasper": str(grasper),
                         **{k: v for k, v in result.items() if k not in ("success", "steps")}})
    return rows
