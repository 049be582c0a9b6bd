"""The fast cross score against the float64 per-pixel oracle, and its invariances, on every
array backend this machine has (the ``backend`` fixture: NumPy, PyTorch on the CPU, on CUDA).

Tolerance: the fast path evaluates in float32 after float64 coefficients, so its error is
bounded relative to the two Mahalanobis terms that cancel, not to their difference:
``|fast - oracle| <= 1e-4 * (t0 + t1) + 1e-3``.
"""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from mrad_oracle import cross_score_terms, cross_score_vectorised, edges

from allo_mrad_ros.detector.score import cross_score, rx_score

ABS_FLOOR, REL_FLOOR = 4.0, 1e-3


def assert_matches_oracle(
    query, reference, grid, abs_floor=ABS_FLOOR, rel_floor=REL_FLOOR, backend="numpy"
):
    fast = cross_score(query, reference, grid, abs_floor, rel_floor, backend=backend)
    t0, t1 = cross_score_terms(query, reference, grid, abs_floor, rel_floor)
    assert fast.dtype == np.float32
    assert np.isfinite(fast).all()
    error = np.abs(fast.astype(np.float64) - (t0 - t1))
    bound = 1e-4 * (t0 + t1) + 1e-3
    assert (error <= bound).all(), f"max excess {np.max(error - bound):.3g}"


