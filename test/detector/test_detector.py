"""detect() end to end: the hard cases of the method (docs/method.md), bad input, and a
synthetic scene."""

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector import METHODS, MradParams, detect, profile
from allo_mrad_ros.detector.postprocess import NEGATIVE_BAND
from allo_mrad_ros.example_scene import example_pair

STAGES = [
    "colour_transfer",
    "cross_score",
    "scale_threshold",
    "noise_removal",
    "blur",
    "region_growing",
    "regions",
    "pixel_score",
    "decision",
    "total",
]


def assert_well_formed(result, shape):
    assert result.score.shape == shape and result.score.dtype == np.float32
    assert result.mask.shape == shape and result.mask.dtype == np.uint8
    assert np.isfinite(result.score).all() and np.isfinite(result.raw_score).all()
    assert result.score.min() >= 0 and result.score.max() <= 255
    assert set(np.unique(result.mask)) <= {0, 255}
    assert result.area == np.count_nonzero(result.mask)


def assert_score_confined_to_mask(result):
    assert not result.score[result.mask == 0].any()


@pytest.fixture(scope="module")
def pair():
    return example_pair(270, 480, seed=3)


def iou(a, b):
    return np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1)


def test_pasted_object_is_found_and_clean_frame_is_not(pair):
    reference = cv2.resize(pair.reference, (240, 135), interpolation=cv2.INTER_AREA)
    found = detect(pair.query, reference)
    assert_well_formed(found, pair.query.shape[:2])
    # The default score ranks every pixel: the object's pixels outrank the rest.
    truth = pair.object_mask > 0
    assert np.median(found.score[truth]) > np.percentile(found.score[~truth], 99)
    assert found.anomalous
    assert iou(found.mask > 0, pair.object_mask > 0) >= 0.5
    clean = detect(pair.clean_query, reference)
    assert not clean.anomalous
    assert list(found.timings_ms) == STAGES  # the local cues are off by default
    with_cue = detect(pair.query, reference, MradParams(local_weight=1.0))
    assert list(with_cue.timings_ms) == [*STAGES[:2], "decision_mask", "local", *STAGES[2:]]


def test_full_hd_example_meets_iou():
    pair = example_pair()
    reference = cv2.resize(pair.reference, (480, 270), interpolation=cv2.INTER_AREA)
    result = detect(pair.query, reference)
    assert result.anomalous and iou(result.mask > 0, pair.object_mask > 0) >= 0.5
    assert not detect(pair.clean_query, reference).anomalous


def test_identical_query_and_reference_are_not_anomalous(pair):
    result = detect(pair.reference, pair.reference)
    assert not result.anomalous and result.area == 0
    # At full resolution the query is the reference pixel for pixel: the score cancels.
    exact = detect(pair.reference, pair.reference, MradParams(process_scale=1.0))
    assert not exact.anomalous and np.abs(exact.raw_score).max() < 1e-3


def test_repeat_runs_are_bit_identical(pair):
    a = detect(pair.query, pair.reference)
    b = detect(pair.query.copy(), pair.reference.copy())
    for field in ("score", "raw_score", "mask"):
        assert getattr(a, field).tobytes() == getattr(b, field).tobytes()
    assert a.area == b.area


@pytest.mark.parametrize(
    "fill", [0, 255, "grey"], ids=["all_black", "saturated", "r_equals_g_equals_b"]
)
def test_degenerate_cells(fill):
    rng = np.random.default_rng(0)
    reference = np.zeros((64, 64, 3), dtype=np.uint8)
    if fill == "grey":
        reference[:] = rng.integers(80, 120, (64, 64), dtype=np.uint8)[..., None]
    else:
        reference[:] = fill
    result = detect(reference.copy(), reference)
    assert_well_formed(result, (64, 64))
    assert not result.anomalous
    query = reference.copy()
    query[20:36, 20:36] = (30, 200, 90)  # a coloured object no cell of the reference has
    found = detect(query, reference, MradParams(grid=2))
    assert_well_formed(found, (64, 64))
    assert found.anomalous


