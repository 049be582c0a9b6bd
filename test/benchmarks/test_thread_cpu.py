"""Per-thread CPU of a process by thread name, as bench-node reports it."""

import os
import sys
import threading
import time

import pytest

from allo_mrad_ros.ros.process_tuning import name_this_thread
from benchmarks import thread_cpu

linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc is Linux's")


def test_threads_are_grouped_by_name_without_their_number_and_ranked():
    before = {1: ("python", 1.0), 2: ("dds.shm.7413", 0.5), 3: ("llvmpipe-0", 0.0)}
    after = {
        1: ("python", 1.2),
        2: ("dds.shm.7413", 0.6),
        3: ("llvmpipe-0", 0.1),
        4: ("llvmpipe-1", 0.3),  # started between the samples: counts from zero
        5: ("mrad_detect", 0.0),  # idle: left out
    }
    shares = thread_cpu.per_frame_ms(before, after, frames=100)
    assert list(shares) == ["llvmpipe", "python", "dds.shm"]
    assert shares["llvmpipe"] == pytest.approx(4.0)
    assert shares["python"] == pytest.approx(2.0)
    assert shares["dds.shm"] == pytest.approx(1.0)
    assert thread_cpu.summary(shares, shown=2).endswith("llvmpipe 4.0, main 2.0")
    assert thread_cpu.summary({}).endswith("n/a (no /proc)")


@linux_only
def test_a_named_busy_thread_shows_with_its_cpu():
    done = threading.Event()
    named = []

    def spin() -> None:
        named.append(name_this_thread("cpu_probe"))
        start = time.process_time()
        while not done.is_set() and time.process_time() - start < 5.0:
            pass

    before = thread_cpu.sample(os.getpid())
    worker = threading.Thread(target=spin)
    worker.start()
    # Until the thread has had 50 ms of CPU: 60 s bounds it on a loaded machine, where its
    # share of a core may be small (the loop ends as soon as it has).
    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        shares = thread_cpu.per_frame_ms(before, thread_cpu.sample(os.getpid()), frames=1)
        if shares.get("cpu_probe", 0.0) >= 50.0:
            break
        time.sleep(0.05)
    done.set()
    worker.join()
    assert named == [True]
    assert shares.get("cpu_probe", 0.0) >= 50.0


def test_a_process_that_is_gone_gives_no_threads():
    assert thread_cpu.sample(2**22 + 12345) == {}
