"""The busy loops of ``bench-node --load`` and the feed's priority: started and undone."""

import os

import psutil

from benchmarks.load import busy_loops, prioritised


def test_busy_loops_run_at_the_default_priority_until_the_block_ends():
    with busy_loops(2) as loops:
        assert len(loops) == 2
        processes = [psutil.Process(loop.pid) for loop in loops]
        assert all(loop.poll() is None for loop in loops)
        assert all(process.nice() == 0 for process in processes)
    assert all(loop.poll() is not None for loop in loops)
    with busy_loops(0) as none:
        assert none == []


def test_the_priority_is_raised_where_permitted_and_put_back():
    before = os.getpriority(os.PRIO_PROCESS, 0)
    with prioritised(True, nice=before - 1) as done:
        now = os.getpriority(os.PRIO_PROCESS, 0)
        # Raising needs CAP_SYS_NICE: either it was done, or it says why not.
        assert (now == before - 1 and "at nice" in done) or (
            now == before and "default priority" in done
        )
    assert os.getpriority(os.PRIO_PROCESS, 0) == before
    with prioritised(False) as done:
        assert os.getpriority(os.PRIO_PROCESS, 0) == before and "default priority" in done
