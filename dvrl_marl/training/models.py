"""The MAPPO / IPPO trainer's networks on TorchRL: per-agent Gaussian (or switch) actors, MAPPO's centralised
critics or IPPO's per-agent ones, running normalisation; their export to the numpy policy format
(:mod:`dvrl_marl.policies`); and the torch / BLAS thread and device settings. Task-free: the observation and the
state are whatever the env gives (its ``observation_features`` option included).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from dvrl_marl.suction_debris.layout import MOVE
from dvrl_marl.suction_debris.observation_scaling import MIN_SPREAD
from dvrl_marl.suction_debris.task import TASK

__all__ = ["require_torch", "switch_gaussian", "bounds_loss", "build_models", "export_actor", "actor_arrays",
           "write_actor", "limit_threads",
           "learner_device", "SWITCH_EXPORT_GAIN"]

#: Gain folded into an exported switch head's last layer: clip(gain x logit) is the sign of the logit, the
#: distribution's most likely tool value, in the numpy policy format's plain layers.
SWITCH_EXPORT_GAIN = 1e6



# --- models ---------------------------------------------------------------------------------------------------
def require_torch():
    try:
        import torch  # noqa: F401
        import torchrl  # noqa: F401
    except ImportError as error:
        raise ModuleNotFoundError(f"the MAPPO trainer needs torch and torchrl ({error.name} is missing): "
                                  'pip install "dvrl-marl[train]"', name=error.name) from None
    import torch

    return torch


_SWITCH_CLASS = None



def switch_gaussian():
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
    torch = require_torch()
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
    motion = loc[..., MOVE] if tool_head == "switch" else loc
    return (motion.abs() - 1.0).clamp_min(0.0).pow(2).sum(-1).mean()



def build_models(config, agents, obs_dim: int, state_dim: int, action_dim: int, *, feature_spec: dict | None = None):
    """The actors (one per agent), the critic (MAPPO: centralised; IPPO: per agent), the actors' network and the
    running normalisers. ``obs_dim``: the observation as the env gives it (with the env's ``observation_features``
    appended when it has them; ``feature_spec`` records them for the exported policies)."""
    torch = require_torch()
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

        def moments(self, x):
            """The batch's mean, variance and count over every leading dimension of ``x``: two passes in its own
            precision (within 2e-7 of float64's; a copy in float64 and torch's strided variance took 4-7x as long),
            merged in float64."""
            x = x.reshape(-1, *self.mean.shape)
            mean = x.mean(0)
            centred = x - mean
            return mean.double(), (centred * centred).mean(0).double(), x.shape[0]

        def update(self, x, moments=None):
            """Merge the batch ``x`` into the running statistics (``moments``: those of ``x`` computed already)."""
            batch_mean, batch_var, n = moments or self.moments(x)
            delta, total = batch_mean - self.mean, self.count + n
            self.mean += delta * n / total
            self.var.copy_((self.var * self.count + batch_var * n + delta**2 * self.count * n / total) / total)
            self.count.fill_(total)

        def std(self):
            return torch.sqrt(self.var).clamp_min(MIN_SPREAD)  # constant features (the hand-off point) stay finite

        def forward(self, x):
            return ((x - self.mean.float()) / self.std().float())

    class Tanh(nn.Tanh):
        """tanh as 2 sigmoid(2x) - 1 (within 2e-7 of it; the exported policies compute tanh). Why: torch's CPU tanh
        took 350-440 us for 2,048 x 64 on one thread, this 140 (numpy's tanh 61), and tanh was 18 % of PPO's
        update (measured 2026-11-27, torch 2.13 CPU build)."""

        def forward(self, x):
            return torch.sigmoid(2.0 * x) * 2.0 - 1.0

    def mlp(inputs, outputs):
        layers, width = [], inputs
        for size in config.hidden:
            layers += [nn.Linear(width, int(size)), Tanh()]
            width = int(size)
        layers.append(nn.Linear(width, outputs))
        return nn.Sequential(*layers)

    class PerAgent(nn.Module):
        """One network per agent: input (..., A, d) -> output (..., A, k)."""

        def __init__(self, inputs, outputs, norm):
            super().__init__()
            self.norm = norm
            self.feature_spec = feature_spec
            self.nets = nn.ModuleList(mlp(inputs, outputs) for _ in agents)

        def agent_forward(self, x, index: int):
            """Agent ``index``'s output on its own observations ``(..., d)`` (behaviour cloning)."""
            return self.nets[index](self.norm(x))

        def forward(self, x):
            x = self.norm(x)
            return torch.stack([net(x[..., i, :]) for i, net in enumerate(self.nets)], dim=-2)

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
            seen = self.observation.norm(observation)
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

    obs_norm = RunningNorm((obs_dim,))
    actor_net = PerAgent(obs_dim, action_dim, obs_norm)
    with torch.no_grad():  # small initial means: exploration starts from the standard deviation alone
        for agent, net in zip(agents, actor_net.nets):
            net[-1].weight.mul_(0.01)
            net[-1].bias.zero_()
            if config.tool_head == "switch":  # the tool's initial leaning (a prior the policy may unlearn)
                net[-1].bias[-1] = float(config.initial_tool_logit.get(agent, 0.0))
    policy_module = TensorDictModule(GaussianHead(actor_net), in_keys=[("agents", "observation")],
                                     out_keys=[("agents", "loc"), ("agents", "scale")])
    distribution = switch_gaussian() if config.tool_head == "switch" else IndependentNormal
    actor = ProbabilisticActor(policy_module, in_keys=[("agents", "loc"), ("agents", "scale")],
                               out_keys=[("agents", "action")], distribution_class=distribution,
                               return_log_prob=True, log_prob_key=("agents", "action_log_prob"))
    if config.algorithm == "mappo" and config.critic_input == "state_and_observation":
        state_norm = RunningNorm((state_dim,))
        seen = PerAgent(obs_dim + state_dim, 1, RunningNorm((obs_dim,)))  # inputs: state + observation
        critic = TensorDictModule(AgentSpecificCritic(state_norm, seen), in_keys=["state", ("agents", "observation")],
                                  out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "state": state_norm, "critic_observation": seen.norm}
    elif config.algorithm == "mappo":
        state_norm = RunningNorm((state_dim,))
        critic = TensorDictModule(CentralCritic(state_norm), in_keys=["state"], out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "state": state_norm}
    else:
        critic = TensorDictModule(PerAgent(obs_dim, 1, RunningNorm((obs_dim,))),
                                  in_keys=[("agents", "observation")],
                                  out_keys=[("agents", "state_value")])
        norms = {"observation": obs_norm, "critic_observation": critic.module.norm}
    return actor, critic, actor_net, norms


def update_norms(norms: dict, observations, states=None, *, observation: bool = True) -> None:
    """Move the running normalisers of :func:`build_models` by a rollout's ``observations`` (..., A, d) and
    ``states`` (..., S); the actor's and the critic's observation normalisers see the same batch, whose moments are
    computed once. ``observation=False`` leaves the actor's normaliser as it is (a clone keeps its input scaling)."""
    seen = None
    for key in ("observation", "critic_observation"):
        if key in norms and (observation or key != "observation"):
            seen = seen or norms[key].moments(observations)
            norms[key].update(observations, seen)
    if "state" in norms:
        norms["state"].update(states)


# --- numpy export ---------------------------------------------------------------------------------------------
def actor_arrays(actor_net, index: int, log_std=None) -> dict:
    """Agent ``index``'s actor of a torch ``actor_net`` as numpy arrays (what :func:`write_actor` writes): its
    ``layers`` ``[(weight, bias), ...]``, its normaliser's ``mean`` and ``std``, and ``log_std`` (None: no
    exploration recorded)."""
    norm, net = actor_net.norm, actor_net.nets[index]
    layers = [(linear.weight.detach().cpu().numpy(), linear.bias.detach().cpu().numpy())
              for linear in net if hasattr(linear, "weight")]
    return {"layers": layers, "mean": norm.mean.detach().cpu().numpy(), "std": norm.std().detach().cpu().numpy(),
            "log_std": None if log_std is None else log_std.detach().cpu().numpy()}


def write_actor(arrays: dict, directory, *, name: str, agent: str, metadata: dict, tool_head: str = "gaussian",
                env_id: str = TASK, input_scaling=None, feature_spec: dict | None = None) -> Path:
    """Write a deterministic actor given as numpy ``arrays`` (:func:`actor_arrays`) as a numpy policy folder: the
    Gaussian's mean clipped to the action box (with the switch tool head the tool's more likely value, +1 or -1), the
    observation normalisation folded into the first layer. ``arrays["log_std"]``: its exploration noise, recorded for
    :meth:`dvrl_marl.policies.NumpyPolicy.with_noise`. ``input_scaling``: the env's ``normalize_observations`` map of
    this agent, ``(centre, spread)``, folded in too, so that the exported policy reads the scene's units as every seat
    gives them. ``feature_spec``: the observation features the policy computes before its first layer."""
    from dvrl_marl.training.export import write_policy

    mean = np.asarray(arrays["mean"], dtype=np.float64)
    std = np.asarray(arrays["std"], dtype=np.float64)
    if input_scaling is not None:  # ((x - c) / r - m) / s = (x - (c + r m)) / (r s)
        centre, spread = (np.asarray(v, dtype=np.float64) for v in input_scaling)
        mean, std = centre + spread * mean, spread * std
    layers = []
    for position, (weight, bias) in enumerate(arrays["layers"]):
        weight, bias = np.asarray(weight, dtype=np.float64), np.asarray(bias, dtype=np.float64)
        if position == 0:  # W ((x - m) / s) + b = (W / s) x + (b - W (m / s))
            bias = bias - weight @ (mean / std)
            weight = weight / std[None, :]
        layers.append([weight, bias])
    if tool_head == "switch":  # clip(gain x logit) = sign(logit): the plain format's layers suffice
        layers[-1][0][-1] *= SWITCH_EXPORT_GAIN
        layers[-1][1][-1] *= SWITCH_EXPORT_GAIN
    layers = [(weight.astype(np.float32), bias.astype(np.float32), "clip" if position == len(layers) - 1 else "tanh")
              for position, (weight, bias) in enumerate(layers)]
    if feature_spec is not None:  # the numpy policy computes them before layer 0
        metadata = {**metadata, "features": dict(feature_spec)}
    if arrays.get("log_std") is not None:  # the noise it acted with while training (NumpyPolicy.with_noise)
        std = [float(v) for v in np.exp(np.asarray(arrays["log_std"], dtype=np.float64))]
        if tool_head == "switch":
            std[-1] = None  # the tool is decided open / closed, not perturbed
        metadata = {**metadata, "exploration": {"std": std, "tool_head": tool_head}}
    return write_policy(directory, layers, name=name, env_id=env_id, algorithm="MAPPO",
                        observation_keys=["observation"], action_low=[-1.0] * layers[-1][0].shape[0],
                        action_high=[1.0] * layers[-1][0].shape[0], agent=agent, **metadata)


def export_actor(actor_net, index: int, directory, *, name: str, agent: str, metadata: dict,
                 tool_head: str = "gaussian", log_std=None, env_id: str = TASK,
                 input_scaling=None) -> Path:
    """Write agent ``index``'s deterministic actor of a torch ``actor_net`` as a numpy policy folder
    (:func:`write_actor`; ``log_std``: this agent's log standard deviation per action dimension)."""
    return write_actor(actor_arrays(actor_net, index, log_std), directory, name=name, agent=agent, metadata=metadata,
                       tool_head=tool_head, env_id=env_id, input_scaling=input_scaling,
                       feature_spec=getattr(actor_net, "feature_spec", None))



def limit_threads(count: int) -> None:
    """Cap torch's threads and numpy's BLAS threads (through threadpoolctl, when installed) at ``count``. Why BLAS
    too: a learned partner's numpy forward pass, with OpenBLAS's two threads competing against a second run on a
    2-core machine, took 8.5 ms a call instead of 0.34 (a trainer beside a learned partner ran 4.4x slower)."""
    require_torch().set_num_threads(int(count))
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(int(count), user_api="blas")



def learner_device(config):
    """The torch device of the learner's update (``config.device``; "auto": the first GPU when there is one)."""
    torch = require_torch()
    name = str(config.device)
    if name == "auto":
        name = "cuda" if torch.cuda.is_available() else "cpu"
    device = torch.device(name)
    if device.type == "cuda" and not torch.cuda.is_available():
        raise ValueError(f"device {config.device!r}: this torch sees no GPU (torch {torch.__version__}); "
                         'use device = "cpu" or "auto"')
    return device

