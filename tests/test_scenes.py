"""Model-zoo checks for every scene: compiles, steps without warnings, renders, and matches the DH kinematics."""

import filecmp

import mujoco
import numpy as np
import pytest

from dvrl_marl import assets, kinematics
from dvrl_marl.preview import render_scene, scene_arms, scene_summary
from dvrl_marl.scene import load_model, raise_on_warnings

SCENES = sorted(p.stem for p in assets.scenes_dir().glob("*.xml") if p.stem not in ("common",))
TASK_SCENES = [s for s in SCENES if not s.startswith("psm_")]


def test_expected_scenes_are_shipped():
    for name in ("psm_lnd", "psm_suction_irrigation", "reach_lnd", "reach_suction_irrigation", "pick_lnd",
                 "collaborative"):
        assert name in SCENES


@pytest.mark.parametrize("name", SCENES)
def test_scene_compiles_and_steps_one_second_of_random_motion_without_warnings(name):
    model = load_model(name)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(0)
    limited = [j for j in range(model.njnt) if model.jnt_limited[j]]
    steps = int(round(1.0 / model.opt.timestep))
    for step in range(steps):
        if step % 10 == 0:  # a new random joint configuration every 20 ms, as a kinematic controller would set
            for j in limited:
                lo, hi = model.jnt_range[j]
                data.qpos[model.jnt_qposadr[j]] = rng.uniform(lo, hi)
            data.qvel[:] = 0.0
        mujoco.mj_step(model, data)
        raise_on_warnings(data)
    assert np.all(np.isfinite(data.qpos))


@pytest.mark.parametrize("name", TASK_SCENES)
def test_scene_renders_a_non_blank_endoscope_image(name):
    image = render_scene(name, width=160, height=120)
    assert image.shape == (120, 160, 3)
    assert image.std() > 5.0  # not a flat colour
    assert len(np.unique(image.reshape(-1, 3), axis=0)) > 50


@pytest.mark.parametrize("name", TASK_SCENES)
def test_every_scene_has_an_endoscope_camera_and_named_arms(name):
    model = load_model(name)
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "endoscope") >= 0
    arms = scene_arms(model)
    assert arms
    assert "endoscope" in scene_summary(name)


def test_collaborative_scene_composes_two_prefixed_arms_and_its_task_parts():
    model = load_model("collaborative")
    assert scene_arms(model) == {"suction/": "suction_irrigation", "grasper/": "lnd"}
    for kind, name in [(mujoco.mjtObj.mjOBJ_SITE, "handoff"), (mujoco.mjtObj.mjOBJ_GEOM, "phantom"),
                       (mujoco.mjtObj.mjOBJ_GEOM, "blood_0"), (mujoco.mjtObj.mjOBJ_GEOM, "blood_1"),
                       (mujoco.mjtObj.mjOBJ_SITE, "grasper/grasp_zone"), (mujoco.mjtObj.mjOBJ_SITE, "suction/tip")]:
        assert mujoco.mj_name2id(model, kind, name) >= 0, name
    pins = [model.geom(f"debris_{i}") for i in range(3)]
    for pin in pins:  # 3 mm x 28 mm spring pins
        radius, half_length = pin.size[:2]
        assert radius == pytest.approx(0.0015)
        assert 2 * (half_length + radius) == pytest.approx(0.028)


@pytest.mark.parametrize(
    "scene, prefix, tool",
    [("reach_lnd", "psm/", kinematics.LND), ("reach_suction_irrigation", "psm/", kinematics.SUCTION_IRRIGATION),
     ("pick_lnd", "psm/", kinematics.LND), ("collaborative", "suction/", kinematics.SUCTION_IRRIGATION),
     ("collaborative", "grasper/", kinematics.LND)],
)
def test_mujoco_chain_reproduces_the_dh_forward_kinematics(scene, prefix, tool):
    model = load_model(scene)
    data = mujoco.MjData(model)
    rng = np.random.default_rng(4)
    base = model.body(f"{prefix}rcm").id
    tip = model.site(f"{prefix}tip").id
    addresses = [model.joint(f"{prefix}{name}").qposadr[0] for name in tool.joint_names]
    for _ in range(200):
        q = rng.uniform(tool.lower, tool.upper)
        data.qpos[addresses] = q
        mujoco.mj_kinematics(model, data)
        rotation = data.xmat[base].reshape(3, 3)
        position = rotation.T @ (data.site_xpos[tip] - data.xpos[base])
        orientation = rotation.T @ data.site_xmat[tip].reshape(3, 3)
        expected = kinematics.forward_kinematics(tool, q)
        np.testing.assert_allclose(position, expected[:3, 3], atol=1e-9)
        np.testing.assert_allclose(orientation, expected[:3, :3], atol=1e-9)


def test_grasp_zone_site_sits_at_the_tip_between_the_jaws():
    model = load_model("pick_lnd")
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    np.testing.assert_allclose(data.site_xpos[model.site("psm/grasp_zone").id], data.site_xpos[model.site("psm/tip").id])
    assert int(model.site_type[model.site("psm/grasp_zone").id]) == int(mujoco.mjtGeom.mjGEOM_BOX)


def test_generated_models_and_meshes_are_up_to_date_and_deterministic(tmp_path):
    first = assets.write_generated_assets(tmp_path / "a")
    assets.write_generated_assets(tmp_path / "b")
    for path in first:
        relative = path.relative_to(tmp_path / "a")
        assert filecmp.cmp(path, tmp_path / "b" / relative, shallow=False), f"{relative} is not deterministic"
        shipped = assets.scenes_dir() / relative
        assert shipped.is_file(), f"{relative} is not shipped; run python -m dvrl_marl.assets"
        assert filecmp.cmp(path, shipped, shallow=False), f"{relative} is stale; run python -m dvrl_marl.assets"


def test_environment_docs_are_generated_from_the_docstrings():
    import subprocess
    import sys
    from pathlib import Path

    script = Path(__file__).parents[1] / "docs" / "build_docs.py"
    assert subprocess.run([sys.executable, str(script), "--check"]).returncode == 0


def test_the_package_finds_its_scenes_tasks_and_policies_from_any_directory(tmp_path):
    import subprocess
    import sys

    code = (
        "import gymnasium as gym, dvrl_marl\n"
        "from dvrl_marl import assets, policies\n"
        "from dvrl_marl.envs import suction_debris_v8\n"
        "env = gym.make('dvrl_marl/PSMPick-v1'); env.reset(seed=0)\n"
        "suction_debris_v8.parallel_env().reset(seed=0)\n"
        "print(assets.scenes_dir(), assets.tasks_dir(), policies.available())\n"
    )
    result = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, check=True)
    assert "scenes" in result.stdout and "tasks" in result.stdout


def test_arm_frames_agree_for_a_yawed_base():
    """The float fast paths (tip_world, base_point) must match to_world / to_base when the base is rotated."""
    from dvrl_marl.arm import Arm

    model = load_model("pick_lnd")
    rcm = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "psm/rcm")
    yaw = 0.7
    model.body_quat[rcm] = (np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2))
    arm = Arm(model, mujoco.MjData(model), "psm/", "lnd")
    point = np.array([0.01, -0.02, -0.1])
    world = arm.to_world(point)
    assert not np.allclose(world - arm.base_position, point)  # the rotation matters here
    np.testing.assert_allclose(arm.base_point(*world.tolist()), point, atol=1e-12)
    arm.set_tip(*point.tolist())
    np.testing.assert_allclose(arm.tip_world(), world, atol=1e-12)
