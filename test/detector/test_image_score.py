"""The frame score that I.AUROC ranks: the mask's area or the top of the pixel map."""

import numpy as np
import pytest

from allo_mrad_ros.detector import METHODS, detect, profile
from allo_mrad_ros.detector.decision import image_score
from allo_mrad_ros.example_scene import example_pair


def top_mean_by_sorting(score, fraction):
    # Obviously right: sort every pixel in float64, average the highest ones.
    values = np.sort(score.astype(np.float64).ravel())[::-1]
    count = max(1, round(fraction * values.size))
    return float(values[:count].mean())


@pytest.mark.parametrize("fraction", [1e-6, 1e-4, 0.01, 1.0])
def test_map_top_is_the_mean_of_the_highest_pixels(fraction):
    rng = np.random.default_rng(1)
    score = (rng.random((90, 160)) ** 4 * 255).astype(np.float32)
    params = profile("default", image_score="map_top", image_top_fraction=fraction)
    assert image_score(score, 17, params) == pytest.approx(
        top_mean_by_sorting(score, fraction), rel=1e-6
    )


def test_area_rule_returns_the_area():
    params = profile("default", image_score="area")
    assert image_score(np.zeros((4, 4), np.float32), 17, params) == 17.0


@pytest.fixture(scope="module")
def pair():
    return example_pair(270, 480, seed=3)


# RXD ignores the reference and finds nothing on this scene; PAD's thresholded mask is empty.
@pytest.mark.parametrize(
    ("method", "rule"), [("MRAD", "map_top"), ("MRAD", "area"), ("PAD", "map_top")]
)
def test_a_frame_with_an_object_outranks_the_same_frame_without(pair, method, rule):
    params = profile("default", image_score=rule)
    normal = METHODS[method](pair.clean_query, pair.reference, params)
    anomalous = METHODS[method](pair.query, pair.reference, params)
    assert anomalous.image_score > normal.image_score


def test_detect_reports_the_rule_it_was_given(pair):
    by_area = detect(pair.query, pair.reference, profile("default", image_score="area"))
    by_map = detect(pair.query, pair.reference, profile("default"))
    assert by_area.image_score == by_area.area
    assert by_map.image_score != by_map.area
    assert by_map.anomalous == by_area.anomalous  # the flag is the mask's either way
