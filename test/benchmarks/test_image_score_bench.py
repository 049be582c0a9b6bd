"""The image-score benchmark's candidate frame scores, from one detection result."""

import pytest

from allo_mrad_ros.detector import detect, profile
from allo_mrad_ros.example_scene import example_pair
from benchmarks.image_score import candidates


def test_benchmark_candidates_include_the_area_and_the_map_maximum():
    pair = example_pair(270, 480, seed=3)
    params = profile("default")
    result = detect(pair.query, pair.reference, params)
    scores = candidates(result, params)
    assert scores["area"] == result.area
    assert scores["map maximum"] == pytest.approx(float(result.score.max()))
    assert scores["map maximum"] >= scores["map top 0.0001"] >= scores["map top 0.001"]
