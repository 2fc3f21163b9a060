"""Image observations: the endoscope's view drawn for learning (dvrl_marl.envs.endoscope) is exactly what one drawing
of the whole scene gives, in every world of a batch; the option's spaces, checks, determinism and bad input."""

import gc
import os

import mujoco
import numpy as np
import pytest

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.envs.endoscope import EndoscopeRenderer, _software_renderer


def _stepped(num_envs, steps, seed=0, **options):
    env = suction_debris_v8.batched_env(num_envs=num_envs, **options)
    env.reset(seed=seed)
    rng = np.random.default_rng(seed)
    for _ in range(steps):
        env.step({agent: rng.uniform(-1, 1, (num_envs, 4)) for agent in env.possible_agents})
    return env


def _assert_drawn_alike(actual, expected, exact: bool, err_msg: str = "", levels: int | None = 1) -> None:
    """Equal images; or, drawn elsewhere in a framebuffer (whole scenes in tiles) or by a GPU (whose depths of two
    drawings compare otherwise at an edge), equal but for ``levels`` (None: any, a segmentation's classes) on at most
    one value in a thousand."""
    if exact:
        np.testing.assert_array_equal(actual, expected, err_msg=err_msg)
        return
    differ = actual != expected
    if levels is not None:
        assert np.abs(actual.astype(np.int64) - expected.astype(np.int64)).max() <= levels, err_msg
    assert differ.mean() <= 1e-3, f"{err_msg}: {differ.mean():.2%} of the values differ"


def _whole_scene(renderer, size):
    """MuJoCo's own drawing of the renderer's model: every geom group at once, no shadows or reflections; and a
    function that shows a world's state in it and draws it."""
    model, data = renderer.mirror.model, renderer.mirror.data
    whole = mujoco.Renderer(model, size, size)
    whole.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    whole.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    everything = mujoco.MjvOption()
    everything.geomgroup[:] = 1

    def draw(state):
        renderer.mirror.show(state)
        mujoco.mj_forward(model, data)
        whole.update_scene(data, camera="endoscope", scene_option=everything)
        return whole.render()

    return whole, draw


@pytest.mark.parametrize("worlds, tiles, layers", [(12, 5, True), (20, None, True), (12, 5, False)])
def test_the_composite_is_the_whole_scene_drawn_at_once(worlds, tiles, layers):
    """Three framebuffers' worth of one row each, the last partial; then one framebuffer of 16 x 16 tiles of which two
    rows are read back, the second partial; layers put together (a software renderer's way) or each world's whole
    scene in its tile (a GPU's)."""
    env = _stepped(worlds, 80)
    states = [env.core.world_state(world) for world in range(env.num_envs)]
    renderer = EndoscopeRenderer(env.params, 64, depth=True, tiles=tiles, layers=layers)
    exact = layers and _software_renderer()  # (its context is the current one)
    assert renderer.layers is layers
    drawn = renderer.render(states)
    whole, draw = _whole_scene(renderer, 64)
    for world in range(env.num_envs):
        _assert_drawn_alike(drawn["rgb"][world], draw(states[world]), exact, f"world {world}")
        whole.enable_depth_rendering()
        np.testing.assert_allclose(drawn["depth"][world], draw(states[world]), rtol=0, atol=1e-4)
        whole.disable_depth_rendering()
    # the worlds differ (the instruments move), and the blood is drawn
    assert len({drawn["rgb"][world].tobytes() for world in range(env.num_envs)}) == env.num_envs
    red = (drawn["rgb"][..., 0] > 100) & (drawn["rgb"][..., 1] < 40)
    assert red.mean() > 0.01
    whole.close()
    renderer.close()


