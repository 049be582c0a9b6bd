"""The ALLO metrics of a run, accumulated frame by frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .curves import POSITIVE_CLASS, Curve, roc_auc
from .pixel import PIXEL_KEYS, pixel_curve, pixel_metrics
from .score_counts import DEFAULT_MAX_ENTRIES, PooledScoreCounts


@dataclass(frozen=True)
class AlloMetrics:
    """The ALLO metrics as fractions in 0..1 (``nan`` where undefined); see
    :mod:`allo_mrad_ros.metrics` for which computation each is.

    ``error_bounds`` holds, per pixel metric, an upper bound on its distance from the value
    over every pixel apart: 0.0 (exact) unless the run held more distinct scores than the
    pooled table keeps (:class:`~allo_mrad_ros.metrics.score_counts.PooledScoreCounts`).
    """

    i_auroc: float
    p_auroc: float
    p_ap: float
    p_fpr95: float
    p_aupr: float = float("nan")
    p_fpr95_interp: float = float("nan")
    error_bounds: dict[str, float] = field(
        default_factory=lambda: dict.fromkeys(PIXEL_KEYS, 0.0), hash=False
    )

    @property
    def exact(self) -> bool:
        """Every pixel metric is exact."""
        return not any(self.error_bounds.values())

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
    ground-truth mask has any class-2 pixel. Pixels are counted per distinct score
    (:class:`~allo_mrad_ros.metrics.score_counts.PooledScoreCounts`).

    Parameters
    ----------
    max_entries : int
        Distinct scores the pooled pixel counts keep exactly (see
        :class:`~allo_mrad_ros.metrics.score_counts.PooledScoreCounts`).
    """

    def __init__(self, *, max_entries: int = DEFAULT_MAX_ENTRIES) -> None:
        self.pixels = PooledScoreCounts(max_entries=max_entries)
        self.image_scores: list[float] = []
        self.image_labels: list[bool] = []

    def update(self, score_map: np.ndarray, image_score: float, mask: np.ndarray) -> None:
        """Add one frame's pixel scores, image score and ground-truth mask."""
        self.pixels.update(score_map, mask)
        self.image_scores.append(float(image_score))
        self.image_labels.append(bool(np.any(mask == POSITIVE_CLASS)))

    def _has_both_pixel_classes(self) -> bool:
        table = self.pixels.table()
        return bool(table.positives.any() and table.negatives.any())

    def curve(self) -> Curve | None:
        """The pooled pixels' ROC and PR operating points; None while one class is missing."""
        return pixel_curve(self.pixels.table()) if self._has_both_pixel_classes() else None

    def compute(self) -> AlloMetrics:
        """Return the metrics; a metric whose labels hold one class only is ``nan``."""
        nan = float("nan")
        labels = np.array(self.image_labels, dtype=bool)
        i_auroc = (
            roc_auc(np.array(self.image_scores), labels)
            if labels.any() and not labels.all()
            else nan
        )
        if not self._has_both_pixel_classes():
            return AlloMetrics(i_auroc, nan, nan, nan, nan, nan, dict.fromkeys(PIXEL_KEYS, nan))
        values, bounds = pixel_metrics(self.pixels.table())
        return AlloMetrics(i_auroc, **values, error_bounds=bounds)
