"""The collaborative env's options that help learning (issue 37): start levels, the guided reward, observation
features; in the single, AEC, batched and TorchRL forms, the same episodes in each."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris import start_levels, features
from dvrl_marl.suction_debris.guidance import Guidance, GuidedReward

OPTIONS = dict(reward_type="guided", observation_features="suction_debris_cleared_pins_zoom")


def _run_side_by_side(levels, steps, num_envs=3, seed=10, **kwargs):
    """The batched env against single envs seeded seed + i, same random actions; returns the largest differences
    of observations and rewards, and how many episodes ended."""
    batched = suction_debris_v8.batched_env(num_envs=num_envs, **kwargs)
    batched.reset(seed=seed, options={"level": levels})
    singles = [suction_debris_v8.parallel_env(**kwargs) for _ in range(num_envs)]
    for index, single in enumerate(singles):
        single.reset(seed=seed + index, options={"level": levels[index]})
    rng = np.random.default_rng(0)
    worst_observation = worst_reward = 0.0
    ended = 0
    for _ in range(steps):
        actions = {agent: rng.uniform(-1, 1, (num_envs, 4)) for agent in batched.agents}
        observations, rewards, terminations, truncations, _ = batched.step(actions)
        for index, single in enumerate(singles):
            obs, reward, term, trunc, _ = single.step({agent: actions[agent][index] for agent in single.agents})
            assert term["suction"] == terminations["suction"][index]
            assert trunc["suction"] == truncations["suction"][index]
            for agent in batched.agents:
                worst_reward = max(worst_reward, abs(reward[agent] - rewards[agent][index]))
            if term["suction"] or trunc["suction"]:
                ended += 1
                obs, _ = single.reset()
            for agent in batched.agents:
                worst_observation = max(worst_observation, float(np.abs(obs[agent] - observations[agent][index]).max()))
    return worst_observation, worst_reward, ended


@pytest.mark.extended
def test_single_and_batched_start_the_same_episodes_at_every_level():
    """Easy starts (300-step episodes, autoreset at their level) with the guided reward and features: the batched
    worlds are the single envs, seeded seed + i, bit for bit (rewards to float rounding)."""
    observation, reward, ended = _run_side_by_side([0.0, 0.4, 1.0], 650, **OPTIONS)
    assert observation == 0.0
    assert reward < 1e-9
    assert ended >= 4  # the easy worlds' 300-step episodes ended twice each, at least


def test_level_one_is_the_default_task_bit_for_bit():
    default = suction_debris_v8.batched_env(num_envs=2, reward_type="dense")
    levelled = suction_debris_v8.batched_env(num_envs=2, reward_type="dense", start_level="default")
    a, _ = default.reset(seed=3)
    b, _ = levelled.reset(seed=3, options={"level": 1.0})
    rng = np.random.default_rng(1)
    for _ in range(200):
        actions = {agent: rng.uniform(-1, 1, (2, 4)) for agent in default.agents}
        a, ra, *_ = default.step(actions)
        b, rb, *_ = levelled.step(actions)
        for agent in default.agents:
            assert np.array_equal(a[agent], b[agent]) and np.array_equal(ra[agent], rb[agent])


def test_easy_episodes_are_easier_and_shorter():
    env = suction_debris_v8.batched_env(num_envs=64, start_level="easy", autoreset_mode="disabled")
    env.reset(seed=0)
    core = env.core
    in_play = (~core.delivered).sum(axis=1)
    assert in_play.min() >= 1 and in_play.max() <= env.params.debris_count and in_play.min() < in_play.max()
    assert np.all(core.remaining_ml <= np.asarray(env.params.blood_ml) + 1e-12)
    assert (core.remaining_ml == 0.0).mean() > 0.3  # half of the cavities start empty
    assert np.all(core.limit == 300)
    # the grasper starts just above a visible pin (level 0: nowhere back along the way)
    tip = core.arms["grasper"].tip + core.arms["grasper"].base_position
    visible = core.visible & ~core.delivered
    near = [np.linalg.norm(core.debris_position[w][visible[w]] - tip[w], axis=1).min() < 0.004
            for w in range(env.num_envs) if visible[w].any()]
    assert len(near) > 32 and np.mean(near) > 0.9
    # the episode ends at 300 steps, truncated
    for _ in range(300):
        _, _, terminations, truncations, _ = env.step({agent: np.zeros((64, 4)) for agent in env.agents})
    assert np.all(truncations["suction"] | terminations["suction"])


@settings(max_examples=15, deadline=None)
@given(level=st.floats(0.0, 1.0), seed=st.integers(0, 2**31 - 1))
def test_starts_at_any_level_keep_the_tips_in_the_workspace_and_above_the_surface(level, seed):
    env = suction_debris_v8.batched_env(num_envs=8, start_level=level, autoreset_mode="disabled")
    observations, _ = env.reset(seed=seed)
    core = env.core
    for agent in env.agents:
        assert np.all(np.abs(observations[agent][:, 0:3]) <= 1.0 + 1e-9)
        tip = core.arms[agent].tip + core.arms[agent].base_position
        assert np.all(tip[:, 2] >= core._floor(tip[:, 0], tip[:, 1]) - 1e-9)  # noqa: SLF001 (the core's own rule)
    assert np.all(core._instrument_distance() >= 0.0)  # noqa: SLF001


def test_guided_reward_is_the_dense_reward_plus_the_change_of_its_potential():
    dense = suction_debris_v8.parallel_env(reward_type="dense")
    guided = suction_debris_v8.parallel_env(reward_type="guided")
    terms = GuidedReward(guided, guided.possible_agents, Guidance())
    dense.reset(seed=5, options={"level": 0.0})
    guided.reset(seed=5, options={"level": 0.0})

    def potential():
        return terms.potentials(guided.state()[None], np.asarray(guided.blood.remaining_ml)[None])

    before = potential()
    rng = np.random.default_rng(2)
    extra = {agent: 0.0 for agent in guided.agents}
    for _ in range(120):
        actions = {agent: rng.uniform(-1, 1, 4).astype(np.float32) for agent in guided.agents}
        _, rd, *_ = dense.step(actions)
        _, rg, *_ = guided.step(actions)
        for agent in extra:
            extra[agent] += rg[agent] - rd[agent]
    after = potential()
    for agent in extra:  # the guided terms telescope
        assert extra[agent] == pytest.approx(float(after[agent][0] - before[agent][0]), abs=1e-9)
    assert any(abs(v) > 1e-3 for v in extra.values())


def test_guided_reward_leaves_a_seat_filled_by_a_partner_alone():
    env = suction_debris_v8.batched_env(num_envs=2, surgeon="scripted", reward_type="guided",
                                        guidance={"suction_route": 0.0, "clear_bonus": 0.0})
    env.reset(seed=0)
    assert env.agents == ["suction"]
    _, rewards, *_ = env.step({"suction": np.zeros((2, 4))})
    dense = suction_debris_v8.batched_env(num_envs=2, surgeon="scripted", reward_type="dense")
    dense.reset(seed=0)
    _, expected, *_ = dense.step({"suction": np.zeros((2, 4))})
    assert np.allclose(rewards["suction"], expected["suction"])


def test_observation_features_are_appended_and_match_what_a_policy_computes():
    plain = suction_debris_v8.parallel_env()
    extended = suction_debris_v8.parallel_env(observation_features="suction_debris_routes")
    a, _ = plain.reset(seed=1)
    b, _ = extended.reset(seed=1)
    spec = features.spec("suction_debris_routes", plain.layout(), plain.params.debris_count)
    for agent in plain.agents:
        assert b[agent].shape == extended.observation_space(agent).shape
        assert extended.observation_space(agent).contains(b[agent])
        assert np.array_equal(b[agent], features.apply(spec, a[agent]))
    assert extended.observation_layout["features"] == slice(a["suction"].shape[0], b["suction"].shape[0])


@pytest.mark.parametrize("kwargs, reset_options, message", [
    ({"start_level": 1.5}, None, "level must lie in"),
    ({"start_level": "hard"}, None, "level must be a number"),
    ({}, {"level": float("nan")}, "level must lie in"),
    ({}, {"level": True}, "level must be a number"),
    ({"guidance": {"grasp_path": 5.0}}, None, "guidance settings need reward_type='guided'"),
    ({"reward_type": "guided", "guidance": {"grasp_paths": 5.0}}, None, "grasp_paths"),
    ({"reward_type": "guided", "guidance": {"hold_bonus": -1.0}}, None, "hold_bonus"),
    ({"reward_type": "shaped"}, None, "reward_type: must be one of"),
    ({"observation_features": "suction_debris_everything"}, None, "observation_features: must be one of"),
    ({"start_level": 0.0}, {"blood_ml": [1.0, 1.0]}, "not both"),
])
def test_bad_options_are_refused_by_name(kwargs, reset_options, message):
    with pytest.raises(ValueError, match=message):
        suction_debris_v8.parallel_env(**kwargs).reset(seed=0, options=reset_options)


def test_batched_levels_per_world_and_bad_lengths():
    env = suction_debris_v8.batched_env(num_envs=3, autoreset_mode="disabled")
    env.reset(seed=0, options={"level": [0.0, 1.0, "easy"]})
    assert env.core.limit.tolist() == [300, env.params.max_cycles, 300]
    with pytest.raises(ValueError, match="one per world"):
        env.reset(options={"level": [0.0, 1.0]})
    with pytest.raises(ValueError, match="not both"):
        env.reset(options={"level": 0.0, "debris_count": 1})
    env.set_start_level(1.0)
    env.reset(seed=0)
    assert env.core.limit.tolist() == [env.params.max_cycles] * 3
    # back at the default level every world has the task's blood again (an easy draw's does not linger)
    assert np.allclose(env.core.remaining_ml, np.asarray(env.params.blood_ml))
    auto = suction_debris_v8.batched_env(num_envs=2, start_level="easy", max_cycles=5)
    auto.reset(seed=1)
    auto.set_start_level("default")
    for _ in range(5):  # the easy episodes end (time limit) and restart at the default level
        auto.step({agent: np.zeros((2, 4)) for agent in auto.agents})
    assert np.allclose(auto.core.remaining_ml, np.asarray(auto.params.blood_ml))


def test_pettingzoo_api_and_aec_form_with_every_option():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(suction_debris_v8.parallel_env(start_level=0.3, **OPTIONS), num_cycles=400)
    aec = suction_debris_v8.env(start_level="easy", **OPTIONS)
    aec.reset(seed=0, options={"level": 0.0})
    for agent in aec.agent_iter(40):
        observation, *_ = aec.last()
        assert observation.shape == aec.observation_space(agent).shape
        aec.step(None if aec.terminations[agent] or aec.truncations[agent] else np.zeros(4, dtype=np.float32))


def test_torchrl_env_with_the_options_and_a_level_per_reset():
    pytest.importorskip("torchrl")
    import torch
    from torchrl.envs.utils import check_env_specs

    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=3, seed=0, start_level="easy", **OPTIONS)
    check_env_specs(env)
    assert env.group_map == {"agents": ["suction", "grasper"]}
    td = env.rollout(310, break_when_any_done=False)
    assert td["next", "truncated"].sum() >= 3  # the easy episodes' 300 steps
    reset = env.reset(env.reset().update({"_reset": torch.tensor([[True], [False], [True]]),
                                          "level": torch.tensor([1.0, 0.0, 1.0])}))
    assert env.batched.levels.tolist() == [1.0, 0.0, 1.0]
    assert reset["agents", "observation"].shape[-1] == env.batched.observation_space("suction").shape[0]


def test_sb3_collaborative_vec_env_takes_the_options():
    pytest.importorskip("supersuit")
    from dvrl_marl.integrations.sb3 import make_collaborative_vec_env

    venv = make_collaborative_vec_env(n_envs=2, seed=0, start_level="easy", **OPTIONS)
    observations = venv.reset()
    assert observations.shape[0] == 4 and np.all(np.isfinite(observations))
    # the features reached SuperSuit's padded slots (plus its two-agent indicator)
    assert observations.shape[1] == suction_debris_v8.parallel_env(**OPTIONS).observation_space("suction").shape[0] + 2
    observations, rewards, dones, infos = venv.step(np.zeros((4, 4), dtype=np.float32))
    assert rewards.shape == (4,)
    venv.close()


def test_named_levels():
    assert start_levels.checked_level("easy", "x") == 0.0 and start_levels.checked_level("default", "x") == 1.0


def test_surgeon_seat_gymnasium_env_takes_the_options():
    """The seat as a Gymnasium env (SB3's single-agent path): the options reach the scene; Gymnasium's checker."""
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import dvrl_marl  # noqa: F401  (registers the environments)

    env = gym.make("dvrl_marl/SurgeonSeat-v8", start_level="easy", **OPTIONS)
    check_env(env.unwrapped, skip_render_check=True)
    observation, _ = env.reset(seed=0, options={"level": 0.0})
    assert observation.shape == env.observation_space.shape and env.observation_space.contains(observation)
    steps = 0
    while True:
        _, reward, terminated, truncated, _ = env.step(env.action_space.sample())
        steps += 1
        if terminated or truncated:
            break
    assert steps <= 300  # an easy episode's limit
    env.close()


def test_easy_episodes_can_take_the_tasks_time_limit():
    """easy_episode_steps=None: an easy episode lasts as long as the task's (the scripted team then completes every
    easy episode; with the record's 300 steps it cannot finish those with two full cavities)."""
    env = suction_debris_v8.batched_env(num_envs=4, start_level="easy", easy_episode_steps=None,
                                        autoreset_mode="disabled")
    env.reset(seed=0)
    assert env.core.limit.tolist() == [env.params.max_cycles] * 4
    single = suction_debris_v8.parallel_env(start_level="easy", easy_episode_steps=120)
    single.reset(seed=0)
    for step in range(1, 200):
        _, _, term, trunc, _ = single.step({agent: np.zeros(4, dtype=np.float32) for agent in single.agents})
        if term["suction"] or trunc["suction"]:
            break
    assert step == 120 and trunc["suction"]
    # 0 is None where there is no null (a TOML configuration); a negative count or a fraction is refused by name
    assert suction_debris_v8.parallel_env(easy_episode_steps=0).easy_episode_steps is None
    for bad in (-1, 1.5, "300"):
        with pytest.raises(ValueError, match="easy_episode_steps"):
            suction_debris_v8.parallel_env(easy_episode_steps=bad)


def test_state_observations_append_every_arms_observation_single_and_batched():
    """state_observations: the state, then the suction's and the grasper's observations (features included), named
    by state_layout; the batched worlds' states (and final states) are the single envs' bit for bit; off by default."""
    kwargs = dict(task="suction_debris_v8", state_observations=True, **OPTIONS)
    plain = suction_debris_v8.parallel_env(task="suction_debris_v8", **OPTIONS)
    batched = suction_debris_v8.batched_env(num_envs=2, max_cycles=60, **kwargs)
    singles = [suction_debris_v8.parallel_env(max_cycles=60, **kwargs) for _ in range(2)]
    batched.reset(seed=4)
    observations = [single.reset(seed=4 + index)[0] for index, single in enumerate(singles)]
    layout = singles[0].state_layout
    assert batched.state_space.shape[0] == plain.state_space.shape[0] + 2 * plain.observation_space("suction").shape[0]
    rng = np.random.default_rng(3)
    finals = 0
    for _ in range(130):
        actions = {agent: rng.uniform(-1, 1, (2, 4)) for agent in batched.agents}
        _, _, terminations, truncations, infos = batched.step(actions)
        for index, single in enumerate(singles):
            obs, *_ = single.step({agent: actions[agent][index] for agent in single.agents})
            state = single.state()
            assert single.state_space.contains(state)
            for agent in single.agents:
                assert np.array_equal(state[layout[f"{agent}_observation"]], obs[agent])
            if not single.agents:  # ended: the batched env reports this final state and starts the next episode
                finals += 1
                assert np.array_equal(infos["suction"]["final_state"][index], state)
                single.reset()
            assert np.array_equal(batched.state()[index], single.state())
    assert finals >= 2
    assert plain.state_observations is False and "suction_observation" not in plain.state_layout
    with pytest.raises(ValueError, match="state_observations"):
        suction_debris_v8.parallel_env(state_observations="yes")


def test_batched_state_reuses_the_step_features_and_nothing_stale():
    """state() after step() reuses the features the step computed for the same observations: the same values as a
    fresh env's pass, untouched by a caller who writes into the observations it was given, and recomputed once the
    worlds have moved (here by set_tip_positions, which no step sees)."""
    kwargs = dict(task="suction_debris_v8", state_observations=True, **OPTIONS)
    env = suction_debris_v8.batched_env(num_envs=3, **kwargs)
    env.reset(seed=2)
    rng = np.random.default_rng(2)
    for _ in range(5):
        observations, *_ = env.step({agent: rng.uniform(-1, 1, (3, 4)) for agent in env.agents})
    expected = env.state().copy()
    env._last_features = None  # (what a pass without the reuse computes)
    np.testing.assert_array_equal(env.state(), expected)
    for value in observations.values():
        value[:] = 7.0  # a caller's own copy: the state is not theirs
    np.testing.assert_array_equal(env.state(), expected)
    grasper = env.core.arms["grasper"]
    env.set_tip_positions({"grasper": grasper.tip + grasper.base_position + [0.0, 0.0, 0.002]})
    moved = env.state().copy()
    env._last_features = None
    np.testing.assert_array_equal(env.state(), moved)
    assert not np.array_equal(moved, expected)


def test_torchrl_state_carries_both_observations():
    pytest.importorskip("torchrl")
    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=2, seed=0, state_observations=True, **OPTIONS)
    td = env.reset()
    width = td["agents", "observation"].shape[-1]
    assert td["state"].shape[-1] == env.batched.state_space.shape[0]
    np.testing.assert_allclose(td["state"][:, -2 * width:].reshape(2, 2, width).numpy(),
                               td["agents", "observation"].numpy(), rtol=0, atol=1e-6)


