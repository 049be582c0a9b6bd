"""Per-object recall and IoU of a detected mask, and their per-type summary."""

import numpy as np
import pytest

from allo_mrad_ros.localisation import LocalisationError, object_overlap, summarise


def test_overlap_hand_computed():
    truth = np.ones((10, 10), np.uint8)
    truth[2:4, 2:7] = 2  # 10 object pixels
    detected = np.zeros((10, 10), np.uint8)
    detected[2:4, 5:9] = 255  # 8 detected: 4 on the object, 4 beside it
    overlap = object_overlap(detected, truth)
    assert overlap.found
    assert overlap.recall == pytest.approx(4 / 10)
    assert overlap.iou == pytest.approx(4 / 14)


def test_missed_object_and_summary():
    truth = np.zeros((6, 6), np.uint8)
    truth[0, 0] = 2
    missed = object_overlap(np.zeros((6, 6), np.uint8), truth)
    assert not missed.found and missed.recall == 0.0 and missed.iou == 0.0
    exact = object_overlap((truth == 2).astype(np.uint8), truth)
    assert exact.found and exact.recall == 1.0 and exact.iou == 1.0
    summary = summarise([missed, exact])
    assert summary == {"frames": 2, "found": 0.5, "recall": 0.5, "iou": 0.5}
    assert summarise([])["frames"] == 0 and np.isnan(summarise([])["iou"])


def test_bad_pairs_are_named():
    with pytest.raises(LocalisationError, match="differ"):
        object_overlap(np.zeros((2, 2)), np.zeros((3, 2)))
    with pytest.raises(LocalisationError, match="no anomaly"):
        object_overlap(np.zeros((2, 2)), np.ones((2, 2)))
