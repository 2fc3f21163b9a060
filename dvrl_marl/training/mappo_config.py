"""The MAPPO / IPPO trainer's configuration: its schema (:class:`MappoConfig`), the TOML reader
(:func:`load_config`) and who fills the partner seat. What makes the task learnable is not here: it is the env's
options under ``[env]`` (``reward_type = "guided"``, ``[env.guidance]``, ``observation_features``, ``contact_penalty``)
and ``[curriculum] levels``, a schedule of the env's start level (:mod:`dvrl_marl.suction_debris.start_levels`).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

from dvrl_marl.envs import suction_debris
from dvrl_marl.suction_debris import start_levels
from dvrl_marl.suction_debris.presets import with_preset
from dvrl_marl.schemas import (STRICT, Finite, Flag, Fraction, NonNegative, NonNegativeInt, Positive, PositiveInt, Text,
                               UnitInterval)
from dvrl_marl.training import teams

__all__ = ["MappoConfig", "load_config", "TABLE_KEYS", "RETIRED", "RETIRED_AT", "TRAIN_SEED_BASE", "ALGORITHMS",
           "TOOL_HEADS", "CRITIC_INPUTS", "check_surgeon", "partner", "partners", "demonstrations", "config_toml"]

#: Training worlds of seed s draw from TRAIN_SEED_BASE * (s + 1) + i; evaluation seeds (teams.EVAL_SEED on) lie
#: far beyond them.
TRAIN_SEED_BASE = 1_000_000

ALGORITHMS = ("mappo", "ippo")

TOOL_HEADS = ("gaussian", "switch")

CRITIC_INPUTS = ("state", "state_and_observation")



@dataclass
class MappoConfig:
    """A run's settings (the TOML's tables flattened; see ``baselines/configs/suction_debris_mappo.toml``). The
    annotations are the configuration's schema: pydantic checks every value against them (:func:`load_config`)."""

    __pydantic_config__ = STRICT

    name: Text = "suction_debris_mappo"
    algorithm: Literal[ALGORITHMS] = "mappo"
    total_steps: PositiveInt = 20_000_000  # parallel env steps (one per world per step)
    num_envs: PositiveInt = 512
    rollout_steps: PositiveInt = 64
    eval_every: PositiveInt = 2_000_000
    eval_episodes: PositiveInt = 100
    checkpoint_every: PositiveInt = 2_000_000
    # who fills surgeon_seat while the other seat learns: "none" (both learn), "scripted" (the built-in expert), a
    # policy (a shipped name or a folder), or a list of these (teams.Partners: a share of the worlds each, in
    # training, demonstrations and validation alike; learned partners act with their recorded noise)
    surgeon: Text | list[Text] = "none"
    surgeon_seat: Literal[suction_debris.AGENTS] = "grasper"
    env: dict[Text, Any] = field(default_factory=lambda: {"reward_type": "dense"})
    # PPO
    learning_rate: Positive = 3e-4
    anneal_lr: Flag = True  # linear decay to 0 over the run (PPO's usual schedule; the last policies are steadier)
    epochs: PositiveInt = 5
    minibatches: PositiveInt = 2
    clip_epsilon: UnitInterval = 0.2
    gamma: UnitInterval = 0.99
    gae_lambda: Fraction = 0.95
    entropy_coef: NonNegative = 0.0
    value_coef: NonNegative = 1.0
    max_grad_norm: Positive = 1.0
    # > 0: adds this x sum((|mean| - 1)+^2) over the motion dimensions to the loss (see bounds_loss)
    bounds_loss_coef: NonNegative = 0.0
    hidden: list[PositiveInt] = field(default_factory=lambda: [128, 128])
    initial_std: Positive = 0.6
    # 0: the standard deviation is learnt (PPO's usual). > 0: it follows a schedule, initial_std at the start to
    # final_std at the end of the run, linearly (see exploration_std): the deterministic policy users get is then
    # the one training ended with, not one that leant on noise to get past the cavities' rims
    final_std: NonNegative = 0.0
    # "gaussian": the tool value (valve / jaw) is a fourth Gaussian dimension; "switch": an open/closed decision
    # (Bernoulli, action +1 or -1; see _switch_gaussian), its initial logit per agent in initial_tool_logit
    tool_head: Literal[TOOL_HEADS] = "gaussian"
    initial_tool_logit: dict[Literal[suction_debris.AGENTS], Finite] = field(default_factory=dict)
    # MAPPO's critic input: "state" (the env's state()), or "state_and_observation": the state and the agent's own
    # observation (with its features), one value network per agent (Yu et al. 2022's agent-specific global state)
    critic_input: Literal[CRITIC_INPUTS] = "state"
    # curriculum: the env's start level (dvrl_marl.suction_debris.start_levels) as a piecewise-linear schedule over the run,
    # [[progress, level], ...] (progress in [0, 1], increasing); [] leaves the env's own start_level
    levels: list[tuple[Fraction, Fraction]] = field(default_factory=list)
    torch_threads: NonNegativeInt = 0  # 0: torch's default
    # validation (and so the best checkpoint) with the policies acting with their exploration noise, seeded
    # (PPO optimises the noisy policy; see NumpyPolicy.with_noise); the deterministic figure is measured after
    evaluate_with_noise: Flag = False
    # behaviour cloning before PPO (see dvrl_marl.training.pretrain): "" off, "scripted": the scripted experts of
    # the learning seats ("keep-clear": the bleeding field's KeepClearSuction and KeepClearSurgeon; "sweeping": its
    # SweepingSuction and SweepingSurgeon; "yielding": the suction seat's YieldingSuction), recorded over bc_episodes episodes with DART noise bc_action_noise. A run that uses it
    # learns from demonstrations (reported apart from the runs from scratch).
    bc_expert: Literal["", "scripted", "keep-clear", "sweeping", "yielding"] = ""
    bc_episodes: PositiveInt = 256
    bc_action_noise: NonNegative = 0.3
    bc_epochs: PositiveInt = 30
    bc_learning_rate: Positive = 1e-3
    bc_dagger_rounds: NonNegativeInt = 0  # then this many DAgger rounds: the clone drives, the expert labels, the clone refits
    # fine-tuning: a learning seat's actor starts from a policy (a shipped name or a folder) of the same network
    # and observation features, e.g. { suction = "marl-suction" }; its input scaling is kept, as a clone's is.
    # A run that uses it learns from that policy's demonstrations or runs (reported apart from the runs from scratch).
    init_policy: dict[Literal[suction_debris.AGENTS], Text] = field(default_factory=dict)
    # PPO steps (parallel env steps) at the start of the run during which only the critic learns, the actor frozen
    critic_warmup_steps: NonNegativeInt = 0
    # where the learner's update runs: "cpu", "cuda" (or "cuda:N"), or "auto" (cuda when torch sees a GPU).
    # Collection always runs on CPU (the env is numpy; a few hundred worlds per step are latency-bound on a GPU).
    device: Text = "cpu"

    def exploration_std(self, progress: float) -> float:
        """The motion's standard deviation at ``progress`` in [0, 1] of the run (with ``final_std`` > 0)."""
        progress = min(max(progress, 0.0), 1.0)
        return self.initial_std + (self.final_std - self.initial_std) * progress

    def learning_rate_at(self, progress: float) -> float:
        """The learning rate at ``progress`` in [0, 1] of the run: linearly to 0 with ``anneal_lr``, else constant."""
        return self.learning_rate * (max(1.0 - progress, 0.0) if self.anneal_lr else 1.0)

    def level(self, progress: float) -> float | None:
        """The start level of episodes that begin at ``progress`` in [0, 1] of the run (None: no schedule)."""
        if not self.levels:
            return None
        return start_levels.scheduled_level(self.levels, progress)


