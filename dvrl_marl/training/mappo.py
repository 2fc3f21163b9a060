"""Multi-agent PPO (MAPPO and IPPO) for the collaborative env, on TorchRL, fed by the batched env.

``dvrl-marl train baselines/configs/suction_debris_mappo.toml`` runs it. The pieces:

- **Data**: :func:`suction_debris_v0.batched_env` with ``num_envs`` worlds, stepped ``rollout_steps`` times per
  iteration (autoreset off: the trainer resets ended worlds itself, through the curriculum). Worlds of training
  seed ``s`` are seeded from ``TRAIN_SEED_BASE * (s + 1)``; periodic evaluation (and the choice of the best
  checkpoint) uses the validation seeds ``teams.VALIDATION_SEED`` on, and reported figures the test seeds
  ``teams.EVAL_SEED`` on (``dvrl-marl evaluate-team``): three disjoint ranges.
- **Models**: one actor per agent (no parameter sharing: the two roles see the same layout but do different
  jobs) on its own observation, a Gaussian with a learnt state-independent standard deviation (the env clips to
  the action box; a tanh-squashed Gaussian saturated early and stalled in our runs);
  the critic is centralised on the env's ``state()`` for MAPPO (one value per agent) or one per agent on its own
  observation for IPPO. Running mean/std normalisation of observations and state is part of each network (and
  folded into the exported actor's first layer).
- **Loss**: TorchRL's ``ClipPPOLoss`` and ``GAE`` over the ``("agents", ...)`` keys, rewards scaled by a running
  standard deviation of the discounted return (per agent), a few epochs on large minibatches (Yu et al. 2022).
- **What makes the task learnable** (``[curriculum]``, ``[shaping]``; measured in ``baselines/README.md``: with
  them both arms learn the task together from scratch): the env's dense reward (potential-based shaping
  keeps the optimum; success is still the sparse rule), :class:`dvrl_marl.training.shaping.GraspPathShaping` and a curriculum over start
  states that ends on the default task. A fraction ``easy_fraction`` of the worlds that reset draws an easier
  episode: each cavity empty with ``empty_cavity_probability``, otherwise uniform in ``[0, blood_ml]`` (no blood
  reveals debris at once, so the grasper meets the grasp long before the suction can clear 16 ml), fewer debris,
  with probability
  ``random_start`` the learning arms' tips scattered over the phantom (approaches from everywhere), and with
  probability ``near_debris`` the grasper's tip starting a few millimetres above a visible pin (with
  ``receding_starts`` > 0, somewhere on the way from there back to its ordinary start, at most a fraction
  ``progress / receding_starts`` of that way: a reverse curriculum whose starts recede from the pin). With
  ``easy_episode_steps`` easy episodes end (bootstrapped, as a time limit) after that many steps, so that starts,
  and what follows them, are a larger share of the data. ``easy_fraction`` falls linearly from ``easy_start`` to
  0 between ``anneal_begin`` and ``anneal_end`` (fractions of the run); after that every episode is the default
  task. ``contact_penalty`` replaces the env's in the training reward only (evaluation counts contacts).
- **What the measurements of this trainer added** (each a ``[model]`` or ``[shaping]`` option, off by default so
  that earlier configurations run as they did; ``baselines/README.md`` has the figures):
  ``tool_head = "switch"`` decides the valve / jaw as open or closed (a Bernoulli, :func:`_switch_gaussian`;
  ``initial_tool_logit`` leans it at the start: valve open, jaw closed, which the grasp rule rewards;
  ``held_tool_logit`` adds a fixed offset while the agent holds a pin, so the jaw can lean open on the way to a
  pin and closed while it carries one: :func:`held_pin_prior`);
  ``observation_features`` appends relative targets computed from the actor's own observation
  (:mod:`dvrl_marl.policies.features`; the exported numpy policy computes them too);
  ``critic_input = "state_and_observation"`` gives MAPPO's critic each agent's own observation and features beside
  the state (Yu et al. 2022's agent-specific global state; measured: the state-only critic left MAPPO at 0.5 where
  this one reached 1.00);
  ``suction_route_shaping`` and ``clear_bonus`` (:class:`~dvrl_marl.training.shaping.SuctionRouteShaping`) stop the env's shaping from
  charging the suction for clearing a cavity, and ``route_to_park`` ends that route at the suction's parking place
  (once it has cleared, out of the surgeon's way); ``shaping_over_rims`` measures both shapings' paths around the
  phantom (:class:`~dvrl_marl.training.shaping.OverRims`); ``final_std`` replaces the learnt exploration noise by a schedule;
  ``wait_at_home`` and ``cleared_pins_only`` lead the grasper's shaping to the scripted surgeon's waiting place
  when idle and to pins in cleared cavities only; ``centred_grasps`` measures its way to a pin over a point above the
  pin's centre and charges grasps that cannot be delivered (a pin held by its end), ``off_centre_grasps`` charges
  every grasp by how far off the pin's centre it took it; ``[ppo] bounds_loss_coef`` keeps the actors' means inside the
  action box (:func:`bounds_loss`).
- **Demonstrations** (``[pretrain]``, off by default; the partner-seat configurations only, reported apart from
  the runs from scratch): ``bc_expert = "scripted"`` clones the scripted expert of each learning seat into its actor
  before PPO (:mod:`dvrl_marl.training.pretrain`; the clone is evaluated at step 0 and keeps the observation scaling
  it was fitted with), and ``critic_warmup_steps`` lets the critic learn the clone's values before the actor moves.
- **Partners** (``[run] surgeon``): the seat that does not learn is filled by the scripted expert, a learned policy
  or a list of these (:class:`dvrl_marl.training.teams.Partners`: world ``i`` gets partner ``i % K`` in the
  demonstrations, the DAgger rounds, PPO and validation alike; learned partners act with their recorded noise).
  Measured: a grasper cloned beside the scripted suction alone deadlocked beside learned suctions.
- **Device**: ``device = "cuda"`` (or ``"auto"``) runs the update on a GPU; collection stays on CPU (numpy env), the
  collector acting with a CPU copy of the actor that each rollout refreshes.

A run folder holds ``config.toml``, ``progress.csv`` (one row per evaluation), TensorBoard logs (``tb/``),
``checkpoint.pt`` (``--resume`` continues from it: networks, optimiser, normalisers, counters, random streams;
episodes in flight restart), ``policies/<name>`` (the latest numpy-only actors, see :mod:`dvrl_marl.policies`) and
``policies_best/<name>`` (those of the best validation evaluation).
"""

from __future__ import annotations

import csv
import json
import math
import shutil
import sys
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from dvrl_marl.envs import suction_debris_v0
from dvrl_marl.schemas import (STRICT, Finite, Flag, Fraction, NonNegative, NonNegativeInt, Positive, PositiveInt, Text,
                               UnitInterval)
from dvrl_marl.training import teams
from dvrl_marl.training.teams import evaluate_team_batched

__all__ = ["MappoConfig", "load_config", "train", "export_actor", "load_checkpoint", "TRAIN_SEED_BASE"]

