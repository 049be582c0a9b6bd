"""How a camera image differs from a render: photometric perturbations of a uint8 query.

Each function takes an H x W x 3 uint8 image and returns a new uint8 image; together they
are the render-to-camera gap (exposure, gamma, tone curves including filmic and AgX-like
view transforms, desaturation, white balance, vignetting, light fall-off, sensor noise, JPEG,
bloom). The photometric tests and
``python -m benchmarks.photometric`` apply them to normal frames.
"""

from __future__ import annotations

from collections.abc import Callable

import cv2
import numpy as np

from allo_mrad_ros.errors import InvalidInput

Perturbation = Callable[[np.ndarray], np.ndarray]


class PerturbationError(InvalidInput):
    """A perturbation got an image it cannot handle."""


def _check(image: np.ndarray) -> np.ndarray:
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise PerturbationError(f"need an H x W x 3 uint8 image, got {image.dtype} {image.shape}")
    return image.astype(np.float64) / 255.0


def _to_uint8(unit: np.ndarray) -> np.ndarray:
    return np.clip(np.rint(unit * 255.0), 0, 255).astype(np.uint8)


def exposure(image: np.ndarray, factor: float) -> np.ndarray:
    """Multiply linear values by ``factor`` (clipped at white)."""
    return _to_uint8(_check(image) * factor)


def gamma(image: np.ndarray, power: float) -> np.ndarray:
    """``x ** power`` on the 0..1 scale."""
    return _to_uint8(_check(image) ** power)


def s_curve(image: np.ndarray, contrast: float = 1.6) -> np.ndarray:
    """A film-like S-shaped tone curve, ``x^c / (x^c + (1 - x)^c)`` (black, mid-grey and
    white fixed; shadows darker, highlights brighter), as a view transform applies."""
    x = _check(image)
    xc = x**contrast
    return _to_uint8(xc / (xc + (1.0 - x) ** contrast))


def desaturate(image: np.ndarray, amount: float = 0.35) -> np.ndarray:
    """Move each colour ``amount`` of the way to its grey (Rec. 601 luma)."""
    x = _check(image)
    luma = x @ np.array([0.299, 0.587, 0.114])
    return _to_uint8(x + amount * (luma[..., None] - x))


def white_balance(image: np.ndarray, gains: tuple[float, float, float]) -> np.ndarray:
    """Per-channel gains (R, G, B order of the array's channels)."""
    return _to_uint8(_check(image) * np.asarray(gains))


def vignette(image: np.ndarray, corner: float = 0.5) -> np.ndarray:
    """Radial fall-off ``1 - (1 - corner) * (r / r_corner)^2``: ``corner`` at the corners."""
    x = _check(image)
    h, w = x.shape[:2]
    cy, cx = (h - 1) / 2, (w - 1) / 2
    yy, xx = np.mgrid[0:h, 0:w]
    r2 = ((yy - cy) ** 2 + (xx - cx) ** 2) / (cy**2 + cx**2)
    return _to_uint8(x * (1.0 - (1.0 - corner) * r2)[..., None])


def ramp(image: np.ndarray, left: float = 0.6, right: float = 1.4) -> np.ndarray:
    """Illumination changing linearly from ``left`` to ``right`` across the frame."""
    x = _check(image)
    gain = np.linspace(left, right, x.shape[1])
    return _to_uint8(x * gain[None, :, None])


def sensor_noise(image: np.ndarray, sigma: float = 4.0, seed: int = 0) -> np.ndarray:
    """Additive Gaussian noise of ``sigma`` 8-bit units (seeded)."""
    x = _check(image) * 255.0
    noisy = x + np.random.default_rng(seed).normal(0.0, sigma, x.shape)
    return np.clip(np.rint(noisy), 0, 255).astype(np.uint8)


def jpeg(image: np.ndarray, quality: int = 60) -> np.ndarray:
    """Encode and decode as JPEG at ``quality``."""
    _check(image)
    ok, data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise PerturbationError("JPEG encoding failed")
    return cv2.imdecode(data, cv2.IMREAD_UNCHANGED)


def bloom(image: np.ndarray, sigma: float = 8.0, strength: float = 0.6) -> np.ndarray:
    """Glow around saturated pixels: their blurred footprint added with ``strength``."""
    x = _check(image)
    saturated = (x.max(axis=2) >= 250.0 / 255.0).astype(np.float32)
    size = 2 * int(np.ceil(3 * sigma)) + 1
    glow = cv2.GaussianBlur(saturated, (size, size), sigma).astype(np.float64)
    return _to_uint8(x + strength * glow[..., None])


def _to_linear(x: np.ndarray) -> np.ndarray:
    return x**2.2


def filmic(image: np.ndarray, exposure_factor: float = 2.0) -> np.ndarray:
    """A filmic view transform: Hable's curve on linear light, white at 11.2, display gamma.

    Lifts mid-tones and rolls highlights off, as a path tracer's filmic view does against a
    rasteriser's plain gamma."""

    def hable(v: np.ndarray) -> np.ndarray:
        a, b, c, d, e, f = 0.15, 0.50, 0.10, 0.20, 0.02, 0.30
        return (v * (a * v + c * b) + d * e) / (v * (a * v + b) + d * f) - e / f

    linear = _to_linear(_check(image)) * exposure_factor * 4.0
    return _to_uint8(np.clip(hable(linear) / hable(np.float64(11.2)), 0, 1) ** (1 / 2.2))


def agx_like(image: np.ndarray, exposure_factor: float = 1.0) -> np.ndarray:
    """An AgX-like view transform: log2 encoding of linear light over 16.5 stops, a sigmoid
    per channel, and highlights pulled towards grey (AgX desaturates bright colours)."""
    linear = np.maximum(_to_linear(_check(image)) * exposure_factor, 2.0**-12.5)
    encoded = np.clip((np.log2(linear / 0.18) + 10.0) / 16.5, 0.0, 1.0)
    curved = 1.0 / (1.0 + np.exp(-9.0 * (encoded - 0.606)))
    low, high = 1.0 / (1.0 + np.exp(9.0 * 0.606)), 1.0 / (1.0 + np.exp(-9.0 * 0.394))
    curved = (curved - low) / (high - low)
    luma = curved @ np.array([0.2126, 0.7152, 0.0722])
    mix = 0.35 * luma[..., None] ** 2
    return _to_uint8(np.clip(curved + mix * (luma[..., None] - curved), 0.0, 1.0))


# The render-to-camera gap, each at the end of its stated range.
PERTURBATIONS: dict[str, Perturbation] = {
    "exposure x0.6": lambda im: exposure(im, 0.6),
    "exposure x1.6": lambda im: exposure(im, 1.6),
    "gamma 0.8": lambda im: gamma(im, 0.8),
    "gamma 1.25": lambda im: gamma(im, 1.25),
    "S tone curve": s_curve,
    "desaturate 35 %": desaturate,
    "white balance +-10 %": lambda im: white_balance(im, (1.1, 1.0, 0.9)),
    "vignetting 50 %": vignette,
    "ramp x0.6-x1.4": ramp,
    "noise 4 DN": sensor_noise,
    "JPEG q60": jpeg,
    "bloom": bloom,
}
