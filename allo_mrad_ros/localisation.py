"""How well a detector's mask covers each anomaly: per-frame overlap, per-type summary.

The pixel metrics pool every pixel, so a type whose objects are small (a glove, a CubeSat)
weighs little in them; a missed type only shows when recall and IoU are reported per type.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.metrics import POSITIVE_CLASS


class LocalisationError(InvalidInput):
    """A mask pair cannot be compared (shape mismatch, no anomaly)."""


@dataclass(frozen=True)
class ObjectOverlap:
    """Overlap of a detected mask with one frame's ground-truth anomaly.

    Attributes
    ----------
    found : bool
        At least one anomaly pixel is detected.
    recall : float
        Fraction of the anomaly's pixels detected.
    iou : float
        Intersection over union of the detected mask and the anomaly (the whole frame's
        mask: detections elsewhere lower it).
    """

    found: bool
    recall: float
    iou: float


def object_overlap(detected: np.ndarray, truth: np.ndarray) -> ObjectOverlap:
    """Compare a detected mask (non-zero = anomalous) with a ground-truth mask (class 2).

    Raises
    ------
    LocalisationError
        If the shapes differ or the ground truth holds no anomaly pixel.
    """
    detected = np.asarray(detected)
    truth = np.asarray(truth)
    if detected.shape != truth.shape:
        raise LocalisationError(f"detected mask {detected.shape} and truth {truth.shape} differ")
    positive = truth == POSITIVE_CLASS
    size = int(np.count_nonzero(positive))
    if size == 0:
        raise LocalisationError("the ground truth holds no anomaly pixel (class 2)")
    flagged = detected != 0
    hit = int(np.count_nonzero(flagged & positive))
    union = int(np.count_nonzero(flagged | positive))
    return ObjectOverlap(found=hit > 0, recall=hit / size, iou=hit / union)


def summarise(overlaps: Iterable[ObjectOverlap]) -> dict[str, float]:
    """Fraction of frames found, mean recall and mean IoU (``nan`` for no frames)."""
    items = list(overlaps)
    if not items:
        nan = float("nan")
        return {"frames": 0, "found": nan, "recall": nan, "iou": nan}
    return {
        "frames": len(items),
        "found": float(np.mean([o.found for o in items])),
        "recall": float(np.mean([o.recall for o in items])),
        "iou": float(np.mean([o.iou for o in items])),
    }
