"""The multi-agent trainer's policy pieces: the open/closed tool head, the observation features (the same in numpy
and torch, and in the exported numpy policy), and the learner's device setting."""

from __future__ import annotations

import numpy as np
import pytest
from rule_sets import v0_rules  # a wall that stops a move (the features read it)
from hypothesis import assume, given, settings
from hypothesis import strategies as st

from dvrl_marl import policies
from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.suction_debris import features

torch = pytest.importorskip("torch")
pytest.importorskip("torchrl")

from dvrl_marl.training import mappo, models  # noqa: E402

AGENTS = ["suction", "grasper"]
OBS_DIM = 30  # 10 + 2 cavities + 6 x 3 debris


def _observation(rng, tip, slots, handoff, other):
    """An observation in the collaborative layout with the given pin slots [(position, visible, held, delivered)]."""
    obs = np.zeros(OBS_DIM)
    obs[0:3], obs[4:7] = tip, other
    obs[7:9] = rng.random(2)
    for index, (position, visible, held, delivered) in enumerate(slots):
        start = 9 + 6 * index
        obs[start:start + 3] = position if visible and not delivered else 0.0
        obs[start + 3:start + 6] = visible, held, delivered
    obs[27:30] = handoff
    return obs


coordinate = st.floats(-1.0, 1.0, allow_nan=False)
point = st.tuples(coordinate, coordinate, coordinate).map(np.array)
slot = st.tuples(point, st.booleans(), st.booleans(), st.booleans())


@settings(max_examples=200, deadline=None)
@given(tip=point, other=point, handoff=point, slots=st.lists(slot, min_size=3, max_size=3))
def test_targets_point_at_the_nearest_pin_to_collect(tip, other, handoff, slots):
    # at most one pin is held, as in the env
    held_seen = False
    cleaned = []
    for position, visible, held, delivered in slots:
        held = held and visible and not delivered and not held_seen
        held_seen |= held
        cleaned.append((position, visible, held, delivered))
    obs = _observation(np.random.default_rng(0), tip, cleaned, handoff, other)
    out = features.suction_debris_targets(obs, cavities=2, debris=3)
    assert out.shape == (14,) and np.all(np.isfinite(out))
    pending = [p for p, v, h, d in cleaned if v and not h and not d]
    if pending:
        nearest = min(pending, key=lambda p: float(np.sum((p - tip) ** 2)))
        np.testing.assert_allclose(out[0:3], nearest - tip, atol=1e-12)
        assert out[3] == 1.0
    else:
        assert np.all(out[0:4] == 0.0)
    held_positions = [p for p, v, h, d in cleaned if h]
    assert out[4] == float(bool(held_positions))
    expected_carry = handoff - held_positions[0] if held_positions else np.zeros(3)
    np.testing.assert_allclose(out[5:8], expected_carry, atol=1e-12)
    np.testing.assert_allclose(out[8:11], handoff - tip, atol=1e-12)
    np.testing.assert_allclose(out[11:14], other - tip, atol=1e-12)
    # torch computes the same (batched, float64)
    batched = np.stack([obs, obs[::-1].copy()])
    np.testing.assert_allclose(features.suction_debris_targets(torch.from_numpy(batched), cavities=2, debris=3).numpy(),
                               features.suction_debris_targets(batched, cavities=2, debris=3), atol=1e-12)


def test_targets_on_real_observations_follow_the_env():
    env = suction_debris_v8.batched_env(num_envs=6, surgeon="scripted", surgeon_seat="suction")
    env.reset(seed=3)
    for _ in range(500):  # the scripted suction reveals pins
        env.step({"grasper": np.zeros((6, 4))})
    observation = env.observations()["grasper"]
    out = features.suction_debris_targets(observation, cavities=2, debris=3)
    state = env.state()
    layout = env.state_layout
    assert out[:, 3].any(), "no pin revealed after 500 steps of the scripted suction"
    tips = state[:, layout["grasper_tip"]]
    np.testing.assert_allclose(out[:, 8:11], state[:, layout["handoff"]] - tips, atol=1e-12)


GEOMETRY = features.routes_geometry(suction_debris_v8.batched_env(num_envs=1).layout())


