"""The stereo endoscope (``image_stereo``): the right eye is the scene's endoscope camera moved
``STEREO_BASELINE_MM`` along its own x axis, in every look (the pair one rigid rig); its images are in every form of
the env (parallel, AEC, batched, the seat env, TorchRL), deterministic per seed, and bad input is refused by name."""

import mujoco
import numpy as np
import pytest
from test_endoscope import _stepped  # (a batch stepped with random actions)

from dvrl_marl.envs import suction_debris_v8
from dvrl_marl.envs.endoscope import STEREO_BASELINE_MM, EndoscopeRenderer, _software_renderer
from dvrl_marl.suction_debris.appearance import APPEARANCES


def test_the_right_eye_is_the_endoscope_moved_by_the_baseline_along_its_x_axis():
    """MuJoCo's own drawing of the scene, its endoscope camera moved 5 mm along its x axis, is what the right eye's
    renderer draws (exactly, on a software renderer)."""
    env = _stepped(3, 60)
    states = [env.core.world_state(world) for world in range(3)]
    right = EndoscopeRenderer(env.params, 64, layers=True, eye_mm=STEREO_BASELINE_MM)
    exact = _software_renderer()
    drawn = right.render(states)["rgb"]
    model, data = right.mirror.model, right.mirror.data
    camera = model.camera("endoscope").id
    mujoco.mj_forward(model, data)
    axes = data.cam_xmat[camera].reshape(3, 3).copy()
    model.cam_pos[camera] += STEREO_BASELINE_MM / 1000.0 * axes[:, 0]  # (the camera hangs from the world body)
    whole = mujoco.Renderer(model, 64, 64)
    whole.scene.flags[mujoco.mjtRndFlag.mjRND_SHADOW] = False
    whole.scene.flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = False
    everything = mujoco.MjvOption()
    everything.geomgroup[:] = 1
    for world, state in enumerate(states):
        right.mirror.show(state)
        mujoco.mj_forward(model, data)
        whole.update_scene(data, camera="endoscope", scene_option=everything)
        expected = whole.render()
        if exact:
            np.testing.assert_array_equal(drawn[world], expected, err_msg=f"world {world}")
        else:
            assert (drawn[world] != expected).mean() <= 1e-3
    whole.close()
    right.close()


@pytest.mark.parametrize("look", [None, "train", "held_out"])
def test_the_pair_is_one_rig_the_right_eye_beside_the_left_in_every_look(look):
    """In each world's look (the endoscope shifted and turned), the right eye lies the baseline from the left along
    the left eye's own x axis, looking the same way; and the right image is the left one moved left (nearer things
    more): a horizontal disparity, no vertical one."""
    params = suction_debris_v8.batched_env(num_envs=1).params
    left, right = (EndoscopeRenderer(params, 32, eye_mm=eye) for eye in (0.0, STEREO_BASELINE_MM))
    rng = np.random.default_rng(4)
    for _ in range(3):
        draw = None if look is None else APPEARANCES[look].draw(rng.uniform(0.0, 1.0, 32))
        pair = [renderer._dressing(draw) for renderer in (left, right)]
        camera = left._camera.fixedcamid
        axes = pair[0]["cam_xmat"][camera].reshape(3, 3)
        np.testing.assert_allclose(pair[1]["cam_xmat"][camera], pair[0]["cam_xmat"][camera])
        np.testing.assert_allclose(pair[1]["cam_xpos"][camera] - pair[0]["cam_xpos"][camera],
                                   STEREO_BASELINE_MM / 1000.0 * axes[:, 0], atol=1e-12)
    left.close()
    right.close()
    env = suction_debris_v8.parallel_env(image_size=64, image_stereo=True)
    observation = env.reset(seed=2)[0]["suction"]
    image, right_image = observation["image"].astype(float), observation["image_right"].astype(float)

    def mismatch(dx, dy):  # the right image against the left one moved by (dx, dy) px
        a = image[max(dy, 0):64 + min(dy, 0), max(dx, 0):64 + min(dx, 0)]
        b = right_image[max(-dy, 0):64 + min(-dy, 0), max(-dx, 0):64 + min(-dx, 0)]
        return np.abs(a - b).mean()

    best = min(((dx, dy) for dx in range(-4, 5) for dy in range(-2, 3)), key=lambda shift: mismatch(*shift))
    assert best[1] == 0 and best[0] > 0, best  # right[x] = left[x + d], d > 0


