"""Post-processing and region stages against naive oracles and scikit-learn's MeanShift."""

import cv2
import numpy as np
import pytest
from mrad_oracle import flood_fill_naive, local_std_naive
from skimage.filters import apply_hysteresis_threshold
from sklearn.cluster import MeanShift

from allo_mrad_ros.detector.decision import _largest
from allo_mrad_ros.detector.grid import cell_edges, cell_slices
from allo_mrad_ros.detector.postprocess import (
    NEGATIVE_BAND,
    blur_scores,
    continuous_scores,
    local_std,
    remove_noise,
    scale_scores,
    threshold_scores,
)
from allo_mrad_ros.detector.regions import find_seeds, grow_hysteresis, grow_regions


def test_cell_edges_are_proportional_and_cover_the_image():
    assert cell_edges(1080, 4) == [0, 270, 540, 810, 1080]
    assert cell_edges(10, 4) == [0, 3, 5, 8, 10]  # round half up: 2.5 -> 3, 7.5 -> 8
    slices = cell_slices(10, 7, 3)
    covered = np.zeros((10, 7), int)
    for rows, cols in slices:
        covered[rows, cols] += 1
    assert (covered == 1).all()


def test_scaling_modes():
    raw = np.array([[-5.0, 0.0, 50.0, 2000.0]], dtype=np.float32)
    np.testing.assert_allclose(scale_scores(raw, "fixed", 1000.0), [[0, 0, 12.75, 255]])
    np.testing.assert_allclose(scale_scores(raw, "per_image", 1.0), [[0, 0, 6.375, 255]])
    assert not scale_scores(np.float32([[-5.0, 0.0]]), "per_image", 1.0).any()
    np.testing.assert_array_equal(threshold_scores(np.float32([[1, 25, 30]]), 25.0), [[0, 25, 30]])


def test_local_std_matches_naive_window():
    rng = np.random.default_rng(0)
    scores = (rng.random((23, 31)) * 255).astype(np.float32)
    for window in [(1, 1), (3, 5), (4, 6), (7, 7)]:
        np.testing.assert_allclose(
            local_std(scores, window), local_std_naive(scores, window), atol=2e-2
        )


def test_local_std_rule_zeroes_flat_interiors_and_keeps_varying_scores():
    rng = np.random.default_rng(0)
    scores = np.zeros((80, 80), np.float32)
    scores[5:35, 5:35] = 30.0  # flat plateau above min_score, 56 % of its cell
    scores[45:75, 45:75] = rng.uniform(25, 255, (30, 30))  # strongly varying scores
    cleaned = remove_noise(
        scores,
        2,
        min_score=25,
        kernel_fraction=0.2,
        std_thresh=10,
        large_anomaly_fraction=0.9,
        noise_removal="local_std",
    )
    assert not cleaned[10:30, 10:30].any()  # interior: local std 0
    assert cleaned[5, 5:35].all()  # the plateau's edge has a local std of about 15
    np.testing.assert_array_equal(cleaned[45:75, 45:75], scores[45:75, 45:75])


def test_local_std_rule_keeps_saturated_interiors():
    scores = np.zeros((80, 80), np.float32)
    scores[5:35, 5:35] = 255.0  # a confidently anomalous blob, clipped flat by scaling
    cleaned = remove_noise(
        scores,
        2,
        min_score=25,
        kernel_fraction=0.2,
        std_thresh=10,
        large_anomaly_fraction=0.9,
        noise_removal="local_std",
    )
    np.testing.assert_array_equal(cleaned, scores)


def test_large_anomaly_cell_is_kept_whole():
    scores = np.zeros((80, 80), np.float32)
    scores[:40, :40] = 120.0  # the whole cell is above min_score
    cleaned = remove_noise(
        scores,
        2,
        min_score=25,
        kernel_fraction=0.2,
        std_thresh=10,
        large_anomaly_fraction=0.9,
        noise_removal="local_std",
    )
    np.testing.assert_array_equal(cleaned[:40, :40], 120.0)
    np.testing.assert_array_equal(cleaned[40:], 0.0)


def test_cell_spread_variant_zeroes_cells_of_uniform_speckle_only():
    rng = np.random.default_rng(1)
    scores = np.zeros((200, 200), np.float32)
    # Speckle spread evenly over a whole cell: its local std is high but the same everywhere.
    speckle = rng.random((100, 100)) < 0.3
    scores[:100, 100:] = np.where(speckle, 30 + 10 * rng.random((100, 100)), 0.0)
    scores[140:160, 140:160] = 200.0  # a compact object: its cell's local std varies
    cleaned = remove_noise(
        scores,
        2,
        min_score=25,
        kernel_fraction=0.2,
        std_thresh=10,
        large_anomaly_fraction=0.9,
        noise_removal="cell_spread",
    )
    assert not cleaned[:100, 100:].any()
    np.testing.assert_array_equal(cleaned[100:, 100:], scores[100:, 100:])
    local = remove_noise(
        scores,
        2,
        min_score=25,
        kernel_fraction=0.2,
        std_thresh=10,
        large_anomaly_fraction=0.9,
        noise_removal="local_std",
    )
    assert local[:100, 100:].any()  # the per-region rule keeps speckle (its local std is high)


