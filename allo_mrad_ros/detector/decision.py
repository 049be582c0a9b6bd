"""Stage 6: the frame's decision (mask area against a threshold) and its image score."""

from __future__ import annotations

import cv2
import numpy as np

from allo_mrad_ros.detector.params import MradParams


def decide(mask: np.ndarray, area_threshold: float) -> tuple[int, bool]:
    """Stage 6: the mask's area and whether it exceeds ``area_threshold`` of the image."""
    area = int(cv2.countNonZero(mask))
    return area, area > area_threshold * mask.size


def image_score(score: np.ndarray, area: int, params: MradParams) -> float:
    """Stage 6: the frame's anomaly score, what image-level metrics rank.

    Parameters
    ----------
    score : numpy.ndarray
        The pixel score map at the processing resolution.
    area : int
        The mask's area (the ``area`` rule's score).
    params : MradParams
        ``image_score`` and ``image_top_fraction`` are used.

    Returns
    -------
    float
    """
    if params.image_score == "area":
        return float(area)
    flat = score.ravel()
    count = max(1, round(params.image_top_fraction * flat.size))
    return float(_largest(flat, count).mean(dtype=np.float64))


def _largest(values: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` largest of ``values`` (1-D), in increasing order.

    NumPy's partition slows tenfold when most values are one number (a map at its floor,
    two thirds of a clean frame), so the candidates are first narrowed to the values above
    a threshold read from every 16th value, and sorted; when fewer than ``count`` lie above
    it, all are sorted.
    """
    sample = np.sort(values[::16])
    above = sample[max(0, sample.size - 4 * max(1, count // 16) - 1)]
    candidates = values[values > above]
    if candidates.size < count:
        candidates = values
    return np.sort(candidates)[candidates.size - count :]
