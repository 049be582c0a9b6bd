"""Surfaces the CAD model does not have: the as-built station and worn anomaly objects.

A CAD export gives each material one flat colour; a real station's panels differ from batch
to batch, are stained, wrinkled and seamed, and an object lost during an EVA is worn. Only
the query is rendered from these surfaces; the reference keeps the nominal model.

* :func:`as_built_station` - every part gets its own material: the material's colour and
  roughness drawn once per sequence (``material_variation``), a per-part colour gain
  (``part_variation``) and a procedural albedo texture (``texture_contrast``) with panel
  seams, mapped by a box projection in metres;
* :func:`worn_object` - an anomaly object with a per-part colour gain and the same kind of
  texture, mapped over the object's own size.
"""

from __future__ import annotations

from os import PathLike

import numpy as np
import trimesh
from PIL import Image
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.render.gltf_materials import TEXTURE_SLOTS
from allo_mrad_ros.synth.realism_config import RealismConfig
from allo_mrad_ros.synth.validation import SynthError

TEXTURE_SIZE = 256
"""Texels along one side of a texture tile."""
_SEAM_WIDTH = 0.012  # of a tile: about 2.5 cm at the 2 m default


def procedural_texture(
    rng: np.random.Generator, contrast: float, seam_darkening: float = 0.0
) -> np.ndarray:
    """A tileable albedo texture, linear relative albedo with mean 1.

    Two noise layers: blotches with a 1/f**3 power spectrum (stains, fading, wrinkles over
    tens of centimetres) and a finer 1/f layer at half the strength (weave, grain), in log
    albedo, so the texture stays positive. Seams darken the tile's edges.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of the noise.
    contrast : float
        Standard deviation of the log albedo, >= 0.
    seam_darkening : float
        Relative albedo loss along the tile's edges, in [0, 1).

    Returns
    -------
    numpy.ndarray
        (TEXTURE_SIZE, TEXTURE_SIZE) float64, mean 1, wrapping seamlessly.
    """
    if not 0.0 <= contrast <= 1.0 or not 0.0 <= seam_darkening < 1.0:
        raise SynthError(f"bad texture settings: contrast {contrast}, seams {seam_darkening}")
    n = TEXTURE_SIZE
    f = np.hypot(*np.meshgrid(np.fft.fftfreq(n), np.fft.fftfreq(n), indexing="ij"))
    f[0, 0] = np.inf  # no mean in the noise
    log_albedo = np.zeros((n, n))
    for exponent, weight in ((3.0, 1.0), (1.0, 0.5)):
        spectrum = np.fft.fft2(rng.standard_normal((n, n))) * np.maximum(f, 1.0 / n) ** (
            -exponent / 2
        )
        spectrum[0, 0] = 0.0
        layer = np.real(np.fft.ifft2(spectrum))
        log_albedo += weight * layer / max(float(layer.std()), 1e-12)
    log_albedo *= contrast / max(float(log_albedo.std()), 1e-12)
    albedo = np.exp(log_albedo)
    if seam_darkening > 0:
        u = (np.arange(n) + 0.5) / n
        edge = np.minimum(u, 1.0 - u) < _SEAM_WIDTH
        seam = edge[:, None] | edge[None, :]
        albedo[seam] *= 1.0 - seam_darkening
    return albedo / albedo.mean()


def _material(
    name: str,
    colour: np.ndarray,
    roughness: float,
    metallic: float | None,
    texture: np.ndarray | None,
    double_sided: bool | None,
) -> PBRMaterial:
    """A PBR material whose albedo is ``colour * texture`` (linear), within glTF's [0, 1]."""
    image = None
    factor = np.clip(colour, 0.0, 1.0)
    if texture is not None:
        # The colour is baked into the (sRGB) texture and the factor left at 1, so only the
        # brightest texels of a bright material clip, not the whole part.
        linear = np.clip(texture[..., None] * np.asarray(colour)[None, None], 0.0, 1.0)
        srgb = np.where(linear <= 0.0031308, 12.92 * linear, 1.055 * linear ** (1 / 2.4) - 0.055)
        image = Image.fromarray(np.rint(255.0 * srgb).astype(np.uint8), mode="RGB")
        factor = np.ones(3)
    return PBRMaterial(
        name=name,
        baseColorFactor=(*factor, 1.0),
        baseColorTexture=image,
        metallicFactor=metallic,
        roughnessFactor=roughness,
        doubleSided=double_sided,
    )


