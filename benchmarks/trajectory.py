"""Camera paths for the node benchmark: an arm moving the camera smoothly, or holding it.

A camera feed at 30-60 Hz cannot render full-HD images as it publishes them, so the
benchmark renders one short segment of the path ahead and plays it back and forth
(ping-pong). The path parameter follows ``s(t) = (1 - cos(pi t / T)) / 2`` over the
segment's ``T`` seconds: it starts and ends at rest, so the segment played forwards, then
backwards, then forwards again is exactly this smooth motion continued for ever (poses and
velocities continuous, no jump at a turn). Every published image is the render of the pose
published with it, as a real camera's image matches its arm's TF.

The moving path is an arm's slow sweep: the camera travels along an arc around the station
and climbs a little while its look-at target drifts across the station, within
:data:`MAX_LINEAR_M_S` and :data:`MAX_ANGULAR_DEG_S` (checked when the segment is built).
The still path holds one pose.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.synth.trajectories import ease, speeds

# Fastest motion of the arm camera the benchmark drives the node with.
MAX_LINEAR_M_S = 0.3
MAX_ANGULAR_DEG_S = 5.0
TRAJECTORIES = ("moving", "still")
# The benchmark's camera pose when still, and the start of the moving path.
START_EYE = (-30.0, -12.0, 6.0)
START_TARGET = (0.0, 0.0, 0.0)
# Seconds of path rendered ahead and played back and forth.
SEGMENT_S = 3.0


@dataclass(frozen=True)
class ArmSweep:
    """One segment of the moving path, as functions of the path parameter ``s`` in 0..1.

    Parameters
    ----------
    arc_m : float
        Distance the camera travels along a horizontal arc around the station's z axis.
    climb_m : float
        Height the camera gains over the segment.
    target_drift : tuple of float
        Displacement of the look-at target over the segment (metres, station frame).
    """

    arc_m: float = 0.5
    climb_m: float = 0.12
    target_drift: tuple[float, float, float] = (2.7, -4.8, 1.5)

    def pose(self, s: float) -> np.ndarray:
        """The camera's 4x4 optical-frame pose at path parameter ``s``."""
        x, y, z = START_EYE
        radius = math.hypot(x, y)
        angle = math.atan2(y, x) + s * self.arc_m / radius
        eye = (radius * math.cos(angle), radius * math.sin(angle), z + s * self.climb_m)
        target = np.asarray(START_TARGET) + s * np.asarray(self.target_drift)
        return look_at(eye, target)


def segment_poses(
    kind: str, rate_hz: float, segment_s: float = SEGMENT_S, sweep: ArmSweep | None = None
) -> list[np.ndarray]:
    """The poses of one segment at the frame times ``k / rate_hz``, ``k = 0 .. n - 1``.

    ``moving``: ``n - 1 = round(segment_s * rate_hz)`` frames of travel, first and last at
    rest, to be played with :func:`ping_pong`. ``still``: one pose.

    Raises
    ------
    ValueError
        For an unknown ``kind``, a non-positive rate or segment, or a sweep faster than
        :data:`MAX_LINEAR_M_S` or :data:`MAX_ANGULAR_DEG_S` between two frames.
    """
    if kind not in TRAJECTORIES:
        raise ValueError(f"trajectory must be one of {list(TRAJECTORIES)}, got {kind!r}")
    if not (rate_hz > 0 and segment_s > 0):
        raise ValueError(f"rate and segment must be positive, got {rate_hz} Hz, {segment_s} s")
    if kind == "still":
        return [look_at(START_EYE, START_TARGET)]
    sweep = sweep or ArmSweep()
    steps = max(1, round(segment_s * rate_hz))
    poses = [sweep.pose(ease(k / rate_hz, steps / rate_hz)) for k in range(steps + 1)]
    linear, angular = speeds(poses, rate_hz)
    if linear.max() > MAX_LINEAR_M_S or angular.max() > MAX_ANGULAR_DEG_S:
        raise ValueError(
            f"the sweep moves at up to {linear.max():.3f} m/s and {angular.max():.2f} deg/s; "
            f"the arm's limits are {MAX_LINEAR_M_S} m/s and {MAX_ANGULAR_DEG_S} deg/s"
        )
    return poses


def ping_pong(index: int, count: int) -> int:
    """The segment frame shown as the ``index``-th frame: 0, 1, .., count-1, count-2, .., 1,
    0, 1, ...; with one frame always 0."""
    if count <= 1:
        return 0
    period = 2 * (count - 1)
    phase = index % period
    return phase if phase < count else period - phase


def top_speed_path(
    start: np.ndarray,
    frames: int,
    rate_hz: float,
    max_deg_s: float,
    max_m_s: float,
    rng: np.random.Generator,
) -> list[np.ndarray]:
    """``frames`` camera poses from ``start`` of an arm always at its top speeds.

    The angular velocity (camera frame, ``max_deg_s``) and the linear velocity (station
    frame, ``max_m_s``) keep their magnitudes and turn smoothly at a random pace: the worst
    case for reference reuse, which the reuse accuracy bench measures on.
    """
    dt = 1.0 / rate_hz
    spin_axis, move_axis = rng.normal(size=3), rng.normal(size=3)
    spin_turn, move_turn = rng.normal(size=3), rng.normal(size=3)
    pace = rng.uniform(0.2, 0.6)
    pose = start.copy()
    poses = [pose.copy()]
    for index in range(1, frames):
        phase = pace * index * dt
        spin = _unit_vector(spin_axis + math.sin(phase) * spin_turn)
        move = _unit_vector(move_axis + math.sin(phase) * move_turn)
        rotation, _ = cv2.Rodrigues(spin * math.radians(max_deg_s) * dt)
        pose[:3, :3] = pose[:3, :3] @ rotation
        pose[:3, 3] = pose[:3, 3] + move * max_m_s * dt
        poses.append(pose.copy())
    return poses


def _unit_vector(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)
