"""The statistics grid: proportional cell edges shared by images of any resolution."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from allo_mrad_ros.detector.reference_cache import read_only_cache


def cell_edges(length: int, grid: int) -> list[int]:
    """Return the ``grid + 1`` edges ``round(i * length / grid)`` (halves rounded up).

    Proportional edges let a lower-resolution reference map onto the query's cells.
    """
    return [(2 * i * length + grid) // (2 * grid) for i in range(grid + 1)]


def cell_slices(height: int, width: int, grid: int) -> list[tuple[slice, slice]]:
    """Return the (rows, cols) slices of the ``grid x grid`` cells, row-major.

    Raises
    ------
    ValueError
        If a cell would hold no pixels (the image is smaller than the grid).
    """
    if height < grid or width < grid:
        raise ValueError(
            f"grid={grid} is too fine for a {width}x{height} image: every cell needs a pixel"
        )
    rows, cols = cell_edges(height, grid), cell_edges(width, grid)
    return [
        (slice(rows[i], rows[i + 1]), slice(cols[j], cols[j + 1]))
        for i in range(grid)
        for j in range(grid)
    ]


def iter_cells(height: int, width: int, grid: int) -> Iterator[tuple[int, tuple[slice, slice]]]:
    """Yield ``(cell_index, (rows, cols))`` for each cell, row-major."""
    yield from enumerate(cell_slices(height, width, grid))


@read_only_cache(maxsize=8)
def cell_index_map(height: int, width: int, grid: int) -> np.ndarray:
    """Return the H x W (read-only) row-major index of the cell each pixel lies in."""
    rows = np.searchsorted(cell_edges(height, grid), np.arange(height), side="right") - 1
    cols = np.searchsorted(cell_edges(width, grid), np.arange(width), side="right") - 1
    return (rows[:, None] * grid + cols[None, :]).astype(np.intp)
