"""The ALLO metrics, each named for the way it is computed.

- I.AUROC, P.AUROC: trapezoid area under the ROC curve (scikit-learn's ``roc_auc_score``).
- P.AP (``p_ap``): **step** average precision, ``sum_n (R_n - R_{n-1}) P_n`` (scikit-learn's
  ``average_precision_score``); no interpolation between operating points.
- P.AUPR (``p_aupr``): **trapezoid** area under the precision-recall curve, the curve
  starting at (recall 0, precision 1) -- anomalib's ``AUPR`` (torchmetrics' curve and
  ``auc``), equal to ``sklearn.metrics.auc(recall, precision)``. On maps with many tied
  scores the straight line across a tie block lifts it well above the step AP.
- P.FPR95 (``p_fpr95``): false-positive rate at the **first** threshold (walking down from
  the highest score) whose true-positive rate reaches 95 %; tied scores jump together, so a
  block of ties at 0 forces it to 100 %.
- P.FPR95 interpolated (``p_fpr95_interp``): the ROC curve linearly interpolated at a
  true-positive rate of exactly 95 % (``numpy.interp`` over scikit-learn's ``roc_curve``),
  as the out-of-distribution literature reports it.

Pixel metrics pool the pixels of all test images. A 300-frame 1080p test split holds 600 M
pixels, too many to sort, so :class:`PixelScoreHistogram` counts positives and negatives per
score bin as frames arrive; with bins of 1/64 on the 0..255 score scale the curves are those
of the scores rounded to that grid. The exact functions on arrays are the reference the
histogram is tested against, and they are themselves tested against scikit-learn.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.errors import InvalidInput

POSITIVE_CLASS = 2
TARGET_TPR = 0.95


class MetricsError(InvalidInput):
    """Scores and labels cannot be scored (shape mismatch, one class only, bad values)."""


@dataclass(frozen=True)
class Curve:
    """Operating points ordered by decreasing threshold (the first point is (0, 0))."""

    thresholds: np.ndarray
    tpr: np.ndarray
    fpr: np.ndarray
    precision: np.ndarray


def curve_from_counts(positives: np.ndarray, negatives: np.ndarray) -> Curve:
    """Build the ROC/PR operating points from per-threshold counts.

    Parameters
    ----------
    positives, negatives : numpy.ndarray
        Counts of positive and negative samples at each distinct score, ordered by
        decreasing score.

    Returns
    -------
    Curve
    """
    positives = np.asarray(positives, dtype=np.float64)
    negatives = np.asarray(negatives, dtype=np.float64)
    total_pos, total_neg = positives.sum(), negatives.sum()
    if total_pos == 0 or total_neg == 0:
        raise MetricsError(
            f"need both classes: {int(total_pos)} positive and {int(total_neg)} negative samples"
        )
    tp = np.concatenate([[0.0], np.cumsum(positives)])
    fp = np.concatenate([[0.0], np.cumsum(negatives)])
    predicted = tp + fp
    precision = np.divide(tp, predicted, out=np.ones_like(tp), where=predicted > 0)
    thresholds = np.arange(len(tp), dtype=np.float64)
    return Curve(thresholds, tp / total_pos, fp / total_neg, precision)


def trapezoid_area(y: np.ndarray, x: np.ndarray) -> float:
    """Trapezoid-rule area under ``y(x)`` (``numpy.trapezoid`` is NumPy 2 only; ROS distros
    ship NumPy 1.x)."""
    return float(np.sum(np.diff(x) * (y[1:] + y[:-1])) / 2.0)


def auroc_from_curve(curve: Curve) -> float:
    """Area under the ROC curve (trapezoids, as scikit-learn's ``roc_auc_score``)."""
    return trapezoid_area(curve.tpr, curve.fpr)


def average_precision_from_curve(curve: Curve) -> float:
    """Average precision, ``sum_n (R_n - R_{n-1}) P_n`` (scikit-learn's definition)."""
    return float(np.sum(np.diff(curve.tpr) * curve.precision[1:]))


def aupr_trapezoid_from_curve(curve: Curve) -> float:
    """Trapezoid area under the precision-recall curve (anomalib's AUPR)."""
    return trapezoid_area(curve.precision, curve.tpr)


def fpr_at_tpr_interpolated_from_curve(curve: Curve, target_tpr: float = TARGET_TPR) -> float:
    """False-positive rate on the ROC curve linearly interpolated at ``target_tpr``.

    Between the last operating point below the target and the first one reaching it, the
    FPR is interpolated linearly in TPR (the first point reaching it when TPR jumps to it
    exactly).
    """
    reached = int(np.flatnonzero(curve.tpr >= target_tpr - 1e-12)[0])
    if reached == 0 or curve.tpr[reached] <= target_tpr + 1e-12:
        return float(curve.fpr[reached])
    t0, t1 = curve.tpr[reached - 1], curve.tpr[reached]
    f0, f1 = curve.fpr[reached - 1], curve.fpr[reached]
    return float(f0 + (f1 - f0) * (target_tpr - t0) / (t1 - t0))


def fpr_at_tpr_from_curve(curve: Curve, target_tpr: float = TARGET_TPR) -> float:
    """False-positive rate at the first operating point whose TPR reaches ``target_tpr``.

    Walking the thresholds from high to low, this is the highest threshold that detects
    ``target_tpr`` of the positives, hence the smallest such FPR.
    """
    reached = np.flatnonzero(curve.tpr >= target_tpr - 1e-12)
    return float(curve.fpr[reached[0]])


def _counts_by_score(scores: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    scores = np.asarray(scores, dtype=np.float64).ravel()
    labels = np.asarray(labels).ravel().astype(bool)
    if scores.shape != labels.shape:
        raise MetricsError(f"{scores.size} scores but {labels.size} labels")
    if not np.isfinite(scores).all():
        raise MetricsError("scores contain NaN or Inf")
    unique, inverse = np.unique(-scores, return_inverse=True)
    positives = np.bincount(inverse, weights=labels, minlength=unique.size)
    negatives = np.bincount(inverse, weights=~labels, minlength=unique.size)
    return positives, negatives


def roc_auc(scores: np.ndarray, labels: np.ndarray) -> float:
    """Exact area under the ROC curve of binary ``labels`` ranked by ``scores``."""
    return auroc_from_curve(curve_from_counts(*_counts_by_score(scores, labels)))


def average_precision(scores: np.ndarray, labels: np.ndarray) -> float:
    """Exact average precision of binary ``labels`` ranked by ``scores``."""
    return average_precision_from_curve(curve_from_counts(*_counts_by_score(scores, labels)))


def fpr_at_tpr(scores: np.ndarray, labels: np.ndarray, target_tpr: float = TARGET_TPR) -> float:
    """Exact false-positive rate at the first threshold reaching ``target_tpr``."""
    return fpr_at_tpr_from_curve(curve_from_counts(*_counts_by_score(scores, labels)), target_tpr)


def aupr_trapezoid(scores: np.ndarray, labels: np.ndarray) -> float:
    """Exact trapezoid area under the precision-recall curve (anomalib's AUPR)."""
    return aupr_trapezoid_from_curve(curve_from_counts(*_counts_by_score(scores, labels)))


def fpr_at_tpr_interpolated(
    scores: np.ndarray, labels: np.ndarray, target_tpr: float = TARGET_TPR
) -> float:
    """Exact ROC-interpolated false-positive rate at ``target_tpr``."""
    curve = curve_from_counts(*_counts_by_score(scores, labels))
    return fpr_at_tpr_interpolated_from_curve(curve, target_tpr)


class PixelScoreHistogram:
    """Pooled pixel scores of many frames as per-bin positive/negative counts.

    Parameters
    ----------
    low, high : float
        Score range; scores are clipped into it (0..255 for every detector here).
    bins_per_unit : int
        Bin resolution: scores are rounded to the nearest ``1 / bins_per_unit``.
    """

    def __init__(self, low: float = 0.0, high: float = 255.0, bins_per_unit: int = 64) -> None:
        if not high > low or bins_per_unit < 1:
            raise MetricsError(f"bad histogram range [{low}, {high}] x {bins_per_unit}")
        self.low, self.high, self.bins_per_unit = low, high, bins_per_unit
        size = round((high - low) * bins_per_unit) + 1
        self.positives = np.zeros(size, dtype=np.int64)
        self.negatives = np.zeros(size, dtype=np.int64)

    def update(self, scores: np.ndarray, mask: np.ndarray) -> None:
        """Add one frame: ``scores`` H x W and its ground-truth ``mask`` (class 2 = anomaly)."""
        if scores.shape != mask.shape:
            raise MetricsError(f"score map {scores.shape} and mask {mask.shape} differ in shape")
        if not np.isfinite(scores).all():
            raise MetricsError("score map contains NaN or Inf")
        clipped = np.clip(scores, self.low, self.high)
        index = np.rint((clipped - self.low) * self.bins_per_unit).astype(np.int64).ravel()
        positive = (mask == POSITIVE_CLASS).ravel()
        size = self.positives.size
        self.positives += np.bincount(index[positive], minlength=size)
        self.negatives += np.bincount(index[~positive], minlength=size)

    def curve(self) -> Curve:
        """The operating points, thresholds from the highest bin down."""
        keep = (self.positives + self.negatives)[::-1] > 0
        return curve_from_counts(self.positives[::-1][keep], self.negatives[::-1][keep])


@dataclass(frozen=True)
class AlloMetrics:
    """The ALLO metrics as fractions in 0..1 (``nan`` where undefined); see the module
    docstring for which computation each is."""

    i_auroc: float
    p_auroc: float
    p_ap: float
    p_fpr95: float
    p_aupr: float = float("nan")
    p_fpr95_interp: float = float("nan")

    def as_dict(self) -> dict[str, float]:
        """The metrics as a dictionary with the report's keys."""
        return {
            "i_auroc": self.i_auroc,
            "p_auroc": self.p_auroc,
            "p_ap": self.p_ap,
            "p_fpr95": self.p_fpr95,
            "p_aupr": self.p_aupr,
            "p_fpr95_interp": self.p_fpr95_interp,
        }


class MetricsAccumulator:
    """Accumulate frames and compute the :class:`AlloMetrics`.

    The image score is the detector's frame score (``DetectionResult.image_score``: the
    top of its pixel map, or the mask's area); the image label is whether the
    ground-truth mask has any class-2 pixel.
    """

    def __init__(self, bins_per_unit: int = 64) -> None:
        self.pixels = PixelScoreHistogram(bins_per_unit=bins_per_unit)
        self.image_scores: list[float] = []
        self.image_labels: list[bool] = []

    def update(self, score_map: np.ndarray, image_score: float, mask: np.ndarray) -> None:
        """Add one frame's pixel scores, image score and ground-truth mask."""
        self.pixels.update(score_map, mask)
        self.image_scores.append(float(image_score))
        self.image_labels.append(bool(np.any(mask == POSITIVE_CLASS)))

    def compute(self) -> AlloMetrics:
        """Return the metrics; a metric whose labels hold one class only is ``nan``."""
        nan = float("nan")
        labels = np.array(self.image_labels, dtype=bool)
        i_auroc = (
            roc_auc(np.array(self.image_scores), labels)
            if labels.any() and not labels.all()
            else nan
        )
        if self.pixels.positives.sum() == 0 or self.pixels.negatives.sum() == 0:
            return AlloMetrics(i_auroc, nan, nan, nan)
        curve = self.pixels.curve()
        return AlloMetrics(
            i_auroc,
            auroc_from_curve(curve),
            average_precision_from_curve(curve),
            fpr_at_tpr_from_curve(curve),
            aupr_trapezoid_from_curve(curve),
            fpr_at_tpr_interpolated_from_curve(curve),
        )


def frame_counts(score_map: np.ndarray, mask: np.ndarray, bins_per_unit: int = 2) -> np.ndarray:
    """One frame's pixel counts per score bin, for resampling frames later.

    Parameters
    ----------
    score_map : numpy.ndarray
        H x W pixel scores on the 0..255 scale.
    mask : numpy.ndarray
        H x W ground truth (class 2 = anomaly).
    bins_per_unit : int
        Bin resolution; coarse bins keep hundreds of frames of many settings in memory.

    Returns
    -------
    numpy.ndarray
        (2, bins) int32: positives, then negatives, bins in increasing score.
    """
    histogram = PixelScoreHistogram(bins_per_unit=bins_per_unit)
    histogram.update(score_map, mask)
    return np.stack([histogram.positives, histogram.negatives]).astype(np.int32)


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