def test_single_pixel_cells():
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    result = detect(image, image.copy(), MradParams(grid=16, process_scale=1.0))
    assert_well_formed(result, (16, 16))
    assert not result.anomalous


def test_image_smaller_than_grid_is_rejected():
    image = np.zeros((3, 3, 3), dtype=np.uint8)
    with pytest.raises(ValueError, match="grid=4 is too fine for a 3x3 image"):
        detect(image, image, MradParams(grid=4, process_scale=1.0))
    with pytest.raises(
        ValueError,
        match=r"grid=8 is too fine for the 12x8 query processed at "
        r"process_scale=0.5 \(6x4\)",
    ):
        detect(
            np.zeros((8, 12, 3), np.uint8),
            np.zeros((8, 12, 3), np.uint8),
            MradParams(process_scale=0.5),
        )


@pytest.mark.parametrize("dtype", [np.uint16, np.float32, np.float64])
def test_uint16_and_float_inputs_match_uint8(pair, dtype):
    scale = 257 if dtype == np.uint16 else 1 / 255
    query = (pair.query.astype(np.float64) * scale).astype(dtype)
    reference = (pair.reference.astype(np.float64) * scale).astype(dtype)
    result = detect(query, reference)
    expected = detect(pair.query, pair.reference)
    assert_well_formed(result, pair.query.shape[:2])
    assert result.anomalous == expected.anomalous
    assert iou(result.mask > 0, expected.mask > 0) > 0.95


@pytest.mark.parametrize("size", [(480, 270), (240, 135), (120, 68)])
def test_lower_resolution_reference_still_finds_the_object(size):
    pair = example_pair(540, 960, seed=3)
    reference = cv2.resize(pair.reference, size, interpolation=cv2.INTER_AREA)
    result = detect(pair.query, reference)
    truth = pair.object_mask > 0
    found = result.mask > 0
    assert result.anomalous
    # Hysteresis keeps the whole object and the blur's rim around it (about a quarter of
    # the mask here); the paper's tolerance growth kept a third less of the object.
    assert np.count_nonzero(found & truth) >= 0.7 * np.count_nonzero(found)  # on the object
    assert np.count_nonzero(found & truth) >= 0.9 * np.count_nonzero(truth)  # all of it
    assert not detect(pair.clean_query, reference).anomalous


def test_constant_score_map_gives_no_seeds_and_empty_mask():
    image = np.full((32, 32, 3), 77, dtype=np.uint8)
    result = detect(image, image.copy())
    assert result.area == 0 and not result.mask.any()
    # A zero raw score maps to the bottom of the positive range, the same everywhere.
    np.testing.assert_array_equal(result.score, np.float32(NEGATIVE_BAND))


@pytest.mark.parametrize(
    "changes",
    [
        {"grid": 1},
        {"grid": 16},
        {"tolerance": 0.0},
        {"blur_sigma": 0.0},
        {"noise_removal": "cell_spread"},
        {"noise_removal": "none"},
        {"score_scaling": "per_image"},
        {"process_scale": 0.5},
        {"connectivity": 4},
    ],
    ids=lambda c: "-".join(f"{k}={v}" for k, v in c.items()),
)
def test_extreme_and_alternative_parameters_stay_well_formed(pair, changes):
    params = MradParams().replace(**changes)
    result = detect(pair.query, pair.reference, params)
    assert_well_formed(result, pair.query.shape[:2])
    # A clean frame at full resolution: identical statistics, nothing to find. (Per-image
    # scaling stretches any residual to 255, which is why it is not the default.)
    clean = detect(pair.reference, pair.reference, params.replace(process_scale=1.0))
    assert not clean.anomalous


@pytest.mark.parametrize("name", sorted(METHODS))
def test_every_method_shares_the_interface(pair, name):
    result = METHODS[name](pair.query, pair.reference, MradParams())
    assert_well_formed(result, pair.query.shape[:2])
    assert "total" in result.timings_ms


