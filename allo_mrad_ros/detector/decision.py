"""Stage 6: the frame's decision, its anomaly score in [0, 1], and its image score.

Two decision rules (``MradParams.frame_rule``):

- ``contrast`` (the default): the frame's evidence, the mean of the top ``frame_top_fraction``
  of a score map (``frame_map``), over the frame's own background level, the ``frame_background``
  quantile of the same map over the station pixels outside the mask (never below
  ``frame_floor``). The frame is anomalous when this contrast exceeds ``frame_contrast``. A
  frame whose whole map is lifted (another renderer's shading, glare, a tone curve) needs
  proportionally stronger evidence, so the share of normal frames flagged stays near the
  rate the threshold was chosen for instead of following the map's level.
- ``area`` (the paper's): the mask's area exceeds ``area_threshold`` of the image.

Either rule gives an anomaly score in [0, 1], ``s / (s + t)`` for the rule's statistic ``s``
and threshold ``t``: increasing in the statistic, 0.5 exactly at the threshold, so "score
above 0.5" is the decision.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.params import MradParams
from allo_mrad_ros.detector.postprocess import continuous_scores

DECISION_FIELDS = (
    "area_threshold",
    "image_score",
    "image_top_fraction",
    "frame_rule",
    "frame_map",
    "frame_top_fraction",
    "frame_background",
    "frame_floor",
    "frame_contrast",
)
"""The parameters of the frame decision and image score: they change neither the mask nor the
maps (a benchmark may detect once and decide many times)."""

STATION_LEVEL = 8.0
"""A query pixel whose brightest channel exceeds this (0..255 scale) is station (or an object),
not black space; the background level is read over such pixels. Space scores the map's floor
whatever the frame, and the share of the view it fills would otherwise move the quantile."""

MIN_BACKGROUND = 64
"""Fewer background pixels than this give no level: the floor stands for it."""

MASK_MARGIN = 2
"""Pixels around the mask (processing resolution) left out of the background: the blur
spreads a region's evidence about this far."""


@dataclass(frozen=True)
class FrameEvidence:
    """What the ``contrast`` rule reads of one frame.

    Attributes
    ----------
    evidence : float
        Mean of the top ``frame_top_fraction`` of the ranking map (0..255).
    background : float
        The ``frame_background`` quantile of the map over the station pixels outside the
        mask, or 0 when fewer than :data:`MIN_BACKGROUND` such pixels exist.
    """

    evidence: float
    background: float

    def contrast(self, floor: float) -> float:
        """``evidence / max(background, floor)`` (``floor`` > 0)."""
        return self.evidence / max(self.background, floor)


@dataclass(frozen=True)
class FrameDecision:
    """The frame decision.

    Attributes
    ----------
    anomalous : bool
        The rule's statistic exceeds its threshold (``anomaly_score`` > 0.5).
    anomaly_score : float
        In [0, 1]: ``s / (s + t)`` for the rule's statistic ``s`` and threshold ``t``.
    statistic : float
        ``contrast``: the frame's evidence over its background level; ``area``: the mask's
        area as a fraction of the image.
    area : int
        The mask's pixels at the query's resolution.
    """

    anomalous: bool
    anomaly_score: float
    statistic: float
    area: int


def decide(mask: np.ndarray, area_threshold: float) -> tuple[int, bool]:
    """The ``area`` rule: the mask's area and whether it exceeds ``area_threshold`` of the
    image."""
    area = int(cv2.countNonZero(mask))
    return area, area > area_threshold * mask.size


