"""Paired frame bootstrap of a pooled-pixel AP difference, on coarse per-frame histograms.

Resampling frames needs every frame's counts kept apart, hundreds of frames for each of
many settings, so frames are binned coarsely here (:func:`frame_counts`: 1/2 of a score
unit by default). The bootstrap gives the spread of a difference, not a reported metric:
the metrics themselves come from exact counts (:mod:`allo_mrad_ros.metrics.score_counts`).
"""

from __future__ import annotations

import numpy as np

from .curves import (
    POSITIVE_CLASS,
    MetricsError,
    average_precision_from_curve,
    curve_from_counts,
)

SCORE_RANGE = (0.0, 255.0)
"""Scores are clipped into this range before binning (0..255 for every detector here)."""


def frame_counts(score_map: np.ndarray, mask: np.ndarray, bins_per_unit: int = 2) -> np.ndarray:
    """One frame's pixel counts per score bin, for resampling frames later.

    Parameters
    ----------
    score_map : numpy.ndarray
        H x W pixel scores on the 0..255 scale (clipped into it).
    mask : numpy.ndarray
        H x W ground truth (class 2 = anomaly).
    bins_per_unit : int
        Bin resolution: scores are rounded to the nearest ``1 / bins_per_unit``; coarse
        bins keep hundreds of frames of many settings in memory.

    Returns
    -------
    numpy.ndarray
        (2, bins) int32: positives, then negatives, bins in increasing score.

    Raises
    ------
    MetricsError
        If the shapes differ, a score is NaN or infinite or ``bins_per_unit`` is below 1.
    """
    if score_map.shape != mask.shape:
        raise MetricsError(f"score map {score_map.shape} and mask {mask.shape} differ in shape")
    if bins_per_unit < 1:
        raise MetricsError(f"bins_per_unit must be at least 1, got {bins_per_unit}")
    if not np.isfinite(score_map).all():
        raise MetricsError("score map contains NaN or Inf")
    low, high = SCORE_RANGE
    size = round((high - low) * bins_per_unit) + 1
    clipped = np.clip(score_map, low, high)
    index = np.rint((clipped - low) * bins_per_unit).astype(np.int64).ravel()
    positive = (mask == POSITIVE_CLASS).ravel()
    positives = np.bincount(index[positive], minlength=size)
    negatives = np.bincount(index[~positive], minlength=size)
    return np.stack([positives, negatives]).astype(np.int32)


def _ap_of_pooled(pooled: np.ndarray) -> float:
    positives, negatives = pooled[0][::-1], pooled[1][::-1]
    keep = (positives + negatives) > 0
    return average_precision_from_curve(curve_from_counts(positives[keep], negatives[keep]))


def bootstrap_ap_difference(
    counts_a: np.ndarray, counts_b: np.ndarray, resamples: int = 1000, seed: int = 0
) -> np.ndarray:
    """Paired frame bootstrap of the pooled-pixel AP difference ``AP(b) - AP(a)``.

    Each resample draws frames with replacement and pools the same frames for both
    detectors, so the spread is that of the difference, not of either AP alone.

    Parameters
    ----------
    counts_a, counts_b : numpy.ndarray
        (frames, 2, bins) per-frame counts from :func:`frame_counts`, frames in the same
        order for both.
    resamples : int
        Number of bootstrap resamples (at least 1).
    seed : int
        Seed of the resampling generator.

    Returns
    -------
    numpy.ndarray
        (resamples,) AP differences as fractions; resamples that hold a single class are
        dropped.

    Raises
    ------
    MetricsError
        If the shapes differ or are not (frames, 2, bins).
    """
    a, b = np.asarray(counts_a), np.asarray(counts_b)
    if a.shape != b.shape or a.ndim != 3 or a.shape[1] != 2 or a.shape[0] == 0:
        raise MetricsError(
            f"counts must both be (frames, 2, bins) with frames > 0; got {a.shape} and {b.shape}"
        )
    if resamples < 1:
        raise MetricsError(f"resamples must be at least 1, got {resamples}")
    rng = np.random.default_rng(seed)
    frames = a.shape[0]
    flat_a = a.reshape(frames, -1).astype(np.float64)
    flat_b = b.reshape(frames, -1).astype(np.float64)
    differences = []
    for _ in range(resamples):
        weights = np.bincount(rng.integers(0, frames, frames), minlength=frames)
        pooled_a = (weights @ flat_a).reshape(2, -1)
        pooled_b = (weights @ flat_b).reshape(2, -1)
        if pooled_a[0].sum() == 0 or pooled_a[1].sum() == 0:
            continue
        differences.append(_ap_of_pooled(pooled_b) - _ap_of_pooled(pooled_a))
    return np.asarray(differences)
