"""The seat that sees the endoscope: its numpy policy equals the network it was trained as, it refuses what it
cannot read, the trainer's pieces do what they say, and team evaluations give images only to the seat that sees."""

import json
import shutil

import numpy as np
import pytest

from dvrl_marl import policies
from dvrl_marl.training import teams

torch = pytest.importorskip("torch")
from dvrl_marl.training import pixel_seat  # noqa: E402  (needs torch)


def _config(**overrides):
    return pixel_seat.PixelSeatConfig(**{"algorithm": "pixel-dagger", **overrides})


def _exported(tmp_path, **overrides):
    config = _config(**overrides)
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    return model, config, pixel_seat.export(model, config, tmp_path / "policy", "test-pixels", {})


def _observation(count, size=64, seed=0):
    rng = np.random.default_rng(seed)
    return {"observation": rng.uniform(-1, 1, (count, 30)),
            "image": rng.integers(0, 256, (count, size, size, 3), dtype=np.uint8)}


@pytest.mark.parametrize("normalise", ["none", "per_image", "brightness"])
def test_the_numpy_policy_is_the_network_it_was_trained_as(tmp_path, normalise):
    model, config, folder = _exported(tmp_path, image_size=48, convolutions=[[8, 4, 2], [8, 3, 1]], hidden=[32],
                                      normalise=normalise)
    policy = policies.load(folder)
    observation = _observation(7, size=48)
    with torch.no_grad():
        expected = model(torch.from_numpy(observation["image"]),
                         torch.from_numpy(observation["observation"][:, :4].astype(np.float32))).numpy()
    unclipped = policy._network(policy.features(observation), clip_last=False)
    np.testing.assert_allclose(unclipped, expected, rtol=0, atol=1e-5)
    action = policy(observation)
    assert action.shape == (7, 4) and set(np.unique(action[:, 3])) <= {-1.0, 1.0}  # the valve is a switch
    np.testing.assert_allclose(action[:, :3], np.clip(expected[:, :3], -1, 1), atol=1e-5)
    single = policy({key: value[0] for key, value in observation.items()})  # one world, unbatched
    np.testing.assert_allclose(single, action[0], atol=1e-6)
    assert policy.image_options == {"image_size": 48}
    # the policy reads only the image and its own tip and valve: the privileged rest changes nothing
    private = {**observation, "observation": observation["observation"].copy()}
    private["observation"][:, 4:] = 0.0
    np.testing.assert_array_equal(policy(private), action)
    if normalise != "none":  # a gain over the whole image changes nothing the network reads
        darker = {**observation, "image": (observation["image"] * 0.75).round().astype(np.uint8)}
        np.testing.assert_allclose(policy.encoder(darker["image"]), policy.encoder(observation["image"]), atol=0.05)


def test_a_pixel_policy_refuses_what_it_cannot_read(tmp_path):
    _, _, folder = _exported(tmp_path)
    policy = policies.load(folder)
    with pytest.raises(ValueError, match="image_size=64"):
        policy(np.zeros((2, 30)))  # a vector: the env was made without images
    with pytest.raises(ValueError, match="64 x 64"):
        policy(_observation(2, size=84))
    spec = json.loads((folder / "policy.json").read_text())
    broken = tmp_path / "broken"
    shutil.copytree(folder, broken)
    (broken / "policy.json").write_text(json.dumps({**spec, "layer_sizes": [100, *spec["layer_sizes"][1:]]}))
    with pytest.raises(ValueError, match="layer_sizes"):
        policies.load(broken)
    (broken / "policy.json").write_text(json.dumps({**spec, "image": {**spec["image"], "size": 8}}))
    with pytest.raises(ValueError, match="size"):
        policies.load(broken)
    (broken / "policy.json").write_text(json.dumps(spec))
    _drop_array(folder, broken, "K1")
    with pytest.raises(ValueError, match="K1"):
        policies.load(broken)


def _drop_array(folder, into, name):
    """``folder``'s ``policy.npz`` without the array ``name``, written into ``into``."""
    arrays = dict(np.load(folder / "policy.npz"))
    del arrays[name]
    np.savez(into / "policy.npz", **arrays)