@pytest.mark.parametrize(
    ("query", "reference", "message"),
    [
        (np.zeros((8, 8), np.uint8), np.zeros((8, 8, 3), np.uint8), r"query must have shape"),
        (np.zeros((8, 8, 4), np.uint8), np.zeros((8, 8, 3), np.uint8), r"query must have shape"),
        (np.zeros((8, 8, 3), np.uint8), np.zeros((8, 8, 1), np.uint8), r"reference must have"),
        (np.zeros((0, 8, 3), np.uint8), np.zeros((8, 8, 3), np.uint8), r"query is empty"),
        (np.zeros((8, 8, 3), np.int32), np.zeros((8, 8, 3), np.uint8), r"unsupported dtype int32"),
        (np.zeros((8, 8, 3), bool), np.zeros((8, 8, 3), np.uint8), r"unsupported dtype bool"),
        (np.full((8, 8, 3), np.nan), np.zeros((8, 8, 3)), r"query contains 192 NaN or Inf"),
        (np.zeros((8, 8, 3)), np.full((8, 8, 3), np.inf), r"reference contains 192 NaN"),
        (np.zeros((90, 160, 3), np.uint8), np.zeros((90, 90, 3), np.uint8), r"aspect ratio"),
        ([[1, 2, 3]], np.zeros((8, 8, 3), np.uint8), r"query must be a numpy array"),
    ],
)
def test_bad_images_raise_value_error_naming_the_argument(query, reference, message):
    with pytest.raises(ValueError, match=message):
        detect(query, reference)


def test_missing_reference_is_rejected():
    with pytest.raises(ValueError, match="reference is required"):
        detect(np.zeros((8, 8, 3), np.uint8), None)


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"grid": 0}, r"grid must be an integer in \[1, 64\], got 0"),
        ({"grid": 2.5}, r"grid must be an integer"),
        ({"blur_sigma": -1.0}, r"blur_sigma must be in \[0, 100\], got -1.0"),
        ({"tolerance": 300.0}, r"tolerance must be in \[0, 255\], got 300.0"),
        ({"tolerance": float("nan")}, r"tolerance must be finite"),
        ({"kernel_fraction": 0.0}, r"kernel_fraction must be in \(0, 1\]"),
        ({"score_scaling": "log"}, r"score_scaling must be one of"),
        ({"noise_removal": "median"}, r"noise_removal must be one of"),
        ({"abs_floor": 0.0}, r"abs_floor must be in \(0"),
        ({"connectivity": 6}, r"connectivity must be one of \[4, 8\]"),
        ({"area_threshold": 1.0}, r"area_threshold must be in \[0, 1\)"),
        ({"process_scale": 2.0}, r"process_scale must be in \(0, 1\]"),
        ({"min_score": "high"}, r"min_score must be a number"),
        ({"gird": 4}, r"unknown MRAD parameter"),
    ],
)
def test_invalid_parameters_raise_value_error_naming_them(changes, message):
    with pytest.raises(ValueError, match=message):
        MradParams().replace(**changes)


def test_profiles():
    assert profile("default") == MradParams()
    paper = profile("paper")
    assert (paper.grid, paper.tolerance, paper.kernel_fraction, paper.blur_sigma) == (
        4,
        50.0,
        0.2,
        5.0,
    )
    assert (paper.score_scaling, paper.noise_removal, paper.process_scale) == (
        "per_image",
        "local_std",
        1.0,
    )
    assert paper.pixel_score == "regions"
    assert profile("baseline") == paper.replace(score_scaling="fixed", pixel_score="continuous")
    assert profile("accurate") == MradParams(process_scale=1.0)
    assert profile("baseline", grid=8).grid == 8
    with pytest.raises(ValueError, match="unknown MRAD profile 'best'"):
        profile("best")


def test_blurred_pixel_score_keeps_the_mask_and_ranks_every_pixel(pair):
    regions = detect(
        pair.query, pair.reference, MradParams(process_scale=1.0, pixel_score="regions")
    )
    assert_score_confined_to_mask(regions)
    blurred = detect(
        pair.query, pair.reference, MradParams(process_scale=1.0, pixel_score="blurred")
    )
    np.testing.assert_array_equal(regions.mask, blurred.mask)
    inside = regions.mask > 0
    np.testing.assert_array_equal(regions.score[inside], blurred.score[inside])
    assert blurred.score[~inside].any() and not regions.score[~inside].any()