def gaussian_blobs(shape, centres, sigma, heights):
    rows, cols = np.indices(shape)
    out = np.zeros(shape)
    for (r, c), h in zip(centres, heights, strict=True):
        out += h * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * sigma**2))
    return out.astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_seeds_match_sklearn_mean_shift(seed):
    rng = np.random.default_rng(seed)
    centres = [
        (8 + rng.integers(0, 4), 10 + rng.integers(0, 4)),
        (30 + rng.integers(0, 4), 12 + rng.integers(0, 4)),
        (20 + rng.integers(0, 4), 34 + rng.integers(0, 4)),
    ]
    raw = np.zeros((44, 48), np.float32)
    for r, c in centres:
        raw[r - 2 : r + 3, c - 2 : c + 3] = 200.0
    blurred = blur_scores(raw, 3.0)
    seeds = find_seeds(blurred, min_score=1.0, window=7)
    # Mean shift over score-weighted pixel samples: each pixel repeated by its score.
    weights = np.rint(raw / 20).astype(int)
    points = np.repeat(np.argwhere(weights > 0), weights[weights > 0], axis=0).astype(float)
    modes = MeanShift(bandwidth=6.0).fit(points).cluster_centers_
    assert len(seeds) == len(modes) == 3
    for mode in modes:
        assert np.min(np.linalg.norm(seeds - mode, axis=1)) <= 2.0


def test_seeds_of_a_plateau_are_one_per_plateau():
    blurred = np.zeros((20, 20), np.float32)
    blurred[2:8, 2:8] = 100.0
    blurred[12:15, 12:15] = 50.0
    seeds = find_seeds(blurred, min_score=10.0, window=3)
    assert seeds.tolist() == [[2, 2], [12, 12]]  # highest first, raster-first pixel


def test_constant_map_has_no_seeds():
    assert len(find_seeds(np.zeros((10, 10), np.float32), 1.0, 3)) == 0


@pytest.mark.parametrize("tolerance", [0.0, 10.0, 50.0])
def test_region_growing_matches_naive_flood_fill(tolerance):
    rng = np.random.default_rng(4)
    values = blur_scores((rng.random((30, 30)) * 255).astype(np.float32), 1.5)
    seed = tuple(int(v) for v in np.unravel_index(np.argmax(values), values.shape))
    mask = grow_regions(values, np.array([seed]), tolerance, min_score=20.0)
    expected = flood_fill_naive(values, seed, tolerance, floor=20.0)
    np.testing.assert_array_equal(mask > 0, expected)


@pytest.mark.parametrize("seed", range(4))
def test_hysteresis_growth_matches_scikit_image(seed):
    rng = np.random.default_rng(seed)
    scores = cv2.GaussianBlur(rng.random((60, 80)).astype(np.float32) * 100, (0, 0), 2.0)
    low, high = np.percentile(scores, [60, 95])
    ours = grow_hysteresis(scores, low, high, connectivity=8) > 0
    # scikit-image keeps regions strictly above low that hold a pixel strictly above high;
    # ours are ">=": nudge the thresholds below a float step so the two agree.
    theirs = apply_hysteresis_threshold(scores, np.nextafter(low, -1), np.nextafter(high, -1))
    np.testing.assert_array_equal(ours, theirs)
    assert ours.any() and not ours.all()


def test_hysteresis_keeps_a_thin_line_whole_and_drops_weak_blobs():
    scores = np.zeros((40, 40), np.float32)
    scores[10, 5:35] = 30.0  # a thin line, one pixel reaching the seed score
    scores[10, 20] = 60.0
    scores[25:30, 25:30] = 40.0  # a blob that never reaches it
    mask = grow_hysteresis(scores, 25.0, 50.0)
    assert mask[10, 5:35].all() and not mask[25:30, 25:30].any()
    assert np.count_nonzero(mask) == 30


@pytest.mark.parametrize("scaling", ["fixed", "per_image"])
def test_continuous_map_is_strictly_increasing_in_the_signed_score(scaling):
    # Negative scores are ranked too: no tie at the bottom of the map.
    raw = np.linspace(-3000.0, 3000.0, 6001, dtype=np.float32)[None, :]
    mapped = continuous_scores(raw, scaling, 1000.0).astype(np.float64)
    assert np.all(np.diff(mapped[0]) > 0)
    assert mapped.min() > 0.0 and mapped.max() <= 255.0
    assert mapped[0, raw[0] < 0].max() < NEGATIVE_BAND <= mapped[0, raw[0] >= 0].min()


@pytest.mark.parametrize("kind", ["spread", "floor", "few levels", "constant"])
def test_the_largest_values_equal_a_full_sort_whatever_the_ties(kind):
    rng = np.random.default_rng(5)
    for _ in range(200):
        size = int(rng.integers(1, 4000))
        count = int(rng.integers(1, size + 1))
        values = rng.random(size).astype(np.float32)
        if kind == "floor":  # most of a clean frame's map sits at its floor
            values[rng.random(size) < 0.7] = 1.0
        elif kind == "few levels":
            values = np.round(values * 3)
        elif kind == "constant":
            values[:] = 0.5
        np.testing.assert_array_equal(_largest(values, count), np.sort(values)[size - count :])
