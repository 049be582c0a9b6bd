"""Procedural outposts: station models of other layouts and materials than ``station.glb``.

The path-traced bench (``make bench-pt``) needs stations no one tuned on, and no external
station model is reachable from the machines that build it. These three layouts share no
module, material or proportion with the package's Gateway-like station:

* ``hub``: a spherical node with four radial modules in a cross and a long truss across it
  carrying four solar arrays and two radiators;
* ``spine``: five modules of different radii stacked along one axis, a perpendicular truss
  with two arrays, a radiator mast and a dish;
* ``ring``: six short modules on a ring around a central mast, with a boom of arrays.

``textured=True`` writes every material the way a CAD or DCC export does (the closest
stand-in here for a real export): factors of 1 and the values in maps, a base-colour texture
with panel artwork, a metallic-roughness texture whose metallic channel marks blankets and
paint as dielectric under a metallic factor of 1, a normal map of panel seams and an
occlusion map; UVs by a box projection in metres. Flat (``textured=False``), each material
is factors only.

Usage::

    python -m allo_mrad_ros.render.outpost_model hub --out data/stations_pt/outpost_hub.glb
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.errors import InvalidInput, lookup
from allo_mrad_ros.render.primitives import box, cylinder, dish, frustum, strut

# (base colour linear RGB, metallic, roughness): none of station_model's materials.
MATERIALS: dict[str, tuple[tuple[float, float, float], float, float]] = {
    "beta_cloth": ((0.70, 0.64, 0.50), 0.0, 0.85),
    "grey_paint": ((0.42, 0.43, 0.45), 0.0, 0.5),
    "copper_kapton": ((0.62, 0.30, 0.12), 0.9, 0.3),
    "violet_cells": ((0.07, 0.04, 0.20), 0.3, 0.25),
    "black_paint": ((0.03, 0.03, 0.03), 0.0, 0.4),
    "anodised": ((0.55, 0.57, 0.60), 1.0, 0.3),
    "white_radiator": ((0.80, 0.82, 0.84), 0.0, 0.6),
}
LAYOUTS = ("hub", "spine", "ring")
TEXTURE_SIZE = 128
TILE_M = 1.5
"""Size of one texture tile (one panel), metres."""
_SEAM = 4  # texels of a panel seam


class OutpostError(InvalidInput):
    """An unknown layout."""


Parts = dict[str, list[trimesh.Trimesh]]


def _add(parts: Parts, material: str, *meshes: trimesh.Trimesh) -> None:
    parts.setdefault(material, []).extend(meshes)


def _truss(parts: Parts, p0: Sequence[float], p1: Sequence[float], width: float) -> None:
    """A triangular truss of three longerons with battens every ``width``."""
    p0, p1 = np.asarray(p0, float), np.asarray(p1, float)
    axis = (p1 - p0) / np.linalg.norm(p1 - p0)
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(axis, helper)
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    corners = [width * (math.cos(a) * u + math.sin(a) * v) for a in (0.0, 2.1, 4.2)]
    bars = [strut(p0 + c, p1 + c, 0.08) for c in corners]
    bays = max(1, round(np.linalg.norm(p1 - p0) / (2 * width)))
    for i in range(bays + 1):
        at = p0 + (p1 - p0) * i / bays
        bars += [strut(at + corners[k], at + corners[(k + 1) % 3], 0.05) for k in range(3)]
    _add(parts, "grey_paint", *bars)


def _array(parts: Parts, centre: Sequence[float], along: int, size: tuple[float, float]) -> None:
    """A flat solar array in the plane z = const, its long side along axis ``along``."""
    extents = [0.0, 0.0, 0.05]
    extents[along], extents[1 - along] = size[0], size[1]
    _add(parts, "violet_cells", box(centre, extents))
    frame = list(extents)
    frame[1 - along] = 0.12
    frame[2] = 0.08
    for side in (-0.5, 0.5):
        c = np.asarray(centre, float).copy()
        c[1 - along] += side * size[1]
        _add(parts, "anodised", box(c, frame))


def _hub(parts: Parts) -> None:
    _add(parts, "copper_kapton", trimesh.creation.icosphere(subdivisions=3, radius=2.2))
    for direction in ((0, 1, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1)):
        d = np.asarray(direction, float)
        _add(parts, "anodised", cylinder(1.9 * d, 2.6 * d, 1.0, 28))
        _add(parts, "beta_cloth", cylinder(2.6 * d, 8.6 * d, 1.6, 36))
        _add(parts, "black_paint", cylinder(8.6 * d, 8.75 * d, 0.9, 28))
    _truss(parts, (-15.0, 0.0, 0.0), (15.0, 0.0, 0.0), 0.6)
    for x in (-12.0, 12.0):
        for y in (-4.0, 4.0):
            _array(parts, (x, y, 0.0), 1, (7.0, 3.0))
    for x in (-5.5, 5.5):
        _add(parts, "white_radiator", box((x, 0.0, 2.4), (3.0, 0.06, 4.0)))
    _add(parts, "grey_paint", cylinder((0.0, 0.0, 8.75), (0.0, 0.0, 10.5), 0.08, 10))
    _add(parts, "white_radiator", dish((0.0, 0.0, 10.5), (0.0, 0.4, 1.0), 1.2, 0.35))


def _spine(parts: Parts) -> None:
    x = -12.0
    for length, radius, material in (
        (4.0, 1.2, "beta_cloth"),
        (6.0, 2.0, "grey_paint"),
        (3.0, 1.4, "copper_kapton"),
        (7.0, 1.8, "beta_cloth"),
        (3.5, 1.0, "anodised"),
    ):
        _add(parts, material, cylinder((x, 0, 0), (x + length, 0, 0), radius, 36))
        _add(
            parts,
            "black_paint",
            cylinder((x + length - 0.1, 0, 0), (x + length, 0, 0), radius + 0.05, 36),
        )
        x += length
    _add(parts, "anodised", frustum((x, 0, 0), (x + 1.5, 0, 0), 1.0, 0.4, 24))
    _truss(parts, (-3.0, -16.0, 0.0), (-3.0, 16.0, 0.0), 0.5)
    for y in (-11.0, 11.0):
        _array(parts, (-3.0, y, 0.0), 1, (9.0, 4.0))
    _add(parts, "grey_paint", strut((6.0, 0.0, 1.8), (6.0, 0.0, 8.0), 0.15))
    for z in (3.5, 5.5, 7.5):
        _add(parts, "white_radiator", box((6.0, 0.0, z), (0.06, 3.5, 1.6)))
    _add(parts, "white_radiator", dish((-9.0, 0.0, -1.3), (0.0, -0.3, -1.0), 1.0, 0.3))


def _ring(parts: Parts) -> None:
    _add(parts, "grey_paint", cylinder((0, 0, -6.0), (0, 0, 6.0), 0.7, 24))
    _add(parts, "copper_kapton", cylinder((0, 0, -1.0), (0, 0, 1.0), 1.4, 32))
    for k in range(6):
        a = 2 * math.pi * k / 6
        d = np.array([math.cos(a), math.sin(a), 0.0])
        tangent = np.array([-math.sin(a), math.cos(a), 0.0])
        _add(parts, "anodised", strut(1.4 * d, 6.0 * d, 0.25))
        centre = 7.0 * d
        material = "beta_cloth" if k % 2 else "white_radiator"
        _add(parts, material, cylinder(centre - 1.8 * tangent, centre + 1.8 * tangent, 1.1, 28))
    _truss(parts, (0.0, 0.0, 6.0), (0.0, 0.0, 16.0), 0.45)
    for z in (10.0, 14.0):
        for x in (-4.5, 4.5):
            _add(parts, "violet_cells", box((x, 0.0, z), (7.0, 0.05, 3.0)))
    _add(parts, "black_paint", cylinder((0, 0, -6.2), (0, 0, -6.0), 1.0, 24))


_LAYOUTS: dict[str, Callable[[Parts], None]] = {"hub": _hub, "spine": _spine, "ring": _ring}


def box_projection_uv(mesh: trimesh.Trimesh, tile_m: float) -> trimesh.Trimesh:
    """A copy with one vertex per face corner and UVs from the face's dominant axis, in
    tiles of ``tile_m`` metres; the smooth normals are kept."""
    faces = np.asarray(mesh.faces)
    normals = np.asarray(mesh.vertex_normals)[faces].reshape(-1, 3)
    vertices = np.asarray(mesh.vertices)[faces].reshape(-1, 3)
    axis = np.argmax(np.abs(mesh.face_normals), axis=1).repeat(3)
    others = np.array([[1, 2], [0, 2], [0, 1]])[axis]
    uv = np.take_along_axis(vertices, others, axis=1) / tile_m
    return trimesh.Trimesh(
        vertices=vertices,
        faces=np.arange(len(vertices)).reshape(-1, 3),
        vertex_normals=normals,
        visual=trimesh.visual.TextureVisuals(uv=uv),
        process=False,
    )


def material_maps(
    name: str, rng: np.random.Generator
) -> tuple[Image.Image, Image.Image, Image.Image, Image.Image]:
    """Base colour (sRGB), metallic-roughness (G roughness, B metallic), normal and occlusion
    maps of one material: panel artwork with seams and per-panel variation."""
    colour, metallic, roughness = MATERIALS[name]
    n = TEXTURE_SIZE
    y, x = np.mgrid[0:n, 0:n]
    seam = (np.minimum(x % (n // 2), y % (n // 2)) < _SEAM // 2) | (x < _SEAM // 2)
    panel = (x // (n // 2)) * 2 + (y // (n // 2))
    gains = np.exp(rng.normal(0.0, 0.08, 4))[panel]
    blotch = np.exp(0.06 * rng.standard_normal((n, n)))
    linear = np.clip(np.asarray(colour)[None, None] * (gains * blotch)[..., None], 0.0, 1.0)
    linear[seam] *= 0.55
    base = np.clip(255.0 * linear ** (1 / 2.2), 0, 255).astype(np.uint8)
    rough = np.clip(roughness + rng.normal(0.0, 0.05, 4)[panel], 0.02, 1.0)
    rough[seam] = min(1.0, roughness + 0.2)
    mr = np.zeros((n, n, 3), np.uint8)
    mr[..., 1] = np.round(255 * rough)
    mr[..., 2] = np.round(255 * metallic)
    mr[seam, 2] = 0  # seams are painted: dielectric, whatever the panel
    normal = np.zeros((n, n, 3), np.uint8)
    normal[...] = (128, 128, 255)
    gx = np.gradient(seam.astype(float), axis=1)
    gy = np.gradient(seam.astype(float), axis=0)
    normal[..., 0] = np.clip(128 - 90 * gx, 0, 255)
    normal[..., 1] = np.clip(128 + 90 * gy, 0, 255)
    occlusion = np.full((n, n, 3), 255, np.uint8)
    occlusion[seam] = 150
    return tuple(Image.fromarray(a) for a in (base, mr, normal, occlusion))


def build_outpost(layout: str, textured: bool = False, seed: int = 0) -> trimesh.Scene:
    """Build one outpost.

    Parameters
    ----------
    layout : str
        One of :data:`LAYOUTS`.
    textured : bool
        Materials in texture maps with factors of 1 (see the module's description).
    seed : int
        Seed of the texture artwork.

    Returns
    -------
    trimesh.Scene
        One node per material, metres.

    Raises
    ------
    OutpostError
        For an unknown layout.
    """
    build = lookup(_LAYOUTS, layout, what="outpost layout", error=OutpostError)
    parts: Parts = {}
    build(parts)
    rng = np.random.default_rng(seed)
    scene = trimesh.Scene()
    for material in sorted(parts):
        merged = trimesh.util.concatenate(
            [trimesh.graph.smooth_shade(m, angle=math.radians(40.0)) for m in parts[material]]
        )
        colour, metallic, roughness = MATERIALS[material]
        if textured:
            mesh = box_projection_uv(merged, TILE_M)
            base, mr, normal, occlusion = material_maps(material, rng)
            pbr = PBRMaterial(
                name=material,
                baseColorFactor=(1.0, 1.0, 1.0, 1.0),
                baseColorTexture=base,
                metallicFactor=1.0,
                roughnessFactor=1.0,
                metallicRoughnessTexture=mr,
                normalTexture=normal,
                occlusionTexture=occlusion,
                doubleSided=False,
            )
            mesh.visual = trimesh.visual.TextureVisuals(uv=mesh.visual.uv, material=pbr)
        else:
            mesh = trimesh.Trimesh(
                vertices=merged.vertices,
                faces=merged.faces,
                vertex_normals=merged.vertex_normals,
                process=False,
            )
            mesh.visual = trimesh.visual.TextureVisuals(
                material=PBRMaterial(
                    name=material,
                    baseColorFactor=(*colour, 1.0),
                    metallicFactor=metallic,
                    roughnessFactor=roughness,
                    doubleSided=False,
                )
            )
        scene.add_geometry(mesh, node_name=material, geom_name=material)
    return scene


def main(argv: Sequence[str] | None = None) -> int:
    """Write one outpost as glTF binary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("layout", choices=LAYOUTS)
    parser.add_argument("--textured", action="store_true", help="materials in texture maps")
    parser.add_argument("--out", type=Path, required=True, help="output .glb")
    args = parser.parse_args(argv)
    scene = build_outpost(args.layout, args.textured)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_bytes(scene.export(file_type="glb", include_normals=True))
    print(f"wrote {args.out}: {sum(len(g.faces) for g in scene.geometry.values())} triangles")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