# --- normalize_observations (dvrl_marl.suction_debris.observation_scaling) ------------------------------------------------

def _normalized_pair(**kwargs):
    from dvrl_marl.suction_debris.observation_scaling import ObservationScaling

    kwargs = dict(task="suction_debris_v8", state_observations=True, **OPTIONS, **kwargs)
    return (suction_debris_v8.parallel_env(**kwargs),
            suction_debris_v8.parallel_env(normalize_observations=True, **kwargs), ObservationScaling)


def test_normalize_observations_maps_what_the_agents_read_and_nothing_else():
    """The option's observations and state are the plain ones mapped by the shipped centres and spreads, dimension by
    dimension; the episode itself (rewards, ends) is the plain one's step for step; observations stay in their
    spaces; the batched worlds read what the single envs read."""
    plain, normalized, _ = _normalized_pair(max_cycles=200)
    scaling = normalized.observation_scaling
    assert plain.observation_scaling is None
    batched = suction_debris_v8.batched_env(num_envs=1, normalize_observations=True, max_cycles=200, autoreset_mode="disabled",
                                            task="suction_debris_v8", state_observations=True, **OPTIONS)
    a, _ = plain.reset(seed=5)
    b, _ = normalized.reset(seed=5)
    c, _ = batched.reset(seed=5)
    rng = np.random.default_rng(5)
    moved = {agent: 0.0 for agent in a}
    for _ in range(250):
        for agent in a:
            assert normalized.observation_space(agent).contains(b[agent])
            np.testing.assert_allclose(b[agent], scaling.observation(agent, a[agent]), rtol=0, atol=0)
            np.testing.assert_array_equal(c[agent][0], b[agent])
            moved[agent] = max(moved[agent], float(np.abs(b[agent] - a[agent]).max()))
        assert normalized.state_space.contains(normalized.state())
        np.testing.assert_array_equal(normalized.state(), scaling.state(plain.state()))
        np.testing.assert_array_equal(batched.state()[0], normalized.state())
        if not plain.agents:
            break
        actions = {agent: rng.uniform(-1, 1, 4) for agent in plain.agents}
        a, ra, ta, ua, _ = plain.step(actions)
        b, rb, tb, ub, _ = normalized.step(actions)
        c, *_ = batched.step({agent: value[None] for agent, value in actions.items()})
        assert ra == rb and ta == tb and ua == ub
    assert min(moved.values()) > 1.0  # the map is not the identity
    # the state's observation parts are each arm's normalised observation
    layout = normalized.state_layout
    for agent in normalized.agents:
        np.testing.assert_array_equal(normalized.state()[layout[f"{agent}_observation"]], b[agent])


