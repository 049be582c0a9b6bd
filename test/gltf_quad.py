"""Small glTF binaries for the material tests, written by hand (struct + json).

A quad in the z = 0 plane, 2 m square, centred on the origin, facing +z; its texture
coordinates put the image's left column at x = -1 and its top row at y = +1, as glTF
counts them (v down the image). Textures are 8-bit PNGs made with Pillow.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np
from PIL import Image

QUAD_POSITIONS = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=np.float32)
QUAD_UV = np.array([[0, 1], [1, 1], [1, 0], [0, 0]], dtype=np.float32)
QUAD_FACES = np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint16)


def png(pixels: np.ndarray) -> bytes:
    """PNG bytes of an (h, w, c) uint8 array (c = 1, 3 or 4)."""
    pixels = np.asarray(pixels, dtype=np.uint8)
    mode = {1: "L", 3: "RGB", 4: "RGBA"}[pixels.shape[2]]
    out = io.BytesIO()
    Image.fromarray(pixels if pixels.shape[2] > 1 else pixels[..., 0], mode).save(out, "PNG")
    return out.getvalue()


def halves(left: tuple, right: tuple, size: int = 16) -> np.ndarray:
    """A size x size image whose left half is ``left`` and right half ``right``."""
    image = np.zeros((size, size, len(left)), dtype=np.uint8)
    image[:, : size // 2] = left
    image[:, size // 2 :] = right
    return image


def uniform(value: tuple, size: int = 8) -> np.ndarray:
    return np.tile(np.asarray(value, dtype=np.uint8), (size, size, 1))


class GlbWriter:
    """Collects buffer views, accessors, images and materials; writes one GLB."""

    def __init__(self) -> None:
        self.binary = bytearray()
        self.json: dict = {
            "asset": {"version": "2.0"},
            "scene": 0,
            "scenes": [{"nodes": []}],
            "nodes": [],
            "meshes": [],
            "materials": [],
            "accessors": [],
            "bufferViews": [],
        }

    def _view(self, data: bytes, target: int | None = None) -> int:
        while len(self.binary) % 4:
            self.binary.append(0)
        view = {"buffer": 0, "byteOffset": len(self.binary), "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        self.binary += data
        self.json["bufferViews"].append(view)
        return len(self.json["bufferViews"]) - 1

    def _accessor(self, array: np.ndarray, kind: str, target: int) -> int:
        component = {np.dtype(np.float32): 5126, np.dtype(np.uint16): 5123}[array.dtype]
        accessor = {
            "bufferView": self._view(array.tobytes(), target),
            "componentType": component,
            "count": int(array.shape[0] if kind != "SCALAR" else array.size),
            "type": kind,
        }
        if kind == "VEC3" and array.dtype == np.float32:
            accessor["min"] = array.min(axis=0).tolist()
            accessor["max"] = array.max(axis=0).tolist()
        self.json["accessors"].append(accessor)
        return len(self.json["accessors"]) - 1

    def texture(self, pixels: np.ndarray) -> int:
        """Add an image and a texture of it (default sampler); return the texture index."""
        image = {"bufferView": self._view(png(pixels)), "mimeType": "image/png"}
        self.json.setdefault("images", []).append(image)
        self.json.setdefault("textures", []).append({"source": len(self.json["images"]) - 1})
        return len(self.json["textures"]) - 1

    def material(self, material: dict) -> int:
        self.json["materials"].append(material)
        return len(self.json["materials"]) - 1

    def quad(
        self,
        material: int,
        *,
        offset: tuple = (0.0, 0.0, 0.0),
        normal: tuple = (0.0, 0.0, 1.0),
        extent: float = 1.0,
    ) -> None:
        """Add a quad node (``extent`` half-size, at ``offset``, vertex normal ``normal``)."""
        positions = (QUAD_POSITIONS * np.float32(extent) + np.float32(offset)).astype(np.float32)
        n = np.asarray(normal, dtype=np.float64)
        normals = np.tile(n / np.linalg.norm(n), (4, 1)).astype(np.float32)
        attributes = {
            "POSITION": self._accessor(positions, "VEC3", 34962),
            "NORMAL": self._accessor(normals, "VEC3", 34962),
            "TEXCOORD_0": self._accessor(QUAD_UV, "VEC2", 34962),
        }
        indices = self._accessor(QUAD_FACES.reshape(-1), "SCALAR", 34963)
        primitive = {"attributes": attributes, "indices": indices, "material": material}
        self.json["meshes"].append({"primitives": [primitive]})
        self.json["nodes"].append({"mesh": len(self.json["meshes"]) - 1})
        self.json["scenes"][0]["nodes"].append(len(self.json["nodes"]) - 1)

    def write(self, path: Path) -> Path:
        while len(self.binary) % 4:
            self.binary.append(0)
        self.json["buffers"] = [{"byteLength": len(self.binary)}]
        text = json.dumps(self.json).encode()
        text += b" " * (-len(text) % 4)
        total = 12 + 8 + len(text) + 8 + len(self.binary)
        data = struct.pack("<4sII", b"glTF", 2, total)
        data += struct.pack("<II", len(text), 0x4E4F534A) + text
        data += struct.pack("<II", len(self.binary), 0x004E4942) + bytes(self.binary)
        path.write_bytes(data)
        return path


def quad_file(path: Path, material: dict, textures: dict | None = None, **quad: object) -> Path:
    """A GLB of one quad whose material is ``material`` with ``textures`` (slot -> image;
    slots ``baseColorTexture`` and ``metallicRoughnessTexture`` go under
    ``pbrMetallicRoughness``; a value may be ``(image, extra texture-info fields)``)."""
    writer = GlbWriter()
    material = json.loads(json.dumps(material))
    for slot, image in (textures or {}).items():
        extra = {}
        if isinstance(image, tuple):
            image, extra = image
        info = {"index": writer.texture(image), **extra}
        if slot in ("baseColorTexture", "metallicRoughnessTexture"):
            material.setdefault("pbrMetallicRoughness", {})[slot] = info
        else:
            material[slot] = info
    writer.quad(writer.material(material), **quad)
    return writer.write(path)