def _routes_reference(obs, targets14):
    """The routes features one observation at a time, in plain Python (the scene's geometry from GEOMETRY)."""
    tip = obs[0:3]
    centres = [np.array(c) for c in GEOMETRY["cavity_centres"]]
    mouth, rim = GEOMETRY["cavity_mouth_radius"], GEOMETRY["rim_z"]
    floors = [np.array([*c, z]) for c, z in zip(centres, GEOMETRY["cavity_targets_z"])]
    pending = [k for k in range(2) if obs[7 + k] >= GEOMETRY["blood_threshold_fraction"][k] and obs[7 + k] > 0]
    to_cavity = min((floors[k] - tip for k in pending), key=lambda v: float(v @ v)) if pending else np.zeros(3)

    def over(point):
        return {k for k in range(2) if float(np.sum((point[0:2] - centres[k]) ** 2)) < mouth**2}

    def climb(target, valid=True):
        return max(rim - tip[2], 0.0) if valid and not over(tip) & over(target) else 0.0

    return np.concatenate([targets14, to_cavity, [float(bool(pending))],
                           [climb(tip + to_cavity, bool(pending)), climb(tip + targets14[0:3], targets14[3] > 0.5),
                            climb(obs[27:30])]])


@settings(max_examples=300, deadline=None)
@given(tip=point, other=point, handoff=point, slots=st.lists(slot, min_size=3, max_size=3),
       levels=st.tuples(st.sampled_from([0.0, 0.03, 0.0625, 0.07, 1.0]), st.floats(0.0, 1.0)))
@pytest.mark.slow
def test_routes_name_the_cavity_to_clear_and_the_rims_in_the_way(tip, other, handoff, slots, levels):
    tip = tip * [1.0, 1.0, 0.4] + [0.0, 0.0, -0.45]  # about the phantom, inside and outside its cavities
    floors = [np.array([*c, z]) for c, z in zip(GEOMETRY["cavity_centres"], GEOMETRY["cavity_targets_z"])]
    distances = [float(np.sum((floor - tip) ** 2)) for floor in floors]
    assume(abs(distances[0] - distances[1]) > 1e-9)  # a tip as near one cavity as the other: either is the route
    obs = _observation(np.random.default_rng(0), tip, slots, handoff, other)
    obs[7:9] = levels
    out = features.suction_debris_routes(obs, cavities=2, debris=3, **GEOMETRY)
    assert out.shape == (21,) and np.all(np.isfinite(out))
    targets = features.suction_debris_targets(obs, cavities=2, debris=3)
    np.testing.assert_allclose(out, _routes_reference(obs, targets), atol=1e-12)
    batched = np.stack([obs, obs[::-1].copy()])
    np.testing.assert_allclose(
        features.suction_debris_routes(torch.from_numpy(batched), cavities=2, debris=3, **GEOMETRY).numpy(),
        features.suction_debris_routes(batched, cavities=2, debris=3, **GEOMETRY), atol=1e-12)


@settings(max_examples=300, deadline=None)
@given(tip=point, handoff=point, slots=st.lists(slot, min_size=3, max_size=3),
       levels=st.tuples(st.sampled_from([0.0, 0.03, 0.0625, 0.07, 1.0]), st.sampled_from([0.0, 0.05, 0.5])))