@pytest.mark.slow
def test_normalize_observations_gives_the_scripted_team_unit_scale_inputs():
    """What the option is for: over the scripted team's episode, every dimension that varies reads at about unit
    scale (no spread left 25-100 times below the rest, as the plain pins' y and carry offsets are)."""
    from dvrl_marl.agents.collaborative import ScriptedSuction, ScriptedSurgeon

    env = suction_debris_v8.batched_env(num_envs=4, normalize_observations=True, autoreset_mode="disabled",
                                        task="suction_debris_v8", **OPTIONS)
    experts = {"suction": ScriptedSuction.for_env(env), "grasper": ScriptedSurgeon.for_env(env)}
    plain = env.observation_layout["handoff"].stop
    scaling = env.observation_scaling
    observations, _ = env.reset(seed=11)
    seen = {agent: [] for agent in env.agents}
    for _ in range(1500):
        for agent in env.agents:
            seen[agent].append(observations[agent])
        actions = {agent: experts[agent](scaling.plain_observation(agent, observations[agent])[:, :plain])
                   for agent in env.agents}
        observations, _, terminations, truncations, infos = env.step(actions)
        if (terminations["suction"] | truncations["suction"]).all():
            break
    assert infos["suction"]["is_success"].all()  # the scripted team, given the plain observations back, succeeds
    for agent, rows in seen.items():
        spread = np.concatenate(rows).std(axis=0)
        varying = spread > 1e-9
        assert np.all(spread[varying] > 0.05) and np.all(spread < 20.0), (agent, spread.round(3))