def box_uv(
    mesh: trimesh.Trimesh, tile: float, offset: np.ndarray
) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Split a mesh per face corner and project each face on its dominant axis plane.

    Parameters
    ----------
    mesh : trimesh.Trimesh
        The part. Normals it was given (smooth shading) are kept per corner; without them
        the faces stay flat, as the renderer draws such a mesh.
    tile : float
        Length one texture tile covers, in the mesh's units.
    offset : numpy.ndarray
        (2,) texture offset, in tiles (so parts do not share the same patch).

    Returns
    -------
    mesh : trimesh.Trimesh
        The mesh with three vertices per face.
    uv : numpy.ndarray
        (3 * faces, 2) texture coordinates.
    """
    faces = np.asarray(mesh.faces)
    corners = np.asarray(mesh.vertices)[faces].reshape(-1, 3)
    axis = np.argmax(np.abs(np.asarray(mesh.face_normals)), axis=1)
    drop = np.repeat(axis, 3)
    keep = np.array([[1, 2], [0, 2], [0, 1]])[drop]
    uv = np.take_along_axis(corners, keep, axis=1) / tile + offset
    # trimesh keeps normals read from a file only in its cache (the renderer's rule too).
    if "vertex_normals" in mesh._cache.cache:
        normals = np.asarray(mesh.vertex_normals)[faces].reshape(-1, 3)
    else:
        normals = np.repeat(np.asarray(mesh.face_normals), 3, axis=0)
    split = trimesh.Trimesh(
        vertices=corners,
        faces=np.arange(len(corners)).reshape(-1, 3),
        vertex_normals=normals,
        process=False,
    )
    return split, uv


def _log_gain(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Per-channel colour gain: half the log variance shared (brightness), half per channel."""
    shared = rng.normal(0.0, sigma / np.sqrt(2.0))
    return np.exp(shared + rng.normal(0.0, sigma / np.sqrt(2.0), 3))


def as_built_station(
    model: str | PathLike[str] | trimesh.Scene, rng: np.random.Generator, realism: RealismConfig
) -> trimesh.Scene:
    """The station as built: varied materials, per-part colour shifts, albedo texture.

    Parameters
    ----------
    model : path or trimesh.Scene
        The CAD model (as the renderer takes it).
    rng : numpy.random.Generator
        Source of randomness (materials in name order, then parts in name order).
    realism : RealismConfig
        ``material_variation``, ``part_variation``, ``texture_contrast``,
        ``texture_tile_m`` and ``seam_darkening``; ``enabled=False`` returns the model.

    Returns
    -------
    trimesh.Scene
        A new scene (the model itself when realism is off); the input is not modified.
        Parts without a PBR material keep theirs; textured parts (a real CAD export's
        artwork) keep their texture and UVs and vary only in colour factor and roughness.
    """
    source = model if isinstance(model, trimesh.Scene) else trimesh.load(model, force="scene")
    if not isinstance(source, trimesh.Scene):
        raise SynthError(f"cannot load the station model {model!r} as a scene")
    if not realism.enabled:
        return source
    scene = source.copy()
    amount = realism.material_variation
    nominal: dict[str, tuple[np.ndarray, float]] = {}
    for name in sorted(source.geometry):
        material = getattr(getattr(source.geometry[name], "visual", None), "material", None)
        if isinstance(material, PBRMaterial) and material.name not in nominal:
            nominal[material.name] = _drawn(material, rng, amount)
    for name in sorted(source.geometry):
        mesh = source.geometry[name]  # the original: a copy loses the file's normals
        material = getattr(getattr(mesh, "visual", None), "material", None)
        if not isinstance(material, PBRMaterial):
            continue  # vertex-coloured or plain parts keep their look
        colour, roughness = nominal[material.name]
        colour = colour * _log_gain(rng, realism.part_variation)
        if any(getattr(material, slot, None) is not None for slot in TEXTURE_SLOTS):
            # A textured part of a real CAD export keeps its own textures and UVs: the
            # model's artwork (and its metallic-roughness, normal, occlusion and emissive
            # maps) is what the station looks like; only its colour factor varies.
            scene.geometry[name] = _retinted(mesh, material, colour, roughness, name)
            continue
        texture = None
        if realism.texture_contrast > 0:
            texture = procedural_texture(rng, realism.texture_contrast, realism.seam_darkening)
        mesh, uv = box_uv(mesh, realism.texture_tile_m, rng.random(2))
        mesh.visual = trimesh.visual.TextureVisuals(
            uv=uv,
            material=_material(
                f"{material.name}_{name}",
                colour,
                roughness,
                material.metallicFactor,
                texture,
                material.doubleSided,
            ),
        )
        scene.geometry[name] = mesh
    return scene