#: The configuration's tables and the keys each holds; [run] takes every key (the flat form of the first records),
#: [env] the scene's keyword arguments.
TABLE_KEYS = {
    "run": None,
    "env": None,
    "ppo": ("learning_rate", "anneal_lr", "epochs", "minibatches", "clip_epsilon", "gamma", "gae_lambda",
            "entropy_coef", "value_coef", "max_grad_norm", "bounds_loss_coef"),
    "model": ("hidden", "initial_std", "final_std", "tool_head", "initial_tool_logit", "critic_input"),
    "curriculum": ("levels",),
    "pretrain": ("bc_expert", "bc_episodes", "bc_action_noise", "bc_epochs", "bc_learning_rate", "bc_dagger_rounds",
                 "init_policy", "critic_warmup_steps"),
}

_FIELDS = {f.name for f in fields(MappoConfig)}

#: The last commit whose trainer read the keys below: every run recorded with them is reproducible from it.
LAST_COMMIT_BEFORE_ENV_OPTIONS = "ea6d143"
#: Keys retired when what makes the task learnable moved into the env, and where each went.
_TO_GUIDANCE = 'now the env\'s guided reward: [env] reward_type = "guided" and [env.guidance]'
RETIRED = {
    **dict.fromkeys(("easy_start", "anneal_begin", "anneal_end", "near_debris", "receding_starts", "easy_episode_steps",
                     "empty_cavity_probability"), "now the env's start levels: [curriculum] levels"),
    "random_start": "scattered starts made no configuration of record",
    "observation_features": "now the env's option: [env] observation_features",
    "contact_penalty": "now the env's own: [env] contact_penalty",
    "shaping": _TO_GUIDANCE,
    **dict.fromkeys(("grasp_path_shaping", "hold_bonus", "wait_at_home", "cleared_pins_only", "centred_grasps",
                     "off_centre_grasps", "suction_route_shaping", "clear_bonus", "route_to_park", "shaping_over_rims"),
                    _TO_GUIDANCE),
    "held_tool_logit": "now the env's option: [env] hold_until_handoff = true, a held pin's jaw shut until the "
                       "hand-off",
}
#: Keys retired later, and the last commit whose trainer read each (the others: LAST_COMMIT_BEFORE_ENV_OPTIONS).
RETIRED_AT = {"held_tool_logit": "c59ae5f"}