def test_normalize_observations_keeps_the_seat_plain_and_checks_its_value():
    """A scripted surgeon in the seat reads the scene's units with the option on: the same episode as without it;
    a value that is not a flag, or an observation the statistics were not measured on, is a ValueError naming it."""
    rewards = []
    for normalize in (False, True):
        env = suction_debris_v8.parallel_env(surgeon="scripted", max_cycles=300, normalize_observations=normalize,
                                             task="suction_debris_v8", **OPTIONS)
        env.reset(seed=2)
        total = 0.0
        while env.agents:
            _, reward, *_ = env.step({"suction": np.array([0.3, -0.2, -0.5, 1.0])})
            total += reward["suction"]
        rewards.append(total)
    assert rewards[0] == rewards[1]
    with pytest.raises(ValueError, match="normalize_observations"):
        suction_debris_v8.parallel_env(normalize_observations="yes")
    with pytest.raises(ValueError, match="normalize_observations.*debris"):
        suction_debris_v8.parallel_env(normalize_observations=True, debris_count=2)
    with pytest.raises(ValueError, match="normalize_observations.*observation_features"):
        from dvrl_marl.suction_debris.observation_scaling import ObservationScaling

        ObservationScaling.for_env("env", "no_such_features", ("suction",), 62, 31, False)


