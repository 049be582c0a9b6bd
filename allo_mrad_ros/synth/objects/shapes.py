"""Mesh helpers for the procedural objects: tubes along paths, sheets, bent plates, placement.

Everything is plain NumPy on top of trimesh primitives; none of it needs trimesh's optional
dependencies (shapely, triangle, rtree), which the project does not install.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.maximum(np.linalg.norm(vectors, axis=-1, keepdims=True), 1e-12)


def basis_towards(axis: Sequence[float]) -> np.ndarray:
    """Return a rotation whose z column is ``axis`` (deterministic choice of x and y)."""
    z = _unit(np.asarray(axis, dtype=np.float64))
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = _unit(np.cross(helper, z))
    return np.column_stack([x, np.cross(z, x), z])


def transformed(
    mesh: trimesh.Trimesh,
    rotation: np.ndarray | None = None,
    translation: Sequence[float] = (0.0, 0.0, 0.0),
) -> trimesh.Trimesh:
    """Return a copy of ``mesh`` rotated about the origin, then translated."""
    matrix = np.eye(4)
    if rotation is not None:
        matrix[:3, :3] = rotation
    matrix[:3, 3] = translation
    copy = mesh.copy()
    copy.apply_transform(matrix)
    return copy


def rotation_about(axis: Sequence[float], angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` radians about ``axis`` (Rodrigues)."""
    k = _unit(np.asarray(axis, dtype=np.float64))
    cross = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * cross + (1.0 - np.cos(angle)) * cross @ cross


def rod(
    p0: Sequence[float], p1: Sequence[float], radius: float, sections: int = 12
) -> trimesh.Trimesh:
    """Closed cylinder from ``p0`` to ``p1``."""
    p0 = np.asarray(p0, dtype=np.float64)
    p1 = np.asarray(p1, dtype=np.float64)
    length = float(np.linalg.norm(p1 - p0))
    mesh = trimesh.creation.cylinder(radius=radius, height=length, sections=sections)
    return transformed(mesh, basis_towards(p1 - p0), (p0 + p1) / 2.0)


def slab(
    centre: Sequence[float], extents: Sequence[float], rotation: np.ndarray | None = None
) -> trimesh.Trimesh:
    """Closed box of ``extents`` centred at ``centre``, optionally rotated about its centre."""
    return transformed(trimesh.creation.box(extents=extents), rotation, centre)


def catmull_rom(points: np.ndarray, samples_per_segment: int = 12) -> np.ndarray:
    """Sample a centripetal-free (uniform) Catmull-Rom spline through ``points``.

    Parameters
    ----------
    points : numpy.ndarray
        (n, 3) control points, n >= 2; the curve passes through all of them.
    samples_per_segment : int
        Points per segment between consecutive control points.

    Returns
    -------
    numpy.ndarray
        (m, 3) points along the curve, from the first control point to the last.
    """
    p = np.asarray(points, dtype=np.float64)
    padded = np.vstack([2 * p[0] - p[1], p, 2 * p[-1] - p[-2]])
    t = np.linspace(0.0, 1.0, samples_per_segment, endpoint=False)[:, None]
    t2, t3 = t * t, t * t * t
    out = []
    for i in range(1, len(padded) - 2):
        p0, p1, p2, p3 = padded[i - 1], padded[i], padded[i + 1], padded[i + 2]
        out.append(
            0.5
            * (
                2 * p1
                + (p2 - p0) * t
                + (2 * p0 - 5 * p1 + 4 * p2 - p3) * t2
                + (3 * p1 - p0 - 3 * p2 + p3) * t3
            )
        )
    out.append(p[-1:])
    return np.vstack(out)


def tube(
    path: np.ndarray, radius: float | np.ndarray, sections: int = 12, caps: bool = True
) -> trimesh.Trimesh:
    """A tube of circular cross-section along a polyline (closed with flat caps).

    Frames are carried along the path by projection (no twist), so the tube follows tight
    curves without the flips of Frenet frames.

    Parameters
    ----------
    path : numpy.ndarray
        (n, 3) centre line, n >= 2, no repeated consecutive points.
    radius : float or numpy.ndarray
        Radius, constant or one per path point.
    sections : int
        Vertices around the circumference.
    caps : bool
        Close both ends (the result is watertight).

    Returns
    -------
    trimesh.Trimesh
        The tube, outward-facing.
    """
    path = np.asarray(path, dtype=np.float64)
    n = len(path)
    radii = np.broadcast_to(np.asarray(radius, dtype=np.float64), (n,))
    tangents = _unit(np.gradient(path, axis=0))
    normal = basis_towards(tangents[0])[:, 0]
    normals = np.empty_like(path)
    for i, t in enumerate(tangents):
        normal = _unit(normal - np.dot(normal, t) * t)
        normals[i] = normal
    binormals = np.cross(tangents, normals)
    angles = np.linspace(0.0, 2 * np.pi, sections, endpoint=False)
    ring = (
        np.cos(angles)[None, :, None] * normals[:, None]
        + np.sin(angles)[None, :, None] * (binormals[:, None])
    )
    vertices = (path[:, None] + radii[:, None, None] * ring).reshape(-1, 3)
    i = np.arange(n - 1)[:, None] * sections
    k = np.arange(sections)[None, :]
    a, b = i + k, i + (k + 1) % sections
    c, d = a + sections, b + sections
    faces = np.concatenate(
        [np.stack([a, c, d], -1).reshape(-1, 3), np.stack([a, d, b], -1).reshape(-1, 3)]
    )
    if caps:
        start, end = len(vertices), len(vertices) + 1
        vertices = np.vstack([vertices, path[0], path[-1]])
        ring0 = np.arange(sections)
        ring1 = ring0 + (n - 1) * sections
        faces = np.vstack(
            [
                faces,
                np.stack([np.full(sections, start), (ring0 + 1) % sections, ring0], -1),
                np.stack(
                    [np.full(sections, end), ring1, (ring0 + 1) % sections + (n - 1) * sections],
                    -1,
                ),
            ]
        )
    mesh = trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
    if caps and mesh.volume < 0:
        mesh.invert()
    return mesh


