import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from dvrl_marl import kinematics
from dvrl_marl.kinematics import (
    LND,
    SUCTION_IRRIGATION,
    TIP_ROTATION_DOWN,
    UnreachableError,
    forward_kinematics,
    inverse_kinematics,
    inverse_kinematics_point,
    within_limits,
)

TOOLS = [LND, SUCTION_IRRIGATION]
# A region larger than every environment's workspace, partly unreachable near the RCM and at wide angles.
REGION_LOW = np.array([-0.12, -0.12, -0.25])
REGION_HIGH = np.array([0.12, 0.12, -0.005])


def _reachable_sample(tool, n, seed=0):
    rng = np.random.default_rng(seed)
    points = rng.uniform(REGION_LOW, REGION_HIGH, size=(4 * n, 3))
    points = points[within_limits(tool, points)][:n]
    assert len(points) == n
    return points


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_fk_of_ik_returns_the_position_with_the_tool_pointing_down(tool):
    positions = _reachable_sample(tool, 5000)
    q = inverse_kinematics(tool, positions)
    poses = forward_kinematics(tool, q)
    assert np.max(np.abs(poses[:, :3, 3] - positions)) < 1e-9
    assert np.max(np.abs(poses[:, :3, :3] - TIP_ROTATION_DOWN)) < 1e-9


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_ik_solutions_lie_within_the_joint_limits(tool):
    q = inverse_kinematics(tool, _reachable_sample(tool, 5000, seed=1))
    assert np.all(q >= np.asarray(tool.lower)) and np.all(q <= np.asarray(tool.upper))


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_shaft_passes_through_the_remote_centre_of_motion(tool):
    rng = np.random.default_rng(2)
    q = rng.uniform(tool.lower, tool.upper, size=(2000, tool.n_joints))
    frames = forward_kinematics(tool, q, frames=True)
    insertion_frame = frames[:, 2]  # frame 3: its z axis is the shaft
    origin, axis = insertion_frame[:, :3, 3], insertion_frame[:, :3, 2]
    # Distance from the RCM (origin) to the shaft line.
    distance = np.linalg.norm(np.cross(origin, axis), axis=-1)
    assert np.max(distance) < 1e-12
    # The wrist pitch axis (frame 4 on the LND, frame 3 itself on the S&I) is on the same line.
    pitch_point = frames[:, 3 if tool is LND else 2, :3, 3]
    assert np.max(np.linalg.norm(np.cross(pitch_point, axis), axis=-1)) < 1e-12


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_batched_ik_matches_the_single_point_path_and_keeps_leading_axes(tool):
    positions = _reachable_sample(tool, 24, seed=3)
    batched = inverse_kinematics(tool, positions.reshape(4, 6, 3))
    assert batched.shape == (4, 6, tool.n_joints)
    for p, q in zip(positions, batched.reshape(-1, tool.n_joints)):
        np.testing.assert_allclose(inverse_kinematics_point(tool, *p), q, atol=1e-15)
    assert inverse_kinematics(tool, positions[0]).shape == (tool.n_joints,)
    assert forward_kinematics(tool, batched).shape == (4, 6, 4, 4)


@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_unreachable_positions_raise_with_position_and_limit(tool):
    wide = np.array([0.3, 0.0, -0.05])  # needs a wrist yaw far past its limit
    with pytest.raises(UnreachableError) as caught:
        inverse_kinematics(tool, wide)
    error = caught.value
    np.testing.assert_array_equal(error.position, wide)
    assert error.joint in tool.joint_names
    lower, upper = error.limits
    assert not lower <= error.value <= upper
    assert "unreachable" in str(error) and error.joint in str(error)
    with pytest.raises(UnreachableError):
        inverse_kinematics_point(tool, *wide)
    # In a batch, the first offending position is reported.
    batch = np.array([[0.0, 0.0, -0.1], wide, [0.0, 0.0, -0.1]])
    with pytest.raises(UnreachableError) as caught:
        inverse_kinematics(tool, batch)
    np.testing.assert_array_equal(caught.value.position, wide)
    assert list(within_limits(tool, batch)) == [True, False, True]