def _retinted(
    mesh: trimesh.Trimesh, material: PBRMaterial, colour: np.ndarray, roughness: float, name: str
) -> trimesh.Trimesh:
    visual = trimesh.visual.TextureVisuals(
        uv=mesh.visual.uv,
        material=PBRMaterial(
            name=f"{material.name}_{name}",
            baseColorFactor=(*np.clip(colour, 0.0, 1.0), 1.0),
            baseColorTexture=material.baseColorTexture,
            metallicFactor=material.metallicFactor,
            roughnessFactor=roughness,
            metallicRoughnessTexture=material.metallicRoughnessTexture,
            normalTexture=material.normalTexture,
            occlusionTexture=material.occlusionTexture,
            emissiveTexture=material.emissiveTexture,
            emissiveFactor=material.emissiveFactor,
            alphaMode=material.alphaMode,
            alphaCutoff=material.alphaCutoff,
            doubleSided=material.doubleSided,
        ),
    )
    # A new mesh on the same arrays keeps the file's normals (a copy recomputes them).
    return trimesh.Trimesh(
        mesh.vertices,
        mesh.faces,
        vertex_normals=mesh.vertex_normals,
        visual=visual,
        process=False,
    )


def _drawn(material: PBRMaterial, rng: np.random.Generator, amount: float) -> tuple:
    factor = material.baseColorFactor
    colour = np.asarray(factor if factor is not None else [1.0] * 4, dtype=np.float64)[:3]
    if np.issubdtype(np.asarray(factor).dtype, np.integer):
        colour = colour / 255.0
    colour = np.clip(colour * rng.uniform(1 - amount, 1 + amount, 3), 0.0, 1.0)
    roughness = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
    return colour, float(np.clip(roughness + rng.uniform(-amount, amount), 0.05, 1.0))


def worn_object(
    scene: trimesh.Scene, rng: np.random.Generator, realism: RealismConfig
) -> trimesh.Scene:
    """An anomaly object's scene with per-part colour gains and albedo texture.

    Parameters
    ----------
    scene : trimesh.Scene
        The object's render scene (:attr:`~.objects.AnomalyObject.scene`); not modified.
    rng : numpy.random.Generator
        Source of randomness (parts in name order).
    realism : RealismConfig
        ``anomaly_albedo_sigma`` and ``texture_contrast``; ``enabled=False`` returns ``scene``.

    Returns
    -------
    trimesh.Scene
        The textured object; geometry (and so the mask) unchanged.
    """
    if not realism.enabled:
        return scene
    worn = scene.copy()
    size = float(np.max(scene.extents)) if len(scene.geometry) else 1.0
    for name in sorted(scene.geometry):
        mesh = scene.geometry[name]  # the original: a copy loses smooth-shading normals
        material = getattr(getattr(mesh, "visual", None), "material", None)
        if not isinstance(material, PBRMaterial):
            continue
        factor = np.asarray(material.baseColorFactor, dtype=np.float64)[:3]
        if np.issubdtype(np.asarray(material.baseColorFactor).dtype, np.integer):
            factor = factor / 255.0
        colour = factor * _log_gain(rng, realism.anomaly_albedo_sigma)
        texture = None
        if realism.texture_contrast > 0:
            texture = procedural_texture(rng, realism.texture_contrast)
        # About one tile over the object (never finer than 10 cm per tile): its stains are
        # as large, relative to its size, as the station's.
        mesh, uv = box_uv(mesh, max(size, 0.1), rng.random(2))
        roughness = 1.0 if material.roughnessFactor is None else material.roughnessFactor
        mesh.visual = trimesh.visual.TextureVisuals(
            uv=uv,
            material=_material(
                material.name, colour, roughness, material.metallicFactor, texture, True
            ),
        )
        worn.geometry[name] = mesh
    return worn
