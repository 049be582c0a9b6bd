"""Closed mesh primitives placed in the station frame, for the procedural station model.

Each builds along +z and is placed with a deterministic basis (no SVD), so the station's
exported bytes do not depend on the platform's linear algebra.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh


def basis_with_z(axis: np.ndarray) -> np.ndarray:
    """Return a rotation whose z column is ``axis`` (deterministic, no SVD)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


def placed(mesh: trimesh.Trimesh, rotation: np.ndarray, origin: Sequence[float]) -> trimesh.Trimesh:
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = origin
    mesh.apply_transform(transform)
    return mesh


def _along(mesh: trimesh.Trimesh, p0: Sequence[float], p1: Sequence[float]) -> trimesh.Trimesh:
    """Place a mesh built along +z from z=0 to z=length onto the segment p0 -> p1."""
    p0 = np.asarray(p0, dtype=np.float64)
    return placed(mesh, basis_with_z(np.asarray(p1, dtype=np.float64) - p0), p0)


def cylinder(
    p0: Sequence[float], p1: Sequence[float], radius: float, sections: int = 32
) -> trimesh.Trimesh:
    """Closed cylinder from ``p0`` to ``p1``."""
    return frustum(p0, p1, radius, radius, sections)


def frustum(
    p0: Sequence[float], p1: Sequence[float], r0: float, r1: float, sections: int = 32
) -> trimesh.Trimesh:
    """Closed cone frustum from ``p0`` (radius ``r0``) to ``p1`` (radius ``r1``)."""
    length = float(np.linalg.norm(np.subtract(p1, p0)))
    profile = [[0.0, 0.0], [r0, 0.0], [r1, length], [0.0, length]]
    return _along(trimesh.creation.revolve(profile, sections=sections), p0, p1)


def box(centre: Sequence[float], extents: Sequence[float]) -> trimesh.Trimesh:
    """Axis-aligned box."""
    return placed(trimesh.creation.box(extents=extents), np.eye(3), centre)


def strut(p0: Sequence[float], p1: Sequence[float], width: float) -> trimesh.Trimesh:
    """Square-section bar from ``p0`` to ``p1`` (cheaper than a cylinder: 12 triangles)."""
    length = float(np.linalg.norm(np.subtract(p1, p0)))
    bar = trimesh.creation.box(extents=[width, width, length])
    bar.apply_translation([0.0, 0.0, length / 2.0])
    return _along(bar, p0, p1)


def dish(
    centre: Sequence[float], axis: Sequence[float], radius: float, depth: float
) -> trimesh.Trimesh:
    """Parabolic antenna dish (closed shell 4 cm thick) opening along ``axis``."""
    rho = np.linspace(0.0, radius, 7)
    front = np.column_stack([rho, depth * (rho / radius) ** 2])
    back = front[::-1] - [0.0, 0.04]
    profile = np.vstack([front, back, [[0.0, -0.04]]])
    mesh = trimesh.creation.revolve(profile[::-1], sections=32)
    return placed(mesh, basis_with_z(np.asarray(axis, dtype=np.float64)), centre)
