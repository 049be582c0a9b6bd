"""Stages 2-3: scaling and threshold of the raw score, noise removal, blur."""

from __future__ import annotations

import math

import cv2
import numpy as np

from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.params import SCORE_RANGE

NEGATIVE_BAND = 1.0
"""Part of the continuous map's 0..255 range that ranks negative cross scores."""


def scaling_reference(raw: np.ndarray, scaling: str, score_ref: float, *, flat: float) -> float:
    """The raw score that ``scaling`` takes as its unit: ``score_ref`` for ``fixed``, the
    frame's largest score for ``per_image``.

    Parameters
    ----------
    raw : numpy.ndarray
        Raw score map.
    scaling : {"fixed", "per_image"}
        The score scaling.
    score_ref : float
        The ``fixed`` unit.
    flat : float
        The ``per_image`` unit of a frame with no positive score (each caller's own rule).

    Returns
    -------
    float

    Raises
    ------
    ValueError
        For an unknown ``scaling``.
    """
    if scaling == "per_image":
        peak = float(raw.max())
        return peak if peak > 0.0 else flat
    if scaling == "fixed":
        return float(score_ref)
    raise ValueError(f"score_scaling must be 'fixed' or 'per_image', got {scaling!r}")


def scale_scores(raw: np.ndarray, scaling: str, score_ref: float) -> np.ndarray:
    """Map the raw score onto 0..255.

    Parameters
    ----------
    raw : numpy.ndarray
        H x W float32 raw score.
    scaling : {"fixed", "per_image"}
        ``fixed``: ``clip(255 * max(raw, 0) / score_ref, 0, 255)``; ``per_image``:
        ``255 * max(raw, 0) / max(max(raw, 0))`` (all zeros when nothing is positive).
    score_ref : float
        Raw score mapped to 255 by ``fixed`` scaling.

    Returns
    -------
    numpy.ndarray
        H x W float32 in [0, 255].
    """
    # A frame with no positive score has an infinite reference: every pixel scales to 0.
    factor = SCORE_RANGE / scaling_reference(raw, scaling, score_ref, flat=math.inf)
    _, positive = cv2.threshold(raw, 0.0, 0.0, cv2.THRESH_TOZERO)
    scaled = cv2.multiply(positive, factor)
    cv2.threshold(scaled, SCORE_RANGE, SCORE_RANGE, cv2.THRESH_TRUNC, dst=scaled)
    return scaled


def continuous_scores(raw: np.ndarray, scaling: str, score_ref: float) -> np.ndarray:
    """Map the signed raw score onto 0..255 by a strictly increasing function.

    Non-negative scores follow ``NEGATIVE_BAND + (255 - NEGATIVE_BAND) * s / (s + ref)``
    (``fixed``; ``s / peak`` for ``per_image``, ``peak`` the frame's largest score), which
    saturates softly so the strongest pixels keep their order. Negative scores, where the
    query pixel is closer to the reference model than to its own, fill the band below,
    ``NEGATIVE_BAND * exp(s / ref)``: they keep their order instead of tying at 0, so the
    lowest-ranked anomaly pixels are still ranked.

    Returns
    -------
    numpy.ndarray
        H x W float32 in [0, 255].
    """
    ref = scaling_reference(raw, scaling, score_ref, flat=1.0)
    _, positive = cv2.threshold(raw, 0.0, 0.0, cv2.THRESH_TOZERO)
    span = np.float32(SCORE_RANGE - NEGATIVE_BAND)
    if scaling == "fixed":
        upper = cv2.divide(positive * span, positive + np.float32(ref))
    else:
        upper = cv2.multiply(positive, float(span) / ref)
    _, negative = cv2.threshold(raw, 0.0, 0.0, cv2.THRESH_TRUNC)
    lower = np.exp(negative * np.float32(1.0 / ref)) * np.float32(NEGATIVE_BAND)
    # At 0 both branches give NEGATIVE_BAND; each covers its own side.
    return np.where(raw > 0.0, upper + np.float32(NEGATIVE_BAND), lower).astype(np.float32)