@pytest.mark.slow
def test_image_observations_in_the_parallel_and_batched_env():
    from pettingzoo.test import parallel_api_test

    from pettingzoo.test import api_test

    parallel_api_test(suction_debris_v8.parallel_env(image_size=32, max_cycles=30), num_cycles=40)
    api_test(suction_debris_v8.env(image_size=32, max_cycles=20), num_cycles=30)  # the AEC form
    env = suction_debris_v8.parallel_env(image_size=48, image_depth=True)
    observations, _ = env.reset(seed=3)
    for agent in env.agents:
        space = env.observation_space(agent)
        assert set(space.spaces) == {"observation", "image", "depth"} and space.contains(observations[agent])
        assert observations[agent]["image"].shape == (48, 48, 3)
    np.testing.assert_array_equal(observations["suction"]["image"], observations["grasper"]["image"])  # one camera
    # world i of a batch sees what the single env seeded s + i sees
    batch = suction_debris_v8.batched_env(num_envs=3, image_size=48, image_depth=True)
    batched, _ = batch.reset(seed=1)
    for world in range(3):  # (drawn in another tile: on a GPU, whole scenes, alike within a level at an edge)
        single, _ = suction_debris_v8.parallel_env(image_size=48, image_depth=True).reset(seed=1 + world)
        _assert_drawn_alike(batched["grasper"]["image"][world], single["grasper"]["image"], batch._endoscope.layers)
        np.testing.assert_array_equal(batched["grasper"]["observation"][world], single["grasper"]["observation"])


def test_an_episode_end_hands_back_the_final_image_and_the_next_episodes_first():
    env = suction_debris_v8.batched_env(num_envs=2, image_size=32, max_cycles=5)
    env.reset(seed=0)
    zero = {agent: np.zeros((2, 4)) for agent in env.possible_agents}
    for _ in range(4):
        env.step(zero)
    observations, _, _, truncations, infos = env.step(zero)
    assert truncations["suction"].all()
    final = infos["suction"]["final_observation"]
    assert final["image"].shape == (2, 32, 32, 3) and not np.array_equal(final["image"], observations["suction"]["image"])
    twin = suction_debris_v8.batched_env(num_envs=2, image_size=32, max_cycles=5, autoreset_mode="disabled")
    twin.reset(seed=0)
    for _ in range(5):
        twin.step(zero)
    np.testing.assert_array_equal(final["image"], twin.images()["image"])  # the episode's last view, not the next's


@pytest.mark.parametrize("appearance", [None, "train"])
def test_a_world_whose_episode_ended_keeps_its_last_images_and_the_others_are_drawn_as_ever(appearance):
    """autoreset_mode="disabled": an ended world is not drawn again until it is reset (an evaluation's finished worlds
    cost nothing); it keeps its episode's last images, and the worlds still playing get what drawing every world
    gives them, look by look."""
    options = dict(num_envs=4, image_size=32, max_cycles=6, autoreset_mode="disabled", image_depth=True,
                   image_segmentation=True, image_appearance=appearance)
    env, twin = suction_debris_v8.batched_env(**options), suction_debris_v8.batched_env(**options)
    for each in (env, twin):
        each.reset(seed=2)
    drawn = []
    env.images()  # (the renderer made)
    render = env._endoscope.render
    env._endoscope.render = lambda states, *args, **kwargs: drawn.append(len(states["jaw"])) or render(
        states, *args, **kwargs)  # (the worlds' states stacked: world_states)
    rng = np.random.default_rng(0)
    ended, last = np.zeros(4, dtype=bool), {}
    for step in range(10):
        if step == 3:  # worlds 0 and 1 start again: they end three steps after the others
            for each in (env, twin):
                each.reset(options={"reset_mask": np.array([True, True, False, False])})
        actions = {agent: rng.uniform(-1, 1, (4, 4)) for agent in env.possible_agents}
        seen, _, _, truncations, _ = env.step(actions)
        twin._ended[:] = False  # the twin draws every world at every step
        expected = twin.step(actions)[0]
        for part in ("image", "depth", "segmentation"):
            got, want = seen["suction"][part], expected["suction"][part]
            np.testing.assert_array_equal(got[~ended], want[~ended])
            for world in np.flatnonzero(ended):
                np.testing.assert_array_equal(got[world], last[part][world])
        for part in ("image", "depth", "segmentation"):
            last[part] = {world: seen["suction"][part][world].copy() for world in range(4)} | {
                world: last[part][world] for world in np.flatnonzero(ended)}
        ended |= truncations["suction"]
    # drawn: three steps, the reset of two worlds (every world's observation), three steps, then the two still playing
    # for three steps, then none
    assert ended.all() and drawn == [4] * 7 + [2] * 3


