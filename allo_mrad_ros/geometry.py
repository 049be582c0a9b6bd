"""Rigid poses: quaternions, homogeneous transforms and camera-frame conventions.

Conventions used throughout the package:

* quaternions are ``(x, y, z, w)`` as in ``geometry_msgs/Quaternion``;
* a pose ``T_a_b`` is a 4x4 float64 matrix mapping coordinates in frame *b* into frame *a*;
* camera poses are of the ROS optical frame (x right, y down, z forward) in the station frame.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.errors import InvalidInput

# Unit-norm tolerance for quaternions read from files or messages.
QUATERNION_NORM_TOLERANCE = 1e-3

# Optical (x right, y down, z forward) to OpenGL/Blender camera (x right, y up, z backward).
OPTICAL_TO_OPENGL = np.diag([1.0, -1.0, -1.0])


class PoseError(InvalidInput):
    """A pose, quaternion or rotation is not valid."""


def finite_vector(
    values: object, length: int, name: str, error: type[Exception] = PoseError
) -> np.ndarray:
    """``values`` as a float64 vector of ``length`` finite numbers, else ``error`` naming it."""
    array = np.asarray(values, dtype=np.float64)
    if array.shape != (length,):
        raise error(f"{name} must have {length} elements, got shape {array.shape}")
    if not np.all(np.isfinite(array)):
        raise error(f"{name} must be finite, got {array.tolist()}")
    return array


def unit_vector(values: object, name: str, error: type[Exception] = PoseError) -> np.ndarray:
    """``values`` (3 finite numbers, not all zero) scaled to unit length, else ``error``.

    Divides by the largest component first, so huge (1e300) or tiny (1e-300) vectors keep
    their direction instead of overflowing to infinity or underflowing to zero.
    """
    vector = finite_vector(values, 3, name, error)
    largest = float(np.max(np.abs(vector)))
    if largest == 0.0:
        raise error(f"{name} must not be the zero vector")
    scaled = vector / largest
    return scaled / float(np.linalg.norm(scaled))


def quaternion_to_matrix(quaternion_xyzw: object, normalise: bool = True) -> np.ndarray:
    """Return the 3x3 rotation matrix of an ``(x, y, z, w)`` quaternion.

    Parameters
    ----------
    quaternion_xyzw : array_like, shape (4,)
        The quaternion. A zero or non-finite quaternion raises :class:`PoseError`.
    normalise : bool
        Normalise the quaternion first (default). When False, a norm further than
        :data:`QUATERNION_NORM_TOLERANCE` from 1 raises :class:`PoseError`.

    Returns
    -------
    numpy.ndarray
        3x3 float64 rotation matrix.
    """
    q = finite_vector(quaternion_xyzw, 4, "quaternion")
    # Through the largest component, so a huge quaternion cannot overflow its norm to inf.
    largest = float(np.max(np.abs(q)))
    scaled = q / largest if largest > 0 else q
    norm = largest * float(np.linalg.norm(scaled))
    if norm < 1e-9:
        raise PoseError(f"quaternion has zero norm: {q.tolist()}")
    if not normalise and abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise PoseError(f"quaternion is not unit norm (|q| = {norm:.6f}): {q.tolist()}")
    return Rotation.from_quat(scaled / float(np.linalg.norm(scaled))).as_matrix()


def matrix_to_quaternion(rotation: np.ndarray) -> np.ndarray:
    """Return the ``(x, y, z, w)`` quaternion of a rotation matrix, with ``w >= 0``."""
    q = Rotation.from_matrix(np.asarray(rotation, dtype=np.float64)).as_quat()
    return -q if q[3] < 0 else q


def pose_matrix(position: object, quaternion_xyzw: object) -> np.ndarray:
    """Return the 4x4 transform of a position and an ``(x, y, z, w)`` quaternion."""
    transform = np.eye(4)
    transform[:3, :3] = quaternion_to_matrix(quaternion_xyzw)
    transform[:3, 3] = finite_vector(position, 3, "position")
    return transform


def pose_components(transform: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Split a 4x4 transform into a position and an ``(x, y, z, w)`` quaternion."""
    transform = validate_transform(transform)
    return transform[:3, 3].copy(), matrix_to_quaternion(transform[:3, :3])


def validate_transform(transform: object, name: str = "pose") -> np.ndarray:
    """Check that ``transform`` is a finite rigid 4x4 transform and return it as float64.

    Raises
    ------
    PoseError
        If the shape is wrong, an entry is not finite, the last row is not ``0 0 0 1`` or
        the rotation block is not orthonormal with determinant +1 (tolerance 1e-6).
    """
    matrix = np.asarray(transform, dtype=np.float64)
    if matrix.shape != (4, 4):
        raise PoseError(f"{name} must be a 4x4 matrix, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise PoseError(f"{name} contains non-finite values")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
        raise PoseError(f"{name} last row must be [0, 0, 0, 1], got {matrix[3].tolist()}")
    rotation = matrix[:3, :3]
    if not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6) or np.linalg.det(rotation) < 0:
        raise PoseError(f"{name} rotation block is not a proper rotation")
    return matrix


def euler_zyx_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """Return ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (Blender's XYZ Euler order)."""
    return Rotation.from_euler("xyz", [roll, pitch, yaw]).as_matrix()


def blender_camera_to_optical(rotation_blender: np.ndarray) -> np.ndarray:
    """Convert a Blender/OpenGL camera orientation (looks along -z, y up) to ROS optical."""
    return np.asarray(rotation_blender, dtype=np.float64) @ OPTICAL_TO_OPENGL


def optical_to_opengl_pose(T_station_optical: np.ndarray) -> np.ndarray:
    """Convert a camera-optical-in-station pose into the OpenGL camera pose pyrender expects."""
    pose = validate_transform(T_station_optical).copy()
    pose[:3, :3] = pose[:3, :3] @ OPTICAL_TO_OPENGL
    return pose


def look_at(eye: object, target: object, up: object = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Return the optical-frame pose of a camera at ``eye`` looking at ``target``.

    The camera's z axis points at the target and its y axis (image down) is as close as
    possible to ``-up``. Raises :class:`PoseError` if eye and target coincide or the
    viewing direction is parallel to ``up``.
    """
    eye = finite_vector(eye, 3, "eye")
    forward = finite_vector(target, 3, "target") - eye
    distance = np.linalg.norm(forward)
    if distance < 1e-9:
        raise PoseError("look_at: eye and target coincide")
    forward /= distance
    right = np.cross(forward, finite_vector(up, 3, "up"))
    if np.linalg.norm(right) < 1e-9:
        raise PoseError("look_at: viewing direction is parallel to up")
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    transform = np.eye(4)
    transform[:3, :3] = np.column_stack([right, down, forward])
    transform[:3, 3] = eye
    return transform


def sphere_points(count: int) -> np.ndarray:
    """``count`` unit vectors spread evenly over the sphere (a Fibonacci lattice).

    Parameters
    ----------
    count : int
        How many vectors.

    Returns
    -------
    numpy.ndarray
        ``(count, 3)`` float64, from the +z pole (first) to the -z pole (last), each a turn of
        the golden angle about z from the one before.
    """
    index = np.arange(count) + 0.5
    z = 1.0 - 2.0 * index / count
    angle = math.pi * (3.0 - math.sqrt(5.0)) * index
    radius = np.sqrt(1.0 - z * z)
    return np.c_[radius * np.cos(angle), radius * np.sin(angle), z]
