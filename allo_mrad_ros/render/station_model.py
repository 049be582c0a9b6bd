"""Procedural Gateway-like station model, built deterministically from trimesh primitives.

The committed ``meshes/station.glb`` is the output of this module::

    python -m allo_mrad_ros.render.station_model --out meshes/station.glb

Station frame (metres): origin at the centre of the habitation module (HALO), x along the
module stack (power and propulsion element at -x, a docked crew vehicle at +x), y along the
solar-array wings, z towards the zenith docking port. The model is about 32 m x 43 m x 13 m.

The build is bit-identical from run to run on one machine: every vertex and normal is
quantised before export and the glTF JSON carries no mesh metadata. Another CPU may round
differently, so the test compares the rebuild's geometry with the committed file within a
stated tolerance (0.1 mm), not its bytes.
"""

from __future__ import annotations

import argparse
import hashlib
import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.render.primitives import (
    basis_with_z,
    box,
    cylinder,
    dish,
    frustum,
    placed,
    strut,
)

# Vertex positions are snapped to this grid (metres) so that last-bit differences in the
# trigonometry of the primitive generators cannot change the exported bytes.
POSITION_QUANTUM = 1e-5
NORMAL_QUANTUM = 1e-6
# Faces meeting at more than this angle get split normals (hard edges); less, smooth.
CREASE_ANGLE_RAD = math.radians(40.0)

# glTF metallic-roughness parameters: (base colour RGBA linear, metallic, roughness).
MATERIALS: dict[str, tuple[tuple[float, float, float, float], float, float]] = {
    "white_mli": ((0.86, 0.86, 0.84, 1.0), 0.0, 0.75),
    "gold_foil": ((0.95, 0.68, 0.28, 1.0), 1.0, 0.35),
    "solar_cells": ((0.04, 0.06, 0.16, 1.0), 0.4, 0.3),
    "bare_aluminium": ((0.78, 0.78, 0.80, 1.0), 1.0, 0.45),
    "dark_panel": ((0.06, 0.06, 0.07, 1.0), 0.0, 0.6),
    "radiator": ((0.93, 0.94, 0.95, 1.0), 0.0, 0.35),
    "handrail": ((0.85, 0.62, 0.08, 1.0), 0.1, 0.5),
}


class StationBuilder:
    """Collects primitives per (component, material) and exports one glTF binary."""

    def __init__(self) -> None:
        self._parts: dict[tuple[str, str], list[trimesh.Trimesh]] = {}

    def add(self, component: str, material: str, *meshes: trimesh.Trimesh) -> None:
        """Add meshes to a component, drawn with one of :data:`MATERIALS`."""
        if material not in MATERIALS:
            raise KeyError(f"unknown material {material!r}")
        self._parts.setdefault((component, material), []).extend(meshes)

    def truss(
        self, component: str, p0: Sequence[float], p1: Sequence[float], width: float, bay: float
    ) -> None:
        """Square lattice truss: four longerons, battens and one diagonal per face and bay."""
        p0 = np.asarray(p0, dtype=np.float64)
        p1 = np.asarray(p1, dtype=np.float64)
        rotation = basis_with_z(p1 - p0)
        half = width / 2.0
        corners = [
            rotation @ [sx * half, sy * half, 0.0]
            for sx, sy in ((-1, -1), (1, -1), (1, 1), (-1, 1))
        ]
        n_bays = max(1, round(np.linalg.norm(p1 - p0) / bay))
        stations = [p0 + (p1 - p0) * i / n_bays for i in range(n_bays + 1)]
        bars = [strut(p0 + c, p1 + c, 0.06) for c in corners]
        for i, s in enumerate(stations):
            for k in range(4):
                a, b = corners[k], corners[(k + 1) % 4]
                bars.append(strut(s + a, s + b, 0.04))
                if i < n_bays:
                    bars.append(strut(s + a, stations[i + 1] + b, 0.03))
        self.add(component, "bare_aluminium", *bars)

    def handrail(
        self,
        component: str,
        p0: Sequence[float],
        p1: Sequence[float],
        outward: Sequence[float],
        posts: int = 3,
    ) -> None:
        """EVA handrail from ``p0`` to ``p1`` standing 0.12 m off the surface along ``outward``."""
        p0 = np.asarray(p0, dtype=np.float64)
        p1 = np.asarray(p1, dtype=np.float64)
        lift = 0.12 * np.asarray(outward, dtype=np.float64) / np.linalg.norm(outward)
        bars = [strut(p0 + lift, p1 + lift, 0.035)]
        for i in range(posts):
            foot = p0 + (p1 - p0) * i / (posts - 1)
            bars.append(strut(foot, foot + lift, 0.03))
        self.add(component, "handrail", *bars)

    def scene(self) -> trimesh.Scene:
        """Return the station as a scene with one node per (component, material)."""
        materials = {
            name: PBRMaterial(
                name=name,
                baseColorFactor=colour,
                metallicFactor=metallic,
                roughnessFactor=roughness,
                doubleSided=False,
            )
            for name, (colour, metallic, roughness) in MATERIALS.items()
        }
        scene = trimesh.Scene()
        for (component, material), meshes in self._parts.items():
            shaded = [trimesh.graph.smooth_shade(m, angle=CREASE_ANGLE_RAD) for m in meshes]
            merged = trimesh.util.concatenate(shaded)
            vertices = np.round(merged.vertices / POSITION_QUANTUM) * POSITION_QUANTUM
            normals = np.round(merged.vertex_normals / NORMAL_QUANTUM) * NORMAL_QUANTUM
            vertices, normals, faces = _canonical_order(vertices, normals, merged.faces)
            # A fresh Trimesh drops the generators' metadata (it would land in glTF extras).
            clean = trimesh.Trimesh(
                vertices=vertices, faces=faces, vertex_normals=normals, process=False
            )
            clean.visual = trimesh.visual.TextureVisuals(material=materials[material])
            name = f"{component}_{material}"
            scene.add_geometry(clean, node_name=name, geom_name=name)
        return scene


