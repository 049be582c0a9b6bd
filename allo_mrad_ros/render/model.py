"""Load a station CAD model into a few GPU-friendly vertex groups, one per material.

pyrender issues one draw call (and binds all light uniforms from Python) per primitive, so a
CAD model with hundreds of parts would be slow to render. Loading bakes every node's
transform into its vertices and merges all parts that share a material.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial, SimpleMaterial

from allo_mrad_ros.errors import InvalidInput, one_line
from allo_mrad_ros.render.gltf_materials import DEFAULT_PARAMS, MaterialParams, lookup_for

_LOG = logging.getLogger(__name__)
# A station spanning more than this is probably in millimetres or centimetres.
_SUSPICIOUS_EXTENT_M = 2000.0

ModelSource = str | PathLike | trimesh.Trimesh | trimesh.Scene

MESH_FORMATS: dict[str, str] = {
    "glb": "glTF binary (GLB)",
    "gltf": "glTF",
    "obj": "OBJ",
    "stl": "STL",
    "ply": "PLY",
    "off": "OFF",
    "3mf": "3MF",
    "dae": "COLLADA (DAE)",
}
"""The model formats the documents list, by file suffix, with their names for messages.
What trimesh's readers of them import (a decoder of text that is not UTF-8, lxml, pycollada)
is declared on both install routes (test/render/test_mesh_formats.py checks it)."""


@dataclass(frozen=True)
class MeshGroup:
    """Triangles sharing one material, in the station frame.

    Attributes
    ----------
    name : str
        Material name (for logs).
    positions, normals : numpy.ndarray
        (n, 3) float32 vertex positions (metres) and unit normals.
    faces : numpy.ndarray
        (m, 3) uint32 vertex indices, counter-clockwise seen from outside.
    uv : numpy.ndarray or None
        (n, 2) float32 texture coordinates, if the material has textures.
    colours : numpy.ndarray or None
        (n, 4) float32 vertex colours in [0, 1], for models coloured per vertex or face.
    material : trimesh.visual.material.PBRMaterial or None
        The glTF metallic-roughness material; None for a default grey.
    tangents : numpy.ndarray or None
        (n, 4) float32 unit tangents (along increasing u) and the bitangent's sign, as
        glTF's ``TANGENT``; generated for materials with a normal map.
    params : MaterialParams
        What trimesh does not keep of the glTF material (normal scale, occlusion strength).
    """

    name: str
    positions: np.ndarray
    normals: np.ndarray
    faces: np.ndarray
    uv: np.ndarray | None
    colours: np.ndarray | None
    material: PBRMaterial | None
    tangents: np.ndarray | None = None
    params: MaterialParams = field(default=DEFAULT_PARAMS)


def vertex_tangents(
    positions: np.ndarray, normals: np.ndarray, uv: np.ndarray, faces: np.ndarray
) -> np.ndarray:
    """Per-vertex tangents (n, 4) from positions, normals and texture coordinates.

    Each triangle's direction of increasing u and v (Lengyel's method) is summed over the
    triangles sharing a vertex; the tangent is the u direction made orthogonal to the
    normal, and its fourth component, +1 or -1, the sign that makes
    ``cross(normal, tangent) * w`` follow increasing v (v counted up the image, as trimesh
    stores glTF's coordinates). A vertex whose triangles give no u direction (degenerate
    texture coordinates) gets any unit vector orthogonal to its normal.
    """
    p = np.asarray(positions, dtype=np.float64)
    n = np.asarray(normals, dtype=np.float64)
    t = np.asarray(uv, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    e1, e2 = p[f[:, 1]] - p[f[:, 0]], p[f[:, 2]] - p[f[:, 0]]
    d1, d2 = t[f[:, 1]] - t[f[:, 0]], t[f[:, 2]] - t[f[:, 0]]
    det = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    inverse = np.divide(1.0, det, out=np.zeros_like(det), where=np.abs(det) > 1e-20)
    u_dir = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) * inverse[:, None]
    v_dir = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) * inverse[:, None]
    u_sum = np.zeros_like(p)
    v_sum = np.zeros_like(p)
    for corner in range(3):
        np.add.at(u_sum, f[:, corner], u_dir)
        np.add.at(v_sum, f[:, corner], v_dir)
    tangent = u_sum - n * np.sum(n * u_sum, axis=1, keepdims=True)
    length = np.linalg.norm(tangent, axis=1)
    bad = length < 1e-12
    if bad.any():
        # Any direction orthogonal to the normal: the normal crossed with its least axis.
        axis = np.eye(3)[np.argmin(np.abs(n[bad]), axis=1)]
        tangent[bad] = np.cross(n[bad], axis)
        length[bad] = np.linalg.norm(tangent[bad], axis=1)
    tangent /= np.maximum(length, 1e-12)[:, None]
    sign = np.where(np.sum(np.cross(n, tangent) * v_sum, axis=1) < 0.0, -1.0, 1.0)
    return np.hstack([tangent, sign[:, None]])


def _material_of(mesh: trimesh.Trimesh) -> PBRMaterial | None:
    if mesh.visual.kind != "texture" or mesh.visual.material is None:
        return None
    material = mesh.visual.material
    if isinstance(material, SimpleMaterial):
        material = material.to_pbr()
    return material if isinstance(material, PBRMaterial) else None


def _part_arrays(mesh: trimesh.Trimesh, transform: np.ndarray, two_sided: bool) -> dict:
    """Vertex arrays of one placed part, flat-shaded where the file gave no normals, with
    tangents where its material has a normal map."""
    material = _material_of(mesh)
    kind = mesh.visual.kind
    uv = mesh.visual.uv if kind == "texture" and material is not None else None
    colours = None
    if kind == "vertex":
        colours = np.asarray(mesh.visual.vertex_colors, dtype=np.float32) / 255.0
    faces = np.asarray(mesh.faces, dtype=np.int64)
    # trimesh computes vertex normals lazily; only the cache tells whether the file had them.
    # glTF says a client must use flat normals when a mesh has none, and so do we.
    has_normals = "vertex_normals" in mesh._cache.cache
    if has_normals and kind != "face":
        positions = np.asarray(mesh.vertices, dtype=np.float64)
        normals = np.asarray(mesh.vertex_normals, dtype=np.float64)
    else:
        positions = np.asarray(mesh.vertices, dtype=np.float64)[faces].reshape(-1, 3)
        normals = np.repeat(np.asarray(mesh.face_normals, dtype=np.float64), 3, axis=0)
        uv = None if uv is None else np.asarray(uv)[faces].reshape(-1, 2)
        if kind == "face":
            colours = np.repeat(
                np.asarray(mesh.visual.face_colors, dtype=np.float32) / 255.0, 3, axis=0
            )
        elif colours is not None:
            colours = colours[faces].reshape(-1, colours.shape[1])
        faces = np.arange(len(positions), dtype=np.int64).reshape(-1, 3)
    rotation = transform[:3, :3]
    positions = positions @ rotation.T + transform[:3, 3]
    normals = normals @ np.linalg.inv(rotation)  # inverse-transpose, for scaled nodes too
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
    if np.linalg.det(rotation) < 0:  # a mirroring node flips the winding
        faces = faces[:, ::-1]
    tangents = None
    if uv is not None and getattr(material, "normalTexture", None) is not None:
        # Computed in the station frame, after the node's transform, so that a mirroring
        # node gives the mirrored handedness. trimesh does not read a file's TANGENT.
        tangents = vertex_tangents(positions, normals, uv, faces)
    if two_sided or (material is not None and material.doubleSided):
        # Both sides visible: add the reversed faces with flipped normals so that every
        # render pass (including the back-face-culled segmentation pass) sees them.
        n = len(positions)
        positions = np.vstack([positions, positions])
        normals = np.vstack([normals, -normals])
        faces = np.vstack([faces, faces[:, ::-1] + n])
        uv = None if uv is None else np.vstack([uv, uv])
        colours = None if colours is None else np.vstack([colours, colours])
        if tangents is not None:
            # glTF's back face reverses the whole tangent frame: tangent, bitangent, normal.
            tangents = np.vstack([tangents, -tangents])
    return {
        "positions": positions,
        "normals": normals,
        "faces": faces,
        "uv": uv,
        "colours": colours,
        "material": material,
        "tangents": tangents,
    }


def _as_scene(source: ModelSource) -> trimesh.Scene:
    if isinstance(source, trimesh.Scene):
        return source
    if isinstance(source, trimesh.Trimesh):
        return trimesh.Scene(source)
    path = Path(source)
    if not path.is_file():
        raise InvalidInput(f"station model file not found: {path}")
    suffix = path.suffix.lower().lstrip(".")
    if suffix not in trimesh.available_formats():
        known = ", ".join(MESH_FORMATS.values())
        raise InvalidInput(
            f"cannot load station model {path}: its suffix ({path.suffix or 'none'}) names "
            f"no model format read here ({known}, ...)"
        )
    label = format_name(path)
    if path.stat().st_size == 0:
        raise InvalidInput(f"cannot load station model {path}: the {label} file is empty")
    try:
        return trimesh.load(path, force="scene")
    except ImportError as error:  # a reader's dependency missing: the installation's fault
        missing = f"module {error.name!r} is missing" if error.name else one_line(error)
        raise InvalidInput(
            f"cannot load station model {path}: this installation cannot read {label} files "
            f"({missing}; install the package's requirements)"
        ) from error
    except Exception as error:  # trimesh raises many types for unreadable files
        raise InvalidInput(
            f"cannot load station model {path}: not a readable {label} file ({_reason(error)})"
        ) from error


def format_name(path: str | PathLike) -> str:
    """The name of a model file's format for messages, from its suffix (``OBJ``, ...)."""
    suffix = Path(path).suffix.lower().lstrip(".")
    return MESH_FORMATS.get(suffix, suffix.upper() or "model")


