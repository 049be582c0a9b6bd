"""The pixel metrics of a pooled :class:`~.score_counts.ScoreCounts` table, with error bounds.

Counts per distinct score give every metric exactly. Two facts keep the work small and
say what a coarsened table costs:

- Negatives whose scores lie between the same two positive scores can be counted
  together without changing any metric (each metric reads the curve only where the
  true-positive count changes, and at the point just before), so runs of entries without
  positives are merged before the curve is built: the curve has at most two points per
  entry that holds positives.
- An entry spanning several scores (a coarsened table) leaves unknown only how its own
  positives and negatives are ordered among themselves. Every metric is computed as if
  they were tied, and :func:`pixel_metrics` bounds how far any ordering can move it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .curves import (
    TARGET_TPR,
    Curve,
    aupr_trapezoid_from_curve,
    auroc_from_curve,
    average_precision_from_curve,
    crossing_point,
    curve_from_counts,
    fpr_at_tpr_from_curve,
    fpr_at_tpr_interpolated_from_curve,
)
from .score_counts import ScoreCounts, group_sums, key_scores

PIXEL_KEYS = ("p_auroc", "p_ap", "p_aupr", "p_fpr95", "p_fpr95_interp")


@dataclass(frozen=True)
class _Entries:
    """A table's entries in decreasing score order, runs without positives merged."""

    positives: np.ndarray
    negatives: np.ndarray
    scores: np.ndarray
    ranged: np.ndarray


def _entries(table: ScoreCounts) -> _Entries:
    has_positive = table.positives > 0
    starts = np.ones(table.size, dtype=bool)
    starts[1:] = has_positive[1:] | has_positive[:-1]
    index = np.flatnonzero(starts)
    lengths = np.diff(np.append(index, table.size))
    # An entry with positives is a run of its own; runs without sum their negatives.
    positives = table.positives[index].astype(np.int64)
    negatives = group_sums(table.negatives, index, table.pixels).astype(np.int64)
    ranged = (lengths > 1) | (table.high[index + lengths - 1] != table.low[index])
    scores = key_scores(table.low[index]).astype(np.float64)
    return _Entries(positives[::-1], negatives[::-1], scores[::-1], ranged[::-1])


def pixel_curve(table: ScoreCounts) -> Curve:
    """The ROC and PR operating points of a table (thresholds from the highest score down).

    Raises
    ------
    MetricsError
        If the table holds one class only.
    """
    entries = _entries(table)
    return curve_from_counts(entries.positives, entries.negatives, scores=entries.scores)


def pixel_metrics(
    table: ScoreCounts, target_tpr: float = TARGET_TPR
) -> tuple[dict[str, float], dict[str, float]]:
    """P.AUROC, P.AP, P.AUPR and both P.FPR95 of a table, and a bound on each one's error.

    Returns
    -------
    values : dict
        ``p_auroc``, ``p_ap``, ``p_aupr``, ``p_fpr95``, ``p_fpr95_interp`` as computed with
        each range entry's pixels tied.
    bounds : dict
        For the same keys, an upper bound on ``|value - exact value|``: 0.0 for a table
        whose entries are all single scores. With ``P``, ``N`` the positives and negatives,
        and for a range entry holding ``p`` positives and ``n`` negatives below ``T``
        positives and ``F`` negatives: P.AUROC moves by at most ``p n / (2 P N)`` per entry
        (its pairs, credited one half each); each of its positives adds recall ``1 / P`` at
        a precision in ``[(T + 1) / (T + 1 + F + n), (T + p) / (T + p + F)]``, which bounds
        P.AP and, with the precision at the entry's start, P.AUPR; both P.FPR95 move by at
        most ``n / N`` of the entry where the true-positive rate reaches the target, and
        not at all when that entry is one score.

    Raises
    ------
    MetricsError
        If the table holds one class only.
    """
    entries = _entries(table)
    curve = curve_from_counts(entries.positives, entries.negatives, scores=entries.scores)
    values = {
        "p_auroc": auroc_from_curve(curve),
        "p_ap": average_precision_from_curve(curve),
        "p_aupr": aupr_trapezoid_from_curve(curve),
        "p_fpr95": fpr_at_tpr_from_curve(curve, target_tpr),
        "p_fpr95_interp": fpr_at_tpr_interpolated_from_curve(curve, target_tpr),
    }
    return values, _bounds(entries, curve, target_tpr)


def _bounds(entries: _Entries, curve: Curve, target_tpr: float) -> dict[str, float]:
    bounds = dict.fromkeys(PIXEL_KEYS, 0.0)
    p = entries.positives.astype(np.float64)
    n = entries.negatives.astype(np.float64)
    total_p, total_n = p.sum(), n.sum()
    crossing = crossing_point(curve, target_tpr) - 1  # the curve starts at (0, 0)
    if entries.ranged[crossing]:
        bounds["p_fpr95"] = bounds["p_fpr95_interp"] = float(n[crossing] / total_n)
    mixed = entries.ranged & (p > 0)
    if not mixed.any():
        return bounds
    above_p = (np.cumsum(p) - p)[mixed]
    above_n = (np.cumsum(n) - n)[mixed]
    p, n = p[mixed], n[mixed]
    bounds["p_auroc"] = float(np.sum(p * n) / (2.0 * total_p * total_n))
    # Precision of a positive of the entry: its threshold predicts between T + 1 and
    # T + p positives and between F and F + n negatives.
    low = (above_p + 1) / (above_p + 1 + above_n + n)
    high = (above_p + p) / (above_p + p + above_n)
    tied = (above_p + p) / (above_p + p + above_n + n)
    bounds["p_ap"] = float(np.sum(p / total_p * np.maximum(high - tied, tied - low)))
    # The trapezoid runs from the entry's start to its end; an ordering puts any points in
    # between, each at a precision between T / (T + F + n) and the high above.
    before = above_p + above_n
    start = np.divide(above_p, before, out=np.ones_like(before), where=before > 0)
    reach = above_p + above_n + n
    low = np.divide(above_p, reach, out=np.zeros_like(reach), where=reach > 0)
    mean = (start + tied) / 2.0
    bounds["p_aupr"] = float(np.sum(p / total_p * np.maximum(high - mean, mean - low)))
    return bounds