def degenerate_image(rng, height=24, width=32):
    """Cells of black sky, grey metal, saturated glare and random colour."""
    image = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    image[: height // 2, : width // 2] = 0
    grey = rng.integers(60, 200, (height // 2, width - width // 2), dtype=np.uint8)
    image[: height // 2, width // 2 :] = grey[..., None]
    image[height // 2 :, : width // 2] = 255
    return image


@pytest.mark.parametrize("grid", [1, 2, 3, 4])
def test_random_cells_match_oracle(grid, backend):
    rng = np.random.default_rng(grid)
    query = rng.integers(0, 256, (20, 28, 3), dtype=np.uint8)
    reference = rng.integers(0, 256, (20, 28, 3), dtype=np.uint8)
    assert_matches_oracle(query, reference, grid, backend=backend)


@pytest.mark.parametrize("grid", [1, 2, 4])
def test_degenerate_cells_match_oracle(grid, backend):
    rng = np.random.default_rng(10 + grid)
    query = degenerate_image(rng)
    reference = degenerate_image(rng)
    reference[:12, :16] = 0  # black in both: exactly-zero covariances on both sides
    assert_matches_oracle(query, reference, grid, backend=backend)


def test_lower_resolution_reference_matches_oracle(backend):
    rng = np.random.default_rng(3)
    query = rng.integers(0, 256, (32, 48, 3), dtype=np.uint8)
    reference = rng.integers(0, 256, (8, 12, 3), dtype=np.uint8)
    assert_matches_oracle(query, reference, 4, backend=backend)


@pytest.mark.parametrize("dtype", [np.uint16, np.float32, np.float64])
def test_other_dtypes_match_oracle(dtype, backend):
    rng = np.random.default_rng(4)
    base = rng.random((16, 20, 3))
    scale = 65535 if dtype == np.uint16 else 1.0
    query = (base * scale).astype(dtype)
    reference = (rng.random((16, 20, 3)) * scale).astype(dtype)
    assert_matches_oracle(query, reference, 2, backend=backend)


def test_unregularised_singular_cells_stay_finite(backend):
    # Flat cells have singular covariances; without a floor the precision is clamped, not
    # infinite. The patch's pixels are ~1e16 away from the flat reference; the cell where
    # query and reference are the same flat colour scores exactly 0.
    query = np.full((8, 8, 3), 100, dtype=np.uint8)
    query[2:4, 2:4] = 200
    reference = np.full((8, 8, 3), 100, dtype=np.uint8)
    score = cross_score(query, reference, 2, 0.0, 0.0, backend=backend)
    assert np.isfinite(score).all()
    assert score[2, 2] > 1e15
    assert score[7, 7] == 0.0


def test_identical_images_score_exactly_zero(backend):
    rng = np.random.default_rng(5)
    image = degenerate_image(rng)
    assert not cross_score(image, image, 4, ABS_FLOOR, REL_FLOOR, backend=backend).any()


def test_oracle_loop_agrees_with_vectorised_oracle():
    rng = np.random.default_rng(6)
    query = rng.integers(0, 256, (12, 15, 3), dtype=np.uint8)
    reference = rng.integers(0, 256, (12, 15, 3), dtype=np.uint8)
    t0, t1 = cross_score_terms(query, reference, 3, ABS_FLOOR, REL_FLOOR)
    vectorised = cross_score_vectorised(query, reference, 3, ABS_FLOOR, REL_FLOOR)
    np.testing.assert_allclose(vectorised, t0 - t1, rtol=1e-9, atol=1e-9)


def test_rx_score_is_mahalanobis_to_own_model(backend):
    rng = np.random.default_rng(7)
    image = rng.integers(0, 256, (10, 12, 3), dtype=np.uint8)
    pixels = image.reshape(-1, 3).astype(np.float64)
    cov = np.cov(pixels.T) + ABS_FLOOR * np.eye(3)
    d = pixels - pixels.mean(axis=0)
    expected = np.einsum("ni,ij,nj->n", d, np.linalg.inv(cov), d).reshape(10, 12)
    np.testing.assert_allclose(
        rx_score(image, ABS_FLOOR, 0.0, backend), expected, rtol=1e-4, atol=1e-3
    )


well_conditioned = arrays(np.float64, (3, 3), elements=st.floats(-1, 1)).map(
    lambda m: m + 2.5 * np.eye(3)
)


@settings(max_examples=30, deadline=None)
@given(
    matrix=well_conditioned,
    offset=arrays(np.float64, 3, elements=st.floats(-0.5, 0.5)),
    seed=st.integers(0, 2**16),
)
def test_colour_transform_invariance_without_regularisation(matrix, offset, seed):
    rng = np.random.default_rng(seed)
    query = rng.random((12, 16, 3))
    reference = rng.random((12, 16, 3))
    before = cross_score(query, reference, 2, 0.0, 0.0).astype(np.float64)
    after = cross_score(query @ matrix.T + offset, reference @ matrix.T + offset, 2, 0.0, 0.0)
    t0, t1 = cross_score_terms(query, reference, 2, 1e-300, 0.0)
    np.testing.assert_array_less(np.abs(after - before), 1e-3 * (t0 + t1) + 1e-3)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**16), grid=st.integers(1, 4))
def test_shuffling_reference_pixels_inside_a_cell_keeps_the_score(seed, grid):
    # 8-bit sums are exact integers, so the score is bit-identical, not just close.
    rng = np.random.default_rng(seed)
    query = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    reference = rng.integers(0, 256, (16, 16, 3), dtype=np.uint8)
    shuffled = reference.copy()
    cuts = edges(16, grid)
    for i in range(grid):
        for j in range(grid):
            rows = slice(cuts[i], cuts[i + 1])
            cols = slice(cuts[j], cuts[j + 1])
            block = shuffled[rows, cols]
            shuffled[rows, cols] = rng.permutation(block.reshape(-1, 3)).reshape(block.shape)
    np.testing.assert_array_equal(
        cross_score(query, reference, grid, ABS_FLOOR, REL_FLOOR),
        cross_score(query, shuffled, grid, ABS_FLOOR, REL_FLOOR),
    )


@pytest.mark.parametrize("threads", [1, 2, 3])
def test_cells_split_over_threads_give_the_single_thread_result(threads, monkeypatch):
    import cv2

    from allo_mrad_ros.detector import threads as cell_threads

    # Small images run in one block by default; split them anyway.
    monkeypatch.setattr(cell_threads, "MIN_PIXELS_PER_BLOCK", 1)

    from allo_mrad_ros.detector.score import cross_scores

    rng = np.random.default_rng(7)
    query = degenerate_image(rng, 96, 128)
    reference = degenerate_image(rng, 48, 64)
    previous = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        expected = cross_scores(query, reference, 6, ABS_FLOOR, REL_FLOOR, ["none", "cell_affine"])
        cv2.setNumThreads(threads)
        split = cross_scores(query, reference, 6, ABS_FLOOR, REL_FLOOR, ["none", "cell_affine"])
    finally:
        cv2.setNumThreads(previous)
    for one, many in zip(expected, split, strict=True):
        np.testing.assert_array_equal(one, many)
    assert_matches_oracle(query, reference, 6)


def test_several_models_in_one_pass_equal_one_model_at_a_time():
    from allo_mrad_ros.detector.score import cross_scores

    rng = np.random.default_rng(8)
    query = degenerate_image(rng, 60, 80)
    reference = degenerate_image(rng, 30, 40)
    both = cross_scores(query, reference, 4, ABS_FLOOR, REL_FLOOR, ["cell_affine", "none"])
    for photometric, score in zip(["cell_affine", "none"], both, strict=True):
        single = cross_score(query, reference, 4, ABS_FLOOR, REL_FLOOR, photometric)
        np.testing.assert_array_equal(single, score)


@pytest.mark.parametrize("photometric", ["none", "cell_affine"])
def test_the_smallest_unchecked_floor_keeps_extreme_scores_finite(photometric, backend):
    # From abs_floor 1e-3 on the map is not checked for inf/NaN: its worst case must stay
    # finite. Flat reference cells (black, saturated, grey) against full-range noise, and
    # the largest gain the photometric fit may apply.
    from allo_mrad_ros.detector.score import _BOUNDED_FLOOR

    rng = np.random.default_rng(3)
    reference = degenerate_image(rng, 48, 64)
    reference[24:, 32:] = 128
    query = rng.choice(np.array([0, 255], np.uint8), size=reference.shape)
    score = cross_score(
        query, reference, 4, _BOUNDED_FLOOR, 0.0, photometric, max_gain=100.0, backend=backend
    )
    assert np.isfinite(score).all()
    assert np.abs(score).max() < 1e20
