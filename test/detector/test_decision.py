"""The frame decision: the contrast rule against a slow oracle, its anomaly score, and what it
does that the mask's area did not."""

import numpy as np
import pytest

from allo_mrad_ros.detector import detect, profile
from allo_mrad_ros.detector.decision import (
    DECISION_FIELDS,
    MIN_BACKGROUND,
    FrameEvidence,
    anomaly_score,
    frame_decision,
    frame_evidence,
)
from allo_mrad_ros.detector.params import MradParams, ParamsError
from allo_mrad_ros.example_scene import example_pair


def quantile_by_hand(values, q):
    # Linear interpolation between the order statistics around position q * (n - 1).
    ordered = sorted(values)
    position = q * (len(ordered) - 1)
    low = int(position)
    high = min(low + 1, len(ordered) - 1)
    return ordered[low] + (position - low) * (ordered[high] - ordered[low])


def contrast_by_hand(score, mask, query, params):
    """The contrast rule written out pixel by pixel, in float64."""
    height, width = score.shape
    values = sorted((float(v) for v in score.ravel()), reverse=True)
    count = max(1, round(params.frame_top_fraction * len(values)))
    evidence = sum(values[:count]) / count
    level = 8.0 if query.dtype == np.uint8 else 8.0 / 255.0
    background = []
    for y in range(height):
        for x in range(width):
            if max(float(c) for c in query[y, x]) <= level:
                continue  # black space
            near_mask = any(
                mask[yy, xx]
                for yy in range(max(0, y - 2), min(height, y + 3))
                for xx in range(max(0, x - 2), min(width, x + 3))
            )
            if not near_mask:
                background.append(float(score[y, x]))
    level = quantile_by_hand(background, params.frame_background)
    if len(background) < MIN_BACKGROUND:
        level = 0.0
    return evidence / max(level, params.frame_floor)


def random_frame(seed, *, dtype=np.uint8, space=0.4, regions=3, shape=(36, 52)):
    rng = np.random.default_rng(seed)
    score = (1.0 + rng.gamma(0.6, 3.0, shape)).astype(np.float32)
    query = rng.integers(9, 255, (*shape, 3), dtype=np.uint8)
    query[rng.random(shape) < space] = rng.integers(0, 9, 3)  # space: every channel <= 8
    mask = np.zeros(shape, np.uint8)
    for _ in range(regions):
        y, x = rng.integers(0, shape[0] - 4), rng.integers(0, shape[1] - 4)
        h, w = rng.integers(1, 5, 2)
        mask[y : y + h, x : x + w] = 255
        score[y : y + h, x : x + w] += rng.uniform(20, 200)
    if dtype != np.uint8:
        query = (query / 255.0).astype(dtype)
    return score, mask, query


@pytest.mark.parametrize(
    ("seed", "dtype", "space", "regions", "changes"),
    [
        (0, np.uint8, 0.4, 3, {}),
        (1, np.float32, 0.4, 3, {}),
        (2, np.uint8, 0.0, 0, {"frame_background": 0.5, "frame_floor": 0.5}),
        (3, np.uint8, 0.7, 6, {"frame_top_fraction": 0.05, "frame_background": 1.0}),
        (4, np.float64, 0.2, 2, {"frame_top_fraction": 1.0, "frame_background": 0.0}),
        (5, np.uint8, 0.98, 1, {}),  # under MIN_BACKGROUND station pixels: the floor
    ],
)
def test_contrast_equals_the_pixel_by_pixel_oracle(seed, dtype, space, regions, changes):
    score, mask, query = random_frame(seed, dtype=dtype, space=space, regions=regions)
    params = MradParams(**changes)
    found = frame_evidence(score, mask, query, params).contrast(params.frame_floor)
    assert found == pytest.approx(contrast_by_hand(score, mask, query, params), rel=1e-6)


