"""What a glTF file's materials say that trimesh's reader drops.

trimesh keeps each glTF material's factors, textures, alpha mode and cut-off, and
``doubleSided``, but not the parameters of the texture references: the normal map's
``scale``, the occlusion map's ``strength``, a texture's ``texCoord`` set, or extensions.
This module reads them from the file's JSON (GLB or ``.gltf``) and matches each glTF
material to the trimesh material it became, by name and the values trimesh kept.

Extensions the renderer does not honour are named once per file in a warning: a model
whose look depends on them renders without them.
"""

from __future__ import annotations

import json
import logging
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

import numpy as np
from trimesh.visual.material import PBRMaterial

_LOG = logging.getLogger(__name__)

_GLB_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A
TEXTURE_SLOTS = (
    "baseColorTexture",
    "metallicRoughnessTexture",
    "normalTexture",
    "occlusionTexture",
    "emissiveTexture",
)
"""The glTF material slots that hold a texture, in the specification's order."""
HONOURED_EXTENSIONS: dict[str, str] = {
    "KHR_materials_emissive_strength": "multiplies the emissive factor",
    "KHR_draco_mesh_compression": "decoded by trimesh (needs DracoPy)",
    "EXT_texture_webp": "read by trimesh",
}
"""glTF extensions whose effect the renderer keeps; every other one is ignored, with a
warning naming the file and the extension."""
_APPROXIMATED = {
    "KHR_materials_pbrSpecularGlossiness": (
        "converted to metallic-roughness by trimesh, approximately"
    ),
}
# (file, extension) pairs already warned about: once per process.
_WARNED: set[tuple[str, str]] = set()


@dataclass(frozen=True)
class MaterialParams:
    """The parts of a glTF material trimesh does not keep.

    Attributes
    ----------
    normal_scale : float
        ``normalTexture.scale``: multiplies the X and Y of the sampled tangent-space normal.
    occlusion_strength : float
        ``occlusionTexture.strength``: 0 no occlusion, 1 the full map.
    emissive_strength : float
        ``KHR_materials_emissive_strength``: multiplies the emissive factor.
    """

    normal_scale: float = 1.0
    occlusion_strength: float = 1.0
    emissive_strength: float = 1.0


DEFAULT_PARAMS = MaterialParams()


def read_header(path: str | PathLike) -> dict | None:
    """The JSON of a ``.glb`` or ``.gltf`` file, or None (another format, or unreadable:
    trimesh's reader then says what is wrong)."""
    path = Path(path)
    suffix = path.suffix.lower()
    try:
        if suffix == ".gltf":
            header = json.loads(path.read_text(encoding="utf-8"))
        elif suffix == ".glb":
            with path.open("rb") as stream:
                head = stream.read(20)
                if len(head) < 20 or head[:4] != _GLB_MAGIC:
                    return None
                length, kind = struct.unpack("<II", head[12:20])
                if kind != _JSON_CHUNK:
                    return None
                header = json.loads(stream.read(length).decode("utf-8"))
        else:
            return None
    except (OSError, UnicodeDecodeError, ValueError):
        return None
    return header if isinstance(header, dict) else None


def _number(value: object, default: float) -> float:
    try:
        number = float(value)
    except (TypeError, ValueError):
        return default
    return number if np.isfinite(number) else default


def _params(material: dict) -> MaterialParams:
    normal = material.get("normalTexture") or {}
    occlusion = material.get("occlusionTexture") or {}
    extensions = material.get("extensions") or {}
    emissive = extensions.get("KHR_materials_emissive_strength") or {}
    return MaterialParams(
        normal_scale=_number(normal.get("scale", 1.0), 1.0),
        occlusion_strength=min(max(_number(occlusion.get("strength", 1.0), 1.0), 0.0), 1.0),
        emissive_strength=max(_number(emissive.get("emissiveStrength", 1.0), 1.0), 0.0),
    )


def _slots(material: dict) -> dict[str, dict]:
    pbr = material.get("pbrMetallicRoughness") or {}
    found = {}
    for slot in TEXTURE_SLOTS:
        info = pbr.get(slot) if slot in ("baseColorTexture", "metallicRoughnessTexture") else None
        info = info if info is not None else material.get(slot)
        if isinstance(info, dict):
            found[slot] = info
    return found