def _canonical_order(
    vertices: np.ndarray, normals: np.ndarray, faces: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sort vertices and faces by value (stable sorts; winding kept), so the exported bytes
    depend on the geometry alone: trimesh's smooth shading orders ties by the CPU's SIMD
    sort kernels, and the committed file could not be rebuilt on another machine."""
    vertex_order = np.lexsort(np.column_stack([vertices, normals]).T[::-1])
    new_index = np.empty_like(vertex_order)
    new_index[vertex_order] = np.arange(len(vertex_order))
    faces = new_index[faces]
    first = np.argmin(faces, axis=1)  # rotate each face to start at its smallest index
    faces = faces[np.arange(len(faces))[:, None], (first[:, None] + np.arange(3)) % 3]
    return vertices[vertex_order], normals[vertex_order], faces[np.lexsort(faces.T[::-1])]


def _module_handrails(
    b: StationBuilder,
    component: str,
    x0: float,
    x1: float,
    radius: float,
    angles_deg: Sequence[float],
) -> None:
    for angle in np.radians(angles_deg):
        outward = np.array([0.0, math.cos(angle), math.sin(angle)])
        b.handrail(
            component,
            [x0, *(radius * outward[1:])],
            [x1, *(radius * outward[1:])],
            outward,
            posts=4,
        )


def _equipment_panels(
    b: StationBuilder,
    component: str,
    xs: Sequence[float],
    radius: float,
    angles_deg: Sequence[float],
    size: tuple[float, float],
) -> None:
    """Dark equipment/window panels lying on a cylindrical module."""
    for x, angle in zip(xs, np.radians(angles_deg), strict=True):
        outward = np.array([0.0, math.cos(angle), math.sin(angle)])
        panel = trimesh.creation.box(extents=[size[0], size[1], 0.08])
        rotation = np.column_stack([[1.0, 0.0, 0.0], np.cross(outward, [1.0, 0.0, 0.0]), outward])
        b.add(component, "dark_panel", placed(panel, rotation, [x, *(radius * outward[1:])]))


def _solar_wing(b: StationBuilder, side: int) -> None:
    """One roll-out solar-array wing of the power element along +-y, cells facing +z."""
    name = "ppe_wing_" + ("port" if side > 0 else "starboard")
    b.add(
        name, "bare_aluminium", cylinder([-6.0, side * 1.6, 0.0], [-6.0, side * 2.7, 0.0], 0.3, 20)
    )
    b.truss(name, [-6.0, side * 2.7, 0.0], [-6.0, side * 22.0, 0.0], 0.45, 1.2)
    y0, y1 = side * 3.0, side * 21.6
    for x0, x1 in ((-8.4, -6.35), (-5.65, -3.6)):
        b.add(
            name,
            "solar_cells",
            box([(x0 + x1) / 2, (y0 + y1) / 2, 0.0], [x1 - x0, abs(y1 - y0), 0.04]),
        )
        # Panel hinge lines and the blanket frame show as thin metal strips.
        for y in np.linspace(y0, y1, 13):
            b.add(name, "bare_aluminium", box([(x0 + x1) / 2, y, 0.0], [x1 - x0, 0.06, 0.05]))
    b.add(name, "bare_aluminium", box([-6.0, y1 + side * 0.2, 0.0], [5.0, 0.2, 0.15]))


def build_station() -> trimesh.Scene:
    """Build the Gateway-like station model.

    Returns
    -------
    trimesh.Scene
        One node per (component, material), seven PBR materials, metres, station frame.
    """
    b = StationBuilder()

    # HALO: habitation module at the origin with radial docking ports.
    b.add("halo", "white_mli", cylinder([-3.5, 0, 0], [3.5, 0, 0], 1.5, 40))
    for x in (-3.4, 0.0, 3.4):
        b.add("halo", "bare_aluminium", cylinder([x - 0.08, 0, 0], [x + 0.08, 0, 0], 1.56, 40))
    b.add(
        "halo",
        "bare_aluminium",
        cylinder([1.2, 0, -1.3], [1.2, 0, -2.4], 0.75, 28),
        cylinder([1.2, 0, -2.3], [1.2, 0, -2.45], 0.88, 28),
    )
    b.add("halo", "dark_panel", cylinder([1.2, 0, -2.45], [1.2, 0, -2.5], 0.55, 28))
    _module_handrails(b, "halo", -3.0, -0.3, 1.5, (35, 145, 270))
    _module_handrails(b, "halo", 0.3, 3.0, 1.5, (35, 145, 270))
    _equipment_panels(b, "halo", (-2.0, 1.8, -1.2, 2.2), 1.5, (90, 90, 215, 325), (1.1, 0.7))

    # Power and propulsion element: gold bus, radiators, thrusters and two solar wings.
    b.add("ppe", "bare_aluminium", frustum([-4.4, 0, 0], [-3.5, 0, 0], 1.2, 1.0, 32))
    b.add("ppe", "gold_foil", box([-6.0, 0, 0], [3.2, 3.2, 3.2]))
    for z in (-1.0, 1.0):
        b.add("ppe", "radiator", box([-6.0, 0, z * 1.62], [2.9, 2.9, 0.04]))
    for y in (-0.9, 0.9):
        for z in (-0.9, 0.9):
            b.add("ppe", "dark_panel", frustum([-7.6, y, z], [-8.3, y, z], 0.12, 0.35, 16))
    b.add("ppe", "dark_panel", box([-7.62, 0, 0], [0.04, 1.0, 1.0]))
    _solar_wing(b, +1)
    _solar_wing(b, -1)

    # Crew and science airlock on HALO's zenith port.
    b.add("airlock", "bare_aluminium", cylinder([-0.5, 0, 1.3], [-0.5, 0, 1.9], 0.75, 28))
    b.add("airlock", "white_mli", cylinder([-0.5, 0, 1.9], [-0.5, 0, 4.6], 1.0, 32))
    b.add("airlock", "bare_aluminium", cylinder([-0.5, 0, 4.6], [-0.5, 0, 4.85], 0.8, 28))
    b.add("airlock", "dark_panel", cylinder([-0.5, 0, 4.85], [-0.5, 0, 4.9], 0.55, 28))
    for angle in (0.0, 120.0, 240.0):
        a = math.radians(angle)
        outward = [math.cos(a), math.sin(a), 0.0]
        foot = np.array([-0.5 + 1.0 * math.cos(a), 1.0 * math.sin(a), 0.0])
        b.handrail("airlock", foot + np.array([0, 0, 2.2]), foot + np.array([0, 0, 4.3]), outward)

    # I-Hab: wider habitation module with radiators.
    b.add("ihab", "bare_aluminium", cylinder([3.5, 0, 0], [4.3, 0, 0], 0.8, 28))
    b.add(
        "ihab",
        "white_mli",
        frustum([4.3, 0, 0], [5.0, 0, 0], 0.9, 2.1, 48),
        cylinder([5.0, 0, 0], [10.0, 0, 0], 2.1, 48),
        frustum([10.0, 0, 0], [10.7, 0, 0], 2.1, 0.9, 48),
    )
    for x in (5.0, 7.5, 10.0):
        b.add("ihab", "bare_aluminium", cylinder([x - 0.08, 0, 0], [x + 0.08, 0, 0], 2.16, 48))
    for side in (-1.0, 1.0):
        b.add("ihab", "radiator", box([7.5, side * 2.75, 0.0], [4.2, 0.05, 2.6]))
        for x in (6.0, 9.0):
            b.add(
                "ihab", "bare_aluminium", strut([x, side * 2.05, 0.0], [x, side * 2.72, 0.0], 0.08)
            )
    _module_handrails(b, "ihab", 5.3, 7.2, 2.1, (50, 130, 240, 300))
    _module_handrails(b, "ihab", 7.8, 9.7, 2.1, (50, 130, 240, 300))
    _equipment_panels(b, "ihab", (6.2, 8.8, 6.2, 8.8), 2.1, (90, 90, 270, 270), (1.4, 0.9))

    # ESPRIT: gold-foil refuelling/communications module with two antenna dishes.
    b.add("esprit", "bare_aluminium", cylinder([10.7, 0, 0], [11.3, 0, 0], 0.8, 28))
    b.add("esprit", "gold_foil", cylinder([11.3, 0, 0], [14.5, 0, 0], 1.3, 36))
    b.add("esprit", "white_mli", cylinder([14.5, 0, 0], [14.7, 0, 0], 1.3, 36))
    b.add(
        "esprit",
        "bare_aluminium",
        cylinder([13.0, 0, 1.2], [13.0, 0, 3.0], 0.07, 12),
        cylinder([12.5, -1.2, 0], [12.5, -2.6, 0], 0.06, 12),
    )
    b.add(
        "esprit",
        "radiator",
        dish([13.0, 0, 3.0], [0.3, 0.0, 1.0], 1.0, 0.3),
        dish([12.5, -2.6, 0], [0.0, -1.0, 0.2], 0.6, 0.18),
    )
    _module_handrails(b, "esprit", 11.6, 14.2, 1.3, (150, 210))

    # A docked crew vehicle: capsule, service module, engine and four solar wings.
    b.add(
        "orion",
        "bare_aluminium",
        cylinder([14.7, 0, 0], [15.3, 0, 0], 0.75, 28),
        cylinder([15.2, 0, 0], [15.35, 0, 0], 0.9, 28),
    )
    b.add("orion", "bare_aluminium", frustum([15.35, 0, 0], [18.5, 0, 0], 0.9, 2.5, 40))
    b.add("orion", "dark_panel", cylinder([18.5, 0, 0], [18.75, 0, 0], 2.5, 40))
    b.add("orion", "white_mli", cylinder([18.75, 0, 0], [22.7, 0, 0], 2.0, 40))
    b.add("orion", "dark_panel", frustum([22.7, 0, 0], [23.9, 0, 0], 0.3, 0.65, 24))
    for angle in (45.0, 135.0, 225.0, 315.0):
        a = math.radians(angle)
        direction = np.array([0.0, math.cos(a), math.sin(a)])
        root = np.array([21.0, 0, 0]) + 2.0 * direction
        tip = root + 7.2 * direction
        normal = np.cross([1.0, 0.0, 0.0], direction)
        rotation = np.column_stack([[1.0, 0.0, 0.0], direction, normal])
        wing = trimesh.creation.box(extents=[1.9, 6.6, 0.04])
        b.add("orion", "solar_cells", placed(wing, rotation, root + 3.8 * direction))
        b.add(
            "orion",
            "bare_aluminium",
            strut(root, root + 0.5 * direction, 0.1),
            strut(tip - 0.1 * direction + [0.95, 0, 0], tip - 0.1 * direction - [0.95, 0, 0], 0.06),
        )
    return b.scene()


def export_glb(scene: trimesh.Scene) -> bytes:
    """Export a scene as glTF binary with vertex normals (bytes are deterministic)."""
    return scene.export(file_type="glb", include_normals=True)


def build_glb() -> bytes:
    """Build the station model and return the glTF binary bytes."""
    return export_glb(build_station())


def main(argv: Sequence[str] | None = None) -> int:
    """Command-line entry: write the station model and print its size, triangles and hash."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("meshes/station.glb"),
        help="output .glb path (default: meshes/station.glb)",
    )
    args = parser.parse_args(argv)
    scene = build_station()
    data = export_glb(scene)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_bytes(data)
    triangles = sum(len(g.faces) for g in scene.geometry.values())
    print(
        f"wrote {args.out}: {len(data)} bytes, {triangles} triangles, "
        f"{len(MATERIALS)} materials, sha256 {hashlib.sha256(data).hexdigest()}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