def _check_env(path, config: MappoConfig) -> None:
    """``[env]``: the scene's keyword arguments, checked by building the scene once (its own schema)."""
    try:
        suction_debris.parallel_env(**config.env).close()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: [env] {error}") from None


def load_config(path) -> MappoConfig:
    """Read a configuration TOML, checked against :class:`MappoConfig`'s declared schema: an unknown table or key, a
    key in a table it does not belong to, a value of the wrong type or out of range, and ``[env]`` keyword arguments
    the scene refuses each raise ``ValueError`` naming the file, the table and the field. A file may hold only what
    differs from another: ``[run] extends = "suction_debris_mappo.toml"`` (:func:`dvrl_marl.files.read_extended_toml`)."""
    from dvrl_marl.files import read_extended_toml
    from dvrl_marl.schemas import validated

    path = Path(path)
    table = read_extended_toml(path)
    values: dict = {"name": path.stem}
    where: dict = {}  # key -> the table it came from, for the messages
    retired = [("shaping", "shaping")] if "shaping" in table else []
    retired += [(section, key) for section, content in table.items() if section != "env" and isinstance(content, dict)
                for key in content if key in RETIRED]
    if retired:
        section, key = retired[0]
        # the oldest commit among those of the retired keys present reads them all
        commit = (LAST_COMMIT_BEFORE_ENV_OPTIONS if any(name not in RETIRED_AT for _, name in retired)
                  else RETIRED_AT[key])
        raise ValueError(f"{path}: [{section}] {key}: retired when the env took it over ({RETIRED.get(key, RETIRED['shaping'])}); "
                         f"a run recorded with it is reproducible from commit {commit} (baselines/README.md)")
    for section, content in table.items():
        if section not in TABLE_KEYS or not isinstance(content, dict):
            raise ValueError(f"{path}: unknown table [{section}] (known: {', '.join(TABLE_KEYS)})")
        if section == "env":
            # a preset becomes its options here, so the trainer reads every option the scene runs with; its name
            # stays (the same scene either way: the options given win over the preset's) for the exports to record
            named = {"preset": content["preset"]} if content.get("preset", "default") != "default" else {}
            values["env"], where["env"] = {**named, **with_preset(dict(content), f"{path}: [env]")}, "env"
            continue
        for key, value in content.items():
            allowed = TABLE_KEYS[section]
            if key in ("name", "env") or (allowed is not None and key not in allowed) or key not in _FIELDS:
                home = next((name for name, keys in TABLE_KEYS.items() if keys and key in keys), None)
                hint = f" (it belongs in [{home}])" if home and key in _FIELDS else ""
                raise ValueError(f"{path}: [{section}] {key}: unknown key{hint}")
            if key in values:
                raise ValueError(f"{path}: [{section}] {key}: set twice (also in [{where[key]}])")
            values[key], where[key] = value, section
    config = validated(MappoConfig, values, str(path), tables=where)
    _check_env(path, config)
    check_surgeon(path, config)
    if not (config.device in ("cpu", "auto") or str(config.device).startswith("cuda")):
        raise ValueError(f"{path}: device must be \"cpu\", \"auto\" or \"cuda\" (\"cuda:N\"), got {config.device!r}")
    if config.critic_input != "state" and config.algorithm != "mappo":
        raise ValueError(f"{path}: critic_input is MAPPO's (IPPO's critics read each agent's own observation)")
    start_levels.checked_schedule(config.levels, f"{path}: [curriculum] levels")
    _check_init_policy(path, config)
    if config.bc_expert == "yielding" and (config.surgeon == "none" or config.surgeon_seat != "grasper"):
        raise ValueError(f"{path}: [pretrain] bc_expert = \"yielding\" clones the suction seat's expert: the suction "
                         "must be the only learning seat (a surgeon in surgeon_seat = \"grasper\")")
    return config


