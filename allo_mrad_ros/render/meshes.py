"""pyrender meshes and materials from the loaded model's groups and from celestial bodies."""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType

import numpy as np
import trimesh

from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.render.model import MeshGroup

# Icosphere subdivisions of body spheres: level 4 keeps the silhouette within 0.1 % of the
# radius (under a pixel for a Moon filling the image).
BODY_SUBDIVISIONS = 4


def material(pr: ModuleType, group: MeshGroup) -> object:
    """The pyrender material of one mesh group."""
    m = group.material
    if m is None:
        colour = (1.0, 1.0, 1.0, 1.0) if group.colours is not None else (0.5, 0.5, 0.5, 1.0)
        return pr.MetallicRoughnessMaterial(
            baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.8, alphaMode="OPAQUE"
        )
    colour = np.asarray(m.baseColorFactor if m.baseColorFactor is not None else [1.0] * 4)
    if np.issubdtype(colour.dtype, np.integer):
        colour = colour / 255.0
    return pr.MetallicRoughnessMaterial(
        name=m.name,
        baseColorFactor=colour,
        baseColorTexture=m.baseColorTexture if group.uv is not None else None,
        metallicFactor=1.0 if m.metallicFactor is None else float(m.metallicFactor),
        roughnessFactor=1.0 if m.roughnessFactor is None else float(m.roughnessFactor),
        emissiveFactor=m.emissiveFactor,
        alphaMode=m.alphaMode or "OPAQUE",
        # Two-sided parts already carry reversed faces (see model.load_model).
        doubleSided=False,
    )


def mesh_from_groups(pr: ModuleType, groups: Sequence[MeshGroup]) -> object:
    """A pyrender mesh with one primitive per group."""
    primitives = [
        pr.Primitive(
            positions=g.positions,
            normals=g.normals,
            texcoord_0=g.uv,
            color_0=g.colours,
            indices=g.faces,
            material=material(pr, g),
            mode=pr.constants.GLTF.TRIANGLES,
        )
        for g in groups
    ]
    return pr.Mesh(primitives=primitives)


def body_mesh(pr: ModuleType, body: CelestialBody) -> object:
    """A unit sphere mesh with the body's material (emissive for the Sun)."""
    colour = (*body.resolved_colour, 1.0)
    if body.is_emissive:
        material = pr.MetallicRoughnessMaterial(
            baseColorFactor=(0.0, 0.0, 0.0, 1.0),
            emissiveFactor=body.resolved_colour,
            metallicFactor=0.0,
            roughnessFactor=1.0,
            alphaMode="OPAQUE",
        )
    else:
        material = pr.MetallicRoughnessMaterial(
            baseColorFactor=colour,
            metallicFactor=0.0,
            roughnessFactor=1.0,
            alphaMode="OPAQUE",
        )
    sphere = trimesh.creation.icosphere(subdivisions=BODY_SUBDIVISIONS, radius=1.0)
    return pr.Mesh.from_trimesh(sphere, material=material, smooth=True)