def _reason(error: BaseException) -> str:
    """What a reader said, on one line; its type where the text alone says little (a
    missing key or member names only the key)."""
    text = one_line(error)
    return text if " " in text else f"{type(error).__name__}: {text or 'no detail'}"


def _merge(name: str, parts: Sequence[dict]) -> MeshGroup:
    offsets = np.cumsum([0] + [len(p["positions"]) for p in parts[:-1]])
    uv = None
    if all(p["uv"] is not None for p in parts):
        uv = np.vstack([p["uv"] for p in parts]).astype(np.float32)
    colours = None
    if all(p["colours"] is not None for p in parts):
        colours = np.vstack([p["colours"] for p in parts]).astype(np.float32)
    tangents = None
    if all(p["tangents"] is not None for p in parts):
        tangents = np.vstack([p["tangents"] for p in parts]).astype(np.float32)
    return MeshGroup(
        name=name,
        positions=np.vstack([p["positions"] for p in parts]).astype(np.float32),
        normals=np.vstack([p["normals"] for p in parts]).astype(np.float32),
        faces=np.vstack([p["faces"] + o for p, o in zip(parts, offsets, strict=True)]).astype(
            np.uint32
        ),
        uv=uv,
        colours=colours,
        material=parts[0]["material"],
        tangents=tangents,
        params=parts[0]["params"],
    )