def test_poses_worked_out_at_once_put_what_show_writes():
    """The renderer's way of writing a world's state (every world's worked out at once, then put) leaves the model as
    the mirror's ``show`` does: every joint, the blood's surfaces (those drawn), over worlds that hand pins over."""
    from dvrl_marl.envs.scene_mirror import SceneMirror

    env = _stepped(6, 0, seed=1)
    env.core.delivered[2, 0] = True  # (a pin handed over: out of the scene)
    env.core.remaining_ml[3] = 0.0  # (a cavity cleared: its blood not drawn)
    shown, put = SceneMirror(env.params), SceneMirror(env.params)
    poses = put.poses(env.core.world_states(range(6)))
    assert poses["qpos"].shape == (6, put.model.nq)
    np.testing.assert_array_equal(poses["qpos"], put.poses([env.core.world_state(w) for w in range(6)])["qpos"])
    blood = shown.blood_geoms
    for world in range(6):
        shown.show(env.core.world_state(world))
        put.put(poses, world)
        seen = np.ones(put.model.nq, dtype=bool)  # (a handed-over pin's turn: out of the scene, either way)
        for pin, address in enumerate(put._debris_qpos):
            seen[address + 3:address + 7] = not env.core.delivered[world, pin]
        np.testing.assert_allclose(put.data.qpos[seen], shown.data.qpos[seen], rtol=0, atol=1e-15,
                                   err_msg=f"world {world}")
        np.testing.assert_array_equal(put.data.qpos[put._debris_qpos[0]:put._debris_qpos[0] + 3][2] < 0,
                                      env.core.delivered[world, 0])
        drawn = shown.model.geom_rgba[blood, 3] > 0
        np.testing.assert_array_equal(put.model.geom_rgba[blood, 3] > 0, drawn)
        for name in ("geom_rgba", "geom_size", "geom_pos"):
            np.testing.assert_array_equal(getattr(put.model, name)[blood][drawn],
                                          getattr(shown.model, name)[blood][drawn], err_msg=f"world {world}, {name}")


@pytest.mark.parametrize("appearance", [None, "train"])
def test_whole_scenes_per_tile_give_the_layers_images_look_by_look(appearance):
    """A GPU's way (each world's whole scene in its tile, no layers put together) gives what the layers give, every
    part, each world in its own look with its noise; and the renderer picks the layers on this software renderer."""
    env = _stepped(6, 30, seed=5, image_size=32, image_depth=True, image_segmentation=True,
                   image_appearance=appearance)
    chosen = env._endoscope
    chosen._bind()
    assert chosen.layers == _software_renderer()  # (Mesa's llvmpipe: the phantom's triangles per world its cost)
    layered, whole = (EndoscopeRenderer(env.params, 32, depth=True, segmentation=True, layers=layers)
                      for layers in (True, False))
    env._endoscope = whole
    drawn = env.images()
    env._endoscope = layered
    expected = env.images()
    env._endoscope = chosen
    layered.close()
    for part in ("image", "segmentation"):
        _assert_drawn_alike(drawn[part], expected[part], False, part)
    np.testing.assert_allclose(drawn["depth"], expected["depth"], rtol=0, atol=1e-5)
    whole.close()