@pytest.mark.extended
def test_shipped_observation_scales_are_what_measure_gives():
    """The shipped centres and spreads are the measurement's (deterministic): rerunning it for the benchmark's feature
    set gives the file's numbers."""
    import json

    from dvrl_marl.envs import observation_measure
    from dvrl_marl.suction_debris import observation_scaling

    shipped = json.loads(observation_scaling.SCALES_FILE.read_text())
    name = OPTIONS["observation_features"]
    assert shipped["feature_sets"][name] == observation_measure.measure(name)
    assert set(shipped["feature_sets"]) == {"", *features.SCENE_FEATURE_SETS}


def test_normalize_observations_passes_the_pettingzoo_and_torchrl_checks():
    from pettingzoo.test import parallel_api_test

    parallel_api_test(suction_debris_v8.parallel_env(normalize_observations=True, max_cycles=60,
                                                     task="suction_debris_v8", **OPTIONS), num_cycles=80)
    pytest.importorskip("torchrl")
    from torchrl.envs.utils import check_env_specs

    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=2, seed=0, state_observations=True, normalize_observations=True,
                                  task="suction_debris_v8", **OPTIONS)
    check_env_specs(env)
    td = env.reset()
    scaling = env.batched.observation_scaling
    assert scaling is not None
    width = td["agents", "observation"].shape[-1]
    np.testing.assert_allclose(td["state"][:, -2 * width:].reshape(2, 2, width).numpy(),
                               td["agents", "observation"].numpy(), rtol=0, atol=1e-5)