def ignored_features(header: dict) -> list[str]:
    """What the file uses that the renderer ignores, one phrase each, in file order."""
    used = list(header.get("extensionsUsed") or [])
    for material in header.get("materials") or []:
        used += list((material.get("extensions") or {}).keys())
        for info in _slots(material).values():
            used += list((info.get("extensions") or {}).keys())
    found: list[str] = []
    for name in dict.fromkeys(str(u) for u in used):
        if name in HONOURED_EXTENSIONS:
            continue
        how = _APPROXIMATED.get(name, "ignored")
        found.append(f"extension {name} ({how})")
    for material in header.get("materials") or []:
        for info in _slots(material).values():
            if int(_number(info.get("texCoord", 0), 0)) != 0:
                phrase = "texture coordinate sets other than the first (the first is used)"
                if phrase not in found:
                    found.append(phrase)
    return found


def warn_ignored(path: str | PathLike, header: dict) -> None:
    """Log, once per file and feature, what the file uses that the renderer ignores."""
    for feature in ignored_features(header):
        key = (str(path), feature)
        if key not in _WARNED:
            _WARNED.add(key)
            _LOG.warning("station model %s: glTF %s", path, feature)


def _signature_of_gltf(material: dict) -> tuple:
    pbr = material.get("pbrMetallicRoughness") or {}
    return (
        material.get("name"),
        str(material.get("alphaMode", "OPAQUE")),
        frozenset(_slots(material)),
        tuple(_number(c, 1.0) for c in pbr.get("baseColorFactor", (1.0, 1.0, 1.0, 1.0))),
        _number(pbr.get("metallicFactor", 1.0), 1.0),
        _number(pbr.get("roughnessFactor", 1.0), 1.0),
    )


def _matches(signature: tuple, material: PBRMaterial) -> bool:
    name, mode, slots, colour, metallic, roughness = signature
    if material.name != name or (material.alphaMode or "OPAQUE") != mode:
        return False
    if frozenset(s for s in TEXTURE_SLOTS if getattr(material, s, None) is not None) != slots:
        return False
    # trimesh stores the base colour as 8-bit: compare within one level.
    kept = material.baseColorFactor
    kept = np.ones(4) if kept is None else np.asarray(kept, dtype=np.float64)
    if kept.dtype.kind != "f" or kept.max() > 1.0:
        kept = kept / 255.0
    want = np.resize(np.asarray(colour, dtype=np.float64), 4)
    if kept.shape != (4,) or np.abs(kept - want).max() > 1.0 / 255.0 + 1e-9:
        return False
    kept_m = 1.0 if material.metallicFactor is None else float(material.metallicFactor)
    kept_r = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
    return abs(kept_m - metallic) < 1e-6 and abs(kept_r - roughness) < 1e-6


class ParamsLookup:
    """The :class:`MaterialParams` of the trimesh materials read from one glTF file."""

    def __init__(self, path: str | PathLike, header: dict | None) -> None:
        self._path = str(path)
        self._entries: list[tuple[tuple, MaterialParams]] = []
        for material in (header or {}).get("materials") or []:
            if isinstance(material, dict):
                self._entries.append((_signature_of_gltf(material), _params(material)))

    def __call__(self, material: PBRMaterial | None) -> MaterialParams:
        """The parameters of ``material``; the defaults if it matches no glTF material, or
        several with different parameters (a warning says so)."""
        if material is None or not self._entries:
            return DEFAULT_PARAMS
        found = {params for signature, params in self._entries if _matches(signature, material)}
        if len(found) == 1:
            return found.pop()
        if len(found) > 1:
            key = (self._path, f"ambiguous:{material.name}")
            if key not in _WARNED:
                _WARNED.add(key)
                _LOG.warning(
                    "station model %s: glTF materials named %r differ only in normal scale, "
                    "occlusion strength or emissive strength; the defaults are used",
                    self._path,
                    material.name,
                )
        return DEFAULT_PARAMS


def lookup_for(path: str | PathLike | None) -> ParamsLookup:
    """The parameter lookup of a model file (warning once about what it ignores); for a
    trimesh object, or a file of another format, one that gives the defaults."""
    if path is None:
        return ParamsLookup("", None)
    header = read_header(path)
    if header is not None:
        warn_ignored(path, header)
    return ParamsLookup(path, header)


def slots_of(material: PBRMaterial | None) -> Iterable[str]:
    """The texture slots ``material`` fills."""
    if material is None:
        return ()
    return tuple(s for s in TEXTURE_SLOTS if getattr(material, s, None) is not None)