@pytest.mark.parametrize("appearance", [None, "train"])
def test_gl_contexts_in_threads_draw_the_one_contexts_images(appearance):
    """``image_contexts``: each world drawn by one of three GL contexts, each in a thread of its own, gives the images
    one context gives, look by look, worlds that ended (not drawn again) among them. (A depth's last bits depend on
    where in the framebuffer a world is drawn: 1e-5 m.)"""
    options = dict(num_envs=7, image_size=32, image_depth=True, image_segmentation=True, image_appearance=appearance,
                   max_cycles=9, autoreset_mode="disabled")
    one, three = (suction_debris_v8.batched_env(**options, image_contexts=contexts) for contexts in (1, 3))
    for env in (one, three):
        env.reset(seed=3)
    rng = np.random.default_rng(0)
    for step in range(12):
        if step == 4:  # worlds 0, 3 and 5 start again: the others end first
            for env in (one, three):
                env.reset(options={"reset_mask": np.isin(np.arange(7), [0, 3, 5])})
        actions = {agent: rng.uniform(-1, 1, (7, 4)) for agent in one.possible_agents}
        expected, drawn = one.step(actions)[0]["suction"], three.step(actions)[0]["suction"]
        for part in ("image", "segmentation"):  # (exact where layers are put together: a software renderer's)
            _assert_drawn_alike(drawn[part], expected[part], one._endoscope.layers, f"step {step}, {part}")
        np.testing.assert_allclose(drawn["depth"], expected["depth"], rtol=0, atol=1e-5, err_msg=f"step {step}")
    assert three._ended.any() and not three._ended.all()
    assert three._endoscope.contexts == 3
    for env in (one, three):
        env.close()


class _ReleasesTheThreadsContext:
    """What MuJoCo 3.3's GL context does when it is freed: ``eglReleaseThread()``, whichever context the thread
    holds (MuJoCo 4 releases only its own)."""

    def __del__(self):
        from OpenGL import EGL

        EGL.eglReleaseThread()


@pytest.mark.skipif(os.environ.get("MUJOCO_GL") != "egl", reason="the release is EGL's")
def test_another_gl_context_collected_while_drawing_leaves_the_images_as_they_are():
    """A dropped env collected between binding the renderer's context and reading it back would leave its drawings
    undone (MuJoCo 3.3, the floor: its freed context releases the thread's). Here every world's drawing leaves such
    garbage behind, with a collection at nearly every allocation. (Without the fix it fails on the floors; in the
    README's environment the release leaves the context current, and it passes either way.)"""
    env = _stepped(3, 20, image_size=32, image_depth=True, image_segmentation=True)
    states = [env.core.world_state(world) for world in range(env.num_envs)]
    renderer = env._endoscope
    expected = renderer.render(states)
    put = renderer.mirror.put

    def put_leaving_garbage(poses, world):
        cycle = {"context": _ReleasesTheThreadsContext()}
        cycle["itself"] = cycle  # (only a collection frees it)
        put(poses, world)

    renderer.mirror.put = put_leaving_garbage
    thresholds = gc.get_threshold()
    gc.set_threshold(1)
    try:
        drawn = renderer.render(states)
    finally:
        gc.set_threshold(*thresholds)
        renderer.mirror.put = put
        gc.collect()
    for part in expected:
        np.testing.assert_array_equal(drawn[part], expected[part], err_msg=part)


def test_a_dropped_renderer_frees_its_gl_objects_and_never_another_renderers():
    """MuJoCo frees a renderer's framebuffers by their ids in whichever GL context is current: a dropped env's
    renderer, collected while another's context is current, must free its own (the other's images came back black)."""
    dropped, kept = (_stepped(2, 5, seed=seed, image_size=32) for seed in (0, 1))
    dropped.images()
    states = [kept.core.world_state(world) for world in range(kept.num_envs)]
    before = kept._endoscope.render(states)["rgb"]  # (the kept renderer's context is the current one now)
    del dropped
    gc.collect()
    np.testing.assert_array_equal(kept._endoscope.render(states)["rgb"], before)


