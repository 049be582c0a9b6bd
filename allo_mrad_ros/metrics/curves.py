"""Operating-point curves and the metrics read from them, on arrays or on counts.

Every metric is a function of the counts of positive and negative samples per distinct
score, ordered by decreasing score (tied scores form one operating point, as in
scikit-learn's ``roc_curve`` and ``precision_recall_curve``); :func:`curve_from_counts`
turns such counts into the curve, and the ``*_from_curve`` functions read the metrics.
The functions on arrays (:func:`roc_auc`, ...) count the distinct scores of one array and
are the slow, obvious reference the streaming counts of
:mod:`allo_mrad_ros.metrics.score_counts` are tested against; they are themselves tested
against scikit-learn.
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
    """Operating points ordered by decreasing threshold.

    The first point is (0, 0), before any sample is predicted positive; ``thresholds[i]``
    is the lowest score predicted positive at point ``i`` (``inf`` for the first point, the
    point's index where the counts came without scores).
    """

    thresholds: np.ndarray
    tpr: np.ndarray
    fpr: np.ndarray
    precision: np.ndarray


def curve_from_counts(
    positives: np.ndarray, negatives: np.ndarray, *, scores: np.ndarray | None = None
) -> Curve:
    """Build the ROC/PR operating points from per-threshold counts.

    Parameters
    ----------
    positives, negatives : numpy.ndarray
        Counts of positive and negative samples at each distinct score, ordered by
        decreasing score.
    scores : numpy.ndarray, optional
        The score of each count (the lowest of a group of scores counted together), for
        the curve's thresholds.

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
    if scores is None:
        thresholds = np.arange(len(tp), dtype=np.float64)
    else:
        thresholds = np.concatenate([[np.inf], np.asarray(scores, dtype=np.float64)])
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


def crossing_point(curve: Curve, target_tpr: float = TARGET_TPR) -> int:
    """Index of the first operating point (walking the thresholds from high to low) whose
    TPR reaches ``target_tpr`` (a TPR within 1e-12 below it counts as reaching it)."""
    return int(np.flatnonzero(curve.tpr >= target_tpr - 1e-12)[0])


def fpr_at_tpr_interpolated_from_curve(curve: Curve, target_tpr: float = TARGET_TPR) -> float:
    """False-positive rate on the ROC curve linearly interpolated at ``target_tpr``.

    Between the last operating point below the target and the first one reaching it, the
    FPR is interpolated linearly in TPR (the first point reaching it when TPR jumps to it
    exactly).
    """
    reached = crossing_point(curve, target_tpr)
    if reached == 0 or curve.tpr[reached] <= target_tpr + 1e-12:
        return float(curve.fpr[reached])
    t0, t1 = curve.tpr[reached - 1], curve.tpr[reached]
    f0, f1 = curve.fpr[reached - 1], curve.fpr[reached]
    return float(f0 + (f1 - f0) * (target_tpr - t0) / (t1 - t0))


def fpr_at_tpr_from_curve(curve: Curve, target_tpr: float = TARGET_TPR) -> float:
    """False-positive rate at the first operating point whose TPR reaches ``target_tpr``.

    Walking the thresholds from high to low, this is the highest threshold that detects
    ``target_tpr`` of the positives, hence the smallest such FPR; tied scores are one
    threshold, so a tie block that holds the crossing counts all its negatives.
    """
    return float(curve.fpr[crossing_point(curve, target_tpr)])


def _counts_by_score(scores: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    scores = np.asarray(scores, dtype=np.float64).ravel()
    labels = np.asarray(labels).ravel().astype(bool)
    if scores.shape != labels.shape:
        raise MetricsError(f"{scores.size} scores but {labels.size} labels")
    if not np.isfinite(scores).all():
        raise MetricsError("scores contain NaN or Inf")
    # Every pixel apart, in float64 (as scikit-learn casts them): the slow reference.
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
