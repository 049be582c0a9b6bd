"""Frame-parallel work for ``evaluate`` and ``ablate``: one renderer per worker process.

Worker processes are started with ``spawn``: an OpenGL context does not survive ``fork``, and
each worker builds its own :class:`~allo_mrad_ros.render.ReferenceRenderer` in its
initializer. The parent reads frames and hands them out with at most two frames per worker
in flight, so memory stays bounded however long the input is (``Pool.imap`` would read the
whole input ahead). Results come back in input order.

:class:`concurrent.futures.ProcessPoolExecutor` rather than ``multiprocessing.Pool``: when
an initializer fails (no OpenGL in the worker, say) or a worker dies, the executor reports a
broken pool at once, where ``Pool`` would restart the worker forever and hang.
"""

from __future__ import annotations

import multiprocessing
import time
from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass
from typing import Any

from tqdm import tqdm

from allo_mrad_ros.errors import BackendError


class ParallelError(BackendError):
    """A worker failed on a frame (the message names the frame)."""


@dataclass
class RunClock:
    """Wall time of a run: from the first frame handed out to the last result."""

    start: float = 0.0
    end: float = 0.0

    @property
    def seconds(self) -> float:
        """Elapsed seconds."""
        return max(0.0, self.end - self.start)


def run_frames(
    jobs_in: Iterable[Any],
    total: int,
    *,
    initializer: Callable[..., None],
    initargs: tuple,
    work: Callable[[Any], Any],
    jobs: int = 1,
    progress: bool = True,
    desc: str = "frames",
    clock: RunClock | None = None,
) -> Iterator[Any]:
    """Apply ``work`` to every item of ``jobs_in``, in ``jobs`` processes, in order.

    Parameters
    ----------
    jobs_in : iterable
        Work items (picklable), read lazily.
    total : int
        Number of items, for the progress bar.
    initializer, initargs
        Called once per worker process (and once in this process when ``jobs`` is 1).
    work : callable
        Module-level function applied to each item.
    jobs : int
        Worker processes; 1 runs everything in this process.
    progress : bool
        Show a tqdm progress bar on stderr.
    desc : str
        Progress bar label.
    clock : RunClock, optional
        Filled with the run's wall time.

    Yields
    ------
    object
        ``work(item)`` for each item, in input order.
    """
    if jobs < 1:
        raise ParallelError(f"jobs must be at least 1, got {jobs}")
    clock = clock or RunClock()
    bar = tqdm(total=total, desc=desc, unit="frame", disable=not progress, dynamic_ncols=True)
    try:
        if jobs == 1:
            initializer(*initargs)
            clock.start = time.perf_counter()
            for item in jobs_in:
                result = work(item)
                clock.end = time.perf_counter()
                bar.update(1)
                yield result
            return
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(
            jobs, mp_context=context, initializer=initializer, initargs=initargs
        ) as pool:
            pending: deque = deque()
            clock.start = time.perf_counter()
            try:
                for item in jobs_in:
                    pending.append(pool.submit(work, item))
                    while len(pending) >= 2 * jobs:
                        yield _collect(pending, bar, clock)
                while pending:
                    yield _collect(pending, bar, clock)
            except BrokenProcessPool as error:
                raise ParallelError(
                    f"a worker process failed to start or died ({error}); run with --jobs 1 "
                    "to see the error"
                ) from None
            finally:
                for future in pending:
                    future.cancel()
    finally:
        bar.close()


def _collect(pending: deque, bar: tqdm, clock: RunClock) -> Any:
    result = pending.popleft().result()
    clock.end = time.perf_counter()
    bar.update(1)
    return result