#: Training worlds of seed s draw from TRAIN_SEED_BASE * (s + 1) + i; evaluation seeds (teams.EVAL_SEED on) lie
#: far beyond them.
TRAIN_SEED_BASE = 1_000_000
ALGORITHMS = ("mappo", "ippo")
TOOL_HEADS = ("gaussian", "switch")
CRITIC_INPUTS = ("state", "state_and_observation")
#: Gain folded into an exported switch head's last layer: clip(gain x logit) is the sign of the logit, the
#: distribution's most likely tool value, in the numpy policy format's plain layers.
SWITCH_EXPORT_GAIN = 1e6


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
    surgeon_seat: Literal[suction_debris_v0.AGENTS] = "grasper"
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
    initial_tool_logit: dict[Literal[suction_debris_v0.AGENTS], Finite] = field(default_factory=dict)
    # with the switch head, a fixed offset added to an agent's tool logit while its observation says it holds a pin
    # (see held_pin_prior): the grasper's jaw can lean open while it approaches and closed while it carries
    held_tool_logit: dict[Literal[suction_debris_v0.AGENTS], Finite] = field(default_factory=dict)
    # "": the actors read the observation; a name in dvrl_marl.policies.features.FEATURES: they also read features
    # computed from it (relative targets), and the exported policies compute the same
    observation_features: Text = ""
    # MAPPO's critic input: "state" (the env's state()), or "state_and_observation": the state and the agent's own
    # observation (with its features), one value network per agent (Yu et al. 2022's agent-specific global state)
    critic_input: Literal[CRITIC_INPUTS] = "state"
    # curriculum
    easy_start: Fraction = 0.0
    anneal_begin: Fraction = 0.0
    anneal_end: Fraction = 0.5
    near_debris: Fraction = 0.0
    random_start: Fraction = 0.0
    easy_episode_steps: NonNegativeInt = 0  # > 0: easy episodes are cut (bootstrapped) after this many steps
    # > 0: near-debris starts recede along the way from the pin back to the grasper's ordinary start, reaching it
    # at this fraction of the run (a reverse curriculum; 0: always just above the pin)
    receding_starts: Fraction = 0.0
    empty_cavity_probability: Fraction = 0.5  # each cavity of an easy episode starts empty this often
    # trainer-side potential-based shaping (see dvrl_marl.training.shaping)
    grasp_path_shaping: NonNegative = 0.0
    hold_bonus: NonNegative = 0.0
    wait_at_home: Flag = False  # the grasper's shaping leads it to the scripted surgeon's waiting place when idle
    cleared_pins_only: Flag = False  # the grasper's shaping collects only pins in cleared cavities (the expert's rule)
    centred_grasps: Flag = False  # the grasper's shaping: pins approached from above, undeliverable grasps cost
    off_centre_grasps: NonNegative = 0.0  # the grasper's shaping: a held pin costs this x weight per metre off the tip
    suction_route_shaping: NonNegative = 0.0  # see dvrl_marl.training.shaping.SuctionRouteShaping
    clear_bonus: NonNegative = 0.0
    route_to_park: Flag = False  # the suction's route ends at its parking place (out of the surgeon's way)
    shaping_over_rims: Flag = False  # both shapings measure paths around the phantom (see shaping.OverRims)
    contact_penalty: NonNegative | None = None  # training reward only; None: the env's value. Evaluation uses the env's.
    torch_threads: NonNegativeInt = 0  # 0: torch's default
    # validation (and so the best checkpoint) with the policies acting with their exploration noise, seeded
    # (PPO optimises the noisy policy; see NumpyPolicy.with_noise); the deterministic figure is measured after
    evaluate_with_noise: Flag = False
    # behaviour cloning before PPO (see dvrl_marl.training.pretrain): "" off, "scripted": the scripted experts of
    # the learning seats, recorded over bc_episodes episodes with DART noise bc_action_noise. A run that uses it
    # learns from demonstrations (reported apart from the runs from scratch).
    bc_expert: Literal["", "scripted"] = ""
    bc_episodes: PositiveInt = 256
    bc_action_noise: NonNegative = 0.3
    bc_epochs: PositiveInt = 30
    bc_learning_rate: Positive = 1e-3
    bc_dagger_rounds: NonNegativeInt = 0  # then this many DAgger rounds: the clone drives, the expert labels, the clone refits
    # PPO steps (parallel env steps) at the start of the run during which only the critic learns, the actor frozen
    critic_warmup_steps: NonNegativeInt = 0
    # where the learner's update runs: "cpu", "cuda" (or "cuda:N"), or "auto" (cuda when torch sees a GPU).
    # Collection always runs on CPU (the env is numpy; a few hundred worlds per step are latency-bound on a GPU).
    device: Text = "cpu"

    def exploration_std(self, progress: float) -> float:
        """The motion's standard deviation at ``progress`` in [0, 1] of the run (with ``final_std`` > 0)."""
        progress = min(max(progress, 0.0), 1.0)
        return self.initial_std + (self.final_std - self.initial_std) * progress

    def easy_fraction(self, progress: float) -> float:
        """Fraction of resets that draw an easy episode, ``progress`` in [0, 1] of the run."""
        if progress <= self.anneal_begin:
            return self.easy_start
        if progress >= self.anneal_end:
            return 0.0
        return self.easy_start * (self.anneal_end - progress) / (self.anneal_end - self.anneal_begin)


#: The configuration's tables and the keys each holds; [run] takes every key (the flat form of the first records),
#: [env] the scene's keyword arguments.
TABLE_KEYS = {
    "run": None,
    "env": None,
    "ppo": ("learning_rate", "anneal_lr", "epochs", "minibatches", "clip_epsilon", "gamma", "gae_lambda",
            "entropy_coef", "value_coef", "max_grad_norm", "bounds_loss_coef"),
    "model": ("hidden", "initial_std", "final_std", "tool_head", "initial_tool_logit", "held_tool_logit",
              "observation_features", "critic_input"),
    "curriculum": ("easy_start", "anneal_begin", "anneal_end", "near_debris", "random_start", "easy_episode_steps",
                   "receding_starts", "empty_cavity_probability"),
    "shaping": ("grasp_path_shaping", "hold_bonus", "wait_at_home", "cleared_pins_only", "centred_grasps",
                "off_centre_grasps", "suction_route_shaping", "clear_bonus", "route_to_park", "shaping_over_rims",
                "contact_penalty"),
    "pretrain": ("bc_expert", "bc_episodes", "bc_action_noise", "bc_epochs", "bc_learning_rate", "bc_dagger_rounds",
                 "critic_warmup_steps"),
}
_FIELDS = {f.name for f in fields(MappoConfig)}


def _check_env(path, config: MappoConfig) -> None:
    """``[env]``: the scene's keyword arguments, checked by building the scene once (its own schema)."""
    try:
        suction_debris_v0.parallel_env(**config.env).close()
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: [env] {error}") from None


def load_config(path) -> MappoConfig:
    """Read a configuration TOML, checked against :class:`MappoConfig`'s declared schema: an unknown table or key, a
    key in a table it does not belong to, a value of the wrong type or out of range, and ``[env]`` keyword arguments
    the scene refuses each raise ``ValueError`` naming the file, the table and the field."""
    from dvrl_marl.files import read_toml
    from dvrl_marl.schemas import validated

    path = Path(path)
    table = read_toml(path)
    values: dict = {"name": path.stem}
    where: dict = {}  # key -> the table it came from, for the messages
    for section, content in table.items():
        if section not in TABLE_KEYS or not isinstance(content, dict):
            raise ValueError(f"{path}: unknown table [{section}] (known: {', '.join(TABLE_KEYS)})")
        if section == "env":
            values["env"], where["env"] = dict(content), "env"
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
    _check_surgeon(path, config)
    if config.observation_features:
        from dvrl_marl.policies import features

        if config.observation_features not in features.FEATURES:
            raise ValueError(f"{path}: observation_features must be one of {sorted(features.FEATURES)} or \"\", "
                             f"got {config.observation_features!r}")
    if not (config.device in ("cpu", "auto") or str(config.device).startswith("cuda")):
        raise ValueError(f"{path}: device must be \"cpu\", \"auto\" or \"cuda\" (\"cuda:N\"), got {config.device!r}")
    if config.critic_input != "state" and config.algorithm != "mappo":
        raise ValueError(f"{path}: critic_input is MAPPO's (IPPO's critics read each agent's own observation)")
    if any(config.held_tool_logit.values()) and config.tool_head != "switch":
        raise ValueError(f"{path}: held_tool_logit needs tool_head = \"switch\" (it leans the open/closed "
                         f"decision), got tool_head = {config.tool_head!r}")
    if not 0.0 <= config.anneal_begin < config.anneal_end <= 1.0:
        raise ValueError(f"{path}: need 0 <= anneal_begin < anneal_end <= 1")
    return config


