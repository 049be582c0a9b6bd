"""The gap between the CAD model and a camera image, for the generated queries.

Two parts:

* :func:`as_built_station` - the "real" station: the CAD model's geometry with its
  materials' colours and roughness drawn around the nominal values once per sequence, so
  the query and the reference disagree a little everywhere, as a real station and its model
  do;
* :func:`apply_camera` - the camera: exposure, the Sun's glare (halo, diffraction spikes,
  lens ghosts) when it is in view, bloom around highlights, vignetting, optical blur, shot
  and read noise, 8-bit quantisation.

The effects are modelled from plain camera physics with moderate defaults
(:class:`~.config.RealismConfig`); none is tuned against any detector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from os import PathLike

import cv2
import numpy as np
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.render import RenderResult
from allo_mrad_ros.synth.config import RealismConfig, SynthError

_GAMMA = 2.2
_WIDTH_REF = 1920.0  # effect sizes are given at this image width
# Aperture blades: 6 blades give 6 diffraction spikes, fixed to the camera.
_SPIKE_ANGLES = np.radians([15.0, 75.0, 135.0])
# Lens ghosts along the line from the Sun through the image centre: (position along the
# line as a multiple of sun-to-centre, radius as a fraction of the width, strength, tint).
_GHOSTS = (
    (1.35, 0.030, 0.006, (0.6, 1.0, 0.7)),
    (1.8, 0.060, 0.003, (0.9, 0.6, 1.0)),
    (2.4, 0.020, 0.008, (1.0, 0.8, 0.5)),
)


@dataclass(frozen=True)
class SunInView:
    """Where the Sun's disc is in an image.

    Attributes
    ----------
    x, y : float
        Centre in pixels.
    radius_px : float
        Disc radius in pixels.
    visible : float
        Fraction of the disc not hidden by the station, in [0, 1].
    """

    x: float
    y: float
    radius_px: float
    visible: float


def as_built_station(
    model: str | PathLike[str] | trimesh.Scene, rng: np.random.Generator, amount: float
) -> trimesh.Scene:
    """The station model with every material's colour and roughness varied a little.

    Parameters
    ----------
    model : path or trimesh.Scene
        The CAD model (as the renderer takes it).
    rng : numpy.random.Generator
        Source of randomness (one draw per material, in material-name order).
    amount : float
        Relative spread: each colour channel is scaled by U(1 - amount, 1 + amount), the
        roughness moved by U(-amount, amount).

    Returns
    -------
    trimesh.Scene
        A new scene; the input is not modified.
    """
    scene = model.copy() if isinstance(model, trimesh.Scene) else trimesh.load(model, force="scene")
    if not isinstance(scene, trimesh.Scene):
        raise SynthError(f"cannot load the station model {model!r} as a scene")
    materials: dict[str, PBRMaterial] = {}
    for name in sorted(scene.geometry):
        mesh = scene.geometry[name]
        visual = getattr(mesh, "visual", None)
        material = getattr(visual, "material", None)
        if not isinstance(material, PBRMaterial):
            continue  # vertex-coloured or plain parts keep their look
        key = material.name or f"material{id(material)}"
        if key not in materials:
            materials[key] = _varied(material, rng, amount)
        mesh.visual = trimesh.visual.TextureVisuals(uv=visual.uv, material=materials[key])
    return scene


def _varied(material: PBRMaterial, rng: np.random.Generator, amount: float) -> PBRMaterial:
    colour = np.asarray(
        material.baseColorFactor if material.baseColorFactor is not None else [1.0] * 4,
        dtype=np.float64,
    )
    if np.issubdtype(np.asarray(material.baseColorFactor).dtype, np.integer):
        colour = colour / 255.0
    colour[:3] = np.clip(colour[:3] * rng.uniform(1 - amount, 1 + amount, 3), 0.0, 1.0)
    roughness = 1.0 if material.roughnessFactor is None else float(material.roughnessFactor)
    roughness = float(np.clip(roughness + rng.uniform(-amount, amount), 0.05, 1.0))
    return PBRMaterial(
        name=material.name,
        baseColorFactor=colour,
        baseColorTexture=material.baseColorTexture,
        metallicFactor=material.metallicFactor,
        roughnessFactor=roughness,
        emissiveFactor=material.emissiveFactor,
        alphaMode=material.alphaMode,
        doubleSided=material.doubleSided,
    )


def find_sun(
    result: RenderResult, sun_centre: np.ndarray, T_station_camera: np.ndarray, sun_radius: float
) -> SunInView | None:
    """Locate the Sun's disc in a render made with ``labels=True``.

    Parameters
    ----------
    result : RenderResult
        The render; its instance image tells how much of the disc is visible.
    sun_centre : numpy.ndarray
        (3,) the scaled Sun's centre in the station frame.
    T_station_camera : numpy.ndarray
        (4, 4) camera pose of the render.
    sun_radius : float
        The scaled Sun's radius.

    Returns
    -------
    SunInView or None
        None when the Sun is not drawn or entirely hidden.
    """
    if "sun" not in result.bodies_in_view or result.instances is None:
        return None
    optical = T_station_camera[:3, :3].T @ (np.asarray(sun_centre) - T_station_camera[:3, 3])
    if optical[2] <= 0:
        return None
    k = result.intrinsics
    distance = float(np.linalg.norm(optical))
    radius_px = k.fx * math.tan(math.asin(min(1.0, sun_radius / distance)))
    pixels = int(np.count_nonzero(result.instances == result.instance_names.index("sun")))
    if pixels == 0:
        return None
    disc = max(math.pi * radius_px * radius_px, 1.0)
    return SunInView(
        x=k.fx * optical[0] / optical[2] + k.cx,
        y=k.fy * optical[1] / optical[2] + k.cy,
        radius_px=radius_px,
        visible=min(1.0, pixels / disc),
    )


@cache
def _radial(height: int, width: int) -> np.ndarray:
    """Squared distance from the image centre over the squared half-diagonal."""
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    r2 = (x - (width - 1) / 2) ** 2 + (y - (height - 1) / 2) ** 2
    return r2 / np.float32((width / 2) ** 2 + (height / 2) ** 2)


@cache
def _to_linear() -> np.ndarray:
    return ((np.arange(256, dtype=np.float64) / 255.0) ** _GAMMA).astype(np.float32)


def _glare(shape: tuple[int, int], sun: SunInView, strength: float) -> np.ndarray:
    """Veiling glare, diffraction spikes and ghosts of the Sun, linear units, (h, w, 3)."""
    height, width = shape
    s = width / _WIDTH_REF
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    dx, dy = x - np.float32(sun.x), y - np.float32(sun.y)
    r2 = dx * dx + dy * dy
    core = max(2.5 * sun.radius_px, 2.0)
    halo = 2.0 * np.exp(-r2 / np.float32(core * core))
    halo += 0.2 / (1.0 + r2 / np.float32((0.03 * width) ** 2)) ** 1.5
    halo += 0.002 / (1.0 + r2 / np.float32((0.25 * width) ** 2))
    for angle in _SPIKE_ANGLES:
        c, n = np.float32(math.cos(angle)), np.float32(math.sin(angle))
        along = np.abs(dx * c + dy * n)
        across = dx * n - dy * c
        halo += (
            0.4
            * np.exp(-along / np.float32(0.12 * width))
            * np.exp(-(across * across) / np.float32((1.2 * s) ** 2 + 0.25))
        )
    glare = np.repeat((strength * halo)[..., None], 3, axis=2)
    cx, cy = (width - 1) / 2, (height - 1) / 2
    for position, radius, weight, tint in _GHOSTS:
        gx = sun.x + position * (cx - sun.x)
        gy = sun.y + position * (cy - sun.y)
        rad = radius * width
        d = np.sqrt((x - np.float32(gx)) ** 2 + (y - np.float32(gy)) ** 2)
        disc = np.clip((rad - d) / np.float32(0.2 * rad), 0.0, 1.0) * np.float32(strength * weight)
        glare += disc[..., None] * np.asarray(tint, dtype=np.float32)
    return glare


def _blur(image: np.ndarray, sigma: float) -> np.ndarray:
    return cv2.GaussianBlur(image, (0, 0), sigmaX=sigma, sigmaY=sigma)


def _bloom(linear: np.ndarray, width: int) -> np.ndarray:
    """Halo around saturated highlights (lens scatter), computed at a quarter size."""
    highlights = np.maximum(linear - np.float32(0.8), 0.0)
    if not np.any(highlights):
        return np.zeros_like(linear)
    h, w = linear.shape[:2]
    small = cv2.resize(highlights, (max(1, w // 4), max(1, h // 4)), interpolation=cv2.INTER_AREA)
    s = width / _WIDTH_REF
    halo = _blur(small, max(0.5, 6.0 * s / 4)) + 0.5 * _blur(small, max(0.5, 25.0 * s / 4))
    return cv2.resize(halo, (w, h), interpolation=cv2.INTER_LINEAR)


@dataclass(frozen=True)
class CameraEffects:
    """The per-frame draws of :func:`apply_camera`, recorded in the frame's extra columns."""

    exposure: float
    noise_gain: float