def test_images_are_deterministic_per_seed():
    first = _stepped(3, 20, seed=4, image_size=32).observations()["suction"]["image"]
    second = _stepped(3, 20, seed=4, image_size=32).observations()["suction"]["image"]
    np.testing.assert_array_equal(first, second)


@pytest.mark.parametrize("options, named", [({"image_size": 16}, "image_size"), ({"image_size": 300}, "image_size"),
                                            ({"image_size": "84"}, "image_size"), ({"image_depth": True}, "image_depth"),
                                            ({"image_size": 84, "image_depth": 1}, "image_depth"),
                                            ({"image_size": 84, "image_contexts": 0}, "image_contexts"),
                                            ({"image_size": 84, "image_contexts": "2"}, "image_contexts"),
                                            ({"image_contexts": 2}, "image_contexts")])
def test_bad_image_options_are_refused_by_name(options, named):
    with pytest.raises(ValueError, match=named):
        suction_debris_v8.parallel_env(**options)


def test_images_without_the_option_say_how_to_ask_for_them():
    with pytest.raises(ValueError, match="image_size"):
        suction_debris_v8.batched_env(num_envs=1).images()


@pytest.mark.slow
def test_the_segmentation_is_mujocos_own_of_the_whole_scene_in_classes():
    from dvrl_marl.envs.endoscope import SEGMENT_CLASSES

    env = _stepped(5, 60, image_size=64, image_segmentation=True)
    observed = env.observations()["grasper"]["segmentation"]
    states = [env.core.world_state(world) for world in range(env.num_envs)]
    renderer = env._endoscope
    whole, draw = _whole_scene(renderer, 64)
    whole.enable_segmentation_rendering()
    for world in range(env.num_envs):
        ids = draw(states[world])  # (objid, objtype) per pixel
        geoms = (ids[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (ids[..., 0] >= 0)
        expected = np.where(geoms, renderer._geom_class[np.maximum(ids[..., 0], 0)], 0)
        _assert_drawn_alike(observed[world], expected, renderer.layers, f"world {world}", levels=None)
    present = set(np.unique(observed).tolist())
    assert {SEGMENT_CLASSES.index(name) for name in ("tissue", "blood", "instrument")} <= present
    whole.close()


@pytest.mark.parametrize("appearance", [None, "train"])
def test_a_part_asked_alone_is_the_part_the_observations_carry(appearance):
    """``images(parts=...)`` draws a part on request (a segmentation for the steps a dataset records), the same as an
    env made to carry it in every observation, look and noise included; an unknown part is refused by name."""
    options = dict(image_size=32, image_depth=True, image_segmentation=True, image_appearance=appearance)
    carrying = _stepped(4, 0, seed=6, **options)
    asking = _stepped(4, 0, seed=6, image_size=32, image_appearance=appearance)
    rng = np.random.default_rng(6)
    for step in range(12):
        if step % 3 == 0:  # the segmentation first (a still layer drawn without it), then the rest
            whole = carrying.images()
            np.testing.assert_array_equal(asking.images(parts="segmentation")["segmentation"], whole["segmentation"])
            alone = asking.images(parts=["depth", "image"])
            np.testing.assert_array_equal(alone["image"], whole["image"])
            np.testing.assert_array_equal(alone["depth"], whole["depth"])
            assert set(alone) == {"image", "depth"}
            assert set(asking.images()) == {"image"}  # the env's own parts unchanged
        actions = {agent: rng.uniform(-1, 1, (4, 4)) for agent in carrying.possible_agents}
        carrying.step(actions)
        asking.step(actions)
    for bad in ("rgb", [], ["image", "colour"]):
        with pytest.raises(ValueError, match="parts must be some of"):
            asking.images(parts=bad)


def test_appearance_draws_lie_in_their_ranges_and_the_held_out_range_outside_the_training_one():
    from dvrl_marl.envs.endoscope import APPEARANCES, Appearance

    train, held_out = APPEARANCES["train"], APPEARANCES["held_out"]
    rng = np.random.default_rng(0)
    kept = []
    for _ in range(200):
        u = rng.random(Appearance.UNIFORMS)
        seen, unseen = train.draw(u), held_out.draw(u)
        assert np.all(np.abs(seen["tissue"] - 1.0) <= train.colour) and np.all(np.abs(seen["blood"] - 1.0) <= train.colour)
        assert np.all(np.abs(unseen["tissue"] - 1.0) >= train.colour)
        assert np.all(np.abs(unseen["tissue"] - 1.0) <= held_out.colour)
        assert np.all(np.abs(seen["camera_shift"]) <= train.camera_mm * 1e-3 + 1e-15)
        assert np.all(np.abs(unseen["camera_shift"]) >= train.camera_mm * 1e-3 - 1e-15)
        assert np.all(np.abs(np.degrees(unseen["camera_turn"])) >= train.camera_degrees - 1e-9)
        assert 0.0 <= seen["noise"] <= train.noise <= unseen["noise"] <= held_out.noise
        kept.append(np.all(seen["tissue"] == 1.0) and np.all(seen["blood"] == 1.0) and seen["instrument"] == 1.0)
    # a share of training looks keeps the scene's own colours; no held-out look does (checked above)
    assert abs(np.mean(kept) - train.scene_colours) < 0.1 and 0.0 < train.scene_colours < 1.0


@pytest.mark.slow
def test_each_world_wears_its_own_look_for_its_episode_seeded_like_everything_else():
    options = dict(image_size=48, image_appearance="train")
    batch = suction_debris_v8.batched_env(num_envs=4, **options)
    first, _ = batch.reset(seed=7)
    again, _ = suction_debris_v8.batched_env(num_envs=4, **options).reset(seed=7)
    np.testing.assert_array_equal(first["suction"]["image"], again["suction"]["image"])
    # world i of a batch looks as a single world seeded s + i (drawn in another tile: on a GPU, alike)
    single, _ = suction_debris_v8.parallel_env(**options).reset(seed=9)
    _assert_drawn_alike(first["grasper"]["image"][2], single["grasper"]["image"], batch._endoscope.layers)
    plain, _ = suction_debris_v8.batched_env(num_envs=4, image_size=48).reset(seed=7)
    looks = first["suction"]["image"].astype(int)
    assert all(np.abs(looks[w] - plain["suction"]["image"][w]).mean() > 2.0 for w in range(4))
    # within an episode the look holds (only the noise moves); the next episode wears another
    env = suction_debris_v8.batched_env(num_envs=2, max_cycles=3, **options)
    observations, _ = env.reset(seed=1)
    still = {agent: np.zeros((2, 4)) for agent in env.possible_agents}
    following = env.step(still)[0]["suction"]["image"].astype(int)
    assert np.abs(following - observations["suction"]["image"]).mean() < 6.0
    # the image noise: a function of the world's look and its frame, another at the next frame
    from dvrl_marl.envs.endoscope import APPEARANCES, Appearance

    renderer = EndoscopeRenderer(env.params, 32)
    state = [env.core.world_state(0)]
    look = [APPEARANCES["train"].draw(np.full(Appearance.UNIFORMS, 0.9))]  # (noise 3.6 of 255)
    frame = [renderer.render(state, look, [(1, 2, 3)], frames=[step])["rgb"].astype(int) for step in (4, 4, 5)]
    np.testing.assert_array_equal(frame[0], frame[1])
    assert 1.0 < np.abs(frame[2] - frame[0]).mean() < 6.0
    renderer.close()
    env.step(still)
    observations, _, _, truncations, _ = env.step(still)
    assert truncations["suction"].all()
    assert np.abs(observations["suction"]["image"].astype(int) - following).mean() > 4.0


def test_bad_appearance_options_are_refused_by_name():
    with pytest.raises(ValueError, match="image_appearance"):
        suction_debris_v8.batched_env(num_envs=1, image_size=32, image_appearance="bright")
    with pytest.raises(ValueError, match="image_appearance needs image_size"):
        suction_debris_v8.batched_env(num_envs=1, image_appearance="train")
    with pytest.raises(ValueError, match="endoscope.Appearance"):
        suction_debris_v8.batched_env(num_envs=1, image_size=32, image_appearance={"light": 0.5})


def test_a_range_of_ones_own_draws_as_the_named_range_it_equals():
    from dvrl_marl.envs.endoscope import APPEARANCES, Appearance

    named, _ = suction_debris_v8.batched_env(num_envs=2, image_size=32, image_appearance="held_out").reset(seed=3)
    own = Appearance(**{**vars(APPEARANCES["held_out"])})
    mine, _ = suction_debris_v8.batched_env(num_envs=2, image_size=32, image_appearance=own).reset(seed=3)
    np.testing.assert_array_equal(named["suction"]["image"], mine["suction"]["image"])
    only_light = Appearance(**{**vars(APPEARANCES["train"]), "light": 0.4, "scene_colours": 0.0,
                               "low": Appearance(0.0, 0.2, 0.0, 0.0, 0.0, 0.0)})
    other, _ = suction_debris_v8.batched_env(num_envs=2, image_size=32, image_appearance=only_light).reset(seed=3)
    assert not np.array_equal(other["suction"]["image"], named["suction"]["image"])


def test_the_seat_env_takes_image_observations_and_passes_gymnasiums_checker():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make("dvrl_marl/SurgeonSeat-v8", seat="suction", partner="scripted", image_size=32,
                   image_appearance="train", max_cycles=40)
    check_env(env.unwrapped, skip_render_check=True)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation) and observation["image"].shape == (32, 32, 3)
    for _ in range(5):
        observation, *_ = env.step(env.action_space.sample())
    assert env.observation_space.contains(observation)


def test_torchrls_adapter_hands_the_images_over_as_pixels():
    pytest.importorskip("torchrl")
    import torch
    from torchrl.envs.utils import check_env_specs

    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    env = SuctionDebrisTorchRLEnv(num_envs=3, seed=2, image_size=32, image_depth=True, image_segmentation=True,
                                  max_cycles=20)
    check_env_specs(env)
    rollout = env.rollout(25, break_when_any_done=False)
    assert rollout["pixels"].shape == (3, 25, 32, 32, 3) and rollout["pixels"].dtype == torch.uint8  # worlds, steps
    assert rollout["depth"].shape == (3, 25, 32, 32) and rollout["segmentation"].dtype == torch.uint8
    assert rollout["agents", "observation"].shape[:3] == (3, 25, 2)


def test_the_device_env_refuses_images_by_name():
    pytest.importorskip("jax")
    with pytest.raises(ValueError, match="image_size"):
        suction_debris_v8.batched_env(num_envs=1, device="cpu", image_size=32)


def test_one_quantity_held_out_draws_it_from_the_held_out_range_and_the_rest_from_the_training_range():
    from dvrl_marl.envs.endoscope import APPEARANCES, QUANTITIES, Appearance, held_out_only

    train, held_out = APPEARANCES["train"], APPEARANCES["held_out"]
    rng = np.random.default_rng(0)
    for quantity, fields in QUANTITIES.items():
        look = held_out_only(quantity)
        for name in ("colour", "light", "light_degrees", "camera_mm", "camera_degrees", "noise"):
            assert getattr(look, name) == getattr(held_out if name in fields else train, name)
            assert getattr(look.low, name) == (getattr(held_out.low, name) if name in fields else 0.0)
        assert look.scene_colours == 0.0
        drawn = [look.draw(rng.uniform(size=Appearance.UNIFORMS)) for _ in range(50)]
        light = np.array([d["light"] for d in drawn])
        assert (np.abs(light - 1.0) >= 0.2 - 1e-12).all() == (quantity == "light")
    together = held_out_only("colour", "light")  # several at once: each from the held-out range, the rest not
    assert (together.colour, together.light, together.light_degrees) == (held_out.colour, held_out.light,
                                                                        held_out.light_degrees)
    assert (together.camera_mm, together.noise, together.low.camera_mm) == (train.camera_mm, train.noise, 0.0)
    assert together.low.colour == held_out.low.colour and together.low.light == held_out.low.light
    for wrong in [("blood",), ("colour", "blood"), ()]:
        with pytest.raises(ValueError, match="quantities must be among"):
            held_out_only(*wrong)


@pytest.mark.parametrize("form", ["batched", "parallel"])
def test_an_env_with_images_is_pickled_and_copied_after_it_drew_and_a_copy_outlives_the_original(form):
    """The renderers do not travel: a pickle, a deep copy and a shallow copy make their own when they first draw, and
    draw what the original drew (a shallow copy that shared them once broke when the original closed)."""
    import copy
    import pickle

    make = {"batched": lambda: suction_debris_v8.batched_env(num_envs=2, image_size=32, image_stereo=True),
            "parallel": lambda: suction_debris_v8.parallel_env(image_size=32)}[form]
    env = make()
    drawn, _ = env.reset(seed=3)
    copies = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env), copy.copy(env)]
    env.close()
    for copied in copies:
        again, _ = copied.reset(seed=3)
        for key in drawn["suction"]:
            np.testing.assert_array_equal(again["suction"][key], drawn["suction"][key])
        copied.close()