# --- models ---------------------------------------------------------------------------------------------------
def _torch():
    try:
        import torch  # noqa: F401
        import torchrl  # noqa: F401
    except ImportError as error:
        raise ModuleNotFoundError(f"the MAPPO trainer needs torch and torchrl ({error.name} is missing): "
                                  'pip install "dvrl-marl[train]"', name=error.name) from None
    import torch

    return torch


_SWITCH_CLASS = None


def _switch_gaussian():
    """The ``tool_head = "switch"`` distribution class (built once torch is imported).

    Why: the grasp rule holds a pin only while the jaw stays below ``grasp_threshold`` (a command under -0.5). A
    Gaussian tool dimension with the usual exploration noise (standard deviation 0.6) opens the jaw on about one
    step in five even when its mean says "closed", so every carry of 50+ steps drops its pin, and the noise that
    lets the arm explore its motion is the noise that makes holding impossible (measured: the grasper grasped,
    held a pin 11-51 % of the time and never delivered one in 8M steps). The env's tool value is a threshold, so the
    policy decides it as one: a Bernoulli over open (+1) / closed (-1) whose logit the network outputs in the place
    of the fourth mean; its certainty is learnt per state, apart from the motion's standard deviation.
    """
    global _SWITCH_CLASS
    if _SWITCH_CLASS is not None:
        return _SWITCH_CLASS
    torch = _torch()
    from torch import distributions

    class SwitchGaussian(distributions.Distribution):
        """Independent Normal over the motion (first dimensions) and a Bernoulli open/closed tool (last
        dimension, values +1 / -1). ``loc[..., -1]`` is the tool's logit; ``scale[..., -1]`` is ignored."""

        arg_constraints = {}
        has_rsample = False

        def __init__(self, loc, scale):
            self.motion = distributions.Normal(loc[..., :-1], scale[..., :-1], validate_args=False)
            self.tool = distributions.Bernoulli(logits=loc[..., -1], validate_args=False)
            super().__init__(batch_shape=loc.shape[:-1], event_shape=loc.shape[-1:], validate_args=False)

        def sample(self, sample_shape=torch.Size()):
            with torch.no_grad():
                tool = self.tool.sample(sample_shape) * 2.0 - 1.0
                return torch.cat([self.motion.sample(sample_shape), tool.unsqueeze(-1)], dim=-1)

        def log_prob(self, value):
            return (self.motion.log_prob(value[..., :-1]).sum(-1)
                    + self.tool.log_prob((value[..., -1] > 0.0).to(value.dtype)))

        def entropy(self):
            return self.motion.entropy().sum(-1) + self.tool.entropy()

        @property
        def mode(self):
            return torch.cat([self.motion.loc, torch.sign(self.tool.logits).unsqueeze(-1)], dim=-1)

        @property
        def deterministic_sample(self):
            return self.mode

        @property
        def mean(self):
            return torch.cat([self.motion.loc, (2.0 * self.tool.probs - 1.0).unsqueeze(-1)], dim=-1)

    _SWITCH_CLASS = SwitchGaussian
    return SwitchGaussian


def bounds_loss(loc, tool_head: str = "gaussian"):
    """Mean over the batch of sum((|mean| - 1)+^2) over the motion dimensions of the actors' means ``loc``.

    The env clips actions to [-1, 1]; a Gaussian mean beyond that saturates: at a mean of 2.4 with the standard
    deviation 0.5 a sample falls inside the box once in 300, so the policy stops exploring that dimension and its
    gradient there carries nothing (measured: 90 % of both learned arms' means lay beyond +-1.5 after 2M steps, and
    both pushed into walls at full speed for the rest of their episodes). A penalty on the excess keeps the means
    where sampling still matters without limiting what the policy can do (a mean of 1 is full speed half the time;
    the bounds loss of rl_games' PPO does the same). The switch tool's logit is left free."""
    motion = loc[..., :3] if tool_head == "switch" else loc
    return (motion.abs() - 1.0).clamp_min(0.0).pow(2).sum(-1).mean()


def observation_feature_spec(config: MappoConfig, obs_dim: int) -> dict | None:
    """The ``features`` entry of the exported policies (None without ``observation_features``): the feature set's
    name, the observation's layout (cavities, debris slots) and, for the sets that need them, the scene's fixed
    geometry (read from the env the configuration describes)."""
    if not config.observation_features:
        return None
    from dvrl_marl.policies import features

    cavities, debris = _observation_slots(obs_dim)
    spec = {"name": config.observation_features, "cavities": cavities, "debris": debris}
    if config.observation_features in features.NEEDS_GEOMETRY:
        env = suction_debris_v0.batched_env(num_envs=1, autoreset_mode="disabled", **config.env)
        spec.update(features.routes_geometry(env.layout()))
        env.close()
    return spec


def _observation_slots(obs_dim: int) -> tuple[int, int]:
    """(cavities, debris slots) of a collaborative agent's observation: 10 + cavities + 6 x debris values."""
    from dvrl_marl import assets

    cavities = len(assets.CAVITY_CENTRES)
    return cavities, (obs_dim - 10 - cavities) // 6


def held_flag_indices(obs_dim: int) -> list[int]:
    """Where a collaborative agent's observation says which pin is held (one flag per debris slot; at most one is
    set, so their sum is 1 while the arm holds a pin and 0 otherwise)."""
    cavities, debris = _observation_slots(obs_dim)
    return [7 + cavities + 6 * slot + 4 for slot in range(debris)]


def held_pin_prior(config: MappoConfig, agents) -> list[float]:
    """Per agent, the fixed offset ``held_tool_logit`` adds to its tool logit while it holds a pin (0: none).

    Why: with one leaning for the jaw in every state, a grasper from scratch either keeps it closed (the grasp rule
    then takes a pin wherever the tip first passes within 3 mm of its axis, and where that happens is decided by the
    whole approach path, many steps before; measured: a fifth to a quarter of such grasps took a pin by its end,
    which can never be delivered) or leans it open (and drops every pin it carries). Leaning the jaw open while the
    arm holds nothing and closed while it holds a pin makes the grasp a decision of one step, at the place where it
    closes, which PPO credits directly (the scripted surgeon approaches open and closes over the pin's centre). The
    prior is a function of the agent's own observation (its held flags), a fixed part of the actor that the
    network's own logit can outweigh; the exported numpy policy computes it too (:func:`export_actor`)."""
    return [float(config.held_tool_logit.get(agent, 0.0)) for agent in agents]


