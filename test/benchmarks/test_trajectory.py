"""The camera paths of bench-node: within the arm's speeds, continuous, played back and
forth without a jump; the still path holds one pose."""

import itertools

import numpy as np
import pytest

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.synth.trajectories import ease
from benchmarks.trajectory import (
    MAX_ANGULAR_DEG_S,
    MAX_LINEAR_M_S,
    ArmSweep,
    ping_pong,
    segment_poses,
    speeds,
    top_speed_path,
)


@pytest.mark.parametrize("rate_hz", [30.0, 60.0])
def test_the_moving_path_stays_within_the_arm_speeds_and_moves(rate_hz):
    poses = segment_poses("moving", rate_hz, 3.0)
    assert len(poses) == round(3.0 * rate_hz) + 1
    linear, angular = speeds(poses, rate_hz)
    assert linear.max() <= MAX_LINEAR_M_S and angular.max() <= MAX_ANGULAR_DEG_S
    # It does move like an arm: well above nothing at its fastest.
    assert linear.max() > 0.5 * MAX_LINEAR_M_S and angular.max() > 0.5 * MAX_ANGULAR_DEG_S
    for pose in poses:  # rigid transforms
        np.testing.assert_allclose(pose[:3, :3] @ pose[:3, :3].T, np.eye(3), atol=1e-12)


def test_the_moving_path_is_continuous_and_starts_and_ends_at_rest():
    rate_hz = 30.0
    poses = segment_poses("moving", rate_hz, 3.0)
    linear, angular = speeds(poses, rate_hz)
    # Continuous: no step is more than the largest speed allows in one frame period, and
    # the speed changes smoothly from frame to frame (no jump in velocity).
    steps = np.linalg.norm(np.diff([p[:3, 3] for p in poses], axis=0), axis=1)
    assert steps.max() <= MAX_LINEAR_M_S / rate_hz
    assert np.abs(np.diff(linear)).max() < 0.02 and np.abs(np.diff(angular)).max() < 0.3
    # At rest at both ends, fastest in the middle: the turn of the ping-pong is smooth.
    assert linear[0] < 0.02 * linear.max() and linear[-1] < 0.02 * linear.max()
    assert angular[0] < 0.02 * angular.max() and angular[-1] < 0.02 * angular.max()
    assert abs(int(np.argmax(linear)) - len(linear) // 2) <= 1


def test_ping_pong_plays_the_segment_back_and_forth_without_a_jump():
    count = 5
    shown = [ping_pong(i, count) for i in range(20)]
    assert shown[:12] == [0, 1, 2, 3, 4, 3, 2, 1, 0, 1, 2, 3]
    assert all(abs(a - b) == 1 for a, b in itertools.pairwise(shown))
    assert [ping_pong(i, 1) for i in range(3)] == [0, 0, 0]


def test_the_path_parameter_rests_at_both_ends():
    assert ease(0.0, 3.0) == 0.0 and ease(3.0, 3.0) == 1.0
    assert ease(1.5, 3.0) == pytest.approx(0.5)
    assert ease(-1.0, 3.0) == 0.0 and ease(9.0, 3.0) == 1.0


def test_the_still_path_is_one_constant_pose():
    poses = segment_poses("still", 60.0)
    assert len(poses) == 1
    np.testing.assert_array_equal(poses[0], look_at((-30.0, -12.0, 6.0), (0.0, 0.0, 0.0)))
    linear, angular = speeds(poses * 10, 60.0)
    assert not linear.any() and not angular.any()


def test_a_sweep_faster_than_the_arm_is_refused():
    with pytest.raises(ValueError, match="deg/s"):
        segment_poses("moving", 30.0, 3.0, ArmSweep(target_drift=(20.0, -30.0, 5.0)))
    with pytest.raises(ValueError, match="trajectory must be one of"):
        segment_poses("orbit", 30.0)


def test_speeds_of_a_known_motion():
    # 1 cm and 0.1 degree per frame at 30 Hz: 0.3 m/s and 3 deg/s.
    poses = []
    for k in range(4):
        angle = np.radians(0.1 * k)
        pose = np.eye(4)
        pose[:3, :3] = [
            [np.cos(angle), -np.sin(angle), 0],
            [np.sin(angle), np.cos(angle), 0],
            [0, 0, 1],
        ]
        pose[0, 3] = 0.01 * k
        poses.append(pose)
    linear, angular = speeds(poses, 30.0)
    np.testing.assert_allclose(linear, 0.3, rtol=1e-9)
    np.testing.assert_allclose(angular, 3.0, rtol=1e-6)


def test_the_top_speed_path_holds_both_speeds_and_turns_smoothly():
    rng = np.random.default_rng(4)
    start = look_at([-20.0, 5.0, 3.0], [0.0, 0.0, 0.0])
    poses = top_speed_path(start, 90, 30.0, MAX_ANGULAR_DEG_S, MAX_LINEAR_M_S, rng)
    assert len(poses) == 90 and np.array_equal(poses[0], start)
    linear, angular = speeds(poses, 30.0)
    np.testing.assert_allclose(linear, MAX_LINEAR_M_S, rtol=1e-9)
    np.testing.assert_allclose(angular, MAX_ANGULAR_DEG_S, rtol=1e-6)
    steps = np.diff([pose[:3, 3] for pose in poses], axis=0)
    turn = np.degrees(np.arccos(np.clip(np.sum(steps[1:] * steps[:-1], 1) / 0.01**2, -1, 1)))
    assert turn.max() < 2.0  # the direction of motion turns, it does not jump
