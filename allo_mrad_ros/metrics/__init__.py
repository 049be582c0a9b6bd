"""The ALLO metrics, each named for the way it is computed.

- I.AUROC, P.AUROC: trapezoid area under the ROC curve (scikit-learn's ``roc_auc_score``).
- P.AP (``p_ap``): **step** average precision, ``sum_n (R_n - R_{n-1}) P_n`` (scikit-learn's
  ``average_precision_score``); no interpolation between operating points.
- P.AUPR (``p_aupr``): **trapezoid** area under the precision-recall curve, the curve
  starting at (recall 0, precision 1) -- anomalib's ``AUPR`` (torchmetrics' curve and
  ``auc``), equal to ``sklearn.metrics.auc(recall, precision)``. On maps with many tied
  scores the straight line across a tie block lifts it well above the step AP.
- P.FPR95 (``p_fpr95``): false-positive rate at the **first** threshold (walking down from
  the highest score) whose true-positive rate reaches 95 %; tied scores are one threshold
  and jump together, so a block of ties at 0 forces it to 100 %.
- P.FPR95 interpolated (``p_fpr95_interp``): the ROC curve linearly interpolated at a
  true-positive rate of exactly 95 % (``numpy.interp`` over scikit-learn's ``roc_curve``),
  as the out-of-distribution literature reports it.

Pixel metrics pool the pixels of all test images and are computed from the count of
positive and negative pixels per distinct score (:mod:`.score_counts`), exactly as
scikit-learn computes them over every pixel apart, ties included. A run with more distinct
scores than the pooled table keeps (4 M by default) merges neighbouring scores that hold
few pixels, and each metric then carries a bound on its error (:mod:`.pixel`,
:attr:`AlloMetrics.error_bounds`). The functions on arrays (:mod:`.curves`) are the slow
reference, tested against scikit-learn.
"""

from .accumulator import AlloMetrics, MetricsAccumulator
from .bootstrap import bootstrap_ap_difference, frame_counts
from .curves import (
    POSITIVE_CLASS,
    TARGET_TPR,
    Curve,
    MetricsError,
    aupr_trapezoid,
    aupr_trapezoid_from_curve,
    auroc_from_curve,
    average_precision,
    average_precision_from_curve,
    crossing_point,
    curve_from_counts,
    fpr_at_tpr,
    fpr_at_tpr_from_curve,
    fpr_at_tpr_interpolated,
    fpr_at_tpr_interpolated_from_curve,
    roc_auc,
    trapezoid_area,
)
from .pixel import PIXEL_KEYS, pixel_curve, pixel_metrics
from .score_counts import DEFAULT_MAX_ENTRIES, PooledScoreCounts, ScoreCounts

__all__ = [
    "DEFAULT_MAX_ENTRIES",
    "PIXEL_KEYS",
    "POSITIVE_CLASS",
    "TARGET_TPR",
    "AlloMetrics",
    "Curve",
    "MetricsAccumulator",
    "MetricsError",
    "PooledScoreCounts",
    "ScoreCounts",
    "aupr_trapezoid",
    "aupr_trapezoid_from_curve",
    "auroc_from_curve",
    "average_precision",
    "average_precision_from_curve",
    "bootstrap_ap_difference",
    "crossing_point",
    "curve_from_counts",
    "fpr_at_tpr",
    "fpr_at_tpr_from_curve",
    "fpr_at_tpr_interpolated",
    "fpr_at_tpr_interpolated_from_curve",
    "frame_counts",
    "pixel_curve",
    "pixel_metrics",
    "roc_auc",
    "trapezoid_area",
]
