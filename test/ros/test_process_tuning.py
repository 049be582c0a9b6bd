"""The node's process-wide settings: the C allocator keeps freed frame buffers, and
OpenCV's thread count. Allocator settings are global to a process, so they are measured in
child processes, never in the test process."""

from __future__ import annotations

import platform
import subprocess
import sys

import cv2
import pytest

from allo_mrad_ros.ros import process_tuning

# A worker thread (its own malloc arena, as the node's DDS and pipeline threads) allocates
# one 1080p frame's buffers (image, float32 score, overlay, mask), all alive at once, and
# frees them, again and again; the page faults counted are those of the loop alone.
_FAULTS_PER_FRAME = """
import resource, sys, threading
import numpy as np
from allo_mrad_ros.ros.process_tuning import keep_freed_memory
applied = keep_freed_memory(int(sys.argv[1]))
result = {}
def frame():
    image = np.ones(1920 * 1080 * 3, np.uint8)
    return image, np.ones(1920 * 1080, np.float32), image.copy(), np.ones(1920 * 1080, np.uint8)
def frames():
    frame()  # warm up
    before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(40):
        frame()
    result["faults"] = (resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before) / 40
thread = threading.Thread(target=frames)
thread.start()
thread.join()
print(applied, result["faults"])
"""

glibc_only = pytest.mark.skipif(
    platform.libc_ver()[0] != "glibc", reason="mallopt settings are glibc's"
)


def _faults_per_frame(megabytes: int) -> tuple[bool, float]:
    out = subprocess.run(
        [sys.executable, "-c", _FAULTS_PER_FRAME, str(megabytes)],
        capture_output=True,
        text=True,
        check=True,
        timeout=120,
    ).stdout.split()
    return out[0] == "True", float(out[1])


@glibc_only
def test_kept_memory_stops_page_faults_on_every_frame() -> None:
    default_applied, default_faults = _faults_per_frame(0)
    kept_applied, kept_faults = _faults_per_frame(512)
    assert (default_applied, kept_applied) == (False, True)
    # 22.8 MB of buffers span about 5,600 pages; glibc's default trims and maps fresh ones.
    assert default_faults > 1000
    assert kept_faults < 0.05 * default_faults


def test_negative_memory_is_refused() -> None:
    with pytest.raises(ValueError, match="megabytes must be 0 or more, got -1"):
        process_tuning.keep_freed_memory(-1)


def test_opencv_threads_are_set_and_zero_restores_the_default() -> None:
    before = cv2.getNumThreads()  # an earlier test may have changed it
    try:
        cv2.setNumThreads(-1)
        opencv_default = cv2.getNumThreads()
        assert process_tuning.set_opencv_threads(1) == 1
        assert cv2.getNumThreads() == 1
        assert process_tuning.set_opencv_threads(0) == opencv_default
    finally:
        cv2.setNumThreads(before)
    with pytest.raises(ValueError, match="threads must be 0 or more, got -2"):
        process_tuning.set_opencv_threads(-2)


def test_apply_says_what_took_effect() -> None:
    default = cv2.getNumThreads()
    try:
        line = process_tuning.apply(0, 1)
    finally:
        cv2.setNumThreads(default)
    assert line == "C allocator: its default; OpenCV threads: 1"
