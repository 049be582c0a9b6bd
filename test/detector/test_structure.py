"""The structure cue: a float64 per-pixel oracle, its parameter, and what it finds.

The case it is for: a dark object on a dark surface of the same colour, whose outline and
highlight are the only difference from the reference.
"""

import cv2
import numpy as np
import pytest
from mrad_oracle import structure_score_naive

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.structure import (
    DARK_FLOOR,
    NEAR,
    NOISE_SIGMAS,
    luminance,
    structure_channel,
    structure_score,
)


def _noisy(shape, level, sigma, rng):
    return np.clip(rng.normal(level, sigma, shape), 0, 255).astype(np.uint8)


@pytest.mark.parametrize(("grid", "seed"), [(1, 0), (2, 1), (3, 2)])
def test_structure_score_matches_the_float64_oracle(grid, seed):
    rng = np.random.default_rng(seed)
    reference = _noisy((23, 31, 3), 60, 25, rng)
    query = _noisy((23, 31, 3), 50, 35, rng)
    query[5:12, 8:20] = 200  # an edged block the reference does not have
    expected = structure_score_naive(query, reference, grid, DARK_FLOOR, NEAR, NOISE_SIGMAS)
    got = structure_score(query, reference, grid)
    assert got.dtype == np.float32 and got.shape == query.shape[:2]
    np.testing.assert_allclose(got, expected, atol=2e-4)
    assert np.count_nonzero(expected) > 0


def test_structure_score_of_float_and_uint16_input_equals_uint8():
    rng = np.random.default_rng(4)
    reference = _noisy((20, 24, 3), 40, 20, rng)
    query = _noisy((20, 24, 3), 40, 30, rng)
    expected = structure_score_naive(query, reference, 2)
    as_float = structure_score(
        query.astype(np.float32) / 255, reference.astype(np.float32) / 255, 2
    )
    as_u16 = structure_score(query.astype(np.uint16) * 257, reference.astype(np.uint16) * 257, 2)
    np.testing.assert_allclose(as_float, expected, atol=2e-4)
    np.testing.assert_allclose(as_u16, expected, atol=2e-4)


def test_lower_resolution_reference_scores_at_its_resolution_then_resizes():
    rng = np.random.default_rng(5)
    query = _noisy((32, 48, 3), 30, 10, rng)
    query[8:20, 10:30] = 120
    reference = _noisy((16, 24, 3), 30, 10, rng)
    # The query's luma, area-averaged 2 x 2, against the reference, in float64.
    luma = luminance(query).astype(np.float64)
    low = luma.reshape(16, 2, 24, 2).mean(axis=(1, 3))
    low_rgb = np.repeat(low[..., None], 3, axis=2) / 255.0
    ref_luma = luminance(reference).astype(np.float64)
    ref_rgb = np.repeat(ref_luma[..., None], 3, axis=2) / 255.0
    expected_low = structure_score_naive(low_rgb, ref_rgb, 2).astype(np.float32)
    expected = cv2.resize(expected_low, (48, 32), interpolation=cv2.INTER_LINEAR)
    got = structure_score(query, reference, 2)
    assert got.shape == (32, 48)
    np.testing.assert_allclose(got, expected, atol=2e-3)


def test_identical_images_score_zero():
    rng = np.random.default_rng(6)
    image = _noisy((40, 40, 3), 80, 30, rng)
    np.testing.assert_array_equal(structure_score(image, image, 2), 0.0)


def test_channel_is_luminance_normalised():
    # A 20 % step weighs the same on a dark and a bright surface (above the dark floor).
    dark = np.full((9, 9), 40.0 - DARK_FLOOR, np.float32)
    dark[:, 5:] = 1.2 * 40.0 - DARK_FLOOR
    bright = np.full((9, 9), 200.0 - DARK_FLOOR, np.float32)
    bright[:, 5:] = 1.2 * 200.0 - DARK_FLOOR
    np.testing.assert_allclose(structure_channel(dark), structure_channel(bright), atol=1e-5)


def _dark_object_scene(seed):
    # A dark surface (14 DN, noise SD 2) between bright struts, so every cell's colours
    # spread widely, with a disc of nearly the same colour whose outline is a faintly
    # brighter rim and which carries a small highlight: what a dark visor is to a camera.
    rng = np.random.default_rng(seed)
    size = (160, 240)
    reference = np.full((*size, 3), 14, np.uint8)
    for col in range(0, 240, 100):
        reference[:, col : col + 12] = 150
    query = reference.astype(np.float64)
    disc = np.zeros(size, np.uint8)
    cv2.circle(disc, (60, 80), 30, 1, -1)
    query[disc > 0] = 18
    rim = np.zeros(size, np.uint8)
    cv2.circle(rim, (60, 80), 29, 1, 2)
    query[rim > 0] = 26
    cv2.circle(query, (52, 72), 2, (90, 90, 90), -1)
    query += rng.normal(0, 2, query.shape)
    return np.clip(query, 0, 255).astype(np.uint8), reference, disc > 0


def test_cue_ranks_a_dark_outlined_object_higher():
    query, reference, disc = _dark_object_scene(7)
    base = MradParams(process_scale=1.0, grid=4)
    off = detect(query, reference, base)
    on = detect(query, reference, base.replace(structure_weight=1.0))
    assert "structure" in on.timings_ms and "structure" not in off.timings_ms
    background = ~cv2.dilate(disc.astype(np.uint8), np.ones((15, 15), np.uint8)).astype(bool)

    def separation(result):
        # Share of the object's pixels above the background's 95th percentile.
        threshold = np.percentile(result.score[background], 95)
        return float(np.mean(result.score[disc] > threshold))

    assert separation(on) > separation(off) + 0.05


def test_weight_zero_leaves_the_detection_unchanged():
    query, reference, _ = _dark_object_scene(8)
    params = MradParams(process_scale=0.5)
    a = detect(query, reference, params)
    b = detect(query, reference, params.replace(structure_weight=0.0))
    np.testing.assert_array_equal(a.score, b.score)
    np.testing.assert_array_equal(a.mask, b.mask)


@pytest.mark.parametrize("value", [-0.1, 100.5, float("nan"), float("inf"), "1", True, None])
def test_structure_weight_is_validated(value):
    with pytest.raises(ValueError, match="structure_weight"):
        MradParams(structure_weight=value)


def test_structure_weight_accepts_its_range_and_defaults_off():
    assert MradParams().structure_weight == 0.0
    for value in (0.0, 0.25, 100.0, 3):
        assert MradParams(structure_weight=value).structure_weight == value
