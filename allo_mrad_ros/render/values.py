"""The renderer's input and output values (extra objects, render results) and their checks."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput

# Per-pixel classes, as in ALLO's masks.
LABEL_SPACE = 0
LABEL_STATION = 1  # the station and the celestial bodies
LABEL_ANOMALY = 2  # default class of extra objects


@dataclass(frozen=True)
class ExtraObject:
    """An object added for one render only, e.g. an anomaly placed by the generator.

    Parameters
    ----------
    mesh : trimesh.Trimesh or trimesh.Scene
        The object in its own frame, metres. Thin open sheets are fine: extra objects are
        always drawn two-sided.
    pose : array_like, shape (4, 4)
        Object frame in the station frame; rotation, translation and positive scale.
    label : int
        Class written to the label image (0..255, default :data:`LABEL_ANOMALY`).
    name : str
        Name in :attr:`RenderResult.instance_names` (default ``extra<i>``).
    """

    mesh: trimesh.Trimesh | trimesh.Scene
    pose: np.ndarray
    label: int = LABEL_ANOMALY
    name: str = ""


@dataclass(frozen=True)
class RenderResult:
    """One rendered reference frame.

    Attributes
    ----------
    rgb : numpy.ndarray
        (h, w, 3) uint8 image.
    depth : numpy.ndarray or None
        (h, w) float32 distance along the optical axis in metres, 0 where nothing was hit.
        Bodies pulled inside the far plane report their pulled distance.
    labels : numpy.ndarray or None
        (h, w) uint8 class per pixel: 0 space, 1 station and celestial bodies, extra objects
        their ``label`` (2 by default).
    instances : numpy.ndarray or None
        (h, w) int32 object index per pixel into :attr:`instance_names`.
    instance_names : tuple of str
        ``("space", "station", <bodies in view>..., <extra objects>...)``.
    bodies_in_view : tuple of str
        Names of the celestial bodies that intersected the frustum and were drawn.
    intrinsics : CameraIntrinsics
        The intrinsics of the output image (the input ones at the output scale).
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    labels: np.ndarray | None
    instances: np.ndarray | None
    instance_names: tuple[str, ...]
    bodies_in_view: tuple[str, ...]
    intrinsics: CameraIntrinsics


def finite_number(
    value: float, name: str, low: float = -math.inf, low_inclusive: bool = True
) -> float:
    """Return ``value`` as a finite float not below ``low`` (strictly above if exclusive)."""
    number = float(value)
    too_low = number < low if low_inclusive else number <= low
    if not math.isfinite(number) or too_low:
        bound = "" if low == -math.inf else f" and {'>=' if low_inclusive else '>'} {low}"
        raise InvalidInput(f"{name} must be finite{bound}, got {value!r}")
    return number


def unit_vector(value: object, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=np.float64)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise InvalidInput(f"{name} must be 3 finite numbers, got {value!r}")
    norm = float(np.linalg.norm(vector))
    if norm < 1e-12:
        raise InvalidInput(f"{name} must not be zero")
    return vector / norm


def object_pose(value: object, name: str) -> np.ndarray:
    """A finite 4x4 affine pose with positive determinant (scaling is allowed)."""
    pose = np.asarray(value, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise InvalidInput(f"{name} pose must be a finite 4x4 matrix")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]) or np.linalg.det(pose[:3, :3]) <= 0:
        raise InvalidInput(f"{name} pose must be affine with a positive determinant")
    return pose


def z_towards(direction: np.ndarray, position: np.ndarray | None = None) -> np.ndarray:
    """A pose whose local +z axis is ``direction`` (pyrender lights shine along -z)."""
    z = direction
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    if position is not None:
        pose[:3, 3] = position
    return pose


def segment_colour(index: int) -> np.ndarray:
    # 24-bit object index spread over RGB; the 8-bit colour buffer returns it exactly.
    return np.array([index & 0xFF, (index >> 8) & 0xFF, (index >> 16) & 0xFF], dtype=np.float64)