def _build_models(config: MappoConfig, agents, obs_dim: int, state_dim: int, action_dim: int):
    torch = _torch()
    from dvrl_marl.policies import features
    from tensordict.nn import TensorDictModule
    from torch import nn
    from torchrl.modules import IndependentNormal, ProbabilisticActor

    class RunningNorm(nn.Module):
        """Running mean and variance (Chan et al. parallel update), applied as (x - mean) / std."""

        def __init__(self, shape):
            super().__init__()
            self.register_buffer("mean", torch.zeros(shape, dtype=torch.float64))
            self.register_buffer("var", torch.ones(shape, dtype=torch.float64))
            self.register_buffer("count", torch.tensor(1e-4, dtype=torch.float64))

        def update(self, x):
            x = x.reshape(-1, *self.mean.shape).double()
            batch_mean, batch_var, n = x.mean(0), x.var(0, unbiased=False), x.shape[0]
            delta, total = batch_mean - self.mean, self.count + n
            self.mean += delta * n / total
            self.var.copy_((self.var * self.count + batch_var * n + delta**2 * self.count * n / total) / total)
            self.count.fill_(total)

        def std(self):
            return torch.sqrt(self.var).clamp_min(1e-2)  # constant features (the hand-off point) stay finite

        def forward(self, x):
            return ((x - self.mean.float()) / self.std().float())

    def mlp(inputs, outputs):
        layers, width = [], inputs
        for size in config.hidden:
            layers += [nn.Linear(width, int(size)), nn.Tanh()]
            width = int(size)
        layers.append(nn.Linear(width, outputs))
        return nn.Sequential(*layers)

    feature_spec = observation_feature_spec(config, obs_dim)
    extra = 0 if feature_spec is None else features.feature_count(feature_spec["name"])

    class PerAgent(nn.Module):
        """One network per agent: input (..., A, d) -> output (..., A, k); the observation features, when the
        configuration asks for them, are appended before the normalisation."""

        def __init__(self, inputs, outputs, norm, held_prior=None):
            super().__init__()
            self.norm = norm
            self.feature_spec = feature_spec
            self.nets = nn.ModuleList(mlp(inputs + extra, outputs) for _ in agents)
            # the tool logit's fixed offset while a pin is held (held_pin_prior), per agent; None: no offset
            self.held_prior = held_prior if held_prior is not None and any(held_prior) else None
            self.held_flags = held_flag_indices(inputs) if self.held_prior is not None else []

        def with_features(self, x):
            """The observation with the configured features appended (what the normaliser sees)."""
            return x if self.feature_spec is None else features.apply(self.feature_spec, x)

        def _leaning(self, raw, output, offset):
            """``output`` with ``offset`` added to its last (tool) value where ``raw`` says a pin is held."""
            holding = raw[..., self.held_flags].sum(-1, keepdim=True).to(output.dtype)
            return torch.cat([output[..., :-1], output[..., -1:] + offset * holding], dim=-1)

        def agent_forward(self, x, index: int):
            """Agent ``index``'s output on its own observations ``(..., d)`` (behaviour cloning)."""
            out = self.nets[index](self.norm(self.with_features(x)))
            if self.held_prior is not None and self.held_prior[index]:
                out = self._leaning(x, out, self.held_prior[index])
            return out

        def forward(self, x):
            raw = x
            x = self.norm(self.with_features(x))
            outputs = [net(x[..., i, :]) for i, net in enumerate(self.nets)]
            if self.held_prior is not None:
                outputs = [self._leaning(raw[..., i, :], out, offset) if offset else out
                           for i, (out, offset) in enumerate(zip(outputs, self.held_prior))]
            return torch.stack(outputs, dim=-2)

    class CentralCritic(nn.Module):
        """MAPPO's critic: the global state in, one value per agent out (..., A, 1)."""

        def __init__(self, norm):
            super().__init__()
            self.norm = norm
            self.net = mlp(state_dim, len(agents))

        def forward(self, state):
            return self.net(self.norm(state)).unsqueeze(-1)

    class AgentSpecificCritic(nn.Module):
        """MAPPO's critic on the agent-specific global state (Yu et al. 2022): agent i's value from the global state
        and agent i's own observation with its features, one network per agent (..., A, 1). Why: the trainer's
        shaping potentials are functions of what the features compute (the pin to collect, the climb out of a
        cavity, the carry); IPPO's critics read those features and MAPPO's state-only critic had to rebuild them
        from raw positions (measured on the same recipe, test seeds: 0.52 and 0.47 against 1.00 x 3 with this critic)."""

        def __init__(self, state_norm, observation):
            super().__init__()
            self.norm = state_norm
            self.observation = observation  # a PerAgent: its normaliser and feature spec; its nets give the values

        def forward(self, state, observation):
            state = self.norm(state).unsqueeze(-2).expand(*observation.shape[:-1], state_dim)
            seen = self.observation.norm(self.observation.with_features(observation))
            x = torch.cat([state, seen], dim=-1)
            return torch.stack([net(x[..., i, :]) for i, net in enumerate(self.observation.nets)], dim=-2)

    class GaussianHead(nn.Module):
        """Mean from the network, a learnt state-independent standard deviation per agent and action dimension
        (the usual PPO parameterisation; the env clips actions to [-1, 1])."""

        def __init__(self, net):
            super().__init__()
            self.net = net
            self.log_std = nn.Parameter(torch.full((len(agents), action_dim), math.log(config.initial_std)),
                                        requires_grad=not config.final_std)  # final_std: a schedule, not learnt

        def forward(self, x):
            loc = self.net(x)
            return loc, self.log_std.exp().expand_as(loc)

    obs_norm = RunningNorm((obs_dim + extra,))
    actor_net = PerAgent(obs_dim, action_dim, obs_norm, held_pin_prior(config, agents))
    with torch.no_grad():  # small initial means: exploration starts from the standard deviation alone
        for agent, net in zip(agents, actor_net.nets):
            net[-1].weight.mul_(0.01)
            net[-1].bias.zero_()
            if config.tool_head == "switch":  # the tool's initial leaning (a prior the policy may unlearn)
                net[-1].bias[-1] = float(config.initial_tool_logit.get(agent, 0.0))
    policy_module = TensorDictModule(GaussianHead(actor_net), in_keys=[("agents", "observation")],
                                     out_keys=[("agents", "loc"), ("agents", "scale")])
    distribution = _switch_gaussian() if config.tool_head == "switch" else IndependentNormal
    actor = ProbabilisticActor(policy_module, in_keys=[("agents", "loc"), ("agents", "scale")],
                               out_keys=[("agents", "action")], distribution_class=distribution,
                               return_log_prob=True, log_prob_key=("agents", "action_log_prob"))
    if config.algorithm == "mappo" and config.critic_input == "state_and_observation":
        state_norm = RunningNorm((state_dim,))
        seen = PerAgent(obs_dim + state_dim, 1, RunningNorm((obs_dim + extra,)))  # inputs: state + observation
        critic = TensorDictModule(AgentSpecificCritic(state_norm, seen), in_keys=["state", ("agents", "observation")],
                                  out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "state": state_norm, "critic_observation": seen.norm}
    elif config.algorithm == "mappo":
        state_norm = RunningNorm((state_dim,))
        critic = TensorDictModule(CentralCritic(state_norm), in_keys=["state"], out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "state": state_norm}
    else:
        critic = TensorDictModule(PerAgent(obs_dim, 1, RunningNorm((obs_dim + extra,))),
                                  in_keys=[("agents", "observation")],
                                  out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "critic_observation": critic.module.norm}
    return actor, critic, actor_net, norms


# --- numpy export ---------------------------------------------------------------------------------------------
def export_actor(actor_net, index: int, directory, *, name: str, agent: str, metadata: dict,
                 tool_head: str = "gaussian", log_std=None, env_id: str = "suction_debris_v0") -> Path:
    """Write agent ``index``'s deterministic actor (the Gaussian's mean, clipped to the action box; with the switch
    tool head the tool's more likely value, +1 or -1) as a numpy policy folder, the observation normalisation
    folded into the first layer. ``log_std``: this agent's exploration noise (log standard deviation per action
    dimension), recorded for :meth:`dvrl_marl.policies.NumpyPolicy.with_noise`."""
    from dvrl_marl.training.export import write_policy

    norm, net = actor_net.norm, actor_net.nets[index]
    mean = norm.mean.detach().cpu().numpy()
    std = norm.std().detach().cpu().numpy()
    linears = [m for m in net if hasattr(m, "weight")]
    layers = []
    for position, linear in enumerate(linears):
        weight = linear.weight.detach().cpu().numpy().astype(np.float64)
        bias = linear.bias.detach().cpu().numpy().astype(np.float64)
        if position == 0:  # W ((x - m) / s) + b = (W / s) x + (b - W (m / s))
            bias = bias - weight @ (mean / std)
            weight = weight / std[None, :]
        layers.append([weight, bias])
    held_prior = getattr(actor_net, "held_prior", None)
    if held_prior is not None and held_prior[index]:
        _fold_held_prior(layers, actor_net.held_flags, held_prior[index])
    if tool_head == "switch":  # clip(gain x logit) = sign(logit): the plain format's layers suffice
        layers[-1][0][-1] *= SWITCH_EXPORT_GAIN
        layers[-1][1][-1] *= SWITCH_EXPORT_GAIN
    layers = [(weight.astype(np.float32), bias.astype(np.float32), "clip" if position == len(layers) - 1 else "tanh")
              for position, (weight, bias) in enumerate(layers)]
    if getattr(actor_net, "feature_spec", None) is not None:  # the numpy policy computes them before layer 0
        metadata = {**metadata, "features": dict(actor_net.feature_spec)}
    if log_std is not None:  # the noise it acted with while training (NumpyPolicy.with_noise)
        std = [float(v) for v in np.exp(log_std.detach().cpu().numpy().astype(np.float64))]
        if tool_head == "switch":
            std[-1] = None  # the tool is decided open / closed, not perturbed
        metadata = {**metadata, "exploration": {"std": std, "tool_head": tool_head}}
    return write_policy(directory, layers, name=name, env_id=env_id, algorithm="MAPPO",
                        observation_keys=["observation"], action_low=[-1.0] * layers[-1][0].shape[0],
                        action_high=[1.0] * layers[-1][0].shape[0], agent=agent, **metadata)