def test_positions_at_the_rcm_or_beyond_the_insertion_limit_are_unreachable():
    with pytest.raises(UnreachableError) as caught:
        inverse_kinematics(LND, [0.0, 0.0, -0.0102])  # the wrist would have to sit at the RCM
    assert caught.value.joint == "geometry"
    with pytest.raises(UnreachableError) as caught:
        inverse_kinematics(LND, [0.0, 0.0, -0.40])
    assert caught.value.joint == "insertion"


@pytest.mark.parametrize("bad", [[np.nan, 0.0, -0.1], [0.0, np.inf, -0.1], [0.0, 0.0, -np.inf]])
@pytest.mark.parametrize("tool", TOOLS, ids=lambda t: t.name)
def test_non_finite_input_raises_value_error(tool, bad):
    with pytest.raises(ValueError, match="finite"):
        inverse_kinematics(tool, bad)
    with pytest.raises(ValueError, match="finite"):
        forward_kinematics(tool, np.full(tool.n_joints, np.nan))
    assert not isinstance(ValueError("x"), UnreachableError)


def test_wrong_shapes_and_unknown_tools_raise():
    with pytest.raises(ValueError, match="shape"):
        inverse_kinematics(LND, [0.0, 0.0])
    with pytest.raises(ValueError, match="shape"):
        forward_kinematics(LND, np.zeros(5))
    with pytest.raises(ValueError, match="unknown tool"):
        inverse_kinematics("scissors", [0.0, 0.0, -0.1])
    assert kinematics.get_tool("lnd") is LND


def test_home_configuration_points_down_the_z_axis():
    q = np.zeros(6)
    q[2] = 0.1
    pose = forward_kinematics(LND, q)
    expected_depth = 0.1 - (kinematics.L_RCC - kinematics.L_TOOL) + kinematics.L_PITCH2YAW + kinematics.L_YAW2CTRLPNT
    np.testing.assert_allclose(pose[:3, 3], [0.0, 0.0, -expected_depth], atol=1e-15)
    np.testing.assert_allclose(pose[:3, :3], TIP_ROTATION_DOWN, atol=1e-15)


coordinates = st.floats(-0.12, 0.12, allow_nan=False)
depths = st.floats(-0.25, -0.005, allow_nan=False)


@settings(max_examples=300, deadline=None)
@given(x=coordinates, y=coordinates, z=depths, tool=st.sampled_from(TOOLS))
def test_ik_either_solves_exactly_within_limits_or_raises(x, y, z, tool):
    try:
        q = inverse_kinematics_point(tool, x, y, z)
    except UnreachableError as error:
        assert error.joint == "geometry" or not error.limits[0] <= error.value <= error.limits[1]
        assert not within_limits(tool, [x, y, z])
        return
    assert within_limits(tool, [x, y, z])
    assert all(lo <= v <= hi for v, lo, hi in zip(q, tool.lower, tool.upper))
    tip = forward_kinematics(tool, q)[:3, 3]
    assert math.dist(tip, (x, y, z)) < 1e-9


def test_unreachable_error_copies_and_pickles_with_its_facts():
    # Ray copies and ships a worker's exception: one that cannot be rebuilt hides the real error behind a TypeError.
    import copy
    import pickle

    error = kinematics.UnreachableError("lnd", (0.01, 0.02, -0.04), "outer_pitch", -0.9251, (-0.925, 0.925))
    for clone in (copy.copy(error), pickle.loads(pickle.dumps(error))):
        assert type(clone) is kinematics.UnreachableError and str(clone) == str(error)
        assert (clone.tool, clone.joint, clone.value, clone.limits) == ("lnd", "outer_pitch", -0.9251, (-0.925, 0.925))
        assert clone.position.tolist() == [0.01, 0.02, -0.04]