@pytest.mark.parametrize("process_scale", [1.0, 0.5])
def test_continuous_score_is_the_soft_saturated_raw_score_and_keeps_the_mask(pair, process_scale):
    # The map from the same photometric model as the mask, so raw_score is its input.
    params = MradParams(process_scale=process_scale, score_sigma=0.0, map_photometric="cell_affine")
    continuous = detect(pair.query, pair.reference, params)
    regions = detect(pair.query, pair.reference, params.replace(pixel_score="regions"))
    np.testing.assert_array_equal(continuous.mask, regions.mask)
    raw = continuous.raw_score.astype(np.float64)
    band = NEGATIVE_BAND
    positive = np.maximum(raw, 0)
    expected = np.where(
        raw > 0,
        band + (255.0 - band) * positive / (positive + params.score_ref),
        band * np.exp(np.minimum(raw, 0) / params.score_ref),
    )
    if process_scale < 1.0:
        size = pair.query.shape[1::-1]
        expected = cv2.resize(expected.astype(np.float32), size, interpolation=cv2.INTER_LINEAR)
    np.testing.assert_allclose(continuous.score, expected, atol=1e-3)
    # Soft saturation: the strongest scores keep their order instead of tying at 255.
    top = continuous.score[continuous.score > 200]
    assert top.size == 0 or top.max() < 255.0


def test_continuous_score_smoothing_is_a_gaussian_of_the_map(pair):
    sharp = detect(pair.query, pair.reference, MradParams(process_scale=1.0, score_sigma=0.0))
    smooth = detect(pair.query, pair.reference, MradParams(process_scale=1.0, score_sigma=2.0))
    expected = cv2.GaussianBlur(sharp.score, (13, 13), 2.0, borderType=cv2.BORDER_REFLECT)
    np.testing.assert_allclose(smooth.score, expected, atol=1e-3)


def test_twelve_bit_uint16_is_read_at_its_bit_depth(pair):
    # A 12-bit camera's image in uint16: values 0..4095.
    query12 = np.rint(pair.query.astype(np.float64) * 4095 / 255).astype(np.uint16)
    reference12 = np.rint(pair.reference.astype(np.float64) * 4095 / 255).astype(np.uint16)
    expected = detect(pair.query, pair.reference)
    result = detect(query12, reference12, MradParams(bit_depth=12))
    assert result.anomalous == expected.anomalous
    assert iou(result.mask > 0, expected.mask > 0) > 0.95
    # Read as 16-bit it is 16 times too dark: the object is lost in the floor.
    dark = detect(query12, reference12)
    assert iou(dark.mask > 0, expected.mask > 0) < 0.5
    with pytest.raises(ValueError, match=r"query is a 12-bit uint16 image but holds 4096"):
        detect(np.full((8, 8, 3), 4096, np.uint16), reference12[:8, :8], MradParams(bit_depth=12))


@pytest.mark.parametrize(("low", "high"), [(-0.1, 0.5), (0.0, 1.5), (0.0, 255.0)])
def test_float_outside_unit_range_is_rejected(low, high):
    image = np.linspace(low, high, 8 * 8 * 3).reshape(8, 8, 3)
    with pytest.raises(ValueError, match=r"query is a float image with values in .* \[0, 1\]"):
        detect(image, np.zeros((8, 8, 3)))


def test_ranking_map_and_mask_may_use_different_photometric_models(pair):
    both = MradParams(process_scale=1.0, score_sigma=0.0, map_photometric="cell_affine")
    split = both.replace(map_photometric="none")
    plain = both.replace(photometric="none", map_photometric="none")
    with_model, mixed, without = (
        detect(pair.query, pair.reference, p) for p in (both, split, plain)
    )
    np.testing.assert_array_equal(mixed.mask, with_model.mask)  # the mask follows photometric
    np.testing.assert_array_equal(mixed.raw_score, with_model.raw_score)
    np.testing.assert_array_equal(mixed.score, without.score)  # the map, map_photometric
    assert not np.array_equal(with_model.score, without.score)