def threshold_scores(scaled: np.ndarray, min_score: float) -> np.ndarray:
    """Zero every scaled score below ``min_score`` (in place; returns the array)."""
    # THRESH_TOZERO keeps values strictly above its threshold: use the float just below.
    below = float(np.nextafter(np.float32(min_score), np.float32(-np.inf)))
    cv2.threshold(scaled, below, 0.0, cv2.THRESH_TOZERO, dst=scaled)
    return scaled


def local_std(scores: np.ndarray, window: tuple[int, int]) -> np.ndarray:
    """Standard deviation over a ``(height, width)`` box around each pixel.

    Edges are reflected (``BORDER_REFLECT``) at the borders of ``scores``.

    Box filters of the map and of its square give the local variance in O(1) per pixel.
    """
    mean = cv2.boxFilter(scores, cv2.CV_32F, (window[1], window[0]), borderType=cv2.BORDER_REFLECT)
    mean_sq = cv2.boxFilter(
        cv2.multiply(scores, scores),
        cv2.CV_32F,
        (window[1], window[0]),
        borderType=cv2.BORDER_REFLECT,
    )
    variance = np.maximum(mean_sq - mean * mean, 0.0, dtype=np.float32)
    return cv2.sqrt(variance)


def std_window(height: int, width: int, grid: int, kernel_fraction: float) -> tuple[int, int]:
    """Window of ``kernel_fraction`` of a cell's height and width, at least one pixel."""
    return (
        max(1, round(kernel_fraction * height / grid)),
        max(1, round(kernel_fraction * width / grid)),
    )


def remove_noise(
    scores: np.ndarray,
    grid: int,
    *,
    min_score: float,
    kernel_fraction: float,
    std_thresh: float,
    large_anomaly_fraction: float,
    noise_removal: str,
) -> np.ndarray:
    """Zero flat noise in a thresholded score map, cell by cell.

    A cell with more than ``large_anomaly_fraction`` of its scores above ``min_score`` is a
    large anomaly and is kept whole. Elsewhere ``local_std`` zeroes pixels whose local
    standard deviation (window ``kernel_fraction`` of the cell) is below ``std_thresh``,
    except saturated (255) scores, which clipping flattened;
    ``cell_spread`` zeroes a whole cell when the spread (max - min) of its local standard
    deviations is below ``std_thresh``; ``none`` keeps the map.

    Returns
    -------
    numpy.ndarray
        A new H x W float32 map.
    """
    if noise_removal not in ("local_std", "cell_spread", "none"):
        raise ValueError(
            f"noise_removal must be local_std, cell_spread or none, got {noise_removal!r}"
        )
    cleaned = scores.copy()
    if noise_removal == "none" or not cleaned.any():
        return cleaned
    for cell in cell_slices(*scores.shape, grid):
        cell_scores = scores[cell]
        if not cell_scores.any():
            continue
        if np.count_nonzero(cell_scores > min_score) > large_anomaly_fraction * cell_scores.size:
            continue
        # The window stays inside the cell (reflected at its edges): cells are independent.
        spread = local_std(cell_scores, std_window(*cell_scores.shape, 1, kernel_fraction))
        if noise_removal == "local_std":
            # Saturated scores are flat because scaling clipped them, not because they are
            # noise: keep them, or a confident object loses its interior.
            flat_noise = (spread < std_thresh) & (cell_scores < SCORE_RANGE)
            cleaned[cell][flat_noise] = 0.0
        elif float(np.ptp(spread)) < std_thresh:
            cleaned[cell] = 0.0
    return cleaned


def blur_scores(scores: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian blur with standard deviation ``sigma`` pixels (a copy when ``sigma == 0``)."""
    if sigma <= 0.0:
        return scores.copy()
    # Truncate the kernel at 3 sigma (OpenCV's float default is 4 sigma): 0.3 % of the mass.
    size = 2 * math.ceil(3.0 * sigma) + 1
    return cv2.GaussianBlur(
        scores, (size, size), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_REFLECT
    )
