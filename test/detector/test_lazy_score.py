"""The full-resolution score is made on first read: the processing-resolution map
interpolated bilinearly (pixel centres aligned, edges held) and, for the ``regions`` map,
zero outside the mask. The processing-resolution map is what the image score ranks."""

import math
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


def bilinear_weights(source: int, target: int) -> np.ndarray:
    """The (target x source) float64 matrix of 1-D linear interpolation weights, written
    out pixel by pixel: target pixel i's centre lies at source position
    (i + 0.5) * source / target - 0.5; positions before the first or past the last source
    centre take that edge pixel."""
    weights = np.zeros((target, source))
    for i in range(target):
        position = (i + 0.5) * source / target - 0.5
        position = min(max(position, 0.0), source - 1.0)
        low = math.floor(position)
        high = min(low + 1, source - 1)
        fraction = position - low
        weights[i, low] += 1.0 - fraction
        weights[i, high] += fraction
    return weights


def expected_score(work_score: np.ndarray, mask: np.ndarray, pixel_score: str) -> np.ndarray:
    """The full-resolution score, slowly and in float64: each row, then each column
    interpolated, and the regions map zero outside the mask."""
    height, width = mask.shape
    rows = bilinear_weights(work_score.shape[0], height)
    cols = bilinear_weights(work_score.shape[1], width)
    score = rows @ work_score.astype(np.float64) @ cols.T
    if pixel_score == "regions":
        score[mask == 0] = 0.0
    return score


@pytest.mark.parametrize("pixel_score", ["continuous", "blurred", "regions"])
def test_the_lazy_score_equals_the_eager_one(pair, pixel_score):
    params = MradParams(pixel_score=pixel_score)
    result = detect(pair.query, pair.reference, params)
    assert result.work_score.shape == (68, 120)  # 480x270 at process_scale 0.25
    assert result.mask.shape == (270, 480)
    assert "score" not in vars(result)  # not made by detect()
    expected = expected_score(result.work_score, result.mask, pixel_score)
    assert result.score.dtype == np.float32
    # float32 interpolation of values on 0..255: a few units in the last place.
    np.testing.assert_allclose(result.score, expected, rtol=0, atol=1e-4)
    if pixel_score == "regions":
        assert not result.score[result.mask == 0].any()
    assert result.score is result.score  # made once
    assert result.area > 0  # the example's object is found: the regions map is not all zero
    assert result.image_score == image_score(result.work_score, result.area, params)
    # Pickled results (the evaluator's worker processes) keep working.
    assert pickle.loads(pickle.dumps(result)).score.tobytes() == result.score.tobytes()


def test_at_full_processing_resolution_both_maps_are_one(pair):
    result = detect(pair.query, pair.reference, MradParams(process_scale=1.0))
    assert result.score is result.work_score


def test_the_interpolation_oracle_holds_on_known_values():
    # Doubling a 1-D ramp 0, 4: the centres of the new pixels lie at source positions
    # -0.25, 0.25, 0.75, 1.25, so the edges are held and the middle is interpolated.
    ramp = expected_score(np.array([[0.0, 4.0]]), np.ones((1, 4), np.uint8), "continuous")
    np.testing.assert_array_equal(ramp, [[0.0, 1.0, 3.0, 4.0]])
    # The regions map is cut to the mask; the others are not.
    work = np.full((2, 2), 100.0, np.float32)
    mask = np.zeros((4, 4), np.uint8)
    mask[:2, :2] = 255
    assert expected_score(work, mask, "regions").sum() == 4 * 100.0
    assert expected_score(work, mask, "blurred").sum() == 16 * 100.0


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