def test_cleared_pins_are_those_in_a_cleared_cavity(tip, handoff, slots, levels):
    tip = tip * [1.0, 1.0, 0.4] + [0.0, 0.0, -0.45]
    obs = _observation(np.random.default_rng(0), tip, slots, handoff, np.zeros(3))
    obs[7:9] = levels
    out = features.suction_debris_cleared_pins(obs, cavities=2, debris=3, **GEOMETRY)
    assert out.shape == (26,) and np.all(np.isfinite(out))
    np.testing.assert_array_equal(out[:21], features.suction_debris_routes(obs, cavities=2, debris=3, **GEOMETRY))
    centres = np.array(GEOMETRY["cavity_centres"])
    clear = [levels[k] < GEOMETRY["blood_threshold_fraction"][k] or levels[k] <= 0 for k in range(2)]
    candidates = []
    for index in range(3):
        start = 9 + 6 * index
        position, (visible, held, delivered) = obs[start:start + 3], obs[start + 3:start + 6]
        cavity = int(np.argmin(np.sum((position[0:2] - centres) ** 2, axis=1)))
        if visible > 0.5 and held < 0.5 and delivered < 0.5 and clear[cavity]:
            candidates.append(position)
    if candidates:
        nearest = min(candidates, key=lambda p: float(np.sum((p - tip) ** 2)))
        np.testing.assert_allclose(out[21:24], nearest - tip, atol=1e-12)
        assert out[24] == 1.0
        mouth = GEOMETRY["cavity_mouth_radius"]
        same = any(np.sum((tip[0:2] - c) ** 2) < mouth**2 and np.sum((nearest[0:2] - c) ** 2) < mouth**2
                   for c in centres)
        assert out[25] == pytest.approx(0.0 if same else max(GEOMETRY["rim_z"] - tip[2], 0.0))
    else:
        assert np.all(out[21:26] == 0.0)
    batched = np.stack([obs, obs[::-1].copy()])
    np.testing.assert_allclose(
        features.suction_debris_cleared_pins(torch.from_numpy(batched), cavities=2, debris=3, **GEOMETRY).numpy(),
        features.suction_debris_cleared_pins(batched, cavities=2, debris=3, **GEOMETRY), atol=1e-12)


@settings(max_examples=200, deadline=None)
@given(tip=point, handoff=point, slots=st.lists(slot, min_size=3, max_size=3),
       levels=st.tuples(st.sampled_from([0.0, 0.03, 1.0]), st.sampled_from([0.0, 0.5])))
def test_zoomed_features_magnify_the_pin_and_carry_offsets(tip, handoff, slots, levels):
    obs = _observation(np.random.default_rng(0), tip, slots, handoff, np.zeros(3))
    obs[7:9] = levels
    out = features.suction_debris_cleared_pins_zoom(obs, cavities=2, debris=3, **GEOMETRY)
    base = features.suction_debris_cleared_pins(obs, cavities=2, debris=3, **GEOMETRY)
    assert out.shape == (32,) and np.all(np.isfinite(out)) and np.all(np.abs(out[26:]) <= 1.0)
    np.testing.assert_array_equal(out[:26], base)
    np.testing.assert_allclose(out[26:29], np.tanh(base[21:24] / (0.005 / 0.08)), atol=1e-12)
    np.testing.assert_allclose(out[29:32], np.tanh(base[5:8] / (0.005 / 0.08)), atol=1e-12)
    batched = np.stack([obs, obs[::-1].copy()])
    np.testing.assert_allclose(
        features.suction_debris_cleared_pins_zoom(torch.from_numpy(batched), cavities=2, debris=3, **GEOMETRY).numpy(),
        features.suction_debris_cleared_pins_zoom(batched, cavities=2, debris=3, **GEOMETRY), atol=1e-12)


def test_zoom_resolves_millimetres():
    """1 mm and 3 mm from a pin read far apart in the zoomed copy (0.2 against 0.5), not in the plain offset."""
    one, three = (np.tanh(np.array([0.001, 0.003]) / 0.08 / features.ZOOM)).tolist()
    assert one == pytest.approx(0.197, abs=1e-3) and three == pytest.approx(0.537, abs=1e-3)


def test_climb_reads_the_wall_the_env_enforces():
    """The climb feature against the env's own wall rule: from a cleared cavity's floor, with blood left in the other,
    steps straight toward the next cavity never get the tip out while the climb reads more than 0; after rising
    until it reads 0, the same steps do."""
    env = v0_rules.batched_env(num_envs=1, surgeon=None, autoreset_mode="disabled")
    env.reset(seed=0, options={"blood_ml": [[8.0, 0.0]]})
    layout = env.layout()
    rho, centre = env.workspace_range, np.asarray(env.params.workspace_centre)
    mouth_centre = np.asarray(layout.cavity_centres[1])
    floor = np.array([*mouth_centre, layout.cavity_floor[1] + layout.clearance]) * rho + centre
    env.set_tip_positions({"suction": floor[None] + [0.0, 0.0, 0.0005]})
    park = {"grasper": np.zeros((1, 4))}

    def read():
        observation = env.observations()["suction"]
        out = features.suction_debris_routes(observation, cavities=2, debris=3, **GEOMETRY)[0]
        assert out[17] == 1.0 and out[14] < 0  # the full cavity (0, at -x) is the next to clear
        inside = np.hypot(*(observation[0, 0:2] - mouth_centre)) < layout.cavity_mouth_radius
        return out[18], inside

    def across(steps):
        for _ in range(steps):
            env.step({"suction": np.array([[-1.0, 0.0, 0.0, -1.0]]), **park})

    climb, inside = read()
    assert climb > 0 and inside
    across(60)  # to the wall, and against it
    climb, inside = read()
    assert climb > 0 and inside, "the tip left the cavity through its wall"
    rises = 0
    while read()[0] > 0:
        env.step({"suction": np.array([[0.0, 0.0, 1.0, -1.0]]), **park})
        rises += 1
        assert rises < 60
    across(30)
    assert not read()[1], "at the rim's height the tip still could not leave the cavity"


