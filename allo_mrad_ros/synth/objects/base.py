"""Parts, materials and the built :class:`AnomalyObject` shared by every object family."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

# glTF metallic-roughness: (linear base colour RGB, metallic, roughness).
MATERIALS: dict[str, tuple[tuple[float, float, float], float, float]] = {
    "gold_foil": ((0.95, 0.68, 0.28), 1.0, 0.35),
    "silver_foil": ((0.90, 0.90, 0.92), 1.0, 0.25),
    "white_cloth": ((0.85, 0.85, 0.82), 0.0, 0.9),
    "white_paint": ((0.80, 0.80, 0.78), 0.0, 0.55),
    "black_cable": ((0.05, 0.05, 0.05), 0.0, 0.5),
    "orange_cable": ((0.90, 0.35, 0.05), 0.0, 0.55),
    "grey_plastic": ((0.35, 0.36, 0.38), 0.0, 0.6),
    "black_plastic": ((0.06, 0.06, 0.07), 0.0, 0.5),
    "yellow_plastic": ((0.90, 0.70, 0.05), 0.0, 0.5),
    "green_plastic": ((0.10, 0.45, 0.15), 0.0, 0.5),
    "dark_metal": ((0.22, 0.22, 0.24), 1.0, 0.4),
    "aluminium": ((0.80, 0.80, 0.82), 1.0, 0.35),
    "blue_anodised": ((0.10, 0.25, 0.70), 0.8, 0.35),
    "solar_cells": ((0.04, 0.06, 0.20), 0.4, 0.3),
    "rubber": ((0.10, 0.10, 0.10), 0.0, 0.9),
    "handrail_yellow": ((0.85, 0.62, 0.08), 0.1, 0.5),
    "carbon": ((0.08, 0.08, 0.09), 0.2, 0.4),
    # A dark tinted visor: a dielectric (specular reflectance 4 %) of very low roughness,
    # so nearly all it sends back is a sharp highlight of the lights.
    "visor_black": ((0.02, 0.02, 0.025), 0.0, 0.06),
    # Black Kapton, a blanket's outer layer: 3 % albedo, a soft sheen.
    "black_kapton": ((0.03, 0.03, 0.03), 0.0, 0.35),
}

# ALLO's colour variants recolour an object; these are the named colours used.
COLOURS: dict[str, tuple[float, float, float]] = {
    "red": (0.75, 0.06, 0.05),
    "orange": (0.90, 0.40, 0.05),
    "yellow": (0.90, 0.80, 0.10),
    "green": (0.10, 0.55, 0.15),
    "blue": (0.08, 0.20, 0.75),
    "white": (0.90, 0.90, 0.90),
    "black": (0.04, 0.04, 0.04),
    "grey": (0.45, 0.45, 0.47),
}
DEFAULT_COLOUR = "default"
# Faces meeting at more than this angle keep a hard edge when smooth-shaded.
CREASE_ANGLE_RAD = math.radians(35.0)
# Spacing of the surface samples used for the placement checks (metres).
SAMPLE_SPACING_M = 0.04


@dataclass(frozen=True, eq=False)
class Part:
    """One mesh of an object and how to draw it.

    Attributes
    ----------
    mesh : trimesh.Trimesh
        Closed (watertight) solid or open sheet, metres, object frame.
    material : str
        A key of :data:`MATERIALS`.
    smooth : bool
        Smooth-shade across edges below :data:`CREASE_ANGLE_RAD` (curved surfaces).
    """

    mesh: trimesh.Trimesh
    material: str
    smooth: bool = False

    def __post_init__(self) -> None:
        if self.material not in MATERIALS:
            raise KeyError(f"unknown material {self.material!r}")


def _pbr(name: str, colour: tuple[float, float, float] | None) -> PBRMaterial:
    base, metallic, roughness = MATERIALS[name]
    rgb = base if colour is None else colour
    return PBRMaterial(
        name=name if colour is None else f"{name}_variant",
        baseColorFactor=(*rgb, 1.0),
        metallicFactor=metallic,
        roughnessFactor=roughness,
        doubleSided=True,
    )


def _render_mesh(part: Part) -> trimesh.Trimesh:
    mesh = part.mesh
    if part.smooth:
        shaded = trimesh.graph.smooth_shade(mesh, angle=CREASE_ANGLE_RAD)
        # Passing the normals in puts them in trimesh's cache, which the renderer takes as
        # "the file has normals"; without them it flat-shades (the glTF rule).
        return trimesh.Trimesh(
            vertices=shaded.vertices,
            faces=shaded.faces,
            vertex_normals=shaded.vertex_normals,
            process=False,
        )
    return trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces, process=False)


def sample_triangles(triangles: np.ndarray, spacing: float) -> np.ndarray:
    """Deterministic samples of triangles: a barycentric lattice, at most ``spacing`` apart.

    Parameters
    ----------
    triangles : numpy.ndarray
        (m, 3, 3) triangle corners.
    spacing : float
        Largest gap between neighbouring samples along a triangle edge, positive.

    Returns
    -------
    numpy.ndarray
        (n, 3) points, including every corner.
    """
    triangles = np.asarray(triangles, dtype=np.float64)
    edges = np.linalg.norm(triangles - np.roll(triangles, 1, axis=1), axis=2).max(axis=1)
    steps = np.maximum(1, np.ceil(edges / spacing).astype(int))
    points = [triangles.reshape(-1, 3)]
    for n in np.unique(steps):
        if n == 1:
            continue
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        weights = np.stack([i[keep], j[keep], n - i[keep] - j[keep]], -1) / n
        points.append(np.matmul(weights[None], triangles[steps == n]).reshape(-1, 3))
    return np.vstack(points)


def sample_surface(mesh: trimesh.Trimesh, spacing: float) -> np.ndarray:
    """Deterministic surface samples of a mesh (see :func:`sample_triangles`)."""
    return sample_triangles(np.asarray(mesh.triangles), spacing)


@dataclass(frozen=True, eq=False)
class AnomalyObject:
    """A built anomaly object, centred on its bounding box, in metres.

    Attributes
    ----------
    kind : str
        Object type name (a key of :data:`~allo_mrad_ros.synth.objects.ANOMALY_TYPES`).
    seed : int
        Seed it was built from; the same kind, seed and colour give the same object.
    colour : str
        ``default`` or a key of :data:`COLOURS` that recoloured its main (first) part.
    parts : tuple of Part
        The meshes and their materials.
    scale : float
        Size factor applied to the built object (ALLO's scale variant).
    """

    kind: str
    seed: int
    colour: str
    parts: tuple[Part, ...]
    scale: float = 1.0

    @cached_property
    def mesh(self) -> trimesh.Trimesh:
        """All parts as one mesh (geometry only)."""
        return trimesh.util.concatenate([p.mesh for p in self.parts])

    @cached_property
    def scene(self) -> trimesh.Scene:
        """The object for the renderer: one node per part, with its PBR material."""
        scene = trimesh.Scene()
        for i, part in enumerate(self.parts):
            mesh = _render_mesh(part)
            recolour = COLOURS.get(self.colour) if i == 0 else None
            mesh.visual = trimesh.visual.TextureVisuals(material=_pbr(part.material, recolour))
            scene.add_geometry(mesh, node_name=f"{self.kind}_{i}", geom_name=f"{self.kind}_{i}")
        return scene

    @property
    def extents(self) -> np.ndarray:
        """Bounding-box size (x, y, z) in metres."""
        return np.asarray(self.mesh.extents, dtype=np.float64)

    @cached_property
    def radius(self) -> float:
        """Radius of the bounding sphere about the origin (the bounding-box centre)."""
        return float(np.linalg.norm(self.mesh.vertices, axis=1).max())

    @cached_property
    def surface_points(self) -> np.ndarray:
        """(n, 3) surface samples at most :data:`SAMPLE_SPACING_M` apart, object frame."""
        return np.vstack([sample_surface(p.mesh, SAMPLE_SPACING_M) for p in self.parts])
