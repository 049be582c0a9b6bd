"""The full-resolution score is made on first read, with the values the detector used to
return eagerly; the processing-resolution map is what the image score ranks."""

import pickle

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.decision import image_score
from allo_mrad_ros.example_scene import example_pair


@pytest.fixture(scope="module")
def pair():
    return example_pair(270, 480, seed=3)


def eager_score(work_score: np.ndarray, mask: np.ndarray, pixel_score: str) -> np.ndarray:
    """What detect() computed before the score became lazy: bilinear to the mask's size,
    then, for the regions map, zero outside the mask."""
    height, width = mask.shape
    score = cv2.resize(work_score, (width, height), interpolation=cv2.INTER_LINEAR)
    if pixel_score == "regions":
        out = np.zeros_like(score)
        out[mask > 0] = score[mask > 0]
        return out
    return score


@pytest.mark.parametrize("pixel_score", ["continuous", "blurred", "regions"])
def test_the_lazy_score_equals_the_eager_one(pair, pixel_score):
    params = MradParams(pixel_score=pixel_score)
    result = detect(pair.query, pair.reference, params)
    assert result.work_score.shape == (68, 120)  # 480x270 at process_scale 0.25
    assert result.mask.shape == (270, 480)
    assert "score" not in vars(result)  # not made by detect()
    expected = eager_score(result.work_score, result.mask, pixel_score)
    assert result.score.dtype == np.float32
    assert result.score.tobytes() == expected.tobytes()
    assert result.score is result.score  # made once
    assert result.area > 0  # the example's object is found: the regions map is not all zero
    assert result.image_score == image_score(result.work_score, result.area, params)
    # Pickled results (the evaluator's worker processes) keep working.
    assert pickle.loads(pickle.dumps(result)).score.tobytes() == expected.tobytes()


def test_at_full_processing_resolution_both_maps_are_one(pair):
    result = detect(pair.query, pair.reference, MradParams(process_scale=1.0))
    assert result.score is result.work_score


def test_the_eager_reference_sees_a_difference():
    # The comparison above can fail: masking matters for the regions map.
    work = np.full((2, 2), 100.0, np.float32)
    mask = np.zeros((4, 4), np.uint8)
    mask[:2, :2] = 255
    assert (
        eager_score(work, mask, "regions").tobytes() != eager_score(work, mask, "blurred").tobytes()
    )


def test_the_work_query_and_mask_are_what_the_detector_saw_and_decided(pair):
    params = MradParams()
    result = detect(pair.query, pair.reference, params)
    height, width = result.work_score.shape
    assert result.work_query.shape == (height, width, 3)
    # The area average of the query (not the colour-transferred one).
    area = cv2.resize(pair.query, (width, height), interpolation=cv2.INTER_AREA)
    assert np.abs(result.work_query.astype(int) - area.astype(int)).max() <= 1
    # The full mask is the work mask made larger, nearest neighbour.
    rows = np.minimum(
        (np.arange(result.mask.shape[0]) * height) // result.mask.shape[0], height - 1
    )
    cols = np.minimum((np.arange(result.mask.shape[1]) * width) // result.mask.shape[1], width - 1)
    np.testing.assert_array_equal(result.mask, result.work_mask[rows][:, cols])
    assert result.work_mask.any()
