"""Every form of the collaborative scene spells out the keywords it takes (dvrl_marl.envs.scene_keywords): the same
scene keywords in each, with defaults that are the defaults (every keyword given its written default makes the scene
that none makes), and a keyword no form takes named."""

import dataclasses
import inspect

import numpy as np
import pytest

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.seats.seat_env import SeatEnv
from dvrl_marl.suction_debris.task import SuctionDebrisParams

#: The keywords a form takes of its own: the parallel env's seat and window, the batch's, a device's.
SEAT = {"teleop_timeout"}
BATCH = {"num_envs", "autoreset_mode", "render_world", "device", "arrays", "check_actions"}
HOST = {"surgeon", "surgeon_seat", "render_mode", "width", "height", "image_size", "image_depth",
        "image_segmentation", "image_stereo", "image_appearance", "image_contexts"}


def _names(form) -> set:
    parameters = inspect.signature(form).parameters.values()
    assert not any(parameter.kind is inspect.Parameter.VAR_KEYWORD for parameter in parameters)  # (spelled out)
    return {parameter.name for parameter in parameters}


def test_every_form_names_the_same_scene_keywords():
    parallel, batched, jax_world = (_names(form) for form in (suction_debris_v8.parallel_env,
                                                                suction_debris_v8.batched_env,
                                                                suction_debris_v8.jax_env))
    assert _names(suction_debris_v8.env) == parallel
    assert parallel - SEAT == batched - BATCH
    assert jax_world == parallel - SEAT - HOST
    task = {field.name for field in dataclasses.fields(SuctionDebrisParams)}
    assert task | {"preset", "reward_type", "guidance", "observation_features", "start_level"} <= jax_world
    assert "irrigation_ml_s" in inspect.signature(suction_debris_v8.parallel_env).parameters
    # the seat as a Gymnasium env: its own keywords (the seat, its partner), then the scene's, as parallel_env's
    assert _names(SeatEnv) == {"seat", "partner"} | parallel - SEAT - {"surgeon", "surgeon_seat"}
    # each task parameter's default is the task file's value, its annotation its checked type (its range)
    defaults = SuctionDebrisParams.from_task()
    parameter = inspect.signature(suction_debris_v8.batched_env).parameters["blood_threshold_ml"]
    assert parameter.default == defaults.blood_threshold_ml and parameter.annotation == "NonNegative"


def _written_defaults(form, skip=()) -> dict:
    return {parameter.name: parameter.default for parameter in inspect.signature(form).parameters.values()
            if parameter.default is not inspect.Parameter.empty and parameter.name not in skip}


def _rollout(env, steps: int = 60, worlds: tuple = ()):
    observations, _ = env.reset(seed=3)
    random = np.random.default_rng(0)
    seen = [observations]
    for _ in range(steps):
        actions = {agent: random.uniform(-1, 1, worlds + env.action_space(agent).shape)
                   for agent in env.possible_agents}
        observations, rewards, *_ = env.step(actions)
        seen.append((observations, rewards))
    return seen


def _same(a, b) -> None:
    if isinstance(a, dict):
        assert a.keys() == b.keys()
        for key in a:
            _same(a[key], b[key])
    elif isinstance(a, (tuple, list)):
        for x, y in zip(a, b, strict=True):
            _same(x, y)
    else:
        np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("preset", ["default", "irrigation"])
def test_every_keyword_given_its_written_default_makes_the_scene_that_none_makes(preset):
    written = _written_defaults(suction_debris_v8.parallel_env, skip={"preset"})
    if preset != "default":  # (a preset fills only the keywords not given: give only the rest)
        written = {name: value for name, value in written.items()
                   if name not in suction_debris_v8.PRESETS[preset]}
    _same(_rollout(suction_debris_v8.parallel_env(preset=preset, **written)),
          _rollout(suction_debris_v8.parallel_env(preset=preset)))
    batched = _written_defaults(suction_debris_v8.batched_env, skip={"preset", "num_envs", "device"} | set(
        suction_debris_v8.PRESETS[preset]))
    _same(_rollout(suction_debris_v8.batched_env(num_envs=3, preset=preset, **batched), 20, (3,)),
          _rollout(suction_debris_v8.batched_env(num_envs=3, preset=preset), 20, (3,)))


def test_a_keyword_no_form_takes_is_named():
    with pytest.raises(TypeError, match="'irigation_ml_s'"):
        suction_debris_v8.parallel_env(irigation_ml_s=1.0)
    with pytest.raises(TypeError, match="'irigation_ml_s'"):
        suction_debris_v8.batched_env(num_envs=2, irigation_ml_s=1.0)
    assert "irrigation_ml_s" in inspect.signature(suction_debris_v8.jax_env).parameters