def test_unknown_features_are_named():
    with pytest.raises(ValueError, match="unknown observation features 'bogus'"):
        features.apply({"name": "bogus"}, np.zeros(OBS_DIM))
    with pytest.raises(ValueError, match="unknown observation features"):
        features.feature_count("bogus")


def _config(**model):
    return mappo.MappoConfig(hidden=[16, 16], **model)


def test_switch_head_samples_open_or_closed_with_its_log_probability():
    config = _config(tool_head="switch", initial_tool_logit={"suction": 2.0, "grasper": -2.0})
    actor, _, _, _ = models.build_models(config, AGENTS, OBS_DIM, 31, 4)
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    td = TensorDict({"agents": TensorDict({"observation": torch.zeros(4000, 2, OBS_DIM)}, batch_size=[4000, 2])},
                    batch_size=[4000])
    with torch.no_grad(), set_exploration_type(ExplorationType.RANDOM):
        actor(td)
    action = td["agents", "action"]
    assert set(action[..., 3].unique().tolist()) == {-1.0, 1.0}
    # the initial leaning: suction's valve open, grasper's jaw closed, with probability sigmoid(2) = 0.88
    open_share = (action[..., 3] > 0).float().mean(0)
    assert abs(float(open_share[0]) - 0.881) < 0.03 and abs(float(open_share[1]) - 0.119) < 0.03
    # the stored log-probability is the distribution's, motion (Gaussian) plus tool (Bernoulli)
    with torch.no_grad():
        dist = actor.get_dist(td)
    np.testing.assert_allclose(dist.log_prob(action).numpy(), td["agents", "action_log_prob"].numpy(), atol=1e-5)
    motion = torch.distributions.Normal(td["agents", "loc"][..., :3], td["agents", "scale"][..., :3])
    tool = torch.distributions.Bernoulli(logits=td["agents", "loc"][..., 3])
    expected = motion.log_prob(action[..., :3]).sum(-1) + tool.log_prob((action[..., 3] > 0).float())
    np.testing.assert_allclose(dist.log_prob(action).numpy(), expected.numpy(), atol=1e-5)
    assert torch.allclose(dist.entropy(), motion.entropy().sum(-1) + tool.entropy())
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        actor(td)
    assert torch.equal(td["agents", "action"][..., 3], torch.tensor([1.0, -1.0]).expand(4000, 2))


