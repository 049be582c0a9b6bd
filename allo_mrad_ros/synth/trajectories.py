"""Arm trajectories: smooth camera sweeps past objects at known places in the station frame.

A trajectory is an arm moving the camera for a few seconds: the eye travels along a straight
line while the point looked at drifts across the station, both following
``s(t) = (1 - cos(pi t / T)) / 2`` so the arm starts and stops at rest (as the node
benchmark's moving feed). Peak speeds are drawn per trajectory from
:attr:`TrajectoryConfig.speed_m_s` and :attr:`TrajectoryConfig.turn_deg_s`.

A trajectory either passes objects (``objects``: static or slowly drifting anomaly objects,
placed where the path sees them in front of the station, against space, or behind a module),
or shows none and makes the view-dependent trouble a single frame cannot tell from an
object: ``glare`` (the Sun at the edge of or in the view), ``bodies`` (the Earth or the Moon
in view), ``shadows`` (the Sun turning, so station shadows move).

Everything here is decided from the sequence seed before a frame is rendered, except what
depends on the station model, which :mod:`~.trajectory_frames` settles from the same seed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.trajectory_config import (
    NORMAL_SCENES,
    OBJECT_SCENE,
    PLACEMENTS,
    SCENES,
    TrajectoryConfig,
)

__all__ = [
    "NORMAL_SCENES",
    "OBJECT_SCENE",
    "PLACEMENTS",
    "SCENES",
    "TrajectoryConfig",
]

STREAM_TRAJECTORY = 8
"""Random stream of one trajectory's path and objects (after the frame streams of
:mod:`~.planning`)."""
# The light of every frame of a trajectory comes from this stream index (one draw per
# trajectory, so the query's Sun offset does not jump from frame to frame).
TRAJECTORY_LIGHT_OFFSET = 1 << 40


def ease(t: float, duration: float) -> float:
    """``s(t)`` in 0..1: at rest at ``t = 0`` and ``t = duration``."""
    return 0.5 * (1.0 - math.cos(math.pi * min(max(t / duration, 0.0), 1.0)))


@dataclass(frozen=True, eq=False)
class Sweep:
    """One trajectory's camera path: eye and look-at point move from start to end.

    Attributes
    ----------
    eye, target : numpy.ndarray
        (2, 3) start and end of the eye and of the point looked at, station frame.
    up : numpy.ndarray
        (3,) the image's up direction, kept along the path.
    """

    eye: np.ndarray
    target: np.ndarray
    up: np.ndarray

    def pose(self, s: float) -> np.ndarray:
        """The 4x4 optical-frame pose at path parameter ``s`` in 0..1."""
        eye = (1.0 - s) * self.eye[0] + s * self.eye[1]
        target = (1.0 - s) * self.target[0] + s * self.target[1]
        return look_at(eye, target, self.up)

    def poses(self, frames: int, rate_hz: float) -> list[np.ndarray]:
        """Poses at the frame times ``k / rate_hz``; the last frame ends the sweep."""
        duration = (frames - 1) / rate_hz
        return [self.pose(ease(k / rate_hz, duration)) for k in range(frames)]


def speeds(poses: list[np.ndarray], rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Linear (m/s) and angular (deg/s) speed between consecutive poses ``1 / rate_hz`` apart."""
    if len(poses) < 2:
        return np.zeros(1), np.zeros(1)
    stack = np.asarray(poses, dtype=np.float64)
    linear = np.linalg.norm(np.diff(stack[:, :3, 3], axis=0), axis=1) * rate_hz
    # The angle of the relative rotation R_k^T R_k+1, from its trace.
    relative = np.einsum("kji,kjl->kil", stack[:-1, :3, :3], stack[1:, :3, :3])
    cosine = np.clip((np.trace(relative, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return linear, np.degrees(np.arccos(cosine)) * rate_hz


def _unit(vector: np.ndarray) -> np.ndarray:
    return vector / np.linalg.norm(vector)


def _perpendicular(axis: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A random unit vector perpendicular to ``axis``."""
    while True:
        vector = np.cross(axis, rng.normal(size=3))
        if np.linalg.norm(vector) > 1e-6:
            return _unit(vector)


def turned_towards(start: np.ndarray, goal: np.ndarray, angle: float) -> np.ndarray:
    """The unit vector ``angle`` radians from ``start`` towards ``goal`` (``goal`` itself if
    it is nearer than that)."""
    start, goal = _unit(start), _unit(goal)
    between = math.acos(float(np.clip(start @ goal, -1.0, 1.0)))
    if between <= angle or between < 1e-9:
        return goal
    side = _unit(goal - (start @ goal) * start)
    return math.cos(angle) * start + math.sin(angle) * side


def make_sweep(
    eye: np.ndarray,
    axis: np.ndarray,
    distance: float,
    up: np.ndarray,
    duration_s: float,
    rng: np.random.Generator,
    speed_m_s: tuple[float, float],
    turn_deg_s: tuple[float, float],
) -> Sweep:
    """A sweep from ``eye`` looking along ``axis`` at a point ``distance`` ahead.

    The eye moves sideways (perpendicular to the view) by ``2 v T / pi`` for a peak speed
    ``v`` drawn from ``speed_m_s``; the look-at point moves so the view turns by
    ``2 w T / pi`` for a peak rate ``w`` drawn from ``turn_deg_s`` (the peak of the eased
    motion is ``pi / 2`` times its mean).
    """
    axis = _unit(np.asarray(axis, dtype=np.float64))
    travel = 2.0 * rng.uniform(*speed_m_s) * duration_s / math.pi
    turn = math.radians(2.0 * rng.uniform(*turn_deg_s) * duration_s / math.pi)
    step = _perpendicular(axis, rng) * travel
    end_axis = math.cos(turn) * axis + math.sin(turn) * _perpendicular(axis, rng)
    start_target = eye + distance * axis
    end_eye = eye + step
    end_target = end_eye + distance * end_axis
    # Keep the up direction away from the view axis (look_at needs them apart).
    up = np.asarray(up, dtype=np.float64)
    if abs(_unit(up) @ axis) > 0.9 or abs(_unit(up) @ _unit(end_axis)) > 0.9:
        up = _perpendicular(axis, rng)
    return Sweep(np.array([eye, end_eye]), np.array([start_target, end_target]), up)


def path_clear(occupancy: StationOccupancy, poses: list[np.ndarray], clearance_m: float) -> bool:
    """Whether every eye of the path keeps ``clearance_m`` from the station."""
    return all(occupancy.clearance(pose[:3, 3]) >= clearance_m for pose in poses)


def first_hit(
    occupancy: StationOccupancy, origin: np.ndarray, direction: np.ndarray, max_range: float
) -> float | None:
    """Distance along a ray to the first solid voxel of the station, or None (space)."""
    step = occupancy.pitch / 3.0
    t = np.arange(step, max_range, step)
    solid = occupancy.is_solid(origin + t[:, None] * direction)
    hits = np.flatnonzero(solid)
    return float(t[hits[0]]) if hits.size else None


def exit_after(
    occupancy: StationOccupancy,
    origin: np.ndarray,
    direction: np.ndarray,
    start: float,
    max_range: float,
) -> float | None:
    """Distance along a ray where it leaves the solid it is in at ``start``, or None."""
    step = occupancy.pitch / 3.0
    t = np.arange(start, max_range, step)
    solid = occupancy.is_solid(origin + t[:, None] * direction)
    free = np.flatnonzero(~solid)
    return float(t[free[0]]) if free.size else None


def plan_scenes(anomalous: int, normal: int, scenes: tuple[str, ...]) -> list[str]:
    """The scene of every trajectory of a split: ``objects`` ones first, then the normal
    scenes in turn."""
    return [OBJECT_SCENE] * anomalous + [scenes[i % len(scenes)] for i in range(normal)]
