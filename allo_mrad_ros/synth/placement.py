"""ALLO's anomaly placement rules, the geometric part.

A candidate is drawn uniformly in a box of half-width ``box_half_width`` centred
``distance`` in front of the camera (box axes = camera axes), moved along the viewing axis
by the frame's depth offset and given a uniformly random orientation. It is rejected when
its centre leaves the view frustum, it reaches behind the camera's near range, touches or
sits inside the station, or is hidden by the station (its centre, or more than a given
fraction of its surface samples). The image-space rule (enough visible pixels) needs a
render and lives in the generator.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.synth.objects import AnomalyObject
from allo_mrad_ros.synth.occupancy import StationOccupancy

# Nothing of the object may come closer to the camera than this (lens hood, arm).
MIN_RANGE_M = 0.3
# Surface samples used for the occlusion test (an even subset of the object's samples).
_OCCLUSION_SAMPLES = 256


@dataclass(frozen=True, eq=False)
class Candidate:
    """One proposed placement and the outcome of the geometric checks.

    Attributes
    ----------
    pose : numpy.ndarray
        (4, 4) object frame in the station frame.
    depth_m : float
        Depth offset along the viewing axis it was drawn with.
    rejected : str
        Empty if accepted, else why: ``frustum``, ``range``, ``station`` or ``occluded``.
    occluded_fraction : float
        Fraction of the tested surface samples hidden by the station.
    """

    pose: np.ndarray
    depth_m: float
    rejected: str
    occluded_fraction: float


def propose(
    T_station_camera: np.ndarray,
    rng: np.random.Generator,
    distance_m: float,
    half_width_m: float,
    depth_m: float,
) -> np.ndarray:
    """Draw an object pose in ALLO's placement box, moved ``depth_m`` along the view axis.

    Returns
    -------
    numpy.ndarray
        (4, 4) object pose in the station frame.
    """
    offset = rng.uniform(-half_width_m, half_width_m, 3)
    offset[2] += distance_m + depth_m
    quaternion = rng.normal(size=4)
    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_quat(quaternion / np.linalg.norm(quaternion)).as_matrix()
    pose[:3, 3] = T_station_camera[:3, :3] @ offset + T_station_camera[:3, 3]
    return pose


def check(
    obj: AnomalyObject,
    pose: np.ndarray,
    T_station_camera: np.ndarray,
    intrinsics: CameraIntrinsics,
    occupancy: StationOccupancy,
    max_occluded_fraction: float,
    depth_m: float = 0.0,
) -> Candidate:
    """Apply the geometric placement rules to one candidate.

    Parameters
    ----------
    obj : AnomalyObject
        The object.
    pose : numpy.ndarray
        (4, 4) candidate object pose in the station frame.
    T_station_camera : numpy.ndarray
        (4, 4) camera pose the frame is rendered from.
    intrinsics : CameraIntrinsics
        The camera.
    occupancy : StationOccupancy
        The station.
    max_occluded_fraction : float
        Largest hidden fraction of the surface samples.
    depth_m : float
        Recorded in the result.

    Returns
    -------
    Candidate
        The candidate and the first rule it broke, if any.
    """
    camera_rotation, eye = T_station_camera[:3, :3], T_station_camera[:3, 3]
    centre = pose[:3, 3]
    optical = camera_rotation.T @ (centre - eye)
    k = intrinsics

    def result(reason: str, fraction: float = 0.0) -> Candidate:
        return Candidate(pose, depth_m, reason, fraction)

    if optical[2] <= 0:
        return result("frustum")
    u = k.fx * optical[0] / optical[2] + k.cx
    v = k.fy * optical[1] / optical[2] + k.cy
    if not (-0.5 <= u <= k.width - 0.5 and -0.5 <= v <= k.height - 0.5):
        return result("frustum")
    points = obj.surface_points @ pose[:3, :3].T + centre
    if np.min((points - eye) @ camera_rotation[:, 2]) < MIN_RANGE_M:
        return result("range")
    if occupancy.intersects(points):
        return result("station")
    stride = max(1, len(points) // _OCCLUSION_SAMPLES)
    tested = np.vstack([centre[None], points[::stride]])
    hidden = occupancy.occluded(eye, tested)
    fraction = float(np.mean(hidden[1:]))
    if hidden[0] or fraction > max_occluded_fraction:
        return result("occluded", fraction)
    return result("", fraction)