@pytest.mark.parametrize("model", [
    {"tool_head": "switch", "initial_tool_logit": {"grasper": -3.0}},
    {"observation_features": "suction_debris_targets"},
    {"tool_head": "switch", "observation_features": "suction_debris_targets"},
    {"tool_head": "switch", "observation_features": "suction_debris_routes"},
    {"tool_head": "switch", "observation_features": "suction_debris_cleared_pins"},
    {"tool_head": "switch", "observation_features": "suction_debris_cleared_pins",
     "initial_tool_logit": {"grasper": 2.0}},
    {"tool_head": "switch", "initial_tool_logit": {"grasper": -4.0, "suction": 1.0}, "hidden": []},
    {"tool_head": "switch", "observation_features": "suction_debris_cleared_pins_zoom"},
])
@pytest.mark.slow
def test_export_matches_the_actor_with_switch_and_features(tmp_path, model):
    """The numpy policy (features computed, normalisation folded, the switch as a sign) acts as the torch actor's
    most likely action."""
    from tensordict import TensorDict
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    model = dict(model)
    feature_set = model.pop("observation_features", "")  # the env's option since issue 37
    config = mappo.MappoConfig(**{"hidden": [16, 16], **model})
    env = suction_debris_v8.batched_env(num_envs=40, surgeon=None)
    spec = features.spec(feature_set, env.layout(), env.params.debris_count) if feature_set else None
    width = OBS_DIM + (features.feature_count(feature_set) if feature_set else 0)
    actor, _, actor_net, norms = models.build_models(config, AGENTS, width, 31, 4,
                                                     feature_spec=spec)
    env.reset(seed=0)
    rng = np.random.default_rng(0)
    for _ in range(200):
        env.step({agent: rng.uniform(-1, 1, (40, 4)) for agent in AGENTS})
    observations = np.stack([env.observations()[a] for a in AGENTS], axis=1)
    observations[:, :, 9 + 4:27:6] = 0.0  # held flags: none, but pin 1 (visible) in every other world
    observations[::2, :, 9 + 6 * 1 + 3:9 + 6 * 1 + 5] = 1.0
    extended = observations if spec is None else features.apply(spec, observations)  # what the env would give
    norms["observation"].update(torch.from_numpy(extended))
    for net in actor_net.nets:  # make the head matter
        torch.nn.init.normal_(net[-1].weight, std=0.5)
    td = TensorDict({"agents": TensorDict({"observation": torch.from_numpy(extended).float()},
                                          batch_size=[40, 2])}, batch_size=[40])
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        expected = np.clip(actor(td)["agents", "action"].numpy(), -1.0, 1.0)
    for index, agent in enumerate(AGENTS):
        folder = mappo.export_actor(actor_net, index, tmp_path / agent, name=agent, agent=agent, metadata={},
                                    tool_head=config.tool_head)
        policy = policies.load(folder)
        assert ("features" in policy.spec) == bool(feature_set)
        np.testing.assert_allclose(policy(observations[:, index]), expected[:, index], atol=2e-4)
        np.testing.assert_allclose(policy(extended[:, index]), expected[:, index], atol=2e-4)  # the env's features
        if config.tool_head == "switch":
            assert set(np.unique(policy(observations[:, index])[:, 3])) <= {-1.0, 1.0}
        with pytest.raises(ValueError, match="reads 30 observation features, got 29"):
            policy(np.zeros(29))


@pytest.mark.parametrize("text, message", [
    ("[model]\ntool_head = 'dice'\n", "[model] tool_head: must be one of"),
    ("[run]\ndevice = 'tpu'\n", "device must be"),
    ("[env]\nobservation_features = 'everything'\n", "observation_features: must be one of"),
    ("[env]\nreward_type = 'guided'\n[env.guidance]\nroute_to_park = 'yes'\n", "route_to_park"),
    ("[env]\nreward_type = 'guided'\n[env.guidance]\ncentred_grasps = 1\n", "centred_grasps"),
    ("[ppo]\nbounds_loss_coef = -1.0\n", "[ppo] bounds_loss_coef: must be >= 0"),
    ("[model]\ntool_head = 'switch'\ninitial_tool_logit = { scalpel = 1.0 }\n", "[model] initial_tool_logit.scalpel"),
    ("[model]\ntool_head = 'switch'\nheld_tool_logit = { grasper = -8.0 }\n", "held_tool_logit: retired when the env took it over"),
    ("[model]\ncritic_input = 'everything'\n", "[model] critic_input: must be one of"),
])
def test_bad_head_settings_are_named(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text.replace("[run]\n", "") if text.startswith("[run]") else text)
    if text.startswith("[run]"):
        path.write_text("[run]\nalgorithm = 'mappo'\n" + text.replace("[run]\n", ""))
    else:
        path.write_text("[run]\nalgorithm = 'mappo'\n" + text)
    with pytest.raises(ValueError) as error:
        mappo.load_config(path)
    assert str(path) in str(error.value) and message in str(error.value)


def test_device_setting():
    assert mappo.learner_device(mappo.MappoConfig(device="cpu")).type == "cpu"
    expected = "cuda" if torch.cuda.is_available() else "cpu"
    assert mappo.learner_device(mappo.MappoConfig(device="auto")).type == expected
    if not torch.cuda.is_available():
        with pytest.raises(ValueError, match="sees no GPU"):
            mappo.learner_device(mappo.MappoConfig(device="cuda"))


