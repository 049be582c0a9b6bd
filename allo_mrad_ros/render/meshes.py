"""pyrender meshes and materials from the loaded model's groups and from celestial bodies.

A group's glTF metallic-roughness material reaches pyrender whole: base colour,
metallic-roughness, normal, occlusion and emissive textures with their factors, the alpha
mode and cut-off. What pyrender's material has no field for (the normal map's scale, the
occlusion map's strength) rides on the material object as :data:`NORMAL_SCALE` and
:data:`OCCLUSION_STRENGTH` attributes; :mod:`.shader_patches` binds them.
"""

from __future__ import annotations

from collections.abc import Sequence
from types import ModuleType

import numpy as np
import trimesh

from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.render.model import MeshGroup

NORMAL_SCALE = "allo_normal_scale"
OCCLUSION_STRENGTH = "allo_occlusion_strength"
_TEXTURES = (
    "baseColorTexture",
    "metallicRoughnessTexture",
    "normalTexture",
    "occlusionTexture",
    "emissiveTexture",
)
# Icosphere subdivisions of body spheres: level 4 keeps the silhouette within 0.1 % of the
# radius (under a pixel for a Moon filling the image).
BODY_SUBDIVISIONS = 4


def texture_source(image: object) -> object:
    """A texture image as pyrender reads it right: 8-bit RGB(A) or grey, or floats in [0, 1].

    pyrender takes a PIL image's array as it is, so a palette image would give its indices,
    a grey-and-alpha image cannot fill RGB, and a 16-bit one would wrap around at 256.
    """
    from PIL import Image

    if not isinstance(image, Image.Image) or image.mode in ("RGB", "RGBA", "L"):
        return image
    if image.mode.startswith("I"):  # 16- or 32-bit integer grey: full scale is 65535
        return np.clip(np.asarray(image, dtype=np.float64) / 65535.0, 0.0, 1.0)
    if image.mode == "F":
        return np.clip(np.asarray(image, dtype=np.float64), 0.0, 1.0)
    return image.convert("RGBA")


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
    textures = {
        slot: texture_source(getattr(m, slot, None)) if group.uv is not None else None
        for slot in _TEXTURES
    }
    if group.tangents is None:
        textures["normalTexture"] = None  # no texture coordinates to build a frame from
    emissive = None
    if m.emissiveFactor is not None:
        emissive = np.asarray(m.emissiveFactor, dtype=np.float64)[:3]
        emissive = emissive * group.params.emissive_strength
    alpha_mode = str(m.alphaMode or "OPAQUE").upper()
    result = pr.MetallicRoughnessMaterial(
        name=m.name,
        baseColorFactor=colour,
        metallicFactor=1.0 if m.metallicFactor is None else float(m.metallicFactor),
        roughnessFactor=1.0 if m.roughnessFactor is None else float(m.roughnessFactor),
        emissiveFactor=emissive,
        alphaMode=alpha_mode if alpha_mode in ("OPAQUE", "MASK", "BLEND") else "OPAQUE",
        alphaCutoff=0.5 if m.alphaCutoff is None else float(m.alphaCutoff),
        # Two-sided parts already carry reversed faces (see model.load_model).
        doubleSided=False,
        **textures,
    )
    setattr(result, NORMAL_SCALE, float(group.params.normal_scale))
    setattr(result, OCCLUSION_STRENGTH, float(group.params.occlusion_strength))
    return result


def mesh_from_groups(pr: ModuleType, groups: Sequence[MeshGroup]) -> object:
    """A pyrender mesh with one primitive per group; blended groups are drawn last, over
    what is behind them."""
    primitives = []
    for g in groups:
        pr_material = material(pr, g)
        uses_normal_map = pr_material.normalTexture is not None
        primitives.append(
            pr.Primitive(
                positions=g.positions,
                normals=g.normals,
                tangents=g.tangents if uses_normal_map else None,
                texcoord_0=g.uv,
                color_0=g.colours,
                indices=g.faces,
                material=pr_material,
                mode=pr.constants.GLTF.TRIANGLES,
            )
        )
    primitives.sort(key=lambda p: p.material.alphaMode == "BLEND")
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
