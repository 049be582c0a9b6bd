"""The local cues: float64 per-pixel oracles, their parameters, and what each finds.

The cases they are for: a thin cable and a dark object whose colours occur elsewhere in
their grid cell (bright panels, shadow and space in one cell), which the cross score cannot
separate; and the case no cue can see, a black object in front of space.
"""

import cv2
import numpy as np
import pytest
from mrad_oracle import colour_evidence_naive, dark_evidence_naive, grey_naive

from allo_mrad_ros.detector import MradParams, detect, profile
from allo_mrad_ros.detector.local import (
    colour_evidence,
    combine,
    dark_evidence,
)
from allo_mrad_ros.detector.reference_cache import ReferenceCache


def _scene(rng, shape=(24, 30)):
    # Blocks of bright panel, shadow and space, noise SD 3, with a query that departs from
    # the reference here and there (a darker patch, a brighter line).
    reference = np.zeros((*shape, 3), np.uint8)
    reference[:, : shape[1] // 3] = (180, 170, 160)
    reference[: shape[0] // 2, shape[1] // 3 : 2 * shape[1] // 3] = (40, 42, 45)
    reference = np.clip(reference + rng.normal(0, 3, reference.shape), 0, 255).astype(np.uint8)
    query = np.clip(reference + rng.normal(0, 3, reference.shape), 0, 255)
    query[4:9, 2:7] = (20, 20, 20)
    query[:, 14] = (120, 110, 100)
    query[15:20, 22:27] = (200, 60, 60)
    return query.astype(np.uint8), reference


@pytest.mark.parametrize(("grid", "radius", "seed"), [(1, 0, 0), (2, 1, 1), (3, 2, 2), (4, 1, 3)])
def test_colour_evidence_matches_the_float64_oracle(grid, radius, seed):
    query, reference = _scene(np.random.default_rng(seed))
    expected = colour_evidence_naive(query, reference, grid, radius, 16.0)
    got = colour_evidence(query, reference, grid, radius, 16.0)
    assert got.dtype == np.float32 and got.shape == query.shape[:2]
    np.testing.assert_allclose(got, expected, rtol=1e-6, atol=1e-4)
    assert np.count_nonzero(expected) > 10


def test_colour_evidence_weight_and_empty_value():
    query, reference = _scene(np.random.default_rng(4))
    plain = colour_evidence(query, reference, 2, 1, 16.0)
    scaled = colour_evidence(query, reference, 2, 1, 16.0, weight=2.5, empty=-np.inf)
    found = plain > 0
    np.testing.assert_allclose(scaled[found], 2.5 * plain[found], rtol=1e-6)
    assert np.all(scaled[~found] == -np.inf)


def test_colour_evidence_reads_a_half_size_reference_at_the_query_size():
    # A 2x integer factor: nearest neighbour replicates each reference pixel 2 x 2.
    rng = np.random.default_rng(5)
    query, reference = _scene(rng, (24, 32))
    small = reference[::2, ::2].copy()
    big = np.repeat(np.repeat(small, 2, axis=0), 2, axis=1)
    expected = colour_evidence_naive(query, big, 2, 1, 16.0)
    np.testing.assert_allclose(colour_evidence(query, small, 2, 1, 16.0), expected, atol=1e-4)


def test_colour_evidence_of_float_and_uint16_input_equals_uint8():
    query, reference = _scene(np.random.default_rng(6))
    expected = colour_evidence(query, reference, 2, 1, 16.0)
    as_float = colour_evidence(query.astype(np.float32) / 255, reference, 2, 1, 16.0)
    # check_image hands the detector uint16 input as float on 0..1.
    as_u16 = colour_evidence((query.astype(np.float32) * 257) / 65535, reference, 2, 1, 16.0)
    np.testing.assert_array_equal(as_float, expected)
    np.testing.assert_array_equal(as_u16, expected)


@pytest.mark.parametrize(("grid", "radius", "seed"), [(1, 0, 7), (2, 1, 8), (3, 2, 9)])
def test_dark_evidence_matches_the_float64_oracle(grid, radius, seed):
    query, reference = _scene(np.random.default_rng(seed))
    expected = dark_evidence_naive(query, reference, grid, radius, 16.0)
    got = dark_evidence(query, reference, grid, radius, 16.0)
    assert got.dtype == np.float32 and got.shape == query.shape[:2]
    np.testing.assert_allclose(got, expected, atol=1e-6)
    assert np.count_nonzero(expected) > 5


def test_oracle_grey_is_opencvs():
    image = np.random.default_rng(10).integers(0, 256, (9, 11, 3), dtype=np.uint8)
    np.testing.assert_array_equal(grey_naive(image), cv2.cvtColor(image, cv2.COLOR_RGB2GRAY))


def test_identical_images_give_no_evidence():
    _query, reference = _scene(np.random.default_rng(11))
    assert not colour_evidence(reference, reference, 2, 1, 16.0).any()
    assert not dark_evidence(reference, reference, 2, 1, 16.0).any()


def test_an_edge_moved_within_the_radius_gives_no_evidence():
    # A pose error moves the reference's panel edge by a pixel; the query's mixed pixel at
    # the edge lies between the two sides.
    reference = np.zeros((20, 20, 3), np.uint8)
    reference[:, :10] = 200
    query = np.zeros_like(reference)
    query[:, :11] = 200
    query[:, 11] = 100
    assert not colour_evidence(query, reference, 1, 2, 16.0).any()
    assert colour_evidence(query, reference, 1, 0, 16.0).any()


def test_dark_object_over_space_is_invisible_and_over_lit_surface_is_not():
    reference = np.zeros((20, 40, 3), np.uint8)
    reference[:, 20:] = 150  # lit panel on the right, space on the left
    query = reference.copy()
    query[5:15, 5:15] = 3  # a black object in front of space
    query[5:15, 25:35] = 3  # the same object in front of the lit panel
    dark = dark_evidence(query, reference, 1, 1, 16.0)
    assert not dark[:, :20].any()
    assert dark[6:14, 26:34].min() > 0.9


def test_dark_evidence_ignores_a_cell_darker_than_its_reference_throughout():
    # The query's shading: the whole panel at 70 % of the reference, and one object at 10 %.
    reference = np.full((20, 20, 3), 150, np.uint8)
    query = np.full_like(reference, 105)
    query[8:11, 8:11] = 15
    dark = dark_evidence(query, reference, 1, 1, 16.0)
    assert dark[9, 9] > 0.5
    dark[8:11, 8:11] = 0
    assert not dark.any()


def test_combine_keeps_the_score_where_there_is_no_evidence():
    raw = np.array([[-5.0, 3.0, 10.0, -1.0]], np.float32)
    evidence = np.array([[-np.inf, 8.0, 4.0, 2.0]], np.float32)
    np.testing.assert_array_equal(combine(raw, evidence), [[-5.0, 8.0, 10.0, 2.0]])


def _busy_cell_scene(seed):
    # Bright panels, shadow and space in every 4 x 4 cell, at 160 x 240; a dark disc over a
    # panel and a one-pixel cable of the shadow's grey across a panel: their colours occur in
    # the cells, so the cross score has little to separate them by.
    rng = np.random.default_rng(seed)
    reference = np.zeros((160, 240, 3), np.uint8)
    for col in range(0, 240, 20):
        reference[:, col : col + 8] = (190, 185, 175)
        reference[:, col + 8 : col + 12] = (45, 45, 48)
    query = reference.astype(np.float64)
    disc = np.zeros((160, 240), np.uint8)
    cv2.circle(disc, (64, 40), 3, 1, -1)
    disc &= (reference[..., 0] > 100).astype(np.uint8)
    query[disc > 0] = (8, 8, 8)
    cable = np.zeros((160, 240), bool)
    cable[100, 40:200] = True
    cable &= reference[..., 0] > 100
    query[cable] = (45, 45, 48)
    query += rng.normal(0, 2, query.shape)
    return np.clip(query, 0, 255).astype(np.uint8), reference, disc > 0, cable


def _busy_cell_params(**changes):
    # The busy-cell scene's detector: full resolution, 4 x 4 cells, no colour transfer, the
    # cues off and, when on, at radius 1 (at the default's 3 the cable's grey lies within
    # the window: the shadow strip).
    return MradParams(
        process_scale=1.0, grid=4, colour_transfer="none", local_weight=0.0, local_radius=1
    ).replace(**changes)


def _separation(result, target):
    # Share of the target's pixels above the 99th percentile of the pixels far from it.
    far = ~cv2.dilate(target.astype(np.uint8), np.ones((9, 9), np.uint8)).astype(bool)
    threshold = np.percentile(result.score[far], 99)
    return float(np.mean(result.score[target] > threshold))


@pytest.mark.parametrize("cue", ["local_weight", "dark_weight"])
def test_cues_rank_a_dark_object_in_a_busy_cell_higher(cue):
    query, reference, disc, _ = _busy_cell_scene(12)
    base = _busy_cell_params(score_sigma=0.0)
    off = detect(query, reference, base)
    on = detect(query, reference, base.replace(**{cue: 1.0}))
    assert "local" in on.timings_ms and "local" not in off.timings_ms
    assert _separation(on, disc) > _separation(off, disc) + 0.3


def test_colour_cue_ranks_a_thin_cable_higher():
    query, reference, _, cable = _busy_cell_scene(13)
    base = _busy_cell_params(score_sigma=0.0)
    off = detect(query, reference, base)
    on = detect(query, reference, base.replace(local_weight=1.0))
    assert _separation(on, cable) > _separation(off, cable) + 0.3


@pytest.mark.parametrize("cue", ["local_weight", "dark_weight"])
@pytest.mark.parametrize(
    ("rule", "frame_map"), [("contrast", "mask"), ("contrast", "ranking"), ("area", "mask")]
)
def test_the_frame_decision_reads_the_cell_statistics_alone(cue, rule, frame_map):
    # The cue grows the mask (its regions, the ranking map), but the decision's operating
    # point was calibrated without it: the verdict and the anomaly score stay the cue-free
    # detector's to the bit, while the mask and the regions take the cue's evidence.
    query, reference, disc, _ = _busy_cell_scene(12)
    base = _busy_cell_params(frame_rule=rule, frame_map=frame_map, area_threshold=1e-4)
    off = detect(query, reference, base)
    on = detect(query, reference, base.replace(**{cue: 1.0}))
    assert on.mask[disc].sum() > off.mask[disc].sum()
    assert on.area > off.area
    assert (on.anomalous, on.anomaly_score) == (off.anomalous, off.anomaly_score)
    assert "decision_mask" in on.timings_ms and "decision_mask" not in off.timings_ms


def test_with_a_cue_the_area_image_score_is_the_published_masks():
    # The image score ranks frames by what the detector shows (the cue's mask), the verdict
    # by the cue-free decision.
    query, reference, _, _ = _busy_cell_scene(12)
    params = _busy_cell_params(image_score="area")
    off = detect(query, reference, params)
    on = detect(query, reference, params.replace(local_weight=1.0))
    assert on.image_score == float(on.area) > off.image_score == float(off.area)


def test_weights_zero_leave_the_detection_unchanged():
    query, reference, _, _ = _busy_cell_scene(14)
    params = MradParams(process_scale=0.5, local_weight=0.0)
    a = detect(query, reference, params)
    b = detect(query, reference, params.replace(dark_weight=0.0, local_radius=1))
    assert "local" not in a.timings_ms
    np.testing.assert_array_equal(a.score, b.score)
    np.testing.assert_array_equal(a.mask, b.mask)


def test_a_reused_reference_gives_the_same_detection():
    query, reference, _, _ = _busy_cell_scene(15)
    reference = cv2.resize(reference, (120, 80), interpolation=cv2.INTER_AREA)
    reference.flags.writeable = False
    params = MradParams(process_scale=0.5, local_weight=1.0, dark_weight=0.5)
    cache = ReferenceCache()
    first = detect(query, reference, params, cache=cache)
    again = detect(query, reference, params, cache=cache)
    fresh = detect(query, reference.copy(), params)
    assert cache.hits > 0
    np.testing.assert_array_equal(first.score, fresh.score)
    np.testing.assert_array_equal(again.score, fresh.score)


@pytest.mark.parametrize("name", ["local_weight", "dark_weight"])
@pytest.mark.parametrize("value", [-0.1, 100.5, float("nan"), float("inf"), "1", True, None])
def test_weights_are_validated(name, value):
    with pytest.raises(ValueError, match=name):
        MradParams(**{name: value})


@pytest.mark.parametrize("value", [-1, 5, 1.0, True, "1"])
def test_local_radius_is_validated(value):
    with pytest.raises(ValueError, match="local_radius"):
        MradParams(local_radius=value)


def test_parameters_accept_their_ranges():
    for value in (0.0, 0.25, 100.0, 3):
        assert MradParams(local_weight=value).local_weight == value
        assert MradParams(dark_weight=value).dark_weight == value
    for radius in range(5):
        assert MradParams(local_radius=radius).local_radius == radius


def test_the_local_cues_are_off_by_default_and_in_the_paper():
    params = MradParams()
    assert (params.local_weight, params.local_radius, params.dark_weight) == (0.0, 3, 0.0)
    for name in ("paper", "baseline", "previous"):
        assert profile(name).local_weight == 0.0 and profile(name).dark_weight == 0.0
