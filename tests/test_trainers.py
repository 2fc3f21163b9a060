"""The trainers' registry (dvrl_marl.training.trainers): dvrl-marl train takes the first registered trainer that can
take the run, says which it passed over and why, refuses what no trainer takes by name, and a trainer of one's own
registers like the shipped ones."""

from pathlib import Path

import pytest

from dvrl_marl.training import trainers
from dvrl_marl.training.trainers import Trainer, TrainRequest


@pytest.fixture
def registry(monkeypatch):
    """An empty registry for the test (the shipped trainers are put back after it)."""
    monkeypatch.setattr(trainers, "_REGISTRY", {})
    return trainers


def _trainer(name, rank, **options):
    return Trainer(name=name, algorithms=("mappo",), run=lambda request, table: name, summary=name, rank=rank,
                   **options)


def test_the_first_trainer_that_can_take_the_run_is_chosen_and_the_passed_over_are_named(registry):
    registry.register(_trainer("fast", 0, takes=frozenset({"device"}), needs=("no_such_module_here",),
                               install="pip install fast"))
    registry.register(_trainer("steady", 1, takes=frozenset({"resume"})))
    request = TrainRequest(config=Path("x.toml"))
    chosen, note = registry.choose(request, {"algorithm": "mappo"})
    assert chosen.name == "steady"
    assert note == "trainer: steady (not the fast trainer: it needs no_such_module_here (pip install fast))"
    with pytest.raises(ValueError, match=r"--trainer fast cannot train x.toml: it needs no_such_module_here"):
        registry.choose(request, {"algorithm": "mappo"}, asked="fast")
    with pytest.raises(ValueError, match=r"no trainer can train x.toml: fast: it does not take --validators; "
                                         r"steady: it does not take --validators"):
        registry.choose(TrainRequest(config=Path("x.toml"), validators=2), {"algorithm": "mappo"})


def test_a_configuration_a_trainer_cannot_train_passes_to_the_next(registry):
    registry.register(_trainer("compiled", 0, cannot=lambda table, path: "surgeon = 'scripted' is the other's"
                               if table.get("surgeon") else None))
    registry.register(_trainer("eager", 1))
    request = TrainRequest(config=Path("x.toml"))
    assert registry.choose(request, {"algorithm": "mappo"}) == (registry.registered()["compiled"], None)
    chosen, note = registry.choose(request, {"algorithm": "mappo", "surgeon": "scripted"})
    assert chosen.name == "eager" and "not the compiled trainer: surgeon = 'scripted' is the other's" in note


def test_unknown_algorithms_retired_trainers_and_twice_registered_names_are_named(registry):
    registry.register(_trainer("one", 0))
    request = TrainRequest(config=Path("x.toml"))
    with pytest.raises(ValueError, match="must be one of mappo, got 'mapo'"):
        registry.choose(request, {"algorithm": "mapo"})
    with pytest.raises(ValueError, match="--trainer device was retired"):
        registry.choose(request, {"algorithm": "mappo"}, asked="device")
    with pytest.raises(ValueError, match=r"--trainer two: x.toml \(mappo\) is trained by one"):
        registry.choose(request, {"algorithm": "mappo"}, asked="two")
    with pytest.raises(ValueError, match="a trainer named 'one' is registered already"):
        registry.register(_trainer("one", 5))


def test_the_shipped_trainers_register_themselves_and_mappo_prefers_jax():
    from dvrl_marl.training import clone, jax_mappo, mappo, marl, pixel_seat, runner  # noqa: F401

    shipped = trainers.registered()
    assert {"jax", "torchrl", "sb3", "sb3-team", "bc", "pixel-dagger"} <= set(shipped)
    assert [name for name, trainer in shipped.items() if trainer.trains({"algorithm": "mappo"})] == ["jax", "torchrl"]
    assert [name for name, trainer in shipped.items() if trainer.trains({"algorithm": "ppo", "env_id": "x"})] == ["sb3"]
    assert [name for name, trainer in shipped.items() if trainer.trains({})] == ["sb3-team"]
    # every option a trainer takes is one the command line gives
    options = {field for field in TrainRequest.__dataclass_fields__}
    assert all(trainer.takes <= options for trainer in shipped.values())