def apply_camera(
    rgb: np.ndarray,
    rng: np.random.Generator,
    realism: RealismConfig,
    sun: SunInView | None = None,
    sun_strength: float = 1.0,
) -> tuple[np.ndarray, CameraEffects]:
    """Turn a clean render into a camera image.

    Parameters
    ----------
    rgb : numpy.ndarray
        (h, w, 3) uint8 render.
    rng : numpy.random.Generator
        Source of the exposure, noise gain and noise draws.
    realism : RealismConfig
        Effect strengths; ``enabled=False`` returns the render unchanged.
    sun : SunInView, optional
        The Sun's disc, when in view: adds glare scaled by its visible fraction.
    sun_strength : float
        Relative Sun strength of the frame (dimmer settings glare less).

    Returns
    -------
    image : numpy.ndarray
        (h, w, 3) uint8.
    effects : CameraEffects
        The exposure gain and noise gain drawn.
    """
    if not realism.enabled:
        return rgb.copy(), CameraEffects(1.0, 0.0)
    height, width = rgb.shape[:2]
    exposure = float(math.exp(rng.normal(0.0, realism.exposure_sigma)))
    noise_gain = float(rng.uniform(*realism.noise_gain))
    linear = _to_linear()[rgb] * np.float32(exposure)
    if sun is not None and realism.glare > 0:
        strength = realism.glare * sun.visible * (0.3 + 0.7 * min(sun_strength, 1.0))
        linear += _glare((height, width), sun, strength) * np.float32(exposure)
    if realism.bloom > 0:
        linear += np.float32(realism.bloom) * _bloom(linear, width)
    if realism.vignetting > 0:
        linear *= (1.0 - np.float32(realism.vignetting) * _radial(height, width))[..., None]
    if realism.blur_sigma > 0:
        linear = _blur(linear, realism.blur_sigma * width / _WIDTH_REF)
    display = np.power(np.clip(linear, 0.0, 1.0), np.float32(1.0 / _GAMMA)) * np.float32(255.0)
    read = realism.read_noise_dn * noise_gain
    shot = realism.shot_noise_dn * noise_gain
    sigma = np.sqrt(np.float32(read * read) + np.float32(shot * shot / 255.0) * display)
    noisy = display + sigma * rng.standard_normal(display.shape, dtype=np.float32)
    image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return image, CameraEffects(exposure, noise_gain)


def resize_to(image: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Resize a reduced-scale render to the camera's full size (bilinear)."""
    if image.shape[:2] == (intrinsics.height, intrinsics.width):
        return image
    return cv2.resize(image, (intrinsics.width, intrinsics.height), interpolation=cv2.INTER_LINEAR)
