"""Behaviour cloning of a seat from a Minari dataset: a surgeon learned from demonstrations, then seated.

``dvrl-marl train baselines/configs/surgeon_bc.toml`` records the dataset it names if it is not there yet (the
scripted surgeon, 20 episodes), clones it and evaluates the clone in the seat beside its partner on held-out seeds:

```toml
[run]
algorithm = "bc"
dataset = "dvrl_marl/surgeon-scripted-v1"   # a Minari dataset id (see dvrl_marl.datasets)
[record]                                     # how to make the dataset if it is missing
policy = "scripted"
episodes = 100
action_noise = 0.3                           # DART: the expert corrects noisy motion; labels stay its own
[bc]
hidden = [256, 256]
epochs = 300
cleared_features = true                      # a sharp "cavity cleared" input per cavity (the expert's switch)
[dagger]                                     # optional: DAgger rounds after the clone (needs a queryable expert)
rounds = 3
episodes = 100
[evaluate]
partner = "pipeline"                         # the learned suction
episodes = 100
```

``[dagger]`` (Ross, Gordon and Bagnell 2011): the clone works the seat beside its partner on ``episodes`` training
worlds (seeds from ``seed``, never the held-out range), the expert labels every observation it visited, the
labels join the dataset's and the clone is fitted again; ``rounds`` times. It needs an expert to ask: the
dataset's recorder must be ``"scripted"`` (a person's recording has none). The relabelled transitions are saved
beside the policy (``dagger.npz``).

The network maps the seat's observation (normalised by the dataset's mean and spread, folded into the exported
first layer) to its action through tanh layers; the loss is the mean squared action error. The clone is a numpy
policy (``<out>/policies/bc-surgeon``) that fills the surgeon seat like any other.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dvrl_marl.training import trainers

__all__ = ["CloneConfig", "load_config", "clone", "train", "dagger_round", "DAGGER_SEED"]

#: DAgger's worlds are seeded from here: apart from the recorded episodes' seeds (0...) and from the validation and
#: held-out ranges (teams.VALIDATION_SEED, teams.EVAL_SEED).
DAGGER_SEED = 100_000_000


@dataclass(frozen=True)
class CloneConfig:
    name: str
    dataset: str
    record: dict = field(default_factory=dict)
    hidden: tuple[int, ...] = (256, 256)
    epochs: int = 300
    batch_size: int = 512
    learning_rate: float = 1e-3
    cleared_features: bool = False  # a sharp "cavity cleared" step per cavity (see clone's threshold_features)
    anneal_lr: bool = False  # cosine decay of the learning rate to 0 over the epochs
    action_weights: tuple[float, ...] | None = None  # a weight per action dimension in the squared error
    evaluate: dict = field(default_factory=dict)
    dagger: dict = field(default_factory=dict)


def load_config(path) -> CloneConfig:
    """A behaviour-cloning configuration, each table checked against its schema (:mod:`dvrl_marl.schemas`:
    ``CloneRun``, ``CloneBc``, ``CloneRecord``, ``CloneEvaluate``, ``CloneDagger``)."""
    from dvrl_marl import schemas
    from dvrl_marl.files import read_toml

    path = Path(path)
    table = read_toml(path)
    models = {"run": schemas.CloneRun, "bc": schemas.CloneBc, "record": schemas.CloneRecord,
              "evaluate": schemas.CloneEvaluate, "dagger": schemas.CloneDagger}
    for name, content in table.items():
        if name not in models or not isinstance(content, dict):
            raise ValueError(f"{path}: unknown table [{name}] (known: {', '.join(models)})")
    if "run" not in table:
        raise ValueError(f"{path}: missing table [run] (algorithm = \"bc\" and a dataset id)")
    checked = {name: schemas.validated(model, table[name], str(path), table=name)
               for name, model in models.items() if name in table}
    bc = checked["bc"].model_dump(exclude_none=True) if "bc" in checked else {}
    record = checked["record"].model_dump(exclude_none=True) if "record" in checked else {}
    dagger = checked["dagger"].model_dump() if "dagger" in checked else {}
    evaluate = (checked["evaluate"] if "evaluate" in checked else schemas.CloneEvaluate()).model_dump()
    if dagger and record.get("policy", "scripted") != "scripted":
        raise ValueError(f"{path}: [dagger] asks the expert to label the clone's states: [record] policy must be "
                         "\"scripted\"")
    return CloneConfig(name=path.stem, dataset=checked["run"].dataset, record=record, evaluate=evaluate,
                       dagger=dagger, **bc)


def cleared_features() -> list[tuple[int, float]]:
    """``(observation index, threshold)`` of each cavity's blood fraction in the seat's observation, at the task's
    "cleared" level (the scripted surgeon goes for a cavity's debris once its blood is under it)."""
    from dvrl_marl.envs import suction_debris

    scene = suction_debris.parallel_env()
    blood = scene.observation_layout["blood"]
    thresholds = scene.layout().blood_threshold_fraction
    scene.close()
    return [(blood.start + index, float(level)) for index, level in enumerate(thresholds)]


#: Threshold features: tanh(STEEPNESS x (level - value)), +-0.76 at 1/STEEPNESS from the level (blood fractions
#: hover within 0.005 of it while a partner finishes a cavity).
STEEPNESS = 1000.0
#: Pass-through features: tanh(PASS_SCALE x standardised value), nearly linear over the data's range.
PASS_SCALE = 0.25


def _feature_layer(mean, std, threshold_features):
    """A fixed first layer (weight, bias; tanh): the standardised observation, scaled into tanh's linear range,
    then one sharp step per threshold feature. An MLP cannot draw a step 0.005 wide on its own."""
    dimension = len(mean)
    weight = np.zeros((dimension + len(threshold_features), dimension))
    bias = np.zeros(dimension + len(threshold_features))
    weight[np.arange(dimension), np.arange(dimension)] = PASS_SCALE / std
    bias[:dimension] = -PASS_SCALE * mean / std
    for row, (index, level) in enumerate(threshold_features, start=dimension):
        weight[row, index] = -STEEPNESS
        bias[row] = STEEPNESS * level
    return weight, bias


def clone(observations: np.ndarray, actions: np.ndarray, directory, *, hidden=(256, 256), epochs: int = 300,
          batch_size: int = 512, learning_rate: float = 1e-3, seed: int = 0, name: str = "bc-surgeon",
          metadata: dict | None = None, threshold_features=(), action_weights=None,
          anneal_lr: bool = False) -> tuple[Path, list[float]]:
    """Fit ``observation -> action`` and export it as a numpy policy folder; returns it and the loss per epoch.

    ``threshold_features``: ``(index, level)`` pairs; the network also sees a sharp step at each (a fixed first
    layer, exported with the rest: the numpy policy needs nothing new). ``action_weights``: a weight per action
    dimension in the squared error (the jaw's switch matters more than a motion's last digit); ``anneal_lr``: the
    learning rate falls to 0 along a cosine over the epochs (a sharper fit at the end)."""
    import torch

    from dvrl_marl.training.export import write_policy

    torch.manual_seed(seed)
    generator = np.random.default_rng(seed)
    x = np.asarray(observations, dtype=np.float64)
    y = np.asarray(actions, dtype=np.float32)
    mean, std = x.mean(axis=0), x.std(axis=0) + 1e-6
    features = None
    if threshold_features:
        features = _feature_layer(mean, std, list(threshold_features))
        inputs = torch.as_tensor(np.tanh(x @ features[0].T + features[1]), dtype=torch.float32)
    else:
        inputs = torch.as_tensor((x - mean) / std, dtype=torch.float32)
    targets = torch.as_tensor(y)
    sizes = [inputs.shape[1], *[int(h) for h in hidden], y.shape[1]]
    layers = []
    for index in range(len(sizes) - 1):
        layers += [torch.nn.Linear(sizes[index], sizes[index + 1]), torch.nn.Tanh()]
    net = torch.nn.Sequential(*layers)
    optimiser = torch.optim.Adam(net.parameters(), lr=learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimiser, int(epochs)) if anneal_lr else None
    weights = torch.as_tensor(np.ones(y.shape[1]) if action_weights is None else action_weights, dtype=torch.float32)
    losses = []
    for _ in range(int(epochs)):
        order = torch.as_tensor(generator.permutation(len(inputs)))
        total = 0.0
        for start in range(0, len(order), batch_size):
            batch = order[start:start + batch_size]
            loss = ((net(inputs[batch]) - targets[batch]) ** 2 * weights).mean()
            optimiser.zero_grad()
            loss.backward()
            optimiser.step()
            total += loss.item() * len(batch)
        losses.append(total / len(order))
        if schedule is not None:
            schedule.step()
    exported = [] if features is None else [(features[0].astype(np.float32), features[1].astype(np.float32), "tanh")]
    linears = [module for module in net if isinstance(module, torch.nn.Linear)]
    for position, linear in enumerate(linears):
        weight = linear.weight.detach().numpy().astype(np.float64)
        bias = linear.bias.detach().numpy().astype(np.float64)
        if position == 0 and features is None:  # W ((x - m) / s) + b = (W / s) x + (b - W (m / s))
            bias = bias - weight @ (mean / std)
            weight = weight / std[None, :]
        exported.append((weight.astype(np.float32), bias.astype(np.float32), "tanh"))
    folder = write_policy(directory, exported, name=name, env_id="dvrl_marl/SurgeonSeat-v8",
                          algorithm="behaviour cloning", observation_keys=["observation"],
                          action_low=[-1.0] * y.shape[1], action_high=[1.0] * y.shape[1], agent="grasper",
                          **(metadata or {}))
    return folder, losses


def dagger_round(policy, partner: str, episodes: int, seed: int):
    """Let ``policy`` work the grasper seat beside ``partner`` on ``episodes`` worlds (seeded ``seed``, ``seed + 1``...)
    and return every observation it visited with the scripted surgeon's action for it."""
    from dvrl_marl.envs import suction_debris
    from dvrl_marl.training import teams

    env = suction_debris.batched_env(num_envs=episodes, autoreset_mode="disabled")
    expert, suction = teams.seat("scripted", "grasper"), teams.seat(partner, "suction")
    observations, _ = env.reset(seed=seed)
    done = np.zeros(episodes, dtype=bool)
    visited, labels = [], []
    while not done.all():
        live = ~done
        grasper = observations["grasper"]
        visited.append(grasper[live].copy())
        labels.append(np.asarray(expert(grasper[live]), dtype=np.float32))
        observations, _, terminations, truncations, _ = env.step(
            {"suction": np.asarray(suction(observations["suction"])), "grasper": np.asarray(policy(grasper))})
        done |= terminations["grasper"] | truncations["grasper"]
    env.close()
    return np.concatenate(visited), np.concatenate(labels)


def train(config: CloneConfig, seed: int, out, progress: bool = True) -> dict:
    """Record the dataset if missing, clone it, evaluate the clone; writes ``<out>/result.json``."""
    import minari

    from dvrl_marl import datasets, policies
    from dvrl_marl.training import teams

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    began = time.perf_counter()
    if config.dataset not in minari.list_local_datasets():
        record = {"policy": "scripted", "episodes": 20, "seed": 0, **config.record}
        datasets.record(config.dataset, record["policy"], int(record["episodes"]), seed=int(record["seed"]),
                        env_kwargs=record.get("env_kwargs"), action_noise=float(record.get("action_noise", 0.0)))
        if progress:
            print(f"recorded {record['episodes']} episodes of {record['policy']} as {config.dataset}")
    observations, actions = datasets.transitions(config.dataset)
    fit = dict(hidden=config.hidden, epochs=config.epochs, batch_size=config.batch_size,
               learning_rate=config.learning_rate, seed=seed,
               threshold_features=cleared_features() if config.cleared_features else (),
               anneal_lr=config.anneal_lr, action_weights=config.action_weights)
    folder, losses = clone(observations, actions, out / "policies" / "bc-surgeon", **fit,
                           metadata={"dataset": config.dataset, "transitions": int(len(actions))})
    partner = {"partner": "pipeline", **config.evaluate}["partner"]
    rounds = []
    if config.dagger:
        dagger = {"rounds": 3, "episodes": 100, "seed": DAGGER_SEED, **config.dagger}
        seen, labels = [observations], [actions]
        for index in range(int(dagger["rounds"])):
            visited, expert = dagger_round(policies.load(folder), partner, int(dagger["episodes"]),
                                           int(dagger["seed"]) + index * int(dagger["episodes"]))
            seen.append(visited)
            labels.append(expert)
            observations, actions = np.concatenate(seen), np.concatenate(labels)
            folder, losses = clone(observations, actions, out / "policies" / "bc-surgeon", **fit,
                                   metadata={"dataset": config.dataset, "transitions": int(len(actions)),
                                             "dagger_rounds": index + 1})
            rounds.append({"round": index + 1, "visited": int(len(visited)), "transitions": int(len(actions)),
                           "final_loss": losses[-1]})
            if progress:
                print(f"DAgger round {index + 1}: {len(visited)} states relabelled, {len(actions)} transitions")
        np.savez_compressed(out / "dagger.npz", observations=np.concatenate(seen[1:]),
                            actions=np.concatenate(labels[1:]))
    evaluate = {"partner": "pipeline", "episodes": 100, **config.evaluate}
    team = {"suction": teams.seat(evaluate["partner"], "suction"), "grasper": policies.load(folder)}
    result = teams.evaluate_team_batched(team, int(evaluate["episodes"]))
    summary = {"dataset": config.dataset, "transitions": int(len(actions)), "final_loss": losses[-1],
               "partner": evaluate["partner"], "policy": str(folder), "dagger": rounds,
               "wall_seconds": round(time.perf_counter() - began, 1),
               **{k: v for k, v in result.items() if k not in ("success", "steps")}}
    (out / "result.json").write_text(json.dumps(summary, indent=2) + "\n")
    return summary


def train_from_request(request, run_table: dict) -> int:
    """``dvrl-marl train`` with a behaviour-cloning configuration."""
    config = load_config(request.config)
    out = request.out_folder(config.name)
    result = train(config, request.seed, out, progress=request.progress)
    print(f"{config.name} seed {request.seed}: the clone succeeds in {result['success_rate']:.0%} of "
          f"{result['episodes']} held-out episodes beside the {result['partner']} partner; policy in "
          f"{result['policy']}; run folder {out}")
    return 0


TRAINER = trainers.register(trainers.Trainer(
    name="bc", algorithms=("bc",), run=train_from_request, needs=("torch", "minari"),
    install='pip install "dvrl-marl[train,data]"',
    summary="a seat cloned from a Minari dataset of demonstrations (behaviour cloning)"))