def scene_metadata(config: MappoConfig) -> dict:
    """What an exported policy records of the scene it learnt on: its preset, where not the default (evaluations
    make that scene: ``dvrl-marl evaluate-team``)."""
    preset = config.env.get("preset", "default")
    return {} if preset == "default" else {"preset": preset}


def _check_init_policy(path, config: MappoConfig) -> None:
    """``init_policy``: learning seats only, not with a clone, each a policy trained for that seat."""
    if not config.init_policy:
        return
    if config.bc_expert:
        raise ValueError(f"{path}: [pretrain] init_policy and bc_expert both start the actors: give one")
    for agent, name in config.init_policy.items():
        if config.surgeon != "none" and agent == config.surgeon_seat:
            raise ValueError(f"{path}: [pretrain] init_policy names {agent!r}, the partner's seat (surgeon_seat): "
                             "only a learning seat starts from a policy")
        try:
            teams.seat(name, agent)
        except (ValueError, FileNotFoundError, KeyError) as error:
            raise ValueError(f"{path}: [pretrain] init_policy {agent} = {name!r}: {error}") from None


def check_surgeon(path, config: MappoConfig) -> None:
    """``surgeon``: "none", or one or more partners that exist and were trained for ``surgeon_seat``."""
    spec = config.surgeon
    if spec == "none":
        return
    names = [spec] if isinstance(spec, str) else spec
    if not isinstance(names, list) or not names or not all(isinstance(name, str) and name for name in names):
        raise ValueError(f"{path}: surgeon must be \"none\", \"scripted\", a policy or a non-empty list of these, "
                         f"got {spec!r}")
    if "none" in names and len(names) > 1:
        raise ValueError(f"{path}: surgeon \"none\" cannot be one of several partners")
    if config.surgeon_seat not in suction_debris.AGENTS:
        raise ValueError(f"{path}: surgeon_seat must be one of {suction_debris.AGENTS}, got {config.surgeon_seat!r}")
    for name in names:
        if name in ("scripted", "pipeline"):
            continue
        try:
            teams.seat(name, config.surgeon_seat)
        except (ValueError, FileNotFoundError, KeyError) as error:
            raise ValueError(f"{path}: surgeon {name!r} cannot fill the {config.surgeon_seat!r} seat: {error}") from None


def partner(config: MappoConfig, env, noise_from: int):
    """The filler of the partner seat (see MappoConfig.surgeon and teams.partner), or None; ``env``: the one whose
    layout a scripted partner reads (None: a world of ``config.env``)."""
    if config.surgeon == "none":
        return None
    if env is None:
        env = suction_debris.parallel_env(**config.env)
    return teams.partner(config.surgeon, config.surgeon_seat, env, noise_from=noise_from)


def partners(config: MappoConfig) -> list:
    """Who filled the other seat while this policy learnt (recorded in its policy.json): [] when both learnt."""
    if config.surgeon == "none":
        return []
    return [config.surgeon] if isinstance(config.surgeon, str) else list(config.surgeon)


def demonstrations(config: MappoConfig) -> dict:
    """What a policy learnt from besides its reward (recorded in its policy.json): nothing, the cloned expert, or the
    policies its actors started from."""
    if config.init_policy:
        return {"demonstrations": None, "started_from": dict(config.init_policy)}
    if not config.bc_expert:
        return {"demonstrations": None}
    return {"demonstrations": {"expert": config.bc_expert, "episodes": int(config.bc_episodes),
                               "action_noise": config.bc_action_noise, "dagger_rounds": int(config.bc_dagger_rounds)}}


def config_toml(config: MappoConfig) -> str:
    lines = ["[run]"]
    for f in fields(MappoConfig):
        value = getattr(config, f.name)
        if f.name in ("env", "name") or value is None:  # TOML has no null: an absent key is the default (None)
            continue
        lines.append(f"{f.name} = {toml_value(value)}")
    lines.append("[env]")
    missing = sorted(k for k, v in config.env.items() if v is None)
    if missing:  # an absent key would read back as the env's default, not as None
        raise ValueError(f"[env] {', '.join(missing)}: None cannot be written to TOML (it has no null); give the "
                         "value the option takes for it (easy_episode_steps: 0)")
    lines += [f"{k} = {toml_value(v)}" for k, v in config.env.items()]
    return "\n".join(lines) + "\n"


def toml_value(value) -> str:
    if isinstance(value, dict):  # an inline table (JSON's braces are not TOML's)
        return "{ " + ", ".join(f"{k} = {toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)
