"""The PyTorch array backend: the cross score's per-pixel work on a GPU (or the CPU).

Imported only when a ``torch`` backend is selected (:func:`.backends.select_backend`).
Each operation uploads its image, works over all pixels at once -- per-cell sums by
scatter-add into the cell of each pixel, the quadratic forms by gathering each pixel's cell
coefficients -- and returns NumPy arrays. Sums and covariances are float64 (on the device),
the per-pixel score float32, as on the NumPy backend.
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache

import numpy as np
import torch

from allo_mrad_ros.detector.grid import cell_index_map, cell_slices
from allo_mrad_ros.detector.images import to_float32
from allo_mrad_ros.detector.photometric import QUANTILES, cell_quantiles
from allo_mrad_ros.detector.quadratic import PixelQuadratic
from allo_mrad_ros.detector.statistics import CellStatistics


class TorchBackend:
    """Per-pixel operations on a PyTorch device.

    Parameters
    ----------
    device : str, optional
        A PyTorch device (``"cuda"``, ``"cuda:1"``, ``"cpu"``); None: the first CUDA GPU
        when one is visible, else the CPU. :func:`.backends.select_backend` refuses a CUDA
        device where PyTorch sees none, before building the backend.
    """

    def __init__(self, device: str | None = None) -> None:
        if device is None:
            device = "cuda" if torch.cuda.is_available() else "cpu"
        # No CUDA call that creates a context here: selecting a backend (as the node's
        # parameter check does) must stay cheap, and a forked child could not use it.
        self._device = torch.device(device)

    @property
    def name(self) -> str:
        return f"torch:{self._device}"

    @property
    def device(self) -> torch.device:
        """The PyTorch device the work runs on."""
        return self._device

    def _pixels(self, image: np.ndarray) -> torch.Tensor:
        # (H*W, 3) float32 on the 0..255 scale. 8-bit images travel as bytes (a quarter of
        # the transfer) and are converted on the device, exactly.
        if image.dtype == np.uint8:
            uploaded = torch.from_numpy(np.ascontiguousarray(image)).to(self._device)
            return uploaded.reshape(-1, 3).to(torch.float32)
        uploaded = torch.from_numpy(to_float32(image)).to(self._device)
        return uploaded.reshape(-1, 3)

    def cell_statistics(self, image: np.ndarray, grid: int) -> CellStatistics:
        height, width = image.shape[:2]
        cells = _cell_index(height, width, grid, self._device)
        n_cells = grid * grid
        count = torch.bincount(cells, minlength=n_cells)
        if image.dtype == np.uint8 and _integer_moments_fit(int(count.max())):
            return self._integer_cell_statistics(image, cells, count)
        pixels = self._pixels(image).to(torch.float64)
        n = count.to(torch.float64)[:, None]
        sums = torch.zeros((n_cells, 3), dtype=torch.float64, device=self._device)
        mean = sums.index_add_(0, cells, pixels) / n
        # Two passes, around each cell's mean: a flat cell's deviations are exact zeros.
        centred = pixels - mean[cells]
        products = (centred[:, :, None] * centred[:, None, :]).reshape(-1, 9)
        second = torch.zeros((n_cells, 9), dtype=torch.float64, device=self._device)
        second.index_add_(0, cells, products)
        cov = second.reshape(n_cells, 3, 3) / torch.clamp(n - 1.0, min=1.0)[:, :, None]
        return CellStatistics(
            mean=mean.cpu().numpy(), cov=cov.cpu().numpy(), count=count.cpu().numpy()
        )

    def _integer_cell_statistics(
        self, image: np.ndarray, cells: torch.Tensor, count: torch.Tensor
    ) -> CellStatistics:
        # A GPU adds floats in whatever order its atomics land, so two calls on the same
        # image could differ in the last bit (and identical images would not score exactly
        # 0). Sums of 8-bit values and their products are integers: added in int64 they are
        # exact in any order, and n * sum(x x^T) - sum(x) sum(x)^T is the exact scatter
        # times n (exact zeros for a flat cell), divided once.
        values = torch.from_numpy(np.ascontiguousarray(image)).to(self._device)
        values = values.reshape(-1, 3).to(torch.int64)
        n_cells = count.numel()
        sums = torch.zeros((n_cells, 3), dtype=torch.int64, device=self._device)
        sums.index_add_(0, cells, values)
        products = (values[:, :, None] * values[:, None, :]).reshape(-1, 9)
        second = torch.zeros((n_cells, 9), dtype=torch.int64, device=self._device)
        second.index_add_(0, cells, products)
        n = count[:, None, None]
        scatter_times_n = n * second.reshape(n_cells, 3, 3) - sums[:, :, None] * sums[:, None, :]
        denominator = torch.clamp(n * (n - 1), min=1).to(torch.float64)
        cov = scatter_times_n.to(torch.float64) / denominator
        mean = sums.to(torch.float64) / count.to(torch.float64)[:, None]
        return CellStatistics(
            mean=mean.cpu().numpy(), cov=cov.cpu().numpy(), count=count.cpu().numpy()
        )

    def cell_quantiles(self, image: np.ndarray, grid: int) -> np.ndarray:
        if image.dtype != np.uint8:
            # Deeper images are sorted per cell on the CPU (the node's cameras are 8-bit).
            return cell_quantiles(image, grid)
        # One histogram per (cell, channel), then each quantile's order statistics by one
        # sorted search over the histograms' cumulative counts, lifted one above another.
        height, width = image.shape[:2]
        histograms = grid * grid * 3
        bins = _histogram_bins(height, width, grid, self._device)
        values = torch.from_numpy(np.ascontiguousarray(image)).to(self._device)
        bin_of_pixel = bins + values.reshape(-1).to(torch.int64)
        counts = torch.bincount(bin_of_pixel, minlength=histograms * 256)
        cdf = torch.cumsum(counts.reshape(histograms, 256), dim=1)
        total = cdf[:, -1:].to(torch.float64)
        quantiles = torch.as_tensor(QUANTILES, dtype=torch.float64, device=self._device)
        position = quantiles[None, :] * (total - 1.0)
        low = torch.floor(position)
        high = torch.minimum(low + 1.0, total - 1.0)
        lift = torch.arange(histograms, device=self._device)[:, None] * (int(total.max()) + 1)
        lifted = (cdf + lift).reshape(-1)
        base = torch.arange(histograms, device=self._device)[:, None] * 256
        below = torch.searchsorted(lifted, low.to(torch.int64) + lift, right=True) - base
        above = torch.searchsorted(lifted, high.to(torch.int64) + lift, right=True) - base
        result = below + (position - low) * (above - below)
        return result.reshape(grid * grid, 3, QUANTILES.size).cpu().numpy()

    def evaluate(
        self,
        image: np.ndarray,
        grid: int,
        quadratics: Sequence[PixelQuadratic],
        check_finite: bool,
    ) -> list[np.ndarray]:
        height, width = image.shape[:2]
        cells = _cell_index(height, width, grid, self._device)
        pixels = self._pixels(image)
        homogeneous = torch.cat([pixels, torch.ones_like(pixels[:, :1])], dim=1)[:, :, None]
        big = float(np.finfo(np.float32).max)
        scores = []
        for quadratic in quadratics:
            transform = torch.from_numpy(quadratic.transform).to(self._device)[cells]
            weighted = torch.from_numpy(quadratic.weighted).to(self._device)[cells]
            constant = torch.from_numpy(quadratic.constant.astype(np.float32)).to(self._device)
            y = torch.bmm(transform, homogeneous)
            z = torch.bmm(weighted, homogeneous)
            score = (y * z).sum(dim=(1, 2)) + constant[cells]
            if check_finite:
                score = torch.nan_to_num(score, nan=0.0, posinf=big, neginf=-big)
            scores.append(score.reshape(height, width).cpu().numpy())
        return scores


def _integer_moments_fit(largest_cell: int) -> bool:
    """Whether n * sum(x^2) of 8-bit values over a cell of ``largest_cell`` pixels stays
    exact in int64 and in a float64's 53 bits (so its division rounds once)."""
    return largest_cell * largest_cell * 255 * 255 < 2**53


@lru_cache(maxsize=16)
def _cell_index(height: int, width: int, grid: int, device: torch.device) -> torch.Tensor:
    # The row-major cell of every pixel, flattened; cells as in grid.cell_slices.
    cell_slices(height, width, grid)  # raises for an image smaller than the grid
    cells = cell_index_map(height, width, grid).reshape(-1)
    return torch.from_numpy(cells.astype(np.int64)).to(device)


@lru_cache(maxsize=16)
def _histogram_bins(height: int, width: int, grid: int, device: torch.device) -> torch.Tensor:
    # The first bin of each pixel channel's (cell, channel) histogram, flattened like H x W x 3.
    cells = _cell_index(height, width, grid, device)
    channel = torch.arange(3, device=device)
    return (cells[:, None] * 768 + 256 * channel[None, :]).reshape(-1)