def test_a_seat_acting_by_the_teacher_is_the_teacher_on_what_the_image_tells_it(tmp_path):
    """acts_by = "teacher": the read-out's estimates (plus the margin) fill the teacher's observation beside the
    proprioception and the scene's constants; the teacher's own layers and features act on it."""
    config = _config(acts_by="teacher", estimated=[7, 9], estimate_margin=0.02, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    constants = np.full(30, np.nan)
    constants[27:30] = [0.975, 0.0, 0.1875]  # the hand-off point, the same in every world
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-estimates", {}, constants)
    policy, teacher = policies.load(folder), teams.seat("marl-suction", "suction")
    observation = _observation(5)
    with torch.no_grad():
        estimates = model.features(torch.from_numpy(observation["image"])).numpy()
    filled = np.zeros((5, 30))
    filled[:, :4] = observation["observation"][:, :4]
    filled[:, 7:9] = estimates + 0.02
    filled[:, 27:30] = constants[27:30]
    np.testing.assert_allclose(policy(observation), teacher(filled), atol=1e-5)
    private = {**observation, "observation": observation["observation"].copy()}
    private["observation"][:, 4:] = 7.0  # the privileged rest of the observation changes nothing
    np.testing.assert_array_equal(policy(private), policy(observation))
    spec = json.loads((folder / "policy.json").read_text())
    assert spec["features"] == teacher.spec["features"] and spec["image"]["fills"]["estimates_at"] == [7, 8]
    with pytest.raises(ValueError, match="constants"):
        pixel_seat.export(model, config, tmp_path / "again", "test-estimates", {})


def test_a_seat_keeping_its_lowest_estimates_keeps_them_world_by_world_until_its_episodes_start(tmp_path):
    """keep_lowest: each world's estimates are the lowest its episode has seen; ``reset(worlds)`` forgets them in
    those worlds only, ``reset()`` everywhere, and its noisy form starts the same episodes."""
    config = _config(acts_by="teacher", estimated=[7, 9], keep_lowest=True, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    constants = np.full(30, np.nan)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-lowest", {}, constants)
    policy = policies.load(folder)
    assert policy.spec["image"]["fills"]["keep_lowest"] == [7, 8]
    bright, dark = _observation(3, seed=1), _observation(3, seed=2)
    dark["observation"] = bright["observation"]  # one episode: the tips where they were (a jump starts another)
    encoder = policy.encoder
    first = encoder(bright["image"])  # (the margin folded into the read-out)
    second = encoder(dark["image"])
    assert not np.allclose(first, second)
    assert np.any(first < second) and np.any(second < first)  # (keeping the lowest differs from the last look)
    seen = lambda o: encoder.observation(o["image"], o["observation"])[:, 7:9]  # noqa: E731
    np.testing.assert_allclose(seen(bright), first, atol=1e-6)
    np.testing.assert_allclose(seen(dark), np.minimum(first, second), atol=1e-6)
    policy.reset(np.array([False, True, False]))  # world 1 starts a new episode
    expected = np.minimum(first, second)
    expected[1] = first[1]
    np.testing.assert_allclose(seen(bright), expected, atol=1e-6)
    noisy = policy.with_noise(0) if policy.spec.get("exploration") else policy
    noisy.reset()
    np.testing.assert_allclose(seen(dark), second, atol=1e-6)
    # the same images from a fresh start act as a policy that keeps nothing
    plain = policies.load(folder)
    plain.encoder.keep_lowest = None
    policy.reset()
    np.testing.assert_array_equal(policy(bright), plain(bright))


def test_a_seat_called_across_episodes_without_reset_starts_them_where_its_tip_jumps(tmp_path):
    """keep_lowest without reset(): a world whose tip moved NEW_EPISODE_JUMP or more since the last call starts a new
    episode (its lowest estimates forgotten, as reset(worlds) would); smaller moves keep them."""
    from dvrl_marl.policies.image_encoder import NEW_EPISODE_JUMP

    config = _config(acts_by="teacher", estimated=[7, 9], keep_lowest=True, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    folder = pixel_seat.export(pixel_seat.PixelActor(config, 4), config, tmp_path / "policy", "test-jump", {},
                               np.full(30, np.nan))
    policy = policies.load(folder)
    bright, dark = _observation(3, seed=1), _observation(3, seed=2)
    first, second = policy.encoder(bright["image"]), policy.encoder(dark["image"])
    seen = lambda o: policy.encoder.observation(o["image"], o["observation"])[:, 7:9]  # noqa: E731
    seen(bright)
    moved = bright["observation"].copy()
    moved[0, 0:3] += 0.9 * NEW_EPISODE_JUMP / np.sqrt(3)  # a step within an episode
    moved[2, 0:3] += 1.1 * NEW_EPISODE_JUMP / np.sqrt(3)  # a new episode's start
    expected = np.minimum(first, second)
    expected[2] = second[2]
    np.testing.assert_allclose(seen({"image": dark["image"], "observation": moved}), expected, atol=1e-6)


def test_a_seat_reads_its_kept_blood_estimates_at_full_above_or_more_as_full(tmp_path):
    """full_above: a blood estimate kept at its lowest reads as full (1) at the threshold or more, and as it is under
    it; the lowest is kept of the estimates themselves, so a cavity read under the threshold once stays so read."""
    config = _config(acts_by="teacher", estimated=[7, 9], keep_lowest=True, full_above=0.9, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    folder = pixel_seat.export(pixel_seat.PixelActor(config, 4), config, tmp_path / "policy", "test-full", {},
                               np.full(30, np.nan))
    policy, plain = policies.load(folder), policies.load(folder)
    assert policy.spec["image"]["fills"]["full_above"] == 0.9 and policy.encoder.full_above == 0.9
    weights = np.zeros_like(policy.encoder.readout[0])
    observation = _observation(3, seed=1)
    for estimates, read in [((0.95, 0.5), (1.0, 0.5)), ((0.905, 0.6), (1.0, 0.5)), ((0.92, 0.7), (1.0, 0.5)),
                            ((0.85, 0.6), (0.85, 0.5)), ((0.97, 0.4), (0.85, 0.4))]:
        policy.encoder.readout = (weights, np.array(estimates, np.float32))
        seen = policy.encoder.observation(observation["image"], observation["observation"])[:, 7:9]
        np.testing.assert_allclose(seen, np.broadcast_to(read, (3, 2)), atol=1e-6, err_msg=str(estimates))
    # reading 0.95 as full acts as reading exactly 1
    policy.reset()
    policy.encoder.readout = (weights, np.array([0.95, 0.5], np.float32))
    plain.encoder.full_above, plain.encoder.readout = None, (weights, np.array([1.0, 0.5], np.float32))
    np.testing.assert_array_equal(policy(observation), plain(observation))


@pytest.mark.parametrize("settings, message", [("full_above = 0.9", "full_above .* needs keep_lowest = true"),
                                               ("keep_lowest = true\nfull_above = 1.5", "full_above")])
def test_full_above_reads_the_estimates_kept_at_their_lowest(tmp_path, settings, message):
    path = tmp_path / "seat.toml"
    path.write_text(f'[run]\nalgorithm = "pixel-dagger"\nacts_by = "teacher"\n{settings}\n')
    with pytest.raises(ValueError, match=message):
        pixel_seat.load_config(path)


def test_keep_lowest_is_the_teacher_actings_alone(tmp_path):
    path = tmp_path / "seat.toml"
    path.write_text('[run]\nalgorithm = "pixel-dagger"\nkeep_lowest = true\n')
    with pytest.raises(ValueError, match="keep_lowest is for acts_by = 'teacher'"):
        pixel_seat.load_config(path)


@pytest.mark.parametrize("fills, message", [
    ({"template": [0.0] * 30, "estimates_at": [7, 8], "full_above": 0.9}, "name them in fills.keep_lowest"),
    ({"template": [0.0] * 30, "estimates_at": [7, 8], "keep_lowest": [7, 8], "full_above": 0.0}, "full_above"),
    ({"template": [0.0] * 30, "estimates_at": [7]}, "1 indices for a read-out of 2"),
    ({"template": [0.0] * 30, "estimates_at": [3, 8]}, "overlaps the proprioception"),
    ({"template": [0.0] * 8, "estimates_at": [7, 8]}, "8-long template"),
    ({"template": [0.0] * 29 + [float("nan")], "estimates_at": [7, 8]}, "template"),
])
def test_a_fill_that_does_not_fit_is_refused_by_name(tmp_path, fills, message):
    config = _config(acts_by="teacher", convolutions=[[8, 8, 4]])
    model = pixel_seat.PixelActor(config, 4)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-estimates", {}, np.full(30, np.nan))
    spec = json.loads((folder / "policy.json").read_text())
    spec["image"]["fills"] = fills
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=message):
        policies.load(folder)


def test_the_trainers_shift_moves_whole_images():
    images = torch.from_numpy(np.random.default_rng(0).integers(0, 256, (16, 20, 20, 3), dtype=np.uint8))
    assert pixel_seat._shifted(torch, images, 0, None) is images
    shifted = pixel_seat._shifted(torch, images, 2, torch.Generator().manual_seed(0)).numpy()
    original = images.numpy().astype(np.float32)
    for index in range(16):  # each is the original moved by at most 2 px (its interior matches somewhere)
        interior = shifted[index, 2:-2, 2:-2]
        assert any(np.array_equal(interior, original[index, 2 + dy:18 + dy, 2 + dx:18 + dx])
                   for dy in range(-2, 3) for dx in range(-2, 3))
    assert sum(not np.array_equal(shifted[i], original[i]) for i in range(16)) >= 12  # and most of them did move


def test_collect_labels_every_recorded_state_with_the_teachers_action():
    config = _config(worlds=3, max_cycles=12, record_every=3, action_noise=0.0, partners=["scripted"])
    batch = pixel_seat.collect(config, None, seed=5, noise_seed=5)
    assert batch["images"].shape == (12, 64, 64, 3) and batch["images"].dtype == np.uint8  # steps 0, 3, 6, 9
    assert batch["proprioception"].shape == (12, 4) and batch["labels"].shape == (12, 4)
    assert batch["targets"].shape == (12, 5) and batch["cleared"].shape == (12, 2)  # auxiliary targets
    again = pixel_seat.collect(config, None, seed=5, noise_seed=5)  # worlds, looks and labels are seeded
    for key in ("images", "proprioception", "labels", "targets"):
        np.testing.assert_array_equal(batch[key], again[key])
    # the labels are the teacher's actions for the states recorded
    from dvrl_marl.envs import suction_debris_v8

    env = suction_debris_v8.batched_env(num_envs=3, autoreset_mode="disabled", max_cycles=12)
    observations, _ = env.reset(seed=5)
    teacher, partner = teams.seat("marl-suction", "suction"), teams.seat("scripted", "grasper")
    np.testing.assert_allclose(batch["labels"][:3], teacher(observations["suction"]), atol=1e-6)
    np.testing.assert_allclose(batch["proprioception"][:3], observations["suction"][:, :4], atol=1e-6)
    env.step({"suction": teacher(observations["suction"]), "grasper": partner(observations["grasper"])})


def test_class_jitter_colours_each_class_apart_and_its_fit_needs_the_frames_segmentation():
    images = torch.full((32, 8, 8, 3), 100, dtype=torch.uint8)
    segmentation = torch.zeros((32, 8, 8), dtype=torch.uint8)
    segmentation[:, :4, :4], segmentation[:, :4, 4:], segmentation[:, 4:, :4], segmentation[:, 4:, 4:] = 1, 2, 3, 4
    assert pixel_seat._class_jittered(torch, images, segmentation, 0.0, torch.Generator().manual_seed(0)) is images
    gains = pixel_seat._class_jittered(torch, images, segmentation, 0.3, torch.Generator().manual_seed(0)) / 100.0
    assert torch.all((gains >= 0.7 - 1e-5) & (gains <= 1.3 + 1e-5))
    quadrants = [gains[:, :4, :4], gains[:, :4, 4:], gains[:, 4:, :4], gains[:, 4:, 4:]]
    for quadrant in quadrants:  # one gain per image, class and channel
        assert torch.allclose(quadrant, quadrant[:, :1, :1].expand_as(quadrant))
    tissue, blood = quadrants[0][:, 0, 0], quadrants[1][:, 0, 0]
    assert (tissue - blood).abs().max() > 0.2 and (tissue[:, 0] - tissue[:, 1]).abs().max() > 0.2  # apart
    # collected with the option, the frames carry the env's segmentation; a fit with it refuses frames without one
    config = _config(worlds=2, max_cycles=4, record_every=2, action_noise=0.0, partners=["scripted"],
                     class_jitter=0.3, convolutions=[[8, 8, 4]])
    batch = pixel_seat.collect(config, None, seed=3, noise_seed=3)
    assert batch["segmentation"].shape == batch["images"].shape[:3] and batch["segmentation"].dtype == np.uint8
    assert {1, 4} <= set(np.unique(batch["segmentation"]))  # the tissue and the instruments are in view
    model = pixel_seat.PixelActor(config, 4)
    assert np.isfinite(pixel_seat.fit(model, batch, config, 2, 0))
    without = {key: value for key, value in batch.items() if key != "segmentation"}
    with pytest.raises(ValueError, match="class_jitter needs the frames' segmentation"):
        pixel_seat.fit(pixel_seat.PixelActor(config, 4), without, config, 2, 0)


def test_frames_where_the_tips_are_near_are_drawn_more_often_when_asked():
    config = _config(worlds=2, max_cycles=40, record_every=1, action_noise=0.0, partners=["scripted"],
                     acts_by="teacher", estimated=[4, 9], convolutions=[[8, 8, 4]])
    batch = pixel_seat.collect(config, None, seed=3, noise_seed=3)
    # how far apart the tips are, frame by frame: the own tip (proprioception) and the other's (the estimates' first)
    expected = 80.0 * np.linalg.norm(batch["proprioception"][:, :3] - batch["targets"][:, :3], axis=1)
    np.testing.assert_allclose(batch["tips_apart_mm"], expected, rtol=1e-5)
    assert pixel_seat.draw_chances(batch, config) is None  # (by default every frame alike)
    near = config.model_copy(update={"near_weight": 3.0, "near_mm": float(np.median(expected))})
    chances = pixel_seat.draw_chances(batch, near).numpy()
    np.testing.assert_array_equal(chances, np.where(expected < near.near_mm, 4.0, 1.0))
    assert 0 < (chances == 4.0).sum() < len(chances)
    # what the fit draws: with the near frames' weight overwhelming, every minibatch row is a near frame's
    near_rows = {tuple(row) for row in batch["proprioception"][expected < near.near_mm].tolist()}

    def drawn_rows(config):
        model, rows = pixel_seat.PixelActor(config, 4), []
        features = model.features
        model.features = lambda images, own=None: rows.extend(map(tuple, own.tolist())) or features(images, own)
        assert np.isfinite(pixel_seat.fit(model, batch, config, 3, 0))
        return rows

    assert set(drawn_rows(near.model_copy(update={"near_weight": 1e9}))) <= near_rows
    assert not set(drawn_rows(config)) <= near_rows  # (drawn alike, the far frames come too)
    errors = pixel_seat.estimate_errors(pixel_seat.PixelActor(near, 4), batch, blood=pixel_seat._blood_columns(near),
                                        near_mm=near.near_mm)
    assert errors["other_near_mean_absolute"] > 0.0
    without = {key: value for key, value in batch.items() if key != "tips_apart_mm"}
    with pytest.raises(ValueError, match="near_weight needs the frames' tips_apart_mm"):
        pixel_seat.fit(pixel_seat.PixelActor(near, 4), without, near, 2, 0)


def test_the_teacher_drives_its_share_of_the_worlds():
    config = _config(worlds=4, max_cycles=10, record_every=1, action_noise=0.2, partners=["scripted"])
    by_teacher = pixel_seat.collect(config, None, seed=7, noise_seed=7)

    def still(observations):  # a student that never moves: where it drives, the worlds differ from the teacher's
        return np.zeros((len(observations["observation"]), 4))

    half = pixel_seat.collect(config.model_copy(update={"teacher_share": 0.5}), still, seed=7, noise_seed=7)
    whole = pixel_seat.collect(config.model_copy(update={"teacher_share": 1.0}), still, seed=7, noise_seed=7)
    np.testing.assert_array_equal(whole["proprioception"], by_teacher["proprioception"])
    frames = by_teacher["proprioception"].reshape(10, 4, 4)  # step, world, value
    mixed = half["proprioception"].reshape(10, 4, 4)
    np.testing.assert_array_equal(mixed[:, :2], frames[:, :2])  # worlds 0 and 1: the teacher drove
    assert not np.array_equal(mixed[:, 2:], frames[:, 2:])
    np.testing.assert_array_equal(mixed[:, 2:, :3], np.broadcast_to(mixed[:1, 2:, :3], (10, 2, 3)))  # still


@pytest.mark.slow
def test_the_trainer_runs_end_to_end_and_keeps_its_best_round(tmp_path):
    config = _config(worlds=4, rounds=2, max_cycles=30, updates=3, first_updates=5, validation_episodes=2,
                     convolutions=[[8, 8, 4]], hidden=[16], partners=["scripted"])
    result = pixel_seat.train("tiny-pixels", config, 0, tmp_path)
    assert [row["driver"] for row in result["rounds"]] == ["teacher", "student"]
    assert result["rounds"][1]["frames"] > result["rounds"][0]["frames"] > 0  # DAgger aggregates
    policy = policies.load(result["policy"])
    assert policy.image_options == {"image_size": 64} and policy.spec["agent"] == "suction"
    assert "round" in policy.spec["training"]["selected_by"]
    assert json.loads((tmp_path / "result.json").read_text())["selected_round"] == result["selected_round"]


def test_a_run_stopped_after_a_round_keeps_the_record_of_its_rounds(tmp_path, monkeypatch):
    config = _config(worlds=2, rounds=3, max_cycles=10, updates=2, first_updates=2, validation_episodes=2,
                     convolutions=[[4, 8, 4]], hidden=[8], partners=["scripted"])
    validated = []

    def validate_then_stop(policy, config):
        if validated:
            raise KeyboardInterrupt  # (the run stopped during its second round)
        validated.append(policy)
        return {"success_rate": 0.5, "mean_contact_steps": 1.0, "median_steps_to_completion": 7.0}

    monkeypatch.setattr(pixel_seat, "validate", validate_then_stop)
    with pytest.raises(KeyboardInterrupt):
        pixel_seat.train("tiny-pixels", config, 0, tmp_path, progress=False)
    record = json.loads((tmp_path / "result.json").read_text())
    assert [row["round"] for row in record["rounds"]] == [0] and record["selected_round"] is None
    assert record["rounds"][0]["validation"]["success_rate"] == 0.5 and record["config"]["rounds"] == 3


def test_the_kept_round_is_the_best_validated_and_a_tie_goes_to_the_later(tmp_path):
    for index in range(4):
        folder = pixel_seat.round_folder(tmp_path, index)
        folder.mkdir(parents=True)
        (folder / "policy.json").write_text(json.dumps({"training": {"round": index}}))
    rows = [{"validation": {"success_rate": rate, "mean_contact_steps": contacts}}
            for rate, contacts in ((0.5, 0.0), (0.75, 3.0), (0.75, 0.0), (0.75, 0.0))]
    assert pixel_seat.keep_best(tmp_path, "seat", rows) == 3
    spec = json.loads((tmp_path / "policies" / "seat" / "policy.json").read_text())
    assert spec["training"]["round"] == 3 and spec["training"]["selected_by"].endswith("round 3")
    rows[3]["validation"]["mean_contact_steps"] = 1.0  # fewer contacts win over the later round
    assert pixel_seat.keep_best(tmp_path, "seat", rows) == 2


def test_the_shipped_configurations_read():
    from dvrl_marl.cli import resolve_config

    name, config = pixel_seat.load_config(resolve_config("suction_pixels_dagger"))
    assert name == "suction_pixels_dagger" and config.teacher == "marl-suction" and config.image_size == 64
    name, config = pixel_seat.load_config(resolve_config("suction_pixels_estimates"))
    assert config.acts_by == "teacher" and config.estimated == [7, 9]
    # a file holding only what differs: the rest from the one it extends
    name, per_image = pixel_seat.load_config(resolve_config("suction_pixels_estimates_per_image"))
    assert name == "suction_pixels_estimates_per_image" and per_image.normalise == "per_image"
    assert per_image.model_dump() == {**config.model_dump(), "normalise": "per_image"}
    # every pixel seat's file reads, each a change of the one it extends
    import tomllib
    from pathlib import Path

    from dvrl_marl.files import read_extended_toml

    folder = Path(__file__).parents[1] / "baselines" / "configs"  # the checkout's (the package may be installed)
    pixel_files = [path for path in sorted(folder.glob("*.toml"))
                   if read_extended_toml(path).get("run", {}).get("algorithm") == "pixel-dagger"]
    assert {path.stem for path in pixel_files} >= {"suction_pixels_dagger", "suction_pixels_estimates_shading",
                                                    "suction_pixels_estimates_exposure"}
    for path in pixel_files:
        name, read = pixel_seat.load_config(path)
        assert name == path.stem
        base = tomllib.loads(path.read_text())["run"].get("extends")
        if base is not None:
            _, extended = pixel_seat.load_config(folder / base)
            assert read != extended, f"{path.name} changes nothing of {base}"
    _, exposure = pixel_seat.load_config(resolve_config("suction_pixels_estimates_exposure"))
    assert (exposure.normalise, exposure.colour_jitter, exposure.jitter_brightness, exposure.shading) == \
        ("brightness", 0.4, False, 0.3)


def test_a_bad_configuration_names_the_field(tmp_path):
    path = tmp_path / "pixels.toml"
    path.write_text('[run]\nalgorithm = "pixel-dagger"\nimage_size = 20\n')
    with pytest.raises(ValueError, match="image_size"):
        pixel_seat.load_config(path)
    path.write_text('[run]\nalgorithm = "pixel-dagger"\n[model]\nhidden = [8]\n')
    with pytest.raises(ValueError, match="model"):
        pixel_seat.load_config(path)


def test_an_evaluation_gives_images_only_to_the_seat_that_sees(tmp_path):
    _, _, folder = _exported(tmp_path)
    seeing = policies.load(folder)
    with pytest.raises(ValueError, match="image_appearance"):
        teams.evaluate_team_batched(teams.seats("scripted", "scripted"), 2, image_appearance="train")
    with pytest.raises(ValueError, match="image_size"):
        teams.evaluate_team_batched({"suction": seeing, "grasper": teams.seat("scripted", "grasper")}, 2,
                                    image_size=84)
    result = teams.evaluate_team_batched({"suction": seeing, "grasper": teams.seat("scripted", "grasper")}, 2,
                                         max_cycles=20, image_appearance="held_out")
    assert result["episodes"] == 2 and result["success_rate"] == 0.0  # an untrained net in 20 steps


def test_a_bound_surgeon_seat_refuses_a_pixel_policy_by_name(tmp_path):
    from dvrl_marl.envs import suction_debris_v8

    _, _, folder = _exported(tmp_path)
    with pytest.raises(ValueError, match="sees the endoscope"):
        suction_debris_v8.parallel_env(surgeon=policies.load(folder), surgeon_seat="suction")


def test_the_cli_trains_a_pixel_seat_from_its_configuration(tmp_path, capsys):
    from dvrl_marl.cli import main

    config = tmp_path / "tiny_pixels.toml"
    config.write_text('[run]\nalgorithm = "pixel-dagger"\npartners = ["scripted"]\nworlds = 2\nrounds = 1\n'
                      'max_cycles = 20\nfirst_updates = 2\nconvolutions = [[4, 8, 4]]\nhidden = [8]\n'
                      'validation_episodes = 2\n')
    assert main(["train", str(config), "--out", str(tmp_path / "run"), "--export", str(tmp_path / "seat"),
                 "--no-progress"]) == 0
    assert "validation success" in capsys.readouterr().out
    assert policies.load(tmp_path / "seat").image_options == {"image_size": 64}


def test_colour_jitter_scales_each_images_channels_within_its_bound():
    import torch

    images = torch.full((64, 8, 8, 3), 100, dtype=torch.uint8)
    assert pixel_seat._jittered(torch, images, 0.0, torch.Generator().manual_seed(0)) is images
    jittered = pixel_seat._jittered(torch, images, 0.3, torch.Generator().manual_seed(0))
    gains = jittered / 100.0
    assert torch.all((gains >= 0.7) & (gains <= 1.3))
    assert torch.all(gains == gains[:, :1, :1, :])  # one gain per image and channel
    assert gains[:, 0, 0, :].std() > 0.1  # they differ between images and channels
    bright = pixel_seat._jittered(torch, torch.full((8, 2, 2, 3), 250, dtype=torch.uint8), 0.3,
                                  torch.Generator().manual_seed(1))
    assert bright.max() <= 255.0


def test_colour_jitter_without_brightness_keeps_each_images_mean_gain():
    import torch

    images = torch.full((64, 8, 8, 3), 100, dtype=torch.uint8)
    jittered = pixel_seat._jittered(torch, images, 0.3, torch.Generator().manual_seed(0), brightness=False)
    gains = jittered[:, 0, 0, :] / 100.0
    assert torch.allclose(gains.mean(dim=1), torch.ones(64), atol=1e-5)  # the brightness stays
    assert gains.std() > 0.1  # the colour does not
    assert torch.all((gains > 0.7 / 1.3 - 1e-6) & (gains < 1.3 / 0.7 + 1e-6))


def test_shading_is_a_gradient_across_each_image_within_its_bound():
    import torch

    images = torch.full((64, 9, 9, 3), 100, dtype=torch.uint8)
    assert pixel_seat._shaded(torch, images, 0.0, torch.Generator().manual_seed(0)) is images
    gains = pixel_seat._shaded(torch, images, 0.3, torch.Generator().manual_seed(0)) / 100.0
    assert torch.all((gains >= 0.7 - 1e-5) & (gains <= 1.3 + 1e-5))
    assert torch.all(gains == gains[..., :1])  # the light's strength, not its colour
    # a plane: the centre keeps its brightness, opposite pixels lie as far above it as below it
    assert torch.allclose(gains[:, 4, 4, 0], torch.ones(64), atol=1e-5)
    assert torch.allclose(gains[:, 0, 0, 0] + gains[:, 8, 8, 0], torch.full((64,), 2.0), atol=1e-5)
    assert torch.allclose(gains[:, 0, 8, 0] + gains[:, 8, 0, 0], torch.full((64,), 2.0), atol=1e-5)
    edges = torch.stack([gains[:, 4, 0, 0], gains[:, 0, 4, 0]], dim=1) - 1.0
    assert edges.abs().max() > 0.2 and (edges > 0.05).any() and (edges < -0.05).any()  # strengths and directions vary
    bright = pixel_seat._shaded(torch, torch.full((8, 4, 4, 3), 250, dtype=torch.uint8), 0.3,
                                torch.Generator().manual_seed(1))
    assert bright.max() <= 255.0


def test_image_noise_is_zero_mean_with_a_spread_drawn_per_image_up_to_its_bound():
    import torch

    images = torch.full((256, 16, 16, 3), 128, dtype=torch.uint8)
    assert pixel_seat._noised(torch, images, 0.0, torch.Generator().manual_seed(0)) is images
    noised = pixel_seat._noised(torch, images, 8.0, torch.Generator().manual_seed(0)) - 128.0
    spreads = noised.flatten(1).std(dim=1)
    assert abs(float(noised.mean())) < 0.1  # zero mean: no brightness comes with it
    assert spreads.max() < 8.0 * 1.1 and spreads.min() < 1.0 and spreads.max() > 7.0  # drawn per image, up to 8
    again = pixel_seat._noised(torch, images, 8.0, torch.Generator().manual_seed(0)) - 128.0
    assert torch.equal(noised, again)  # the fit's generator alone draws it
    dark = pixel_seat._noised(torch, torch.zeros((8, 4, 4, 3), dtype=torch.uint8), 8.0,
                              torch.Generator().manual_seed(1))
    assert dark.min() >= 0.0


def test_a_seat_estimating_the_other_tip_raises_and_keeps_lowest_only_the_blood(tmp_path):
    """estimated = [4, 9] (the other arm's tip and the blood left): the margin and the lowest kept are the blood's;
    the tip's estimates fill the teacher's observation as they are, image by image."""
    config = _config(acts_by="teacher", estimated=[4, 9], estimate_margin=0.02, keep_lowest=True,
                     convolutions=[[8, 8, 4]])
    np.testing.assert_array_equal(pixel_seat._blood_columns(config), [False, False, False, True, True])
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-other-tip", {}, np.full(30, np.nan))
    policy = policies.load(folder)
    assert policy.spec["image"]["fills"]["estimates_at"] == [4, 5, 6, 7, 8]
    assert policy.spec["image"]["fills"]["keep_lowest"] == [7, 8]
    bright, dark = _observation(3, seed=1), _observation(3, seed=2)
    dark["observation"] = bright["observation"]  # one episode (a tip's jump starts another)
    with torch.no_grad():
        raw = [model.features(torch.from_numpy(o["image"])).numpy() for o in (bright, dark)]
    seen = lambda o: policy.encoder.observation(o["image"], o["observation"])  # noqa: E731
    np.testing.assert_allclose(seen(bright)[:, 4:9], raw[0] + [0, 0, 0, 0.02, 0.02], atol=1e-5)
    later = seen(dark)
    np.testing.assert_allclose(later[:, 4:7], raw[1][:, :3], atol=1e-5)  # the tip: this image's
    np.testing.assert_allclose(later[:, 7:9], np.minimum(raw[0], raw[1])[:, 3:] + 0.02, atol=1e-5)  # the blood: lowest


def test_a_seat_reading_the_other_tip_as_an_offset_adds_its_own_tip_back(tmp_path):
    """other_tip_relative: the read-out estimates the other tip minus the own tip; the policy adds its own tip (the
    proprioception) back before the teacher reads it, and the trainer's targets are those offsets."""
    config = _config(acts_by="teacher", estimated=[4, 9], estimate_margin=0.02, keep_lowest=True,
                     other_tip_relative=True, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-offset", {}, np.full(30, np.nan))
    policy = policies.load(folder)
    assert policy.spec["image"]["fills"]["relative"] == [[4, 0], [5, 1], [6, 2]]
    observation = _observation(3, seed=1)
    with torch.no_grad():
        raw = model.features(torch.from_numpy(observation["image"])).numpy()
    seen = policy.encoder.observation(observation["image"], observation["observation"])
    np.testing.assert_allclose(seen[:, 4:7], raw[:, :3] + observation["observation"][:, 0:3], atol=1e-5)
    np.testing.assert_allclose(seen[:, 7:9], raw[:, 3:] + 0.02, atol=1e-5)  # the blood: as it is read
    np.testing.assert_allclose(policy.encoder.estimates(observation["image"], observation["observation"][:, :4]),
                               seen[:, 4:9], atol=1e-5)  # (the margin is the read-out's; the first lowest kept)
    # the trainer's targets: the other tip's offset from the own tip, the blood as it is
    small = config.model_copy(update={"worlds": 2, "max_cycles": 6, "record_every": 2, "partners": ["scripted"]})
    offsets = pixel_seat.collect(small, None, seed=3, noise_seed=3)["targets"]
    absolute = pixel_seat.collect(small.model_copy(update={"other_tip_relative": False}), None, seed=3,
                                  noise_seed=3)
    np.testing.assert_allclose(offsets[:, :3], absolute["targets"][:, :3] - absolute["proprioception"][:, :3],
                               atol=1e-6)
    np.testing.assert_array_equal(offsets[:, 3:], absolute["targets"][:, 3:])


@pytest.mark.parametrize("relative, message", [
    ([[9, 0]], "first index must be estimated"),
    ([[7, 0]], "not kept at its lowest"),
    ([[4, 0], [4, 1]], "once"),
    ([[4, 5]], "second index must be of the proprioception"),
])
def test_an_offset_that_does_not_fit_is_refused_by_name(tmp_path, relative, message):
    config = _config(acts_by="teacher", estimated=[4, 9], keep_lowest=True, convolutions=[[8, 8, 4]])
    folder = pixel_seat.export(pixel_seat.PixelActor(config, 4), config, tmp_path / "policy", "test-offset", {},
                               np.full(30, np.nan))
    spec = json.loads((folder / "policy.json").read_text())
    spec["image"]["fills"]["relative"] = relative
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=message):
        policies.load(folder)


@pytest.mark.parametrize("option, message", [("other_tip_relative = true", "other_tip_relative reads the other "
                                                "arm's tip as an offset"),
                                             ("keep_clear_mm = 12.0", "keep_clear_mm reads the other arm's tip")])
@pytest.mark.parametrize("settings", ['', 'acts_by = "teacher"\nestimated = [7, 9]\n'])
def test_reading_the_other_tip_needs_it_estimated(tmp_path, settings, option, message):
    path = tmp_path / "seat.toml"
    path.write_text('[run]\nalgorithm = "pixel-dagger"\n' + settings + option + "\n")
    with pytest.raises(ValueError, match=message):
        pixel_seat.load_config(path)


def test_fitting_the_other_tip_weighs_the_blood_towards_empty_and_the_tip_by_its_spread():
    config = _config(acts_by="teacher", estimated=[4, 9], convolutions=[[4, 8, 4]], batch_size=8)
    rng = np.random.default_rng(0)
    count = 32
    data = {"images": rng.integers(0, 256, (count, 64, 64, 3), dtype=np.uint8),
            "proprioception": np.zeros((count, 4), np.float32), "labels": np.zeros((count, 4), np.float32),
            "targets": np.concatenate([rng.normal(0, 0.3, (count, 3)), rng.uniform(0, 1, (count, 2))], 1
                                      ).astype(np.float32), "cleared": np.zeros((count, 2), np.float32)}
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    first = pixel_seat.fit(model, data, config, 60, 0)
    assert np.isfinite(first)
    errors = pixel_seat.estimate_errors(model, data, blood=pixel_seat._blood_columns(config))
    assert set(errors) >= {"mean_absolute", "small_mean", "other_mean_absolute"}
    assert pixel_seat.fit(model, data, config, 200, 1) < first  # it learns the frames it is given


def test_the_other_estimates_weight_scales_their_share_of_the_loss():
    """other_estimate_weight = 0: what the tip's targets hold changes nothing the fit does."""
    rng = np.random.default_rng(1)
    count = 16
    images = rng.integers(0, 256, (count, 64, 64, 3), dtype=np.uint8)
    blood = rng.uniform(0, 1, (count, 2))

    def loss(weight, tip):
        config = _config(acts_by="teacher", estimated=[4, 9], convolutions=[[4, 8, 4]], batch_size=8,
                         other_estimate_weight=weight)
        data = {"images": images, "proprioception": np.zeros((count, 4), np.float32),
                "labels": np.zeros((count, 4), np.float32), "cleared": np.zeros((count, 2), np.float32),
                "targets": np.concatenate([tip, blood], 1).astype(np.float32)}
        torch.manual_seed(0)
        return pixel_seat.fit(pixel_seat.PixelActor(config, 4), data, config, 10, 0)

    near, far = rng.normal(0, 0.1, (count, 3)), rng.normal(0, 0.1, (count, 3)) * 50
    assert loss(0.0, near) == pytest.approx(loss(0.0, far), rel=1e-5)
    assert loss(1.0, near) != pytest.approx(loss(1.0, far), rel=1e-2)


def _keypoint_config(**overrides):
    """A small seat reading the other tip (observation 4-6) from keypoints, the blood (7-8) from the convolutions."""
    return _config(acts_by="teacher", estimated=[4, 9], keep_lowest=True, keypoints=True,
                   convolutions=[[8, 5, 2], [6, 3, 2]], **overrides)


def _torch_estimates(model, observation, own):
    """What the torch student's read-out gives for an observation's images and the own proprioception."""
    with torch.no_grad():
        return model.features(torch.from_numpy(observation["image"]), torch.from_numpy(own.astype(np.float32))).numpy()


def test_a_seat_reading_keypoints_is_the_network_it_was_trained_as_and_reads_them_where_it_says(tmp_path):
    """keypoints: the numpy read-out equals the torch one; the other tip reads only the keypoints and the own
    proprioception, the blood only the flattened convolutions; a keypoint follows what it peaks on."""
    config = _keypoint_config()
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    with torch.no_grad():
        model.gains.copy_(torch.linspace(0.5, 3.0, 6))
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-keypoints", {}, np.full(30, np.nan))
    policy = policies.load(folder)
    assert policy.spec["image"]["keypoints"] is True
    observation = _observation(4, seed=2)
    own = observation["observation"][:, :4]
    expected = _torch_estimates(model, observation, own)
    np.testing.assert_allclose(policy.encoder.estimates(observation["image"], own)[:, :3], expected[:, :3], atol=1e-4)
    np.testing.assert_allclose(policy.encoder.estimates(observation["image"], own)[:, 3:], expected[:, 3:] + 0.02,
                               atol=1e-4)  # (the margin is the blood's)
    # the own tip moves the other tip's estimates, never the blood's
    moved = own + np.array([0.3, -0.2, 0.1, 0.0])
    before, after = (policy.encoder.estimates(observation["image"], o) for o in (own, moved))
    assert not np.allclose(before[:, :3], after[:, :3])
    np.testing.assert_array_equal(before[:, 3:], after[:, 3:])
    weight = np.load(folder / "policy.npz")["R"]
    flat = policy.encoder.readout[0].shape[1] - 2 * 6 - 4
    assert not weight[:3, :flat].any() and not weight[3:, flat:].any() and weight[:3, flat:].all()
    with pytest.raises(ValueError, match="proprioception"):
        policy.encoder(observation["image"])
    # a spatial softmax's keypoint is where its channel peaks: a peak moved right and down moves it by as much
    from dvrl_marl.policies.image_encoder import keypoints

    field = np.zeros((1, 9, 9, 1), np.float32)
    field[0, 2, 3, 0] = 50.0
    np.testing.assert_allclose(keypoints(field, np.ones(1, np.float32)), [[-0.25, -0.5]], atol=1e-6)
    field = np.roll(field, (2, 4), axis=(1, 2))
    np.testing.assert_allclose(keypoints(field, np.ones(1, np.float32)), [[0.75, 0.0]], atol=1e-6)
    # keypoints without a read-out, and a file without its gains, are refused by name
    from dvrl_marl.schemas import PolicyImage, validated

    with pytest.raises(ValueError, match="keypoints are read by the read-out"):
        validated(PolicyImage, {**policy.spec["image"], "readout": None, "fills": None}, "policy.json's image")
    _drop_array(folder, folder, "G")
    with pytest.raises(ValueError, match="'G'"):
        policies.load(folder)


def test_a_tip_reading_the_convolutions_beside_the_keypoints_is_exported_as_trained(tmp_path):
    """tip_reads_convolutions: the other tip reads the flattened convolutions, the keypoints and the proprioception;
    the blood still the flattened convolutions alone; the numpy read-out is the torch one."""
    config = _keypoint_config(tip_reads_convolutions=True)
    torch.manual_seed(1)
    model = pixel_seat.PixelActor(config, 4)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-beside", {}, np.full(30, np.nan))
    policy = policies.load(folder)
    observation = _observation(4, seed=3)
    own = observation["observation"][:, :4]
    expected = _torch_estimates(model, observation, own)
    np.testing.assert_allclose(policy.encoder.estimates(observation["image"], own)[:, :3], expected[:, :3], atol=1e-4)
    weight = np.load(folder / "policy.npz")["R"]
    flat = weight.shape[1] - 2 * 6 - 4
    assert weight[:3].all() and weight[3:, :flat].all() and not weight[3:, flat:].any()
    # the tip's estimates move with the flattened convolutions' features, not only the keypoints': a seat without
    # the option reads different numbers from the same weights
    alone = pixel_seat.PixelActor(config.model_copy(update={"tip_reads_convolutions": False}), 4)
    alone.load_state_dict({key: value for key, value in model.state_dict().items() if key != "mask"}, strict=False)
    other = _torch_estimates(alone, observation, own)
    assert not np.allclose(other[:, :3], expected[:, :3]) and np.allclose(other[:, 3:], expected[:, 3:])


def test_keypoints_are_for_a_seat_acting_by_its_teacher(tmp_path):
    path = tmp_path / "seat.toml"
    path.write_text('[run]\nalgorithm = "pixel-dagger"\nkeypoints = true\n')
    with pytest.raises(ValueError, match="keypoints reads the other arm's tip from keypoints"):
        pixel_seat.load_config(path)
    path.write_text('[run]\nalgorithm = "pixel-dagger"\nacts_by = "teacher"\ntip_reads_convolutions = true\n')
    with pytest.raises(ValueError, match="tip_reads_convolutions .* needs keypoints = true"):
        pixel_seat.load_config(path)


def test_a_seat_keeping_clear_acts_by_the_yielding_rule_on_its_estimate_of_the_other_tip(tmp_path):
    """keep_clear_mm: the exported seat names the yielding suction's rule, which reads the other tip it estimates and
    its own tip it knows; the teacher drives the collection by the same rule."""
    from dvrl_marl.agents.collaborative import YieldingSuction
    from dvrl_marl.envs import suction_debris_v8
    from dvrl_marl.suction_debris.instruments import keep_clear

    config = _config(acts_by="teacher", estimated=[4, 9], keep_clear_mm=12.0, convolutions=[[8, 8, 4]])
    torch.manual_seed(0)
    folder = pixel_seat.export(pixel_seat.PixelActor(config, 4), config, tmp_path / "policy", "test-clear", {},
                               np.full(30, np.nan))
    env = suction_debris_v8.batched_env(num_envs=1)
    rule = YieldingSuction(env.layout(), env.observation_layout, env.workspace_range, 12.0).rule
    env.close()
    policy = policies.load(folder)
    assert policy.spec["keep_clear"] == rule
    observation = _observation(16, seed=4)
    seen = policy.encoder.observation(observation["image"], observation["observation"])
    # the own tip beside the other tip as the seat reads it: the rule has moves to withhold
    observation["observation"][:, 0:3] = seen[:, 4:7] + np.random.default_rng(5).uniform(-0.1, 0.1, (16, 3))
    filled = policy.encoder.observation(observation["image"], observation["observation"])
    acted = policy(observation)
    policy.keep_clear = None
    plain = policy(observation)
    np.testing.assert_array_equal(acted, keep_clear(plain, filled, rule))
    assert (acted != plain).any()
    # the teacher drives by the rule: the scripted suction kept clear is the yielding suction, step for step
    small = config.model_copy(update={"worlds": 2, "max_cycles": 160, "partners": ["in-the-way"], "action_noise": 0.0,
                                      "teacher": "scripted", "record_every": 1})
    driven = [pixel_seat.collect(small.model_copy(update=update), None, seed=3, noise_seed=3)["proprioception"]
              for update in ({}, {"teacher": "yielding", "keep_clear_mm": None}, {"keep_clear_mm": None})]
    np.testing.assert_array_equal(driven[0], driven[1])
    assert driven[0].shape != driven[2].shape or not np.array_equal(driven[0], driven[2])  # the rule withheld moves


def test_a_seat_seeing_the_stereo_pair_is_the_network_it_was_trained_as_and_needs_both_eyes(tmp_path):
    """stereo: the numpy encoder reads the left and right images as six channels, as the torch student did; the
    policy asks the env for the pair, and an observation without the right eye is refused by name."""
    config = _keypoint_config(stereo=True, image_size=48)
    torch.manual_seed(0)
    model = pixel_seat.PixelActor(config, 4)
    folder = pixel_seat.export(model, config, tmp_path / "policy", "test-stereo", {}, np.full(30, np.nan))
    policy = policies.load(folder)
    assert policy.image_options == {"image_size": 48, "image_stereo": True}
    assert policy.spec["observation_keys"] == ["observation", "image", "image_right"]
    observation = _observation(3, size=48, seed=4)
    observation["image_right"] = np.roll(observation["image"], -2, axis=2)
    own = observation["observation"][:, :4]
    pair = np.concatenate([observation["image"], observation["image_right"]], axis=-1)
    with torch.no_grad():
        expected = model.features(torch.from_numpy(pair), torch.from_numpy(own.astype(np.float32))).numpy()
    np.testing.assert_allclose(policy.encoder.estimates(policy.encoder.image(observation), own)[:, :3],
                               expected[:, :3], atol=1e-4)
    assert policy(observation).shape == (3, 4)
    with pytest.raises(ValueError, match="image_stereo=True"):
        policy({key: value for key, value in observation.items() if key != "image_right"})
    with pytest.raises(ValueError, match="stereo pair"):
        policy.encoder(observation["image"], own)
    # a file whose kernels read three channels under a stereo table is refused by name
    spec = json.loads((folder / "policy.json").read_text())
    spec["image"]["stereo"] = False
    (folder / "policy.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match="'K0' must hold finite floats of shape \\(8, 3, 5, 5\\)"):
        policies.load(folder)


def test_a_stereo_seat_collects_both_eyes_and_colours_each_eyes_classes_alike():
    config = _config(worlds=2, max_cycles=4, record_every=2, action_noise=0.0, partners=["scripted"], stereo=True,
                     class_jitter=0.3, convolutions=[[8, 8, 4]])
    batch = pixel_seat.collect(config, None, seed=3, noise_seed=3)
    assert batch["images"].shape == (4, 64, 64, 6) and batch["segmentation"].shape == (4, 64, 64, 2)
    left, right = batch["images"][..., :3], batch["images"][..., 3:]
    assert not np.array_equal(left, right) and not np.array_equal(batch["segmentation"][..., 0],
                                                                  batch["segmentation"][..., 1])
    images = torch.full((4, 8, 8, 6), 100, dtype=torch.uint8)
    segmentation = torch.zeros((4, 8, 8, 2), dtype=torch.uint8)
    segmentation[..., 0], segmentation[..., 1] = 1, 2  # the left eye sees tissue, the right blood
    jittered = pixel_seat._class_jittered(torch, images, segmentation, 0.3, torch.Generator().manual_seed(0))
    tissue = pixel_seat._class_jittered(torch, images[..., :3], segmentation[..., 0], 0.3,
                                        torch.Generator().manual_seed(0))
    torch.testing.assert_close(jittered[..., :3], tissue)  # each eye's classes in the one look's gains
    assert not torch.allclose(jittered[..., :3], jittered[..., 3:])
    gains = pixel_seat._jittered(torch, images, 0.3, torch.Generator().manual_seed(1))
    torch.testing.assert_close(gains[..., :3], gains[..., 3:])  # the colour jitter alike in both eyes
    model = pixel_seat.PixelActor(config, 4)
    assert np.isfinite(pixel_seat.fit(model, batch, config, 2, 0))
