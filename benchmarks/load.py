"""A busy CPU for the node benchmarks: busy loops beside the node, the measurement ahead of them.

:func:`busy_loops` runs N processes that only spin, each pinned to one core in turn (one per
core for N equal to the core count) at the default priority, the node's: they compete with
the node as another job on the robot's computer would. :func:`prioritised` raises the
priority of every thread of this process (the camera feed and the recorder of the node's
outputs) where the system permits, so that what is measured is the node under load, not a
feed that publishes late or a recorder that reads late. Both undo what they did on exit.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from allo_mrad_ros.ros.node_process import wait_or_kill

# Nice value of the feed and recorder threads under load (-20 highest, 0 the default).
FEED_NICE = -10

# A busy loop: the default priority (it may be started by a raised process), one core.
_LOOP = (
    "import os, sys\n"
    "os.setpriority(os.PRIO_PROCESS, 0, 0)\n"
    "try:\n"
    "    os.sched_setaffinity(0, {int(sys.argv[1])})\n"
    "except (AttributeError, OSError):\n"
    "    pass\n"
    "while True:\n"
    "    pass\n"
)


def _cores() -> list[int]:
    """The cores this process may run on, in order."""
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return list(range(os.cpu_count() or 1))


@contextmanager
def busy_loops(count: int) -> Iterator[list[subprocess.Popen]]:
    """Run ``count`` busy-loop processes (the k-th pinned to the k-th core, in turn) until
    the block ends; none for 0."""
    cores = _cores()
    loops = [
        subprocess.Popen([sys.executable, "-c", _LOOP, str(cores[k % len(cores)])])
        for k in range(count)
    ]
    try:
        yield loops
    finally:
        for loop in loops:
            loop.terminate()
        for loop in loops:
            wait_or_kill(loop, 10)


def _threads(pid: int | str = "self") -> list[int]:
    """A process's thread ids (Linux: each thread has its own nice value)."""
    try:
        return [int(task.name) for task in Path(f"/proc/{pid}/task").iterdir()]
    except OSError:
        return [0] if pid == "self" else [int(pid)]


def renice(pid: int, nice: int) -> str:
    """Give every thread of process ``pid`` the nice value ``nice`` (threads it starts later
    inherit it from their creator); what was done, in words."""
    done, refused = 0, ""
    for thread in _threads(pid):
        try:
            os.setpriority(os.PRIO_PROCESS, thread, nice)
            done += 1
        except OSError as error:  # PermissionError without CAP_SYS_NICE, or a thread gone
            refused = refused or type(error).__name__
    if refused and not done:
        return f"node at its own priority (renicing it: {refused})"
    return f"node threads at nice {nice}" + (f" (some: {refused})" if refused else "")


@contextmanager
def prioritised(enabled: bool, nice: int = FEED_NICE) -> Iterator[str]:
    """Give every thread of this process the nice value ``nice`` until the block ends
    (threads started meanwhile inherit it from their creator); yields what was done, in
    words. Child processes started before the block keep their own priority."""
    if not enabled:
        yield "feed and recorder at the default priority"
        return
    changed: dict[int, int] = {}
    refused = ""
    for thread in _threads():
        try:
            before = os.getpriority(os.PRIO_PROCESS, thread)
            os.setpriority(os.PRIO_PROCESS, thread, nice)
            changed[thread] = before
        except OSError as error:  # PermissionError without CAP_SYS_NICE, or a thread gone
            refused = refused or type(error).__name__
    try:
        if changed and not refused:
            yield f"feed and recorder threads at nice {nice}, busy loops at 0"
        elif changed:
            yield f"feed and recorder partly at nice {nice} (some threads: {refused})"
        else:
            yield f"feed and recorder at the default priority (raising it: {refused})"
    finally:
        for thread, before in changed.items():
            with suppress(OSError):  # the thread has ended
                os.setpriority(os.PRIO_PROCESS, thread, before)