def load_model(
    sources: ModelSource | Iterable[ModelSource], two_sided: bool = False
) -> list[MeshGroup]:
    """Load one or more meshes/scenes and merge their parts by material.

    Parameters
    ----------
    sources : path, trimesh.Trimesh, trimesh.Scene, or a list of them
        Any format trimesh loads (glTF/GLB, OBJ, STL, PLY, ...), in metres, in the station
        frame. Scene node transforms are applied.
    two_sided : bool
        Make every part visible from both sides (thin sheets such as blankets), as glTF's
        ``doubleSided`` does per material: reversed copies of the faces are added.

    Returns
    -------
    list of MeshGroup
        One group per distinct material (plus one for vertex-coloured and one for untextured
        parts), in first-seen order.

    Raises
    ------
    InvalidInput
        If a file is missing or unreadable, the model contains no triangles, or all its
        vertices lie at one point (compressed geometry that did not decode).
    """
    if isinstance(sources, (str, PathLike, trimesh.Trimesh, trimesh.Scene)):
        sources = [sources]
    sources = list(sources)
    groups: dict[tuple, list[dict]] = {}
    names: dict[tuple, str] = {}
    for source in sources:
        scene = _as_scene(source)
        params_of = lookup_for(source if isinstance(source, (str, PathLike)) else None)
        for node in scene.graph.nodes_geometry:
            transform, geometry_name = scene.graph[node]
            mesh = scene.geometry[geometry_name]
            if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0:
                continue
            transform = np.asarray(transform, dtype=np.float64)
            if not np.all(np.isfinite(transform)) or not np.all(np.isfinite(mesh.vertices)):
                raise InvalidInput(f"station model part {geometry_name!r} has non-finite values")
            part = _part_arrays(mesh, transform, two_sided)
            material = part["material"]
            part["params"] = params_of(material)
            key = (
                None if material is None else hash(material),
                part["uv"] is not None,
                part["colours"] is not None,
                part["tangents"] is not None,
                part["params"],
            )
            groups.setdefault(key, []).append(part)
            names.setdefault(key, (material.name if material is not None else None) or "default")
    if not groups:
        files = [s for s in sources if isinstance(s, (str, PathLike))]
        if files:  # a reader that skips what it does not understand finds nothing in garbage
            read = ", ".join(f"{Path(f)} ({format_name(f)})" for f in files)
            raise InvalidInput(f"cannot load station model: no triangles in {read}")
        raise InvalidInput("station model contains no triangles")
    merged = [_merge(names[key], parts) for key, parts in groups.items()]
    extent = float(np.ptp(np.vstack([g.positions for g in merged]), axis=0).max())
    if not extent > 0.0:
        # trimesh leaves compressed geometry it cannot decode (glTF's Draco extension
        # without DracoPy) as zeros, with a warning only.
        raise InvalidInput(
            "station model's vertices all lie at one point: its geometry did not decode "
            "(a Draco-compressed glTF needs the DracoPy package, or export it uncompressed)"
        )
    if extent > _SUSPICIOUS_EXTENT_M:
        _LOG.warning("station model spans %.0f m: the renderer expects metres", extent)
    return merged