def test_bleeding_features_read_the_field_in_thresholds_and_the_last_pin():
    torch = pytest.importorskip("torch")
    env = suction_debris_v8.parallel_env(observation_features="suction_debris_bleeding", bleeding_ml_s=0.1)
    observations, _ = env.reset(seed=2)
    layout, threshold = env.observation_layout, np.asarray(env.layout().blood_threshold_fraction)
    assert observations["suction"].shape == env.observation_space("suction").shape
    spec = features.spec("suction_debris_bleeding", env.layout(), env.params.debris_count)
    row = observations["suction"][: layout["features"].start].astype(np.float64)
    row[layout["blood"]] = 0.5 * threshold
    debris = row[layout["debris"]].reshape(-1, 6)
    debris[:, 3:] = (1.0, 0.0, 1.0)  # revealed and delivered...
    debris[0, 3:] = (1.0, 1.0, 0.0)  # ...but the first, held: the last pin
    row[layout["debris"]] = debris.ravel()
    extra = features.apply(spec, row)[-7:]
    assert features.feature_count("suction_debris_bleeding") == 39
    np.testing.assert_allclose(extra, [*np.tanh([0.5, 0.5]), *np.tanh([5.0, 5.0]), 1 / 3, 1.0, 0.0], rtol=1e-6)
    debris[1, 3:] = (0.0, 0.0, 0.0)  # a second pin still hidden: the held one is no longer the last
    row[layout["debris"]] = debris.ravel()
    extra = features.apply(spec, row)[-3:]
    np.testing.assert_allclose(extra, [2 / 3, 0.0, 1.0])
    # torch computes the same (the trainer's actors) as numpy (the exported policy)
    batch = np.stack([row, observations["grasper"][: layout["features"].start]])
    np.testing.assert_allclose(features.apply(spec, torch.as_tensor(batch)).numpy(), features.apply(spec, batch))