def test_stereo_images_in_every_form_of_the_env():
    from pettingzoo.test import api_test, parallel_api_test

    parallel_api_test(suction_debris_v8.parallel_env(image_size=32, image_stereo=True, max_cycles=30), num_cycles=40)
    api_test(suction_debris_v8.env(image_size=32, image_stereo=True, max_cycles=20), num_cycles=30)
    env = suction_debris_v8.parallel_env(image_size=48, image_stereo=True, image_depth=True,
                                         image_appearance="train")
    observations, _ = env.reset(seed=3)
    for agent in env.agents:
        space = env.observation_space(agent)
        assert set(space.spaces) == {"observation", "image", "image_right", "depth"}
        assert space.contains(observations[agent]) and observations[agent]["image_right"].shape == (48, 48, 3)
    assert not np.array_equal(observations["suction"]["image"], observations["suction"]["image_right"])
    # world i of a batch sees what the single env seeded s + i sees; asked for alone, the right eye is the same
    batch = suction_debris_v8.batched_env(num_envs=3, image_size=48, image_stereo=True, image_depth=True,
                                          image_appearance="train")
    batched, _ = batch.reset(seed=1)
    np.testing.assert_array_equal(batch.images(parts="image_right")["image_right"], batched["suction"]["image_right"])
    for world in range(3):
        single, _ = suction_debris_v8.parallel_env(image_size=48, image_stereo=True, image_depth=True,
                                                   image_appearance="train").reset(seed=1 + world)
        if batch._right_eye.layers:
            np.testing.assert_array_equal(batched["grasper"]["image_right"][world], single["grasper"]["image_right"])
    # without the option, the right eye is still drawn on request, and the observations leave it out
    mono = suction_debris_v8.batched_env(num_envs=2, image_size=32)
    observations, _ = mono.reset(seed=0)
    assert "image_right" not in observations["suction"]
    assert mono.images(parts=["image_right", "image"])["image_right"].shape == (2, 32, 32, 3)


def test_the_stereo_pair_is_deterministic_per_seed():
    def run(seed):
        env = _stepped(2, 20, seed=seed, image_size=32, image_stereo=True, image_appearance="held_out")
        return env.images()

    first, again, other = run(7), run(7), run(8)
    np.testing.assert_array_equal(first["image_right"], again["image_right"])
    assert not np.array_equal(first["image_right"], other["image_right"])


def test_the_seat_env_and_torchrl_take_the_stereo_pair():
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    env = gym.make("dvrl_marl/SurgeonSeat-v8", seat="suction", partner="scripted", image_size=32, image_stereo=True,
                   max_cycles=40)
    check_env(env.unwrapped, skip_render_check=True)
    observation, _ = env.reset(seed=0)
    assert env.observation_space.contains(observation) and observation["image_right"].shape == (32, 32, 3)
    pytest.importorskip("torchrl")
    import torch
    from torchrl.envs.utils import check_env_specs

    from dvrl_marl.integrations.torchrl import SuctionDebrisTorchRLEnv

    torchrl_env = SuctionDebrisTorchRLEnv(num_envs=2, seed=2, image_size=32, image_stereo=True, max_cycles=20)
    check_env_specs(torchrl_env)
    rollout = torchrl_env.rollout(5, break_when_any_done=False)
    assert rollout["pixels_right"].shape == (2, 5, 32, 32, 3) and rollout["pixels_right"].dtype == torch.uint8


@pytest.mark.parametrize("options, named", [({"image_stereo": True}, "image_stereo needs image_size"),
                                            ({"image_size": 32, "image_stereo": 1}, "image_stereo"),
                                            ({"image_size": 32, "image_stereo": "yes"}, "image_stereo")])
def test_bad_stereo_options_are_refused_by_name(options, named):
    with pytest.raises(ValueError, match=named):
        suction_debris_v8.parallel_env(**options)
    for parts in ("image_left", 5, [5], [], None.__class__):  # (a number once raised a raw TypeError)
        with pytest.raises(ValueError, match="images' parts must be some of"):
            suction_debris_v8.batched_env(num_envs=1, image_size=32).images(parts=parts)
    with pytest.raises(ValueError, match="eye_mm"):
        EndoscopeRenderer(suction_debris_v8.batched_env(num_envs=1).params, 32, eye_mm=float("nan"))
