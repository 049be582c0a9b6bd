"""Process-wide settings of the node's native libraries, applied once at start.

Two settings decide most of the CPU a camera stream costs beyond the detector itself:

* **The C allocator's give-back of freed memory.** Every received 1080p image is a new
  6 MB buffer (DDS sample, C message, Python array) and every published score a new 8 MB
  one. glibc hands blocks this large back to the kernel when they are freed (``munmap`` or
  a heap trim), so the next frame's buffers fault in their pages one by one: a 1080p image
  taken from its subscription cost 21 ms of CPU, 16 ms of it in the kernel. Keeping freed
  memory mapped brings that to under 5 ms (measured with a publisher at 30 Hz in another
  process). The resident size then stays at its peak instead of dropping between frames.
* **OpenCV's thread pool.** The pipelined node keeps two threads busy already; OpenCV's own
  workers on top of them compete for the same cores and cost more CPU than they save.

Nothing here is needed for correctness; each function says whether it took effect.
"""

from __future__ import annotations

import ctypes
import ctypes.util

import cv2

# glibc's mallopt parameter numbers (malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# prctl option that names the calling thread (linux/prctl.h).
_PR_SET_NAME = 15
# glibc refuses a larger mmap threshold on 64-bit (HEAP_MAX_SIZE / 2).
MMAP_THRESHOLD_MAX_BYTES = 32 * 2**20


def keep_freed_memory(megabytes: int) -> bool:
    """Keep up to ``megabytes`` of freed heap memory mapped instead of returning it.

    Sets glibc's trim threshold to ``megabytes`` and its mmap threshold to its largest
    value (32 MB), so image-sized blocks come from the heap and are reused. Setting either
    turns off glibc's own adaptive thresholds, hence both.

    Parameters
    ----------
    megabytes : int
        Freed memory kept mapped; 0 leaves the allocator as it is.

    Returns
    -------
    bool
        True when applied; False for 0 or where the C library has no ``mallopt``
        (musl, macOS).

    Raises
    ------
    ValueError
        ``megabytes`` is negative.
    """
    if megabytes < 0:
        raise ValueError(f"megabytes must be 0 or more, got {megabytes}")
    if megabytes == 0:
        return False
    name = ctypes.util.find_library("c")
    try:
        mallopt = ctypes.CDLL(name).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    trim = min(megabytes * 2**20, 2**31 - 1)
    return bool(mallopt(_M_TRIM_THRESHOLD, trim)) and bool(
        mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD_MAX_BYTES)
    )


def name_this_thread(name: str) -> bool:
    """Give the calling thread ``name`` (at most 15 bytes) where the OS shows thread names.

    ``top -H``, ``ps -L`` and ``/proc/<pid>/task/*/comm`` then tell the node's processing
    threads apart from DDS's and the renderer's. Linux only (``prctl``); elsewhere nothing
    happens.

    Returns
    -------
    bool
        True when the name was set.
    """
    encoded = name.encode()[:15]
    try:
        prctl = ctypes.CDLL(ctypes.util.find_library("c"), use_errno=True).prctl
    except (OSError, AttributeError, TypeError):
        return False
    return prctl(_PR_SET_NAME, ctypes.c_char_p(encoded), 0, 0, 0) == 0


def set_opencv_threads(threads: int) -> int:
    """Run OpenCV's parallel loops on ``threads`` threads (0: OpenCV's default, all cores).

    Returns
    -------
    int
        The number of threads OpenCV reports afterwards.
    """
    if threads < 0:
        raise ValueError(f"threads must be 0 or more, got {threads}")
    cv2.setNumThreads(threads if threads > 0 else -1)
    return cv2.getNumThreads()


def apply(keep_freed_mb: int, opencv_threads: int) -> str:
    """Apply both settings; one line saying what took effect, for the node's log."""
    kept = keep_freed_memory(keep_freed_mb)
    threads = set_opencv_threads(opencv_threads)
    allocator = f"keeps {keep_freed_mb} MB of freed memory" if kept else "its default"
    return f"C allocator: {allocator}; OpenCV threads: {threads}"
