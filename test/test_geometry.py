"""Tests of the pose conventions shared by the renderer, the node and the generator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.geometry import (
    OPTICAL_TO_OPENGL,
    PoseError,
    blender_camera_to_optical,
    euler_zyx_to_matrix,
    look_at,
    matrix_to_quaternion,
    optical_to_opengl_pose,
    pose_components,
    pose_matrix,
    quaternion_to_matrix,
    sphere_points,
    validate_transform,
)


def _rx(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _ry(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def test_quaternion_order_is_xyzw():
    # 90 degrees about z: x maps to y.
    q = [0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)]
    np.testing.assert_allclose(quaternion_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix([0, 0, 0, 2.0]), np.eye(3))


@pytest.mark.parametrize(
    ("quaternion", "message"),
    [
        ([0.0, 0.0, 0.0, 0.0], "zero norm"),
        ([0.0, 0.0, float("nan"), 1.0], "finite"),
        ([0.0, 0.0, 1.0], "4 elements"),
    ],
)
def test_bad_quaternions_raise(quaternion, message):
    with pytest.raises(PoseError, match=message):
        quaternion_to_matrix(quaternion)


def test_unnormalised_quaternion_is_refused_when_asked():
    with pytest.raises(PoseError, match="unit norm"):
        quaternion_to_matrix([0.0, 0.0, 0.0, 1.1], normalise=False)
    quaternion_to_matrix([0.0, 0.0, 0.0, 1.0005], normalise=False)  # within tolerance


def test_zero_quaternion_pose_raises():
    with pytest.raises(PoseError, match="zero norm"):
        pose_matrix([1.0, 2.0, 3.0], [0.0, 0.0, 0.0, 0.0])
    with pytest.raises(PoseError, match="finite"):
        pose_matrix([1.0, float("inf"), 3.0], [0.0, 0.0, 0.0, 1.0])


def test_pose_round_trip_and_positive_w():
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        t = rng.normal(size=3) * 10
        position, quaternion = pose_components(pose_matrix(t, q))
        np.testing.assert_allclose(position, t)
        assert quaternion[3] >= 0
        np.testing.assert_allclose(quaternion, q if q[3] >= 0 else -q, atol=1e-12)
        np.testing.assert_allclose(matrix_to_quaternion(quaternion_to_matrix(q)), quaternion)


@pytest.mark.parametrize(
    ("transform", "message"),
    [
        (np.eye(3), "4x4"),
        (np.full((4, 4), np.nan), "non-finite"),
        (np.vstack([np.eye(4)[:3], [0, 0, 1, 1]]), "last row"),
        (np.diag([1.0, 1.0, -1.0, 1.0]), "proper rotation"),
        (np.diag([2.0, 1.0, 1.0, 1.0]), "proper rotation"),
    ],
)
def test_validate_transform_rejects(transform, message):
    with pytest.raises(PoseError, match=message):
        validate_transform(transform)


def test_validate_transform_names_the_pose():
    with pytest.raises(PoseError, match="T_station_camera"):
        validate_transform(np.eye(3), "T_station_camera")


def test_euler_is_rz_ry_rx():
    roll, pitch, yaw = 0.3, -0.7, 2.1
    expected = _rz(yaw) @ _ry(pitch) @ _rx(roll)
    np.testing.assert_allclose(euler_zyx_to_matrix(roll, pitch, yaw), expected, atol=1e-12)


def test_blender_camera_to_optical_flips_y_and_z():
    rotation = euler_zyx_to_matrix(1.2, 0.1, -0.4)
    optical = blender_camera_to_optical(rotation)
    # The optical z (forward) is the Blender camera's -z; x stays, y flips.
    np.testing.assert_allclose(optical[:, 2], -rotation[:, 2])
    np.testing.assert_allclose(optical[:, 0], rotation[:, 0])
    np.testing.assert_allclose(optical[:, 1], -rotation[:, 1])
    assert np.linalg.det(optical) == pytest.approx(1.0)


def test_optical_to_opengl_pose_keeps_position_and_view_direction():
    pose = look_at([3.0, -2.0, 1.0], [0.0, 0.0, 0.0])
    gl = optical_to_opengl_pose(pose)
    np.testing.assert_allclose(gl[:3, 3], pose[:3, 3])
    np.testing.assert_allclose(-gl[:3, 2], pose[:3, 2])  # OpenGL looks along -z
    np.testing.assert_allclose(gl[:3, 1], -pose[:3, 1])  # OpenGL y is up, optical y down
    validate_transform(gl)
    np.testing.assert_allclose(optical_to_opengl_pose(gl), pose, atol=1e-12)  # involution
    np.testing.assert_allclose(OPTICAL_TO_OPENGL @ OPTICAL_TO_OPENGL, np.eye(3))


def test_optical_to_opengl_pose_validates():
    with pytest.raises(PoseError):
        optical_to_opengl_pose(np.diag([1.0, 1.0, 1.0, 0.0]))


def test_point_in_front_projects_like_a_pinhole():
    # A station point straight ahead of a look_at camera lands on the principal point, and
    # one above the target (station +z with up = +z) lands in the upper half of the image.
    k = ALLO_INTRINSICS
    pose = look_at([10.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    inverse = np.linalg.inv(pose)

    def project(point: list[float]) -> np.ndarray:
        p = inverse[:3, :3] @ point + inverse[:3, 3]
        assert p[2] > 0
        return (k.matrix @ (p / p[2]))[:2]

    np.testing.assert_allclose(project([0.0, 0.0, 0.0]), [k.cx, k.cy])
    assert project([0.0, 0.0, 1.0])[1] < k.cy
    # Right-handed: image right = forward x up = (-x) x z = +y.
    assert project([0.0, 1.0, 0.0])[0] > k.cx


def test_look_at_axes_and_errors():
    pose = look_at([1.0, 2.0, 3.0], [4.0, 6.0, 3.0], up=(0.0, 0.0, 1.0))
    rotation = pose[:3, :3]
    np.testing.assert_allclose(rotation[:, 2], [0.6, 0.8, 0.0])
    assert rotation[:, 1] @ [0.0, 0.0, 1.0] < 0  # image down is world down
    np.testing.assert_allclose(rotation.T @ rotation, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    with pytest.raises(PoseError, match="coincide"):
        look_at([1.0, 1.0, 1.0], [1.0, 1.0, 1.0])
    with pytest.raises(PoseError, match="parallel"):
        look_at([0.0, 0.0, 0.0], [0.0, 0.0, 5.0])


def test_scipy_agrees_on_quaternion_convention():
    q = Rotation.from_euler("xyz", [0.1, 0.2, 0.3]).as_quat()  # scipy is (x, y, z, w) too
    np.testing.assert_allclose(quaternion_to_matrix(q), euler_zyx_to_matrix(0.1, 0.2, 0.3))


def test_scaled_intrinsics_keep_the_field_of_view():
    k = CameraIntrinsics(width=1920, height=1080, fx=1333.3, fy=1333.3, cx=960.0, cy=540.0)
    small = k.scaled(0.25)
    assert (small.width, small.height) == (480, 270)
    # The image edge (pixel edge -0.5 .. width - 0.5) subtends the same angle.
    assert (k.width - 0.5 - k.cx) / k.fx == pytest.approx((small.width - 0.5 - small.cx) / small.fx)
    assert (-0.5 - k.cy) / k.fy == pytest.approx((-0.5 - small.cy) / small.fy)


def test_resized_intrinsics_keep_every_pixel_edge_on_its_ray():
    k = CameraIntrinsics(width=1920, height=1080, fx=1333.3, fy=1250.0, cx=950.0, cy=545.0)
    depth = k.resized(160, 96)  # a depth image of another size, as rendered next to a query
    assert (depth.width, depth.height) == (160, 96)
    # Each image edge and the image centre (in pixel-edge units) stand at the same angle.
    for u, v in ((0.0, 0.0), (1.0, 1.0), (0.5, 0.5), (0.25, 0.75)):
        ray = ((u * k.width - 0.5 - k.cx) / k.fx, (v * k.height - 0.5 - k.cy) / k.fy)
        resized_ray = (
            (u * depth.width - 0.5 - depth.cx) / depth.fx,
            (v * depth.height - 0.5 - depth.cy) / depth.fy,
        )
        assert resized_ray == pytest.approx(ray)


def test_sphere_points_are_unit_vectors_spread_over_the_whole_sphere():
    points = sphere_points(200)
    assert points.shape == (200, 3)
    np.testing.assert_allclose(np.linalg.norm(points, axis=1), 1.0, atol=1e-12)
    # Evenly spread: centred on the origin, and no two closer than half the spacing a
    # uniform cover of the sphere's area gives each point.
    np.testing.assert_allclose(points.mean(axis=0), 0.0, atol=1e-2)
    distances = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(distances, np.inf)
    assert distances.min() > 0.5 * np.sqrt(4 * np.pi / 200)