@pytest.mark.parametrize("appearance", [None, "train"])
def test_an_ended_world_drawn_again_is_drawn_as_it_ended(appearance):
    """autoreset_mode="disabled": a part an ended world did not keep (a segmentation asked later, the right eye) is
    drawn from the world as it ended, not as its arms went on moving; its kept image and the new drawing agree."""
    env = suction_debris_v8.batched_env(num_envs=2, image_size=32, autoreset_mode="disabled", max_cycles=5,
                                        image_appearance=appearance)
    env.reset(seed=0)
    for _ in range(5):
        ended, *_ = env.step({agent: np.ones((2, 4)) for agent in env.possible_agents})
    for _ in range(6):  # the arms go on moving after the end
        env.step({agent: -np.ones((2, 4)) for agent in env.possible_agents})
    again = env.images(parts=["image", "segmentation", "image_right"])
    np.testing.assert_array_equal(again["image"], ended["suction"]["image"])
    fresh = suction_debris_v8.batched_env(num_envs=2, image_size=32, autoreset_mode="disabled", max_cycles=5,
                                          image_appearance=appearance)
    fresh.reset(seed=0)
    for _ in range(5):
        fresh.step({agent: np.ones((2, 4)) for agent in fresh.possible_agents})
    for part, value in fresh.images(parts=["segmentation", "image_right"]).items():
        np.testing.assert_array_equal(again[part], value, err_msg=part)


def test_a_world_draws_alike_in_every_place_of_a_batch():
    """World i of a batch seeded s is drawn as a single world seeded s + i: colour and segmentation exactly, depth to
    the 1e-5 m the environment's page states (the GL's depth differs by the place in its framebuffer, 4 um seen)."""
    one = suction_debris_v8.batched_env(num_envs=1, image_size=64, image_depth=True, image_segmentation=True)
    batch = suction_debris_v8.batched_env(num_envs=40, image_size=64, image_depth=True, image_segmentation=True)
    alone, _ = one.reset(seed=30)
    among, _ = batch.reset(seed=0)
    for part in ("image", "segmentation"):
        np.testing.assert_array_equal(among["suction"][part][30], alone["suction"][part][0])
    np.testing.assert_allclose(among["suction"]["depth"][30], alone["suction"]["depth"][0], rtol=0, atol=1e-5)