def test_scheduled_exploration_noise(tmp_path):
    """With final_std the motion's standard deviation is not learnt: it falls from initial_std to final_std."""
    config = mappo.MappoConfig(total_steps=2048, num_envs=32, rollout_steps=16, eval_every=2048, eval_episodes=2,
                               checkpoint_every=2048, hidden=[16, 16], epochs=1, minibatches=1, initial_std=0.6,
                               final_std=0.1, tool_head="switch", env={"reward_type": "dense", "max_cycles": 40})
    assert config.exploration_std(0.0) == pytest.approx(0.6) and config.exploration_std(1.0) == pytest.approx(0.1)
    assert config.exploration_std(0.5) == pytest.approx(0.35)
    mappo.train(config, 0, tmp_path / "run", progress=False, tensorboard=False, log=lambda *_: None)
    saved = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    log_std = next(v for k, v in saved["loss_module"].items() if k.endswith("log_std"))
    # the last update ran at 1 - 512/2048 of the run
    assert torch.allclose(log_std.exp(), torch.tensor(config.exploration_std(1 - 512 / 2048)), atol=1e-6)


def test_exported_policy_acts_with_its_recorded_noise(tmp_path):
    """The export records the exploration noise; with_noise adds it (seeded, clipped); the switch tool stays +-1."""
    config = _config(tool_head="switch")
    _, _, actor_net, _ = models.build_models(config, AGENTS, OBS_DIM, 31, 4)
    log_std = torch.log(torch.tensor([0.3, 0.2, 0.1, 0.5]))
    folder = mappo.export_actor(actor_net, 0, tmp_path / "p", name="p", agent="suction", metadata={},
                                tool_head="switch", log_std=log_std)
    policy = policies.load(folder)
    assert policy.spec["exploration"]["std"] == pytest.approx([0.3, 0.2, 0.1, None])
    observations = np.zeros((20000, OBS_DIM))
    mean = policy(observations)
    noisy = policy.with_noise(seed=7)(observations)
    assert np.all(np.abs(noisy) <= 1.0)
    np.testing.assert_array_equal(noisy[:, 3], mean[:, 3])  # the switch: no noise on the tool
    spread = (noisy[:, :3] - mean[:, :3]).std(axis=0)
    np.testing.assert_allclose(spread, [0.3, 0.2, 0.1], rtol=0.05)
    np.testing.assert_array_equal(policy.with_noise(seed=7)(observations), noisy)  # seeded
    assert not np.array_equal(policy.with_noise(seed=8)(observations), noisy)
    # a policy without recorded noise says so
    plain = mappo.export_actor(actor_net, 0, tmp_path / "q", name="q", agent="suction", metadata={})
    with pytest.raises(ValueError, match="records no exploration noise"):
        policies.load(plain).with_noise(0)


@pytest.mark.slow
def test_evaluate_team_with_noise_from_the_cli(tmp_path):
    import subprocess
    import sys

    config = _config(tool_head="switch")
    _, _, actor_net, _ = models.build_models(config, AGENTS, OBS_DIM, 31, 4)
    folder = mappo.export_actor(actor_net, 0, tmp_path / "s", name="s", agent="suction", metadata={},
                                tool_head="switch", log_std=torch.zeros(4))
    command = [sys.executable, "-m", "dvrl_marl.cli", "evaluate-team", "--suction", str(folder), "--grasper",
               "scripted", "--episodes", "2", "--noise"]
    result = subprocess.run(command, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    assert "exploration noise" in result.stdout and "scripted" in result.stdout
    # what --noise seats: the learned policy with its seeded noise, the scripted partner unchanged
    from dvrl_marl.training import teams

    seated = teams.seats(str(folder), "scripted", noise_from=900)
    assert isinstance(seated["suction"], policies.NoisyPolicy)
    assert not isinstance(seated["grasper"], (policies.NoisyPolicy, policies.NumpyPolicy))
    observations = np.zeros((5, OBS_DIM))
    again = teams.seat(str(folder), "suction", noise_from=900)
    np.testing.assert_array_equal(seated["suction"](observations), again(observations))
    assert not np.array_equal(seated["suction"](observations), policies.load(folder)(observations))


@pytest.mark.parametrize("std, message", [([0.1, 0.1], "2 values for 4"), ([0.1, -0.1, 0.1, None], "finite and >= 0"),
                                          ([0.1, float("nan"), 0.1, None], "finite and >= 0")])
def test_bad_recorded_noise_is_named(tmp_path, std, message):
    import json

    config = _config()
    _, _, actor_net, _ = models.build_models(config, AGENTS, OBS_DIM, 31, 4)
    folder = mappo.export_actor(actor_net, 0, tmp_path / "p", name="p", agent="suction", metadata={})
    spec = json.loads((folder / "policy.json").read_text())
    spec["exploration"] = {"std": std}
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=message):
        policies.load(folder).with_noise(0)


