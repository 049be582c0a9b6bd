"""CPU time of each thread of a running process, by thread name (Linux ``/proc``).

The node names its processing threads (``mrad_render``, ``mrad_detect``); Fast DDS and
llvmpipe name theirs; the main thread carries the process's name (``python``). Two samples
around a benchmark run give each thread's share of the CPU a frame costs, the split a
profiler would give, without one. Where ``/proc`` has no task list the samples are empty.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

# A thread's number suffix ("llvmpipe-3", "dds.shm.7413"): threads that differ only in it
# are one kind of work.
_NUMBER_SUFFIX = re.compile(r"[-.]\d+$")


def sample(pid: int) -> dict[int, tuple[str, float]]:
    """Each thread's ``(name, user + system CPU seconds)`` now, by thread id.

    Threads that end while the directory is read are left out; an unreadable ``/proc``
    gives an empty dict.
    """
    ticks = os.sysconf("SC_CLK_TCK")
    threads: dict[int, tuple[str, float]] = {}
    try:
        tasks = list(Path(f"/proc/{pid}/task").iterdir())
    except OSError:
        return threads
    for task in tasks:
        try:
            name = (task / "comm").read_text().strip()
            stat = (task / "stat").read_text()
        except OSError:
            continue
        # Fields after the command, which may itself hold spaces and parentheses.
        fields = stat[stat.rindex(")") + 2 :].split()
        threads[int(task.name)] = (name, (int(fields[11]) + int(fields[12])) / ticks)
    return threads


def per_frame_ms(
    before: dict[int, tuple[str, float]], after: dict[int, tuple[str, float]], frames: int
) -> dict[str, float]:
    """CPU ms per frame of each kind of thread between two :func:`sample` calls.

    Threads are grouped by name without a number suffix; a thread that started between the
    samples counts from zero. Sorted by cost, largest first.
    """
    totals: dict[str, float] = {}
    for tid, (name, seconds) in after.items():
        spent = seconds - before.get(tid, (name, 0.0))[1]
        kind = _NUMBER_SUFFIX.sub("", name)
        totals[kind] = totals.get(kind, 0.0) + spent
    frames = max(frames, 1)
    ranked = sorted(totals.items(), key=lambda item: -item[1])
    return {kind: 1e3 * seconds / frames for kind, seconds in ranked if seconds > 0}


def summary(shares: dict[str, float] | None, shown: int = 6) -> str:
    """One indented line of :func:`per_frame_ms`'s largest shares (the main thread carries
    the process's name, ``python``)."""
    parts = [
        f"{'main' if kind == 'python' else kind} {ms:.1f}" for kind, ms in (shares or {}).items()
    ]
    return "  CPU ms per frame by thread: " + (", ".join(parts[:shown]) or "n/a (no /proc)")
