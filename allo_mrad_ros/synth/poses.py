"""Camera poses: base poses around the station, ALLO's per-frame perturbation, pose error.

Base poses look at points on the station from all around it. Each split gets its own base
poses, drawn from one pool without replacement, so no train pose is ever a test pose (as
ALLO's cameras 1-40 and 41-50).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.geometry import OPTICAL_TO_OPENGL, look_at, sphere_points
from allo_mrad_ros.synth.config import SynthError
from allo_mrad_ros.synth.occupancy import StationOccupancy

# Attempts to find a clear base pose along one lattice direction before giving up on it.
_BASE_ATTEMPTS = 50
# Smallest distance of a perturbed camera from the hull.
MIN_FRAME_CLEARANCE_M = 1.0


@dataclass(frozen=True, eq=False)
class BasePose:
    """A camera base pose.

    Attributes
    ----------
    split : str
        The split it belongs to.
    camera : int
        Its index within the split (the ``Camera<N>`` folder).
    pose_id : int
        Its index in the whole pool (unique across splits).
    T_station_camera : numpy.ndarray
        (4, 4) optical-frame pose in the station frame.
    target : numpy.ndarray
        (3,) the point of the station it looks at.
    """

    split: str
    camera: int
    pose_id: int
    T_station_camera: np.ndarray
    target: np.ndarray


def _fibonacci_directions(count: int, rng: np.random.Generator) -> np.ndarray:
    """``count`` directions spread evenly over the sphere, randomly rotated."""
    return sphere_points(count) @ _random_rotation(rng).T


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    quaternion = rng.normal(size=4)
    return Rotation.from_quat(quaternion / np.linalg.norm(quaternion)).as_matrix()


def _roll(pose: np.ndarray, angle: float) -> np.ndarray:
    """Rotate a camera pose about its own optical axis."""
    c, s = math.cos(angle), math.sin(angle)
    rolled = pose.copy()
    rolled[:3, :3] = pose[:3, :3] @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return rolled


def make_base_poses(
    occupancy: StationOccupancy,
    cameras: Mapping[str, int],
    rng: np.random.Generator,
    distance_m: tuple[float, float] = (12.0, 30.0),
    min_clearance_m: float = 7.0,
) -> dict[str, list[BasePose]]:
    """Draw disjoint base poses per split, looking at points on the station.

    Parameters
    ----------
    occupancy : StationOccupancy
        The station's voxel model (targets are points of its hull).
    cameras : Mapping[str, int]
        Number of base poses per split.
    rng : numpy.random.Generator
        Source of randomness.
    distance_m : tuple of float
        Range of distances from the target.
    min_clearance_m : float
        Smallest distance from the hull; poses closer are pushed back along their ray.

    Returns
    -------
    dict of str to list of BasePose
        Per split, in camera order.

    Raises
    ------
    SynthError
        If no clear pose is found along some direction (a station larger than the
        distances allow).
    """
    total = sum(cameras.values())
    directions = _fibonacci_directions(total, rng)
    order = rng.permutation(total)  # which lattice direction goes to which split
    surface = occupancy.surface_points
    pool = []
    for direction in directions:
        for _ in range(_BASE_ATTEMPTS):
            target = surface[rng.integers(len(surface))]
            distance = rng.uniform(*distance_m)
            eye = target + distance * direction
            # Push back along the ray until clear: views between station parts stay rare.
            while occupancy.clearance(eye) < min_clearance_m and distance < 3 * distance_m[1]:
                distance += 1.0
                eye = target + distance * direction
            if occupancy.clearance(eye) < min_clearance_m:
                continue
            up = np.array([0.0, 0.0, 1.0]) if abs(direction[2]) < 0.95 else np.array([1.0, 0, 0])
            pose = _roll(look_at(eye, target, up), rng.uniform(-math.pi, math.pi))
            pool.append((pose, target))
            break
        else:
            raise SynthError(f"no clear camera pose along direction {direction.round(3).tolist()}")
    result: dict[str, list[BasePose]] = {}
    start = 0
    for split, count in cameras.items():
        chosen = order[start : start + count]
        start += count
        result[split] = [
            BasePose(split, camera, int(pose_id), pool[pose_id][0], pool[pose_id][1])
            for camera, pose_id in enumerate(chosen)
        ]
    return result


def perturb(
    T_station_camera: np.ndarray,
    rng: np.random.Generator,
    position_sigma_m: float,
    rotation_sigma_rad: float,
) -> np.ndarray:
    """ALLO's per-frame perturbation of a base pose.

    The position moves by N(0, sigma) per axis; each Blender XYZ Euler angle of the camera
    (``R = Rz(yaw) Ry(pitch) Rx(roll)`` of the OpenGL-convention camera) moves by
    N(0, sigma), as in ALLO's pipeline.

    Parameters
    ----------
    T_station_camera : numpy.ndarray
        (4, 4) optical-frame base pose.
    rng : numpy.random.Generator
        Source of randomness.
    position_sigma_m, rotation_sigma_rad : float
        Standard deviations.

    Returns
    -------
    numpy.ndarray
        The perturbed (4, 4) optical-frame pose.
    """
    blender = T_station_camera[:3, :3] @ OPTICAL_TO_OPENGL
    euler = Rotation.from_matrix(blender).as_euler("xyz")
    euler = euler + rng.normal(0.0, rotation_sigma_rad, 3)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", euler).as_matrix() @ OPTICAL_TO_OPENGL
    pose[:3, 3] = T_station_camera[:3, 3] + rng.normal(0.0, position_sigma_m, 3)
    return pose


def pose_error(
    T_station_camera: np.ndarray, rng: np.random.Generator, sigma_m: float, sigma_rad: float
) -> np.ndarray:
    """The pose a robot would report for a camera at ``T_station_camera``.

    Adds N(0, sigma_m) per axis to the position and a rotation by a vector drawn from
    N(0, sigma_rad) per axis (arm kinematics and hand-eye calibration error).
    """
    reported = T_station_camera.copy()
    delta = Rotation.from_rotvec(rng.normal(0.0, sigma_rad, 3)).as_matrix()
    reported[:3, :3] = T_station_camera[:3, :3] @ delta
    reported[:3, 3] = T_station_camera[:3, 3] + rng.normal(0.0, sigma_m, 3)
    return reported


def clear_camera(occupancy: StationOccupancy, T_station_camera: np.ndarray) -> bool:
    """Whether a camera at this pose is outside the station with room to spare."""
    return occupancy.clearance(np.asarray(T_station_camera)[:3, 3]) >= MIN_FRAME_CLEARANCE_M