def test_tied_scores_give_the_oracle_quantile():
    # A map at its floor over most of the station (ties), as a clean frame is.
    score, mask, query = random_frame(7)
    score[::2] = 1.0
    params = MradParams(frame_floor=0.01)
    found = frame_evidence(score, mask, query, params).contrast(params.frame_floor)
    assert found == pytest.approx(contrast_by_hand(score, mask, query, params), rel=1e-6)


def raw_for(value, score_ref=1000.0):
    """The raw score that the continuous map puts at ``value`` (>= 1)."""
    return score_ref * (value - 1.0) / (255.0 - value)


def lit_frame(level, *, patch, rows=6, cols=5, shape=(270, 480)):
    """A station frame whose maps (the ranking map, and the mask's raw score on its scale)
    sit at ``level`` everywhere, with a ``rows`` x ``cols`` region of ``patch`` (the mask
    holds the region), and its mask at the query's 4 x size."""
    score = np.full(shape, level, np.float32)
    query = np.full((*shape, 3), 120, np.uint8)
    mask = np.zeros(shape, np.uint8)
    score[100 : 100 + rows, 200 : 200 + cols] = patch
    mask[100 : 100 + rows, 200 : 200 + cols] = 255
    raw = raw_for(score.astype(np.float64)).astype(np.float32)
    full = np.repeat(np.repeat(mask, 4, axis=0), 4, axis=1)
    return full, score, raw, mask, query


def patch_for(contrast, params, pixels, level=1.0, shape=(270, 480)):
    """The value a region of ``pixels`` needs for the frame to reach ``contrast`` when the
    rest of the map is at ``level`` (at most the floor)."""
    count = max(1, round(params.frame_top_fraction * shape[0] * shape[1]))
    evidence = contrast * max(level, params.frame_floor)
    return (evidence * count - (count - pixels) * level) / pixels


def test_a_lifted_map_needs_proportionally_stronger_evidence():
    # One region of 15 x 12 map pixels (0.14 % of the image, over area_threshold, so the area
    # rule flags it on either frame) on a clean frame and on a frame whose whole map another
    # renderer's shading lifted to 10, the region 4 times that: the contrast rule flags the
    # first, and not the second, whose region does not stand out from its own background.
    params = MradParams()
    patch = patch_for(3.0 * params.frame_contrast, params, 180)
    clean = frame_decision(*lit_frame(1.0, patch=patch, rows=15, cols=12), params)
    lifted = frame_decision(*lit_frame(10.0, patch=40.0, rows=15, cols=12), params)
    assert clean.anomalous and not lifted.anomalous
    assert lifted.anomaly_score < 0.5 < clean.anomaly_score
    by_area = params.replace(frame_rule="area")
    assert frame_decision(*lit_frame(10.0, patch=40.0, rows=15, cols=12), by_area).anomalous


def test_a_small_region_that_stands_out_is_found_whatever_its_area():
    # 60 map pixels (960 image pixels, 0.05 % of the image, under area_threshold): the area
    # rule misses it, the contrast rule finds it when it stands out enough.
    params = MradParams()
    patch = patch_for(2.0 * params.frame_contrast, params, 60)
    assert patch < 250.0  # a value the map can hold
    frame = lit_frame(1.0, patch=patch, rows=10, cols=6)
    decision = frame_decision(*frame, params)
    assert decision.area < params.area_threshold * 1080 * 1920
    assert decision.anomalous and decision.anomaly_score > 0.5
    assert not frame_decision(*frame, params.replace(frame_rule="area")).anomalous


def test_the_contrast_is_unchanged_when_the_whole_map_is_scaled():
    # A camera or renderer that lifts every score by one factor moves neither the contrast
    # nor the decision, as long as the background stays above the floor.
    score, mask, query = random_frame(11, space=0.2)
    score += 5.0
    params = MradParams(frame_floor=1.0)
    base = frame_evidence(score, mask, query, params).contrast(1.0)
    scaled = frame_evidence(score * 3.0, mask, query, params).contrast(1.0)
    assert scaled == pytest.approx(base, rel=1e-5)


