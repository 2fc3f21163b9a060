"""The scene's options, one checked record per concern (dvrl_marl.suction_debris.scene_options): every keyword lands in one
record, a preset and the keywords over it are sorted once, a bad value is named before anything is made, and every
form takes the same records."""

from __future__ import annotations

import dataclasses

import pytest
from hypothesis import given, settings, strategies as st

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris.presets import PRESETS
from dvrl_marl.suction_debris.scene_options import RECORDS, SceneOptions
from dvrl_marl.suction_debris.task import SuctionDebrisParams

OWNER = suction_debris_v8.TASK


def _names(record) -> set:
    return {item.name for item in dataclasses.fields(record)}


def test_every_keyword_has_one_record():
    records = [_names(record) for record in RECORDS.values()] + [_names(SuctionDebrisParams)]
    every = set().union(*records)
    assert sum(len(names) for names in records) == len(every), "a keyword in two records"
    for preset in PRESETS.values():  # a preset sets nothing outside the records (or max_cycles, the task's too)
        assert set(preset) <= every


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_a_preset_lands_in_its_records_and_keywords_win(preset):
    options = SceneOptions.of(OWNER, preset=preset)
    for name, value in PRESETS[preset].items():
        part = next(part for part in (options.observation, options.images, options.learning, options.rules)
                    if name in _names(type(part)))
        assert getattr(part, name) == value, name
    over = SceneOptions.of(OWNER, preset=preset, reward_type="dense", tool_speed=0.5, max_cycles=77)
    assert (over.learning.reward_type, over.rules.tool_speed, over.rules.max_cycles) == ("dense", 0.5, 77)


def test_every_form_keeps_the_records_it_was_made_with():
    for env in (suction_debris_v8.parallel_env(preset="benchmark"),
                suction_debris_v8.batched_env(num_envs=2, preset="benchmark")):
        assert env.preset == "benchmark"
        assert env.options == SceneOptions.of(OWNER, preset="benchmark")
        assert env.reward_type == env.options.learning.reward_type == "guided"
        assert env.params == env.options.rules
    assert suction_debris_v8.parallel_env(preset="benchmark").world.preset == "benchmark"


@pytest.mark.parametrize("keywords, named", [
    (dict(image_size=8), "image_size"),
    (dict(image_size=64.0), "image_size"),
    (dict(image_depth=True), "image_depth needs image_size"),
    (dict(image_contexts=2), "image_contexts needs image_size"),
    (dict(image_size=64, image_appearance="sunny"), "image_appearance"),
    (dict(state_observations=1), "state_observations"),
    (dict(normalize_observations="yes"), "normalize_observations"),
    (dict(observation_features="everything"), "observation_features"),
    (dict(reward_type="shaped"), "reward_type"),
    (dict(guidance={"grasp_path": 1.0}), "guidance settings need reward_type='guided'"),
    (dict(reward_type="guided", guidance=[1]), "guidance must be a dict"),
    (dict(reward_type="guided", guidance={"grasp_paths": 5.0}), "guidance: grasp_paths"),
    (dict(reward_type="guided", guidance={"hold_bonus": -1.0}), "guidance: hold_bonus: must be >= 0"),
    (dict(start_level="hard"), "level"),
    (dict(easy_episode_steps=-3), "easy_episode_steps"),
    (dict(contact_penalty=float("nan")), "contact_penalty"),
    (dict(preset="hardest"), "preset"),
])
def test_a_bad_option_is_named_before_anything_is_made(keywords, named):
    with pytest.raises(ValueError, match=named):
        SceneOptions.of(OWNER, **keywords)
    for form in (suction_debris_v8.parallel_env, suction_debris_v8.batched_env):
        with pytest.raises(ValueError, match=named):
            form(**keywords)


def test_an_unknown_keyword_is_named():
    with pytest.raises(TypeError, match="image_sise"):
        suction_debris_v8.parallel_env(image_sise=64)


@settings(max_examples=30, deadline=None)
@given(size=st.integers(-5, 400))
def test_image_sizes_are_refused_or_taken_as_the_range_says(size):
    if size == 0 or 32 <= size <= 256:
        assert SceneOptions.of(OWNER, image_size=size).images.image_size == size
    else:
        with pytest.raises(ValueError, match="image_size"):
            SceneOptions.of(OWNER, image_size=size)
