"""The gap between the CAD model and a camera image, for the generated queries.

The camera, :func:`apply_camera`: exposure, white balance, saturation, the Sun's glare
(halo, diffraction spikes, lens ghosts) when it is in view, bloom around highlights,
vignetting, optical blur, an S-shaped tone curve, shot and read noise, 8-bit quantisation.
The surfaces (as-built station, worn objects) are in :mod:`.surfaces`, the light in
:mod:`.lighting`.

The effects are modelled from plain camera physics with moderate defaults
(:class:`~.realism_config.RealismConfig`); none is tuned against any detector.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache

import cv2
import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.render import RenderResult
from allo_mrad_ros.synth.realism_config import RealismConfig

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


_LUMA = np.array([0.2126, 0.7152, 0.0722], dtype=np.float32)  # Rec. 709, linear RGB


@dataclass(frozen=True)
class CameraLook:
    """The camera's fixed rendering of colour, drawn once per sequence.

    Attributes
    ----------
    tone_contrast : float
        Exponent ``k`` of the S-shaped tone curve on display values (1: none).
    saturation : float
        Saturation factor in linear RGB (1: unchanged).
    """

    tone_contrast: float = 1.0
    saturation: float = 1.0

    @classmethod
    def draw(cls, rng: np.random.Generator, realism: RealismConfig) -> CameraLook:
        """Draw a camera's look from the ranges of ``realism`` (identity when disabled)."""
        if not realism.enabled:
            return cls()
        return cls(
            float(rng.uniform(*realism.tone_contrast)), float(rng.uniform(*realism.saturation))
        )


def tone_curve(display: np.ndarray, contrast: float) -> np.ndarray:
    """S-shaped tone curve ``d**k / (d**k + (1 - d)**k)`` on display values in [0, 1].

    Fixes 0, 1/2 and 1; ``k > 1`` crushes the shadows and rolls off the highlights as a
    camera's picture style or a path tracer's view transform (Filmic, AgX) does.
    """
    d = np.clip(display, 0.0, 1.0)
    if contrast == 1.0:
        return d
    k = np.float32(contrast)
    a = np.power(d, k)
    return a / np.maximum(a + np.power(np.float32(1.0) - d, k), np.float32(1e-12))


@dataclass(frozen=True)
class CameraEffects:
    """The per-frame draws of :func:`apply_camera`, recorded in the frame's extra columns."""

    exposure: float
    noise_gain: float
    white_balance: tuple[float, float] = (1.0, 1.0)


def apply_camera(
    rgb: np.ndarray,
    rng: np.random.Generator,
    realism: RealismConfig,
    sun: SunInView | None = None,
    sun_strength: float = 1.0,
    look: CameraLook | None = None,
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
    look : CameraLook, optional
        The camera's tone curve and saturation; default none (identity).

    Returns
    -------
    image : numpy.ndarray
        (h, w, 3) uint8.
    effects : CameraEffects
        The exposure gain, noise gain and white-balance gains (red, blue) drawn.
    """
    if not realism.enabled:
        return rgb.copy(), CameraEffects(1.0, 0.0)
    height, width = rgb.shape[:2]
    exposure = float(math.exp(rng.normal(0.0, realism.exposure_sigma)))
    noise_gain = float(rng.uniform(*realism.noise_gain))
    limit = 3.0 * realism.white_balance_sigma
    red, blue = np.exp(np.clip(rng.normal(0.0, realism.white_balance_sigma, 2), -limit, limit))
    look = look or CameraLook()
    linear = _to_linear()[rgb] * np.array([red, 1.0, blue], np.float32) * np.float32(exposure)
    if look.saturation != 1.0:
        luma = (linear @ _LUMA)[..., None]
        linear = luma + np.float32(look.saturation) * (linear - luma)
    if sun is not None and realism.glare > 0:
        strength = realism.glare * sun.visible * (0.3 + 0.7 * min(sun_strength, 1.0))
        linear += _glare((height, width), sun, strength) * np.float32(exposure)
    if realism.bloom > 0:
        linear += np.float32(realism.bloom) * _bloom(linear, width)
    if realism.vignetting > 0:
        linear *= (1.0 - np.float32(realism.vignetting) * _radial(height, width))[..., None]
    if realism.blur_sigma > 0:
        linear = _blur(linear, realism.blur_sigma * width / _WIDTH_REF)
    display = np.power(np.clip(linear, 0.0, 1.0), np.float32(1.0 / _GAMMA))
    display = tone_curve(display, look.tone_contrast) * np.float32(255.0)
    read = realism.read_noise_dn * noise_gain
    shot = realism.shot_noise_dn * noise_gain
    sigma = np.sqrt(np.float32(read * read) + np.float32(shot * shot / 255.0) * display)
    noisy = display + sigma * rng.standard_normal(display.shape, dtype=np.float32)
    image = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    return image, CameraEffects(exposure, noise_gain, (float(red), float(blue)))


def resize_to(image: np.ndarray, intrinsics: CameraIntrinsics) -> np.ndarray:
    """Resize a reduced-scale render to the camera's full size (bilinear)."""
    if image.shape[:2] == (intrinsics.height, intrinsics.width):
        return image
    return cv2.resize(image, (intrinsics.width, intrinsics.height), interpolation=cv2.INTER_LINEAR)


def jpeg_round_trip(image: np.ndarray, quality: int) -> np.ndarray:
    """The RGB image as a camera streaming JPEG at ``quality`` (1-100) delivers it."""
    ok, encoded = cv2.imencode(".jpg", image[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError(f"JPEG encoding failed at quality {quality}")
    return np.ascontiguousarray(cv2.imdecode(encoded, cv2.IMREAD_COLOR)[..., ::-1])