@pytest.mark.parametrize("threshold", [0.5, 4.5, 100.0])
def test_anomaly_score_is_half_at_the_threshold_and_increasing(threshold):
    values = np.concatenate([[0.0], np.geomspace(1e-3, 1e4, 60)])
    scores = [anomaly_score(v, threshold) for v in values]
    assert all(0.0 <= s <= 1.0 for s in scores)
    assert np.all(np.diff(scores) > 0)
    assert anomaly_score(threshold, threshold) == 0.5
    assert anomaly_score(-3.0, threshold) == 0.0


def test_frame_evidence_with_arrays_of_two_sizes_names_them():
    score, mask, query = random_frame(0)
    with pytest.raises(ValueError, match="one size"):
        frame_evidence(score, mask[:-1], query, MradParams())


def test_no_background_reads_zero():
    score, mask, query = random_frame(0, space=1.0)
    assert frame_evidence(score, mask, query, MradParams()).background == 0.0
    assert FrameEvidence(10.0, 0.0).contrast(2.0) == 5.0


@pytest.fixture(scope="module")
def pair():
    return example_pair(270, 480, seed=3)


@pytest.mark.parametrize("rule", ["contrast", "area"])
def test_the_result_says_anomalous_exactly_when_its_score_is_over_half(pair, rule):
    params = profile("default", frame_rule=rule)
    for query in (pair.query, pair.clean_query):
        result = detect(query, pair.reference, params)
        assert 0.0 <= result.anomaly_score <= 1.0
        assert result.anomalous == (result.anomaly_score > 0.5)
    assert detect(pair.query, pair.reference, params).anomalous
    assert not detect(pair.clean_query, pair.reference, params).anomalous


def test_the_rule_changes_neither_the_mask_nor_the_maps(pair):
    by_contrast = detect(pair.query, pair.reference, profile("default"))
    by_area = detect(pair.query, pair.reference, profile("default", frame_rule="area"))
    np.testing.assert_array_equal(by_contrast.mask, by_area.mask)
    np.testing.assert_array_equal(by_contrast.work_score, by_area.work_score)
    np.testing.assert_array_equal(by_contrast.raw_score, by_area.raw_score)
    assert by_contrast.regions == by_area.regions
    assert by_contrast.image_score == by_area.image_score


def test_the_paper_profiles_decide_by_area():
    assert profile("paper").frame_rule == "area"
    assert profile("previous").frame_rule == "area"
    assert MradParams().frame_rule == "contrast"


@pytest.mark.parametrize(
    ("name", "value"),
    [
        ("frame_rule", "peak"),
        ("frame_contrast", 0.0),
        ("frame_background", 1.5),
        ("frame_floor", 0.0),
        ("frame_top_fraction", 0.0),
    ],
)
def test_invalid_decision_parameters_are_refused_by_name(name, value):
    with pytest.raises(ParamsError, match=name):
        MradParams(**{name: value})


DECISION_CHANGES = {
    "area_threshold": 0.01,
    "image_score": "area",
    "image_top_fraction": 0.01,
    "frame_rule": "area",
    "frame_map": "ranking",
    "frame_top_fraction": 0.01,
    "frame_background": 0.5,
    "frame_floor": 1.0,
    "frame_contrast": 100.0,
}


def test_the_decision_fields_are_the_parameters_listed():
    assert set(DECISION_CHANGES) == set(DECISION_FIELDS)


@pytest.mark.parametrize("name", sorted(DECISION_CHANGES))
def test_no_decision_field_changes_the_mask_or_the_maps(pair, name):
    # What lets a benchmark detect once and decide many times (benchmarks/decision_cache.py).
    base = detect(pair.query, pair.reference, MradParams())
    changed = detect(pair.query, pair.reference, MradParams(**{name: DECISION_CHANGES[name]}))
    np.testing.assert_array_equal(base.mask, changed.mask)
    np.testing.assert_array_equal(base.work_score, changed.work_score)
    np.testing.assert_array_equal(base.raw_score, changed.raw_score)
    assert base.regions == changed.regions