def grid_sheet(points: np.ndarray) -> trimesh.Trimesh:
    """An open sheet from a (nu, nv, 3) grid of vertices, two triangles per cell."""
    nu, nv, _ = points.shape
    index = np.arange(nu * nv).reshape(nu, nv)
    a, b = index[:-1, :-1].ravel(), index[1:, :-1].ravel()
    c, d = index[1:, 1:].ravel(), index[:-1, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], -1), np.stack([a, c, d], -1)])
    return trimesh.Trimesh(vertices=points.reshape(-1, 3), faces=faces, process=False)


def thick_sheet(points: np.ndarray, thickness: float) -> trimesh.Trimesh:
    """A closed plate from a (nu, nv, 3) grid: the sheet offset both ways along its normals.

    Suitable for gently curved grids (panels): both faces are the grid moved by half the
    thickness along the smoothed vertex normals, joined along the four borders.
    """
    sheet = grid_sheet(points)
    normals = np.asarray(sheet.vertex_normals)
    nu, nv, _ = points.shape
    half = thickness / 2.0
    top = sheet.vertices + half * normals
    bottom = sheet.vertices - half * normals
    vertices = np.vstack([top, bottom])
    offset = nu * nv
    faces = [sheet.faces, sheet.faces[:, ::-1] + offset]
    index = np.arange(nu * nv).reshape(nu, nv)
    border = np.concatenate([index[0, :], index[1:, -1], index[-1, -2::-1], index[-2:0:-1, 0]])
    nxt = np.roll(border, -1)
    faces.append(np.stack([border, nxt, nxt + offset], -1))
    faces.append(np.stack([border, nxt + offset, border + offset], -1))
    mesh = trimesh.Trimesh(vertices=vertices, faces=np.vstack(faces), process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def star_plate(radii: np.ndarray, rings: int, thickness: float) -> trimesh.Trimesh:
    """A closed, flat plate whose outline is star-shaped around the origin (xy plane).

    Parameters
    ----------
    radii : numpy.ndarray
        Outline radius at evenly spaced angles (any count >= 3).
    rings : int
        Concentric vertex rings, so that the plate can later be bent smoothly.
    thickness : float
        Extent along z, centred on z = 0.
    """
    count = len(radii)
    angles = np.linspace(0.0, 2 * np.pi, count, endpoint=False)
    fractions = np.linspace(0.0, 1.0, rings + 1)[1:]
    xy = fractions[:, None, None] * (
        radii[None, :, None] * np.stack([np.cos(angles), np.sin(angles)], -1)[None]
    )
    grid = np.concatenate([np.zeros((1, 2)), xy.reshape(-1, 2)])
    faces = [
        np.stack(
            [np.zeros(count, int), 1 + np.arange(count), 1 + (np.arange(count) + 1) % count], -1
        )
    ]
    for r in range(rings - 1):
        inner = 1 + r * count + np.arange(count)
        outer = inner + count
        inner_next = 1 + r * count + (np.arange(count) + 1) % count
        outer_next = inner_next + count
        faces.append(np.stack([inner, outer, outer_next], -1))
        faces.append(np.stack([inner, outer_next, inner_next], -1))
    top_faces = np.vstack(faces)
    n = len(grid)
    vertices = np.vstack(
        [
            np.column_stack([grid, np.full(n, thickness / 2)]),
            np.column_stack([grid, np.full(n, -thickness / 2)]),
        ]
    )
    rim = 1 + (rings - 1) * count + np.arange(count)
    rim_next = 1 + (rings - 1) * count + (np.arange(count) + 1) % count
    side = np.vstack(
        [np.stack([rim, rim + n, rim_next + n], -1), np.stack([rim, rim_next + n, rim_next], -1)]
    )
    mesh = trimesh.Trimesh(
        vertices=vertices,
        faces=np.vstack([top_faces, top_faces[:, ::-1] + n, side]),
        process=False,
    )
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def ellipsoid(radii: Sequence[float], subdivisions: int = 2) -> trimesh.Trimesh:
    """Closed ellipsoid with semi-axes ``radii`` centred at the origin."""
    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=1.0)
    mesh.apply_scale(np.asarray(radii, dtype=np.float64))
    return mesh


def random_unit(rng: np.random.Generator) -> np.ndarray:
    """A direction drawn uniformly on the sphere."""
    return _unit(rng.normal(size=3))