#: Gain of the exported policy's "holding" unit: tanh(gain x (flags - 1/2)) is +-1 to float precision.
_HELD_UNIT_GAIN = 40.0


def _fold_held_prior(layers: list, held_flags: list[int], offset: float) -> None:
    """Widen every hidden layer of ``layers`` ([weight, bias] pairs, float64, normalisation folded) by one unit that
    carries whether a pin is held (+1) or not (-1) to the last layer, which adds ``offset`` x holding to the tool
    logit: :func:`held_pin_prior` in the plain numpy format (tanh layers), exact to float precision."""
    first_weight, first_bias = layers[0]
    if len(layers) == 1:  # no hidden layer: the flags reach the logit directly
        first_weight[-1, held_flags] += offset
        return
    row = np.zeros((1, first_weight.shape[1]))
    row[0, held_flags] = _HELD_UNIT_GAIN  # the flags sum to 1 while holding, 0 otherwise
    layers[0] = [np.vstack([first_weight, row]), np.append(first_bias, -0.5 * _HELD_UNIT_GAIN)]
    for position in range(1, len(layers)):
        weight, bias = layers[position]
        column = np.zeros((weight.shape[0], 1))
        if position == len(layers) - 1:  # logit + offset x (u + 1) / 2, u = +-1
            column[-1, 0] = 0.5 * offset
            bias = bias.copy()
            bias[-1] += 0.5 * offset
            layers[position] = [np.hstack([weight, column]), bias]
        else:  # pass the unit on: tanh(gain x (+-1)) = +-1
            row = np.zeros((1, weight.shape[1] + 1))
            row[0, -1] = _HELD_UNIT_GAIN
            layers[position] = [np.vstack([np.hstack([weight, column]), row]), np.append(bias, 0.0)]


# --- training -------------------------------------------------------------------------------------------------
#: Box (metres, world frame) of scattered starts: over both cavities and up to the hand-off height.
_SCATTER_LOW = (-0.05, -0.02, 0.035)
_SCATTER_HIGH = (0.075, 0.025, 0.075)


class _Curriculum:
    """Draws reset options for the worlds that ended (see the module documentation)."""

    def __init__(self, config: MappoConfig, env, rng: np.random.Generator):
        self.config = config
        self.env = env
        self.rng = rng
        self.blood = np.asarray(env.params.blood_ml, dtype=np.float64)
        self.debris = env.params.debris_count
        self.range = env.workspace_range
        self.centre = np.asarray(env.params.workspace_centre)
        self.out_of_play = np.zeros(env.num_envs, dtype=np.int64)  # debris each episode left out (count < D)
        self.cut = np.zeros(env.num_envs, dtype=np.int64)  # episode length the trainer imposes (0: the env's)
        self._rims = None  # the way around the phantom's rims (shaping.OverRims), built on first use

    def reset(self, worlds: np.ndarray, easy_fraction: float, progress: float = 0.0):
        n = self.env.num_envs
        easy = worlds & (self.rng.random(n) < easy_fraction)
        hard = worlds & ~easy
        self.out_of_play[worlds] = 0
        self.cut[worlds] = 0
        if hard.any():
            self.env.reset(options={"reset_mask": hard})
        if not easy.any():
            return
        # Each cavity empty half of the time (its debris in view from the start: the grasper's lessons need visible
        # pins, and a pin shows only once the level is a few millimetres deep), otherwise uniform up to the default.
        blood = self.rng.random((n, len(self.blood))) * self.blood
        if self.config.empty_cavity_probability > 0:
            blood[self.rng.random(blood.shape) < self.config.empty_cavity_probability] = 0.0
        count = self.rng.integers(1, self.debris + 1, n)
        self.env.reset(options={"reset_mask": easy, "blood_ml": blood, "debris_count": count})
        self.out_of_play[easy] = self.debris - count[easy]
        self.cut[easy] = self.config.easy_episode_steps
        if self.config.random_start > 0:  # learning agents' tips anywhere over the phantom
            scattered = easy & (self.rng.random(n) < self.config.random_start)
            if scattered.any():
                tips = {agent: self.rng.uniform(_SCATTER_LOW, _SCATTER_HIGH, (n, 3)) for agent in self.env.agents}
                self._place(tips, np.flatnonzero(scattered))
        if "grasper" not in self.env.agents or self.config.near_debris <= 0:
            return
        near = easy & (self.rng.random(n) < self.config.near_debris)
        state = self.env.state()
        debris = self.env.state_layout["debris"].start
        ordinary = self.env.state_layout["grasper_tip"]
        reach = min(1.0, progress / self.config.receding_starts) if self.config.receding_starts > 0 else 0.0
        worlds_near = np.flatnonzero(near)
        targets, chosen = [], []
        for world in worlds_near.tolist():
            pins = [k for k in range(self.debris)
                    if state[world, debris + 6 * k + 3] > 0.5 and state[world, debris + 6 * k + 5] < 0.5]
            if not pins:
                continue
            k = pins[int(self.rng.integers(len(pins)))]
            start = debris + 6 * k
            pin = state[world, start:start + 3] * self.range + self.centre
            # within the jaw's sensor range of the pin's axis: 1-2 mm above it, up to 2 mm aside
            target = pin + np.array([0.0, 0.0, 0.0015]) + self.rng.uniform(-0.002, 0.002, 3) * [1, 1, 0.25]
            if reach > 0:  # the way a tip can take, out of the cavity and around the rims
                if self._rims is None:
                    from dvrl_marl.training.shaping import OverRims

                    self._rims = OverRims(self.env)
                ordinary_tip = state[world, ordinary] * self.range + self.centre
                target = self._rims.point_along(target, ordinary_tip, self.rng.uniform(0.0, reach))
            targets.append(target)
            chosen.append(world)
        if chosen:
            tips = np.zeros((n, 3))
            tips[chosen] = targets
            self._place({"grasper": tips}, chosen)

    def _place(self, tips: dict, worlds) -> None:
        try:
            self.env.set_tip_positions(tips, worlds)
        except ValueError:  # one start collides or is unreachable: place the others one by one
            for world in worlds:
                try:
                    self.env.set_tip_positions(tips, [world])
                except ValueError:
                    pass  # that world keeps its ordinary start


