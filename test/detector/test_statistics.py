"""Cell statistics against NumPy's per-cell mean and covariance (float64, one cell at a time),
on every array backend here (the ``backend`` fixture)."""

import numpy as np
import pytest

from allo_mrad_ros.detector.backends import select_backend
from allo_mrad_ros.detector.grid import cell_slices
from allo_mrad_ros.detector.statistics import cell_statistics


def _per_cell_oracle(image: np.ndarray, grid: int) -> tuple[np.ndarray, np.ndarray]:
    means, covs = [], []
    for rows, cols in cell_slices(image.shape[0], image.shape[1], grid):
        pixels = image[rows, cols].reshape(-1, 3).astype(np.float64)
        means.append(pixels.mean(axis=0))
        covs.append(np.cov(pixels, rowvar=False) if len(pixels) > 1 else np.zeros((3, 3)))
    return np.array(means), np.array(covs)


@pytest.mark.parametrize(
    ("height", "width", "grid"),
    [
        (135, 240, 8),  # the default reference
        (271, 481, 8),  # odd sizes: cells differ by a pixel
        (7, 5, 5),  # one-pixel-wide cells
        (600, 40, 2),  # 300-row bands: sums past float32's exact range
    ],
)
def test_uint8_statistics_match_per_cell_numpy(height, width, grid, backend):
    rng = np.random.default_rng(height * width)
    image = rng.integers(0, 256, size=(height, width, 3), dtype=np.uint8)
    # Near-white rows give the largest sums of squares (past 2**24 in a 300-row column).
    image[: 2 * height // 3] = rng.integers(250, 256, size=(2 * height // 3, width, 3))
    stats = select_backend(backend).cell_statistics(image, grid)
    mean, cov = _per_cell_oracle(image, grid)
    np.testing.assert_allclose(stats.mean, mean, rtol=1e-13, atol=1e-12)
    np.testing.assert_allclose(stats.cov, cov, rtol=1e-11, atol=1e-9)
    assert stats.count.sum() == height * width


def test_flat_cells_have_exactly_zero_covariance(backend):
    image = np.full((540, 960, 3), 255, dtype=np.uint8)
    image[270:] = 17
    stats = select_backend(backend).cell_statistics(image, 8)
    assert np.all(stats.cov == 0.0)
    assert np.all(np.isin(stats.mean, (255.0, 17.0)))


def test_float_and_uint8_paths_agree(backend):
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, size=(90, 160, 3), dtype=np.uint8)
    as_float = image.astype(np.float32) / np.float32(255.0)
    statistics = select_backend(backend).cell_statistics
    eight, floating = cell_statistics(image, 6), statistics(as_float, 6)
    np.testing.assert_allclose(floating.mean, eight.mean, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(floating.cov, eight.cov, rtol=1e-4, atol=1e-2)