def test_unshared_local_collector_acts_with_the_learners_weights():
    """A learner on a GPU collects through a CPU copy of its actor: each rollout loads the learner's weights."""
    from dvrl_marl.training.collectors import make_collectors

    config = mappo.MappoConfig(num_envs=4, rollout_steps=3, hidden=[8], tool_head="switch",
                               env={"reward_type": "dense", "max_cycles": 20})
    learner, _, _, _ = models.build_models(config, AGENTS, OBS_DIM, 31, 4)
    with torch.no_grad():
        for parameter in learner.parameters():
            parameter.add_(0.1)
    collectors = make_collectors(config, 0, actor=None, steps_done=0)
    try:
        assert not collectors.shared
        batch = collectors.collect(learner.state_dict())
        copy = collectors.collector.actor.state_dict()
        assert all(torch.equal(copy[k], v.cpu()) for k, v in learner.state_dict().items())
        assert batch["action"].shape == (3, 4, 2, 4)
    finally:
        collectors.close()


def test_bounds_loss_penalises_only_means_beyond_the_action_box():
    loc = torch.tensor([[0.5, -1.0, 2.0, 9.0], [-3.0, 0.0, 1.0, -9.0]])
    # switch: the tool's logit (last) is free; motion excess 1^2 and 2^2, averaged over the two rows
    assert float(mappo.bounds_loss(loc, "switch")) == pytest.approx((1.0 + 4.0) / 2)
    assert float(mappo.bounds_loss(loc, "gaussian")) == pytest.approx((1.0 + 64.0 + 4.0 + 64.0) / 2)
    assert float(mappo.bounds_loss(torch.zeros(5, 4))) == 0.0


@pytest.mark.slow
def test_bounds_loss_pulls_saturated_means_back_in_training(tmp_path):
    """A tiny run whose actors start saturated (output bias 3): with the bounds loss the exported policy's means
    come back toward the box, without it they stay out."""
    env = suction_debris_v8.batched_env(num_envs=64, surgeon=None)
    observations, _ = env.reset(seed=1)

    def final_means(coef):
        config = mappo.MappoConfig(total_steps=2048, num_envs=16, rollout_steps=16, eval_every=2048, eval_episodes=1,
                                   checkpoint_every=2048, hidden=[16, 16], epochs=4, minibatches=2, anneal_lr=False,
                                   learning_rate=0.01, bounds_loss_coef=coef, tool_head="switch",
                                   env={"reward_type": "dense", "max_cycles": 40})
        original = mappo.build_models

        def saturated(*args, **kwargs):
            built = original(*args, **kwargs)
            with torch.no_grad():
                for net in built[2].nets:
                    net[-1].bias[:3] = 3.0
            return built

        mappo.build_models = saturated
        try:
            mappo.train(config, 0, tmp_path / f"run{coef}", progress=False, tensorboard=False, log=lambda *_: None)
        finally:
            mappo.build_models = original
        policy = policies.load(tmp_path / f"run{coef}" / "policies" / "marl-suction")
        hidden = policy.features(observations["suction"])
        for index, (weight, bias) in enumerate(policy.weights):
            hidden = hidden @ weight.T + bias
            if index < len(policy.weights) - 1:
                hidden = np.tanh(hidden)
        return float(hidden[:, :3].mean())  # the motion means, before the clip

    assert final_means(1.0) < 1.5 and final_means(0.0) > 2.5
