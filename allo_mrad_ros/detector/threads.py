"""Per-cell loops spread over OpenCV's worker count.

The per-cell work of a frame is a few OpenCV calls on each cell, and OpenCV releases the
GIL inside them, so contiguous blocks of cells run side by side on a small shared thread
pool. The worker count is OpenCV's own setting (``cv2.setNumThreads``; 1 runs in the
caller's thread), so one knob governs every thread the detector uses.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import cv2

# Below this many cells per block the pool's hand-off costs more than it saves.
_MIN_CELLS_PER_BLOCK = 4
# Nor below this many pixels per block. Measured on 2 cores (a 1080p query, default
# parameters, one and two threads interleaved): at 480x270 two blocks took 27 ms against 21
# for one, at 960x540 45 against 46, at 1920x1080 117 against 140. The per-cell calls are
# short, so below about half a megapixel the GIL hand-offs cost what the second core gives.
MIN_PIXELS_PER_BLOCK = 500_000

_pool: ThreadPoolExecutor | None = None
_pool_size = 0
_pool_lock = threading.Lock()


def worker_count(
    cells: int, min_per_block: int = _MIN_CELLS_PER_BLOCK, pixels: int | None = None
) -> int:
    """Number of blocks a loop over ``cells`` items (covering ``pixels``) is split into.

    At most OpenCV's thread count, at least ``min_per_block`` items and, when ``pixels`` is
    given, :data:`MIN_PIXELS_PER_BLOCK` pixels per block; at least 1.
    """
    count = min(cv2.getNumThreads(), cells // min_per_block)
    if pixels is not None:
        count = min(count, pixels // MIN_PIXELS_PER_BLOCK)
    return max(1, count)


def for_each_block(
    work: Callable[[range], None],
    cells: int,
    min_per_block: int = _MIN_CELLS_PER_BLOCK,
    pixels: int | None = None,
) -> None:
    """Call ``work`` on contiguous ranges of ``range(cells)`` that together cover it once.

    The ranges run concurrently when :func:`worker_count` gives more than one block;
    ``work`` must write only what belongs to its own cells. An exception raised in any
    block is raised here after every block has finished.
    """
    blocks = worker_count(cells, min_per_block, pixels)
    if blocks == 1:
        work(range(cells))
        return
    bounds = [cells * i // blocks for i in range(blocks + 1)]
    ranges = [range(bounds[i], bounds[i + 1]) for i in range(blocks)]
    futures = [_executor(blocks - 1).submit(work, block) for block in ranges[1:]]
    try:
        work(ranges[0])
    finally:
        errors = [future.exception() for future in futures]
    for error in errors:
        if error is not None:
            raise error


def _executor(size: int) -> ThreadPoolExecutor:
    global _pool, _pool_size
    with _pool_lock:
        if _pool is None or _pool_size < size:
            if _pool is not None:
                _pool.shutdown(wait=False)
            _pool = ThreadPoolExecutor(max_workers=size, thread_name_prefix="mrad-cells")
            _pool_size = size
        return _pool