def train(config: MappoConfig, seed: int, out_dir, *, total_steps: int | None = None, resume: bool = False,
          progress: bool = True, tensorboard: bool = True, log=print, ray_address: str | None = None,
          num_collectors: int = 0, on_iteration=None) -> dict:
    """Train (or resume) a run; returns the last evaluation row. Exports the actors to ``out_dir/policies``.

    ``ray_address`` / ``num_collectors``: collect experience on Ray actors (:mod:`dvrl_marl.training.collectors`;
    ``ray_address="auto"`` joins the cluster this machine belongs to, ``None`` with ``num_collectors`` starts Ray in
    this process); otherwise here. ``on_iteration(iteration, collectors)`` runs after each update (monitoring,
    tests)."""
    torch = _torch()
    from tensordict import TensorDict
    from torchrl.objectives import ClipPPOLoss, ValueEstimators

    from dvrl_marl.policies import features
    from dvrl_marl.training.collectors import make_collectors

    if config.torch_threads:
        limit_threads(int(config.torch_threads))
    device = learner_device(config)
    out = Path(out_dir)
    total = int(total_steps or config.total_steps)
    surgeon = None if config.surgeon == "none" else "scripted"  # (who fills the seat does not change the spaces)
    # The learner's view of the env (spaces, layout for the partner in evaluation): one world.
    env = suction_debris_v0.batched_env(num_envs=1, surgeon=surgeon, surgeon_seat=config.surgeon_seat,
                                        autoreset_mode="disabled", **config.env)
    agents = list(env.possible_agents)
    n, horizon, count = config.num_envs, config.rollout_steps, len(agents)
    obs_dim = env.observation_space(agents[0]).shape[0]
    state_dim = env.state_space.shape[0]
    torch.manual_seed(seed)
    actor, critic, actor_net, norms = _build_models(config, agents, obs_dim, state_dim, 4)
    actor.to(device)
    critic.to(device)
    actor_head = actor.module[0].module  # the GaussianHead (its log_std)
    loss_module = ClipPPOLoss(actor_network=actor, critic_network=critic, clip_epsilon=config.clip_epsilon,
                              entropy_coeff=config.entropy_coef, critic_coeff=config.value_coef,
                              normalize_advantage=True, normalize_advantage_exclude_dims=(-2,),
                              loss_critic_type="smooth_l1")
    loss_module.set_keys(reward=("agents", "reward"), action=("agents", "action"),
                         sample_log_prob=("agents", "action_log_prob"), value=("agents", "state_value"),
                         done=("agents", "done"), terminated=("agents", "terminated"))
    loss_module.make_value_estimator(ValueEstimators.GAE, gamma=config.gamma, lmbda=config.gae_lambda)
    optimiser = torch.optim.Adam(loss_module.parameters(), lr=config.learning_rate)
    # running variance of the discounted return, per agent: rewards are divided by its square root (reward scaling)
    return_var_state = {"mean": np.zeros(count), "var": np.ones(count), "count": 1e-4}
    steps_done, iteration, rng_states, seconds_before = 0, 0, None, 0.0
    checkpoint = out / "checkpoint.pt"
    if resume:
        saved = load_checkpoint(checkpoint, device)
        try:
            loss_module.load_state_dict(saved["loss_module"])
            optimiser.load_state_dict(saved["optimiser"])
        except (KeyError, RuntimeError, ValueError) as error:  # another configuration's networks, or a damaged file
            raise ValueError(f"{checkpoint}: its networks do not fit this configuration ({error}); resume it with "
                             "the configuration it was trained with") from None
        return_var_state = {key: np.asarray(value, dtype=np.float64) if key != "count" else float(value)
                            for key, value in saved["return_var"].items()}
        steps_done, iteration = saved["steps"], saved["iteration"]
        rng_states = saved.get("collector_rng") or [saved["rng"]]  # (checkpoints before collectors kept one stream)
        torch.set_rng_state(saved["torch_rng"].cpu())
        seconds_before = float(saved.get("wall_seconds", 0.0))  # the run's cost counts every session it took
        if steps_done >= total:  # nothing to do: the records stay as they are
            log(f"{out}: the run is finished ({steps_done:,d} steps done, {total:,d} asked); nothing was changed. "
                "Pass a larger --steps to extend it.")
            env.close()
            return _finished_result(out, steps_done)
        log(f"resumed {out} at {steps_done} steps")
    elif (out / "checkpoint.pt").exists() or (out / "progress.csv").exists():
        env.close()
        raise ValueError(f"{out} holds a run already (checkpoint.pt / progress.csv): --resume continues it; another "
                         "--out starts a new one. Nothing was overwritten.")
    out.mkdir(parents=True, exist_ok=True)  # (only now: a refused resume leaves no folder behind)
    (out / "config.toml").write_text(_config_toml(config))
    writer = None
    if tensorboard:
        try:
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(out / "tb"))
        except ImportError:
            log("tensorboard is not installed: no TensorBoard logs")
    collectors = make_collectors(config, seed, actor=actor if device.type == "cpu" else None, steps_done=steps_done,
                                 easy=config.easy_fraction(steps_done / total), progress=steps_done / total,
                                 rng_states=rng_states,
                                 ray_address=ray_address, num_collectors=num_collectors)
    if collectors.count > 1 or ray_address is not None or num_collectors:
        spread = collectors.where()
        log(f"collecting on Ray: {len(spread)} collectors on {len({w['node_id'] for w in spread})} node(s), "
            f"{'/'.join(str(w['worlds']) for w in spread)} worlds")
    progress_file = out / "progress.csv"
    if not (resume and progress_file.is_file()):
        progress_file.write_text("steps,success_rate,blood_removed_ml,median_steps,contact_steps,easy_fraction,"
                                 "episode_success,wall_seconds\n")
    start = time.perf_counter() - seconds_before
    next_eval = (steps_done // config.eval_every + 1) * config.eval_every
    next_checkpoint = (steps_done // config.checkpoint_every + 1) * config.checkpoint_every
    episodes_ended = successes = 0
    delivered_sum = blood_left_sum = 0.0
    best_success, best_blood = -1.0, -1.0
    if resume and (out / "best.json").is_file():
        best_success, best_blood = json.loads((out / "best.json").read_text())
    last = {}

    def evaluate(steps: int, easy: float, episode_success: float) -> dict:
        """Validation of the current actors (with the scripted partner, if any): a progress row, the best
        checkpoint's policies, TensorBoard and the log."""
        nonlocal best_success, best_blood
        seats = _learned_seats(actor_net, agents, out, config, seed, steps, actor_head.log_std)
        if surgeon is not None:
            seats[config.surgeon_seat] = _partner(config, env, noise_from=teams.VALIDATION_SEED)
        result = evaluate_team_batched(seats, config.eval_episodes, seed=teams.VALIDATION_SEED,
                                       **_eval_kwargs(config))
        if result["success_rate"] > best_success or (result["success_rate"] == best_success and
                                                     result["mean_blood_removed_ml"] > best_blood):
            best_success, best_blood = result["success_rate"], result["mean_blood_removed_ml"]
            shutil.copytree(out / "policies", out / "policies_best", dirs_exist_ok=True)
            (out / "best.json").write_text(json.dumps([best_success, best_blood]))
        row = {"steps": steps, "success_rate": result["success_rate"],
               "blood_removed_ml": result["mean_blood_removed_ml"],
               "median_steps": result["median_steps_to_completion"], "contact_steps": result["mean_contact_steps"],
               "easy_fraction": easy, "episode_success": episode_success, "wall_seconds": time.perf_counter() - start}
        with progress_file.open("a", newline="") as handle:
            csv.writer(handle).writerow([row[k] for k in ("steps", "success_rate", "blood_removed_ml", "median_steps",
                                                          "contact_steps", "easy_fraction", "episode_success",
                                                          "wall_seconds")])
        if writer is not None:
            writer.add_scalar("eval/success_rate", result["success_rate"], steps)
            writer.add_scalar("eval/blood_removed_ml", result["mean_blood_removed_ml"], steps)
            writer.add_scalar("eval/contact_steps", result["mean_contact_steps"], steps)
        log(f"{config.name} seed {seed} @ {steps:,d} steps: success {result['success_rate']:.2f}, "
            f"blood removed {result['mean_blood_removed_ml']:.1f} ml, "
            f"debris delivered {result['mean_debris_delivered']:.2f}, "
            f"contacts {result['mean_contact_steps']:.1f}, {time.perf_counter() - start:.0f} s")
        return row

    if config.bc_expert and steps_done == 0:  # demonstrations first (dvrl_marl.training.pretrain)
        from dvrl_marl.training import pretrain

        began = time.perf_counter()
        summary = pretrain.clone_experts(config, seed, actor_net, agents)
        summary["wall_seconds"] = time.perf_counter() - began
        (out / "pretrain.json").write_text(json.dumps(summary, indent=2) + "\n")
        fitted = ", ".join(f"{agent}: {value['transitions']:,d} transitions, loss {value['final_loss']:.4f}"
                           for agent, value in summary["agents"].items())
        log(f"{config.name} seed {seed}: cloned the {config.bc_expert} expert ({fitted}) in "
            f"{summary['wall_seconds']:.0f} s")
        last = evaluate(0, config.easy_fraction(0.0), 0.0)  # what the clone does before PPO
    # Where the time goes (benchmarks/ray_scaling.py reads it from result.json): collecting vs. updating.
    timing = {"collect_seconds": 0.0, "learn_seconds": 0.0, "steps": 0, "collectors": collectors.count}
    try:
        while steps_done < total:
            easy = config.easy_fraction(steps_done / total)
            if config.final_std:  # the scheduled exploration noise (the same in collection and in the update)
                with torch.no_grad():
                    actor_head.log_std.fill_(math.log(config.exploration_std(steps_done / total)))
            # --- collect ---
            began = time.perf_counter()
            # (a CPU copy when the learner is elsewhere)
            batch = collectors.collect(actor.state_dict(), easy, steps_done / total)
            timing["collect_seconds"] += time.perf_counter() - began
            began = time.perf_counter()
            for discounted in batch["discounted_return"]:  # step by step, as the returns grew
                _update_running(return_var_state, discounted)
            episodes_ended += batch["stats"]["episodes_ended"]
            successes += batch["stats"]["successes"]
            delivered_sum += batch["stats"]["debris_delivered"]
            blood_left_sum += batch["stats"]["blood_left_ml"]
            obs_buf, next_obs_buf = batch["observation"], batch["next_observation"]
            state_buf, next_state_buf = batch["state"], batch["next_state"]
            action_buf, logp_buf, reward_buf = batch["action"], batch["log_prob"], batch["reward"]
            done_buf, term_buf = batch["done"], batch["terminated"]
            steps_done += n * horizon
            iteration += 1
            # --- learn ---
            if config.anneal_lr:
                for group in optimiser.param_groups:
                    group["lr"] = config.learning_rate * max(1.0 - (steps_done - n * horizon) / total, 0.0)
            scale = np.sqrt(return_var_state["var"] + 1e-8).astype(np.float32)

            def swap(x):  # (T, N, ...) -> (N, T, ...)
                return torch.from_numpy(np.ascontiguousarray(np.swapaxes(x, 0, 1))).to(device)

            done_t = swap(done_buf)[..., None, None].expand(n, horizon, count, 1)
            term_t = swap(term_buf)[..., None, None].expand(n, horizon, count, 1)
            data = TensorDict({
                "agents": TensorDict({"observation": swap(obs_buf), "action": swap(action_buf),
                                      "action_log_prob": swap(logp_buf)}, batch_size=[n, horizon, count]),
                "state": swap(state_buf),
                "next": TensorDict({
                    "agents": TensorDict({"observation": swap(next_obs_buf),
                                          "reward": swap(reward_buf / scale)[..., None],
                                          "done": done_t.clone(), "terminated": term_t.clone()},
                                         batch_size=[n, horizon, count]),
                    "state": swap(next_state_buf)}, batch_size=[n, horizon]),
            }, batch_size=[n, horizon])
            with torch.no_grad():
                loss_module.value_estimator(data, params=loss_module.critic_network_params,
                                            target_params=loss_module.target_critic_network_params)
            flat = data.reshape(-1)
            size = flat.shape[0] // config.minibatches
            sums = {"loss_objective": 0.0, "loss_critic": 0.0, "loss_entropy": 0.0, "clip_fraction": 0.0,
                    "kl_approx": 0.0, "explained_variance": 0.0, "entropy": 0.0}
            for _ in range(config.epochs):
                order = torch.randperm(flat.shape[0])
                for m in range(config.minibatches):
                    batch = flat[order[m * size:(m + 1) * size]]
                    losses = loss_module(batch)
                    total_loss = losses["loss_objective"] + losses["loss_critic"] + losses.get("loss_entropy", 0.0)
                    if config.bounds_loss_coef > 0.0:
                        bounds = config.bounds_loss_coef * bounds_loss(actor_net(batch["agents", "observation"]),
                                                                       config.tool_head)
                        total_loss = total_loss + bounds
                        sums["loss_bounds"] = sums.get("loss_bounds", 0.0) + float(bounds.detach())
                    if steps_done <= config.critic_warmup_steps:  # the actor frozen while the critic learns
                        total_loss = losses["loss_critic"]
                    optimiser.zero_grad()
                    total_loss.backward()
                    torch.nn.utils.clip_grad_norm_(loss_module.parameters(), config.max_grad_norm)
                    optimiser.step()
                    for key in sums:
                        if key in losses.keys():
                            sums[key] += float(losses[key].detach().float().mean())
            # Normalisers move after the update, so the update sees the statistics the rollout was collected with.
            observed = torch.from_numpy(obs_buf).to(device)
            if actor_net.feature_spec is not None:  # the networks normalise observation + features
                observed = features.apply(actor_net.feature_spec, observed)
            # A clone keeps the input scaling it was fitted with (refitting it to the rollouts took one from 0.88
            # success to 0.00 while its weights were frozen).
            if not config.bc_expert:
                norms["observation"].update(observed)
            if "state" in norms:
                norms["state"].update(torch.from_numpy(state_buf).to(device))
            if "critic_observation" in norms:
                norms["critic_observation"].update(observed)
            if writer is not None:
                updates = config.epochs * config.minibatches
                for key, value in sums.items():
                    writer.add_scalar(f"train/{key}", value / updates, steps_done)
                writer.add_scalar("train/reward_mean", float(reward_buf.mean()), steps_done)
                writer.add_scalar("train/easy_fraction", easy, steps_done)
                for i, agent in enumerate(agents):
                    writer.add_scalar(f"train/reward_{agent}", float(reward_buf[..., i].mean()), steps_done)
                if episodes_ended:
                    writer.add_scalar("train/episode_success", successes / episodes_ended, steps_done)
                    writer.add_scalar("train/debris_delivered", delivered_sum / episodes_ended, steps_done)
                    writer.add_scalar("train/blood_left_ml", blood_left_sum / episodes_ended, steps_done)
            if progress:
                rate = (steps_done) / max(time.perf_counter() - start, 1e-9)
                print(f"\r{config.name} seed {seed}: {steps_done:>11,d}/{total:,d} steps "
                      f"({100 * steps_done / total:5.1f} %), {rate:,.0f} steps/s, easy {easy:.2f}, "
                      f"train success {successes / max(episodes_ended, 1):.2f}", end="", file=sys.stderr, flush=True)
            timing["learn_seconds"] += time.perf_counter() - began
            timing["steps"] += n * horizon
            final = steps_done >= total
            if steps_done >= next_eval or final:
                next_eval += config.eval_every
                if progress:
                    print(file=sys.stderr)
                last = evaluate(steps_done, easy, successes / max(episodes_ended, 1))
                episodes_ended = successes = 0
                delivered_sum = blood_left_sum = 0.0
            if steps_done >= next_checkpoint or final:
                next_checkpoint += config.checkpoint_every
                tmp = checkpoint.with_suffix(".tmp")
                # Plain values and tensors only: the file loads with torch.load(weights_only=True), which runs no
                # code from it.
                return_var = {"mean": return_var_state["mean"].tolist(), "var": return_var_state["var"].tolist(),
                              "count": float(return_var_state["count"])}
                torch.save({"loss_module": loss_module.state_dict(), "optimiser": optimiser.state_dict(),
                            "return_var": return_var, "steps": steps_done, "iteration": iteration,
                            "collector_rng": collectors.rng_states(), "torch_rng": torch.get_rng_state(),
                            "wall_seconds": time.perf_counter() - start, "config": asdict(config)}, tmp)
                tmp.replace(checkpoint)  # atomic: an interruption never leaves a half-written checkpoint
            if on_iteration is not None:
                on_iteration(iteration, collectors)
    finally:
        collectors.close()
    if writer is not None:
        writer.close()
    env.close()
    (out / "result.json").write_text(json.dumps({"config": config.name, "seed": seed, **last, "timing": timing},
                                                indent=2) + "\n")
    return last


def _finished_result(out: Path, steps_done: int) -> dict:
    """The last evaluation of a finished run, from its records (result.json, else progress.csv's last row)."""
    result = out / "result.json"
    if result.is_file():
        return json.loads(result.read_text())
    progress = out / "progress.csv"
    rows = list(csv.DictReader(progress.open())) if progress.is_file() else []
    last = {key: float(value) for key, value in rows[-1].items()} if rows else {"success_rate": float("nan")}
    return {**last, "steps": steps_done}


def load_checkpoint(path, device="cpu") -> dict:
    """A run's ``checkpoint.pt``, read with ``torch.load(weights_only=True)``: tensors and plain values only, so a
    crafted file cannot run code (the earliest checkpoints' numpy arrays are allowed by name, nothing else). A
    missing, damaged or foreign file is a ``ValueError`` naming it."""
    torch = _torch()
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no checkpoint to resume from (a mistyped --out, or a run that never reached its "
                         "first checkpoint); nothing was started or overwritten")
    numpy_arrays = [np.ndarray, np.dtype, getattr(np, "_core", getattr(np, "core", None)).multiarray._reconstruct]
    numpy_arrays += [getattr(np.dtypes, name) for name in ("Float64DType", "Float32DType", "Int64DType", "BoolDType")
                     if hasattr(np, "dtypes")]
    try:
        with torch.serialization.safe_globals(numpy_arrays):
            saved = torch.load(path, weights_only=True, map_location=device)
    except Exception as error:  # noqa: BLE001  (UnpicklingError, RuntimeError, EOFError...: all say "not readable")
        reason = str(error).strip().splitlines()[-1] if str(error).strip() else type(error).__name__
        raise ValueError(f"{path}: not a checkpoint this trainer can read ({type(error).__name__}: "
                         f"{reason[:300]}); it is loaded as weights only, so a file that would run code is refused")
    missing = [key for key in ("loss_module", "optimiser", "return_var", "steps", "iteration", "torch_rng")
               if not isinstance(saved, dict) or key not in saved]
    if missing:
        raise ValueError(f"{path}: not a dvrl-marl MAPPO checkpoint (missing {missing})")
    return saved


def learner_device(config: MappoConfig):
    """The torch device of the learner's update (``config.device``; "auto": the first GPU when there is one)."""
    torch = _torch()
    name = str(config.device)
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {config.device!r}: this torch sees no GPU (torch {torch.__version__}); "
                         'use device = "cpu" or "auto"')
    return device


def _update_running(stats: dict, x: np.ndarray) -> None:
    batch_mean, batch_var, count = x.mean(axis=0), x.var(axis=0), x.shape[0]
    delta, total = batch_mean - stats["mean"], stats["count"] + count
    stats["mean"] = stats["mean"] + delta * count / total
    stats["var"] = (stats["var"] * stats["count"] + batch_var * count + delta**2 * stats["count"] * count / total) / total
    stats["count"] = total


def _eval_kwargs(config: MappoConfig) -> dict:
    return {k: v for k, v in config.env.items() if k != "reward_type"}


def _learned_seats(actor_net, agents, out: Path, config: MappoConfig, seed: int, steps: int, log_std=None) -> dict:
    """Export the current actors and load them back as numpy policies (what users get is what is evaluated);
    with ``evaluate_with_noise`` they act with their exploration noise (seeded), as ``evaluate-team --noise``."""
    from dvrl_marl import policies

    seats = {}
    for index, agent in enumerate(agents):
        folder = out / "policies" / f"marl-{agent}"
        export_actor(actor_net, index, folder, name=f"marl-{agent}", agent=agent, tool_head=config.tool_head,
                     env_id=suction_debris_v0.env_name(str(config.env.get("task", "suction_debris"))),
                     metadata={"training": {"config": config.name, "algorithm": config.algorithm, "seed": seed,
                                            "steps": steps, "partners": _partners(config),
                                            **_demonstrations(config)}},
                     log_std=None if log_std is None else log_std[index])
        seats[agent] = policies.load(folder)
        if config.evaluate_with_noise:
            seats[agent] = seats[agent].with_noise(teams.noise_seed(agent, teams.VALIDATION_SEED))
    return seats


def limit_threads(count: int) -> None:
    """Cap torch's threads and numpy's BLAS threads (through threadpoolctl, when installed) at ``count``. Why BLAS
    too: a learned partner's numpy forward pass, with OpenBLAS's two threads competing against a second run on a
    2-core machine, took 8.5 ms a call instead of 0.34 (a trainer beside a learned partner ran 4.4x slower)."""
    _torch().set_num_threads(int(count))
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(int(count), user_api="blas")


def _check_surgeon(path, config: MappoConfig) -> None:
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
    if config.surgeon_seat not in suction_debris_v0.AGENTS:
        raise ValueError(f"{path}: surgeon_seat must be one of {suction_debris_v0.AGENTS}, got {config.surgeon_seat!r}")
    for name in names:
        if name in ("scripted", "pipeline"):
            continue
        try:
            teams.seat(name, config.surgeon_seat)
        except (ValueError, FileNotFoundError, KeyError) as error:
            raise ValueError(f"{path}: surgeon {name!r} cannot fill the {config.surgeon_seat!r} seat: {error}") from None


def _partner(config: MappoConfig, env, noise_from: int):
    """The filler of the partner seat (see MappoConfig.surgeon and teams.partner), or None; ``env``: the one whose
    layout a scripted partner reads (None: a world of ``config.env``)."""
    if config.surgeon == "none":
        return None
    if env is None:
        env = suction_debris_v0.parallel_env(**config.env)
    return teams.partner(config.surgeon, config.surgeon_seat, env, noise_from=noise_from)


def _partners(config: MappoConfig) -> list:
    """Who filled the other seat while this policy learnt (recorded in its policy.json): [] when both learnt."""
    if config.surgeon == "none":
        return []
    return [config.surgeon] if isinstance(config.surgeon, str) else list(config.surgeon)


def _demonstrations(config: MappoConfig) -> dict:
    """What a policy learnt from besides its reward (recorded in its policy.json): nothing, or the cloned expert."""
    if not config.bc_expert:
        return {"demonstrations": None}
    return {"demonstrations": {"expert": config.bc_expert, "episodes": int(config.bc_episodes),
                               "action_noise": config.bc_action_noise, "dagger_rounds": int(config.bc_dagger_rounds)}}


def _config_toml(config: MappoConfig) -> str:
    lines = ["[run]"]
    for f in fields(MappoConfig):
        value = getattr(config, f.name)
        if f.name in ("env", "name") or value is None:  # TOML has no null: an absent key is the default (None)
            continue
        lines.append(f"{f.name} = {_toml_value(value)}")
    lines.append("[env]")
    lines += [f"{k} = {_toml_value(v)}" for k, v in config.env.items()]
    return "\n".join(lines) + "\n"


def _toml_value(value) -> str:
    if isinstance(value, dict):  # an inline table (JSON's braces are not TOML's)
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    return json.dumps(value)
