"""The busy loops of ``bench-node --load`` and the feed's priority: started and undone."""

import os
import subprocess
import sys

import psutil

from benchmarks.load import busy_loops, prioritised, renice


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


def test_every_thread_of_a_process_is_reniced():
    # Lowering a priority needs no privilege: nice 3 for a child and its two threads.
    code = (
        "import sys, threading, time\n"
        "threading.Thread(target=time.sleep, args=(60,), daemon=True).start()\n"
        "print('ready', flush=True)\n"
        "time.sleep(60)\n"
    )
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout.readline().strip() == "ready"  # its second thread runs
        assert renice(child.pid, 3) == "node threads at nice 3"
        threads = [thread.id for thread in psutil.Process(child.pid).threads()]
        assert len(threads) == 2
        assert all(os.getpriority(os.PRIO_PROCESS, thread) == 3 for thread in threads)
    finally:
        child.kill()
        child.wait()
