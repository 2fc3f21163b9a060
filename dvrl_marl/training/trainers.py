"""The trainers ``dvrl-marl train`` runs, registered by name: each trainer's module registers itself
(:func:`register`), saying which configurations it trains, what it takes from the command line and what it needs
installed; ``dvrl-marl train`` asks :func:`choose` for one (no list of trainers in the command line's code).

A configuration's ``[run] algorithm`` names what it learns; several trainers may train it (MAPPO/IPPO: ``jax``, the
default, and ``torchrl``). ``--trainer`` picks one; without it the first by ``rank`` that can take the run is chosen,
and when one ranked before it could not, the command says which and why (never a silent change of trainer). A
trainer of one's own registers the same way::

    from dvrl_marl.training import trainers

    trainers.register(trainers.Trainer(name="my-mappo", algorithms=("mappo",), rank=-1, run=my_run,
                                       takes=frozenset({"steps", "export"}), summary="MAPPO, my way"))
"""

from __future__ import annotations

import importlib.util
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Callable

__all__ = ["Trainer", "TrainRequest", "register", "registered", "algorithms", "choose", "RETIRED"]


@dataclass(frozen=True)
class TrainRequest:
    """What ``dvrl-marl train`` was asked: the configuration file and the run's options. Options a trainer does not
    take must be left at these defaults (:attr:`Trainer.takes`)."""

    config: Path
    seed: int = 0
    out: Path | None = None
    progress: bool = True
    steps: int | None = None
    export: Path | None = None
    resume: bool = False
    tensorboard: bool = False
    ray_address: str | None = None
    num_collectors: int | None = None
    device: str | None = None
    validators: int | None = None

    def given(self) -> list[str]:
        """The options given beyond the ones every trainer takes (config, seed, out, progress)."""
        common = {"config", "seed", "out", "progress"}
        return [item.name for item in fields(self)
                if item.name not in common and getattr(self, item.name) != item.default]

    def out_folder(self, name: str) -> Path:
        """The run folder: ``--out``, else ``runs/<name>-seed<seed>``."""
        return Path(self.out or Path("runs") / f"{name}-seed{self.seed}")


def flag(option: str) -> str:
    """A :class:`TrainRequest` field as the command line spells it (``ray_address`` -> ``--ray-address``)."""
    return "--" + option.replace("_", "-")


@dataclass(frozen=True)
class Trainer:
    """One trainer: ``run(request, run_table)`` trains (``run_table``: the configuration's ``[run]``, its chain's
    included) and returns the exit status.

    ``algorithms``: the ``[run] algorithm`` values it trains (None: a configuration that names none); ``goal_env``:
    True for configurations of a Gymnasium env (``[run] env_id``), False for the collaborative scene's, None for
    either. ``takes``: the :class:`TrainRequest` options it takes beyond the common ones. ``needs``: modules it
    imports, ``install`` the command that gives them. ``cannot(run_table, config_path)``: why it cannot train this
    configuration (None when it can), checked before any state is touched. ``rank``: lower is chosen first."""

    name: str
    algorithms: tuple
    run: Callable
    summary: str
    takes: frozenset = frozenset()
    goal_env: bool | None = None
    needs: tuple = ()
    install: str = ""
    cannot: Callable | None = None
    rank: int = 0

    def trains(self, run_table: dict) -> bool:
        return run_table.get("algorithm") in self.algorithms and (
            self.goal_env is None or ("env_id" in run_table) == self.goal_env)

    def refusal(self, request: TrainRequest, run_table: dict) -> str | None:
        """Why this trainer cannot take ``request`` (None when it can): an option it does not take, a module it needs
        that is not installed, or what its ``cannot`` says of the configuration."""
        for option in request.given():
            if option not in self.takes:
                takers = [name for name, other in registered().items() if option in other.takes]
                return f"it does not take {flag(option)}" + (f" ({', '.join(takers)} do)" if len(takers) > 1 else
                                                             f" ({takers[0]} does)" if takers else "")
        missing = [name for name in self.needs if importlib.util.find_spec(name) is None]
        if missing:
            return f"it needs {', '.join(missing)} ({self.install})"
        return self.cannot(run_table, request.config) if self.cannot is not None else None


_REGISTRY: dict[str, Trainer] = {}

#: Trainers that were and are no more: the name, and what took their place.
RETIRED = {"record": "the TorchRL trainer is --trainer torchrl",
           "device": "the compiled JAX trainer (--trainer jax, the default) does what it did, faster"}


def register(trainer: Trainer) -> Trainer:
    """Add ``trainer`` (a name registered already is refused: two trainers would answer to it)."""
    if trainer.name in _REGISTRY and _REGISTRY[trainer.name] != trainer:
        raise ValueError(f"a trainer named {trainer.name!r} is registered already ({_REGISTRY[trainer.name].summary})")
    _REGISTRY[trainer.name] = trainer
    return trainer


def registered() -> dict[str, Trainer]:
    """The registered trainers by name, in the order they are chosen (rank, then name)."""
    return dict(sorted(_REGISTRY.items(), key=lambda item: (item[1].rank, item[0])))


def algorithms() -> list[str]:
    """Every ``[run] algorithm`` some registered trainer trains."""
    return sorted({name for trainer in _REGISTRY.values() for name in trainer.algorithms if name is not None})


def choose(request: TrainRequest, run_table: dict, asked: str | None = None) -> tuple[Trainer, str | None]:
    """The trainer for ``request``: ``asked`` (``--trainer``), else the first registered one that trains the
    configuration and can take the run. Returns it and, where a trainer ranked before it could not, a line saying
    which and why. A configuration no trainer trains, a trainer asked for that does not train it or cannot take the
    run, or none that can: ValueError naming what was wrong."""
    algorithm = run_table.get("algorithm")
    candidates = [trainer for trainer in registered().values() if trainer.trains(run_table)]
    if not candidates:
        known = ", ".join(algorithms())
        if algorithm is None:
            raise ValueError(f"{request.config}: [run] algorithm: a configuration with env_id names its algorithm "
                             f"(one of {known})")
        raise ValueError(f"{request.config}: [run] algorithm: must be one of {known}, got {algorithm!r}")
    names = ", ".join(trainer.name for trainer in candidates)
    if asked is not None:
        if asked in RETIRED:
            raise ValueError(f"--trainer {asked} was retired: {RETIRED[asked]}")
        chosen = next((trainer for trainer in candidates if trainer.name == asked), None)
        if chosen is None:
            raise ValueError(f"--trainer {asked}: {request.config} ({algorithm or 'its algorithm'}) is trained by "
                             f"{names}")
        why = chosen.refusal(request, run_table)
        if why is not None:
            raise ValueError(f"--trainer {asked} cannot train {request.config}: {why}")
        return chosen, None
    passed = []
    for trainer in candidates:
        why = trainer.refusal(request, run_table)
        if why is None:
            note = "; ".join(f"not the {name} trainer: {reason}" for name, reason in passed)
            return trainer, (f"trainer: {trainer.name} ({note})" if passed else None)
        passed.append((trainer.name, why))
    raise ValueError(f"no trainer can train {request.config}: "
                     + "; ".join(f"{name}: {reason}" for name, reason in passed))