def frame_evidence(
    score: np.ndarray, mask: np.ndarray, query: np.ndarray, params: MradParams
) -> FrameEvidence:
    """The ``contrast`` rule's evidence and background level of one frame.

    Parameters
    ----------
    score : numpy.ndarray
        h x w float32 ranking map (0..255) at the processing resolution.
    mask : numpy.ndarray
        h x w mask (non-zero = anomalous) at the same resolution.
    query : numpy.ndarray
        h x w x 3 query at the same resolution (uint8, or float on 0..1).
    params : MradParams
        ``frame_top_fraction`` and ``frame_background`` are used.

    Returns
    -------
    FrameEvidence

    Raises
    ------
    ValueError
        If the three arrays are not of one size.
    """
    if mask.shape != score.shape or query.shape[:2] != score.shape:
        raise ValueError(
            f"score {score.shape}, mask {mask.shape} and query {query.shape} must be one size"
        )
    flat = score.ravel()
    count = max(1, round(params.frame_top_fraction * flat.size))
    evidence = float(_largest(flat, count).mean(dtype=np.float64))
    level = STATION_LEVEL if query.dtype == np.uint8 else STATION_LEVEL / 255.0
    # The brightest channel over the level. OpenCV's per-element max of the split channels:
    # NumPy's max over the last axis of a uint8 image is some thirty times slower.
    red, green, blue = cv2.split(np.ascontiguousarray(query))
    background = cv2.compare(cv2.max(cv2.max(red, green), blue), level, cv2.CMP_GT)
    foreground = (mask != 0).astype(np.uint8)
    if cv2.countNonZero(foreground):
        side = 2 * MASK_MARGIN + 1
        near = cv2.dilate(foreground, np.ones((side, side), np.uint8))
        background[near != 0] = 0
    values = score[background != 0]
    if values.size < MIN_BACKGROUND:
        return FrameEvidence(evidence, 0.0)
    return FrameEvidence(evidence, _quantile(values, params.frame_background))


def decision_map(score: np.ndarray, raw: np.ndarray, params: MradParams) -> np.ndarray:
    """The map the ``contrast`` rule reads (``params.frame_map``): ``ranking``, the pixel
    ranking map ``score``; ``mask``, the raw score of the mask's photometric model (``raw``)
    put on the ranking map's 0..255 scale by the same increasing function
    (:func:`~allo_mrad_ros.detector.postprocess.continuous_scores`), unsmoothed."""
    if params.frame_map == "ranking":
        return score
    return continuous_scores(raw, params.score_scaling, params.score_ref)


def frame_decision(
    full_mask: np.ndarray,
    score: np.ndarray,
    raw: np.ndarray,
    mask: np.ndarray,
    query: np.ndarray,
    params: MradParams,
) -> FrameDecision:
    """Stage 6: the frame's decision and anomaly score by ``params.frame_rule``.

    Parameters
    ----------
    full_mask : numpy.ndarray
        The mask at the query's resolution (its area is counted).
    score, raw, mask, query : numpy.ndarray
        The ranking map, the mask's raw score, the mask and the query at the processing
        resolution (see :func:`decision_map` and :func:`frame_evidence`; read by the
        ``contrast`` rule only).
    params : MradParams
        ``frame_rule`` and its parameters; ``area_threshold`` for ``area``.

    Returns
    -------
    FrameDecision
    """
    area = int(cv2.countNonZero(full_mask))
    if params.frame_rule == "area":
        statistic = area / full_mask.size
        threshold = params.area_threshold
    else:
        evidence = frame_evidence(decision_map(score, raw, params), mask, query, params)
        statistic = evidence.contrast(params.frame_floor)
        threshold = params.frame_contrast
    return FrameDecision(
        anomalous=statistic > threshold,
        anomaly_score=anomaly_score(statistic, threshold),
        statistic=statistic,
        area=area,
    )


def anomaly_score(statistic: float, threshold: float) -> float:
    """``statistic / (statistic + threshold)`` in [0, 1] for a statistic >= 0: 0.5 at the
    threshold, increasing, so the frame ranking of the statistic is kept.

    A threshold of 0 (the ``area`` rule's "any pixel") gives 1 for any positive statistic,
    0.5 for none.
    """
    statistic = max(float(statistic), 0.0)
    total = statistic + threshold
    return statistic / total if total > 0 else 0.5


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


def _quantile(values: np.ndarray, q: float) -> float:
    """The ``q`` quantile of 1-D ``values`` by linear interpolation between order statistics
    (NumPy's default ``linear`` method), from two partitions instead of a sort."""
    position = q * (values.size - 1)
    low = int(np.floor(position))
    high = min(low + 1, values.size - 1)
    parts = np.partition(values, (low, high))
    return float(parts[low] + (position - low) * (float(parts[high]) - float(parts[low])))


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
