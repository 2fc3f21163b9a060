"""The dVRK's frames: v1 envs observe and command measured_cp (DH row 6 of the LND), conversions to a base frame."""

import gymnasium as gym
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import TOOL_POINT

import dvrl_marl  # noqa: F401  (registration)
from dvrl_marl import frames, kinematics
from dvrl_marl.envs import suction_debris_v8


def _dvrk_chain_origin(q):
    """The dVRK's own LND chain ends at DH row 6 (LARGE_NEEDLE_DRIVER_400006.json): its origin."""
    return kinematics.forward_kinematics(kinematics.LND, q, frames=True)[..., 5, :3, 3]


@pytest.mark.parametrize("version", ["tool_point", "v1"])
@pytest.mark.parametrize("task", ["Reach", "Pick"])
def test_env_positions_map_to_the_dvrk_chain(version, task):
    env = gym.make(f"dvrl_marl/PSM{task}-v1", **({} if version == "v1" else TOOL_POINT[f"dvrl_marl/PSM{task}-v1"]))
    arm = env.unwrapped.arm
    tip_frame = "measured_cp" if version == "v1" else "tool_point"
    assert env.unwrapped.tip_frame == tip_frame
    rng = np.random.default_rng(7)
    env.reset(seed=3)
    for step in range(300):
        if step % 100 == 0:
            env.reset(seed=step)
        env.step(rng.uniform(-1, 1, env.action_space.shape))
        p = np.array(arm.tip)
        np.testing.assert_allclose(frames.env_to_dvrk(p, env_tip_frame=tip_frame), _dvrk_chain_origin(arm.q),
                                   atol=1e-12)
        if version == "v1":  # the env's p is the robot's measured_cp, unconverted
            np.testing.assert_allclose(p, _dvrk_chain_origin(arm.q), atol=1e-12)
        pose = frames.servo_cp_goal(p, env_tip_frame=tip_frame)
        np.testing.assert_allclose(pose[:3, :3], kinematics.forward_kinematics(kinematics.LND, arm.q)[:3, :3],
                                   atol=1e-12)
        # The tool point (where the jaws sense the object) is 10.2 mm below p in v1, p itself in v0.
        drop = 0.0102 if version == "v1" else 0.0
        np.testing.assert_allclose(np.array(arm.tool_point_world()) - arm.base_position, p - (0, 0, drop),
                                   atol=1e-12)


def test_v1_puts_the_scene_where_the_robot_has_it():
    reach0, reach1 = (gym.make("dvrl_marl/PSMReach-v1", **kw).unwrapped for kw in (TOOL_POINT["dvrl_marl/PSMReach-v1"], {}))
    for env in (reach0, reach1):
        env.reset(seed=0, options={"start": env.workspace_centre})
    above = [env.arm.tool_point_world()[2] - env.arm.base_position[2] - env.table_height for env in (reach0, reach1)]
    assert above == pytest.approx([0.0134, 0.0032], abs=1e-9)  # the 13.4 mm and "about 3 mm"
    pick0, pick1 = (gym.make("dvrl_marl/PSMPick-v1", **kw).unwrapped for kw in (TOOL_POINT["dvrl_marl/PSMPick-v1"], {}))
    descents = []
    for env in (pick0, pick1):
        env.reset(seed=0)
        descents.append(env.arm.tool_point_world()[2] - env.arm.base_position[2] - env.object_position()[2])
    assert descents == pytest.approx([0.0204, 0.0102], abs=1e-9)


def test_collaborative_arms_convert_through_their_base_poses():
    env = suction_debris_v8.parallel_env()
    env.reset(seed=1)
    arm = env.arms["grasper"]
    world_tip = np.array(arm.tip_world())
    converted = frames.env_to_dvrk(world_tip, frames.base_pose_of(arm), env_tip_frame="tool_point")
    np.testing.assert_allclose(converted, _dvrk_chain_origin(arm.q), atol=1e-12)
    back = frames.dvrk_to_env(converted, frames.base_pose_of(arm), env_tip_frame="tool_point")
    np.testing.assert_allclose(back, world_tip, atol=1e-12)
    suction = env.arms["suction"]
    measured = frames.env_to_dvrk(suction.tip_world(), frames.base_pose_of(suction), tool="suction_irrigation",
                                  env_tip_frame="tool_point")
    np.testing.assert_allclose(measured, kinematics.measured_cp_forward_kinematics("suction_irrigation",
                                                                                    suction.q)[:3, 3], atol=1e-12)


def _rotation(quaternion):
    w, x, y, z = np.asarray(quaternion) / np.linalg.norm(quaternion)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=100, deadline=None)
@given(quaternion=st.tuples(finite, finite, finite, finite).filter(lambda q: np.linalg.norm(q) > 0.1),
       offset=st.tuples(finite, finite, finite), point=st.tuples(finite, finite, finite),
       tip_frame=st.sampled_from(kinematics.TIP_FRAMES), tool=st.sampled_from(sorted(kinematics.TOOLS)))
def test_conversions_invert_each_other_for_any_base_pose(quaternion, offset, point, tip_frame, tool):
    pose = frames.BasePose(offset, _rotation(quaternion))
    in_base = frames.env_to_dvrk(point, pose, tool=tool, env_tip_frame=tip_frame)
    np.testing.assert_allclose(frames.dvrk_to_env(in_base, pose, tool=tool, env_tip_frame=tip_frame), point,
                               atol=1e-12)
    # An env point at R b + t is the base point b (plus the 10.2 mm to measured_cp for tool points).
    shift = kinematics.get_tool(tool).measured_cp_to_tool_point if tip_frame == "tool_point" else 0.0
    world = pose.rotation @ np.asarray(point) + np.asarray(offset)
    np.testing.assert_allclose(frames.env_to_dvrk(world, pose, tool=tool, env_tip_frame=tip_frame),
                               np.asarray(point) + (0.0, 0.0, shift), atol=1e-12)


def test_bad_frames_input_is_refused():
    with pytest.raises(ValueError, match="finite"):
        frames.env_to_dvrk([0.0, np.nan, 0.0])
    with pytest.raises(ValueError, match="shape"):
        frames.env_to_dvrk([0.0, 0.0])
    with pytest.raises(ValueError, match="env_tip_frame"):
        frames.env_to_dvrk([0.0, 0.0, 0.0], env_tip_frame="jaw")
    with pytest.raises(ValueError, match="rotation"):
        frames.BasePose((0, 0, 0), np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="tip_frame"):
        gym.make("dvrl_marl/PSMReach-v1", tip_frame="wrist")
