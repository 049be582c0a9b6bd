"""Thread-safe hand-over between the node's callbacks and its processing thread."""

from __future__ import annotations

import bisect
import threading
import time
from collections import deque
from collections.abc import Iterable
from typing import Generic, TypeVar

import numpy as np

T = TypeVar("T")


class LatestSlot(Generic[T]):
    """A one-item mailbox: the newest item wins, an unprocessed older one is dropped.

    The subscription callback only ``put``s, so it never blocks on processing; the
    processing thread ``take``s.
    """

    def __init__(self) -> None:
        self._item: T | None = None
        self._condition = threading.Condition()
        self._closed = False
        self.received = 0
        self.dropped = 0

    def put(self, item: T) -> bool:
        """Store ``item``; return True if it replaced one that was never taken."""
        with self._condition:
            replaced = self._item is not None
            self._item = item
            self.received += 1
            self.dropped += int(replaced)
            self._condition.notify()
            return replaced

    def take(self, timeout: float | None = None) -> T | None:
        """Wait up to ``timeout`` seconds for an item and remove it (None on timeout/close)."""
        with self._condition:
            if self._item is None and not self._closed:
                self._condition.wait(timeout)
            item, self._item = self._item, None
            return item

    def close(self) -> None:
        """Wake any waiting ``take`` for shutdown."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()


class HandOver(Generic[T]):
    """A queue of one item between two threads (render stage to detect stage).

    The producer waits with :meth:`wait_empty` until the consumer has taken the previous
    item, so at most one finished item ever waits and the producer never works more than
    one item ahead.
    """

    def __init__(self) -> None:
        self._item: T | None = None
        self._condition = threading.Condition()
        self._closed = False
        # Monotonic time of the last take: when the consumer started on its current item.
        self.taken_at: float | None = None

    def wait_empty(self, timeout: float | None = None) -> bool:
        """Wait up to ``timeout`` seconds for the slot to be empty; False if full or closed."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is None or self._closed, timeout)
            return self._item is None and not self._closed

    def put(self, item: T, timeout: float | None = None) -> bool:
        """Store ``item`` once the slot is empty; False (item not stored) on timeout or close."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is None or self._closed, timeout)
            if self._item is not None or self._closed:
                return False
            self._item = item
            self._condition.notify_all()
            return True

    def take(self, timeout: float | None = None) -> T | None:
        """Wait up to ``timeout`` seconds for an item and remove it (None on timeout/close)."""
        with self._condition:
            self._condition.wait_for(lambda: self._item is not None or self._closed, timeout)
            item, self._item = self._item, None
            if item is not None:
                self.taken_at = time.monotonic()  # set before the producer can wake
                self._condition.notify_all()
            return item

    def close(self) -> None:
        """Wake every waiting thread for shutdown."""
        with self._condition:
            self._closed = True
            self._condition.notify_all()


class StampedBuffer(Generic[T]):
    """The most recent ``capacity`` values by stamp, looked up by nearest stamp."""

    def __init__(self, capacity: int = 256) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be at least 1, got {capacity}")
        self._stamps: deque[int] = deque(maxlen=capacity)
        self._values: deque[T] = deque(maxlen=capacity)
        self._lock = threading.Lock()

    def add(self, stamp_ns: int, value: T) -> None:
        """Insert a value; out-of-order stamps are placed in order."""
        with self._lock:
            if not self._stamps or stamp_ns >= self._stamps[-1]:
                self._stamps.append(stamp_ns)
                self._values.append(value)
                return
            stamps, values = list(self._stamps), list(self._values)
            index = bisect.bisect_right(stamps, stamp_ns)
            stamps.insert(index, stamp_ns)
            values.insert(index, value)
            self._stamps = deque(stamps, maxlen=self._stamps.maxlen)
            self._values = deque(values, maxlen=self._values.maxlen)

    def nearest(self, stamp_ns: int, tolerance_ns: int) -> T | None:
        """The value whose stamp is closest to ``stamp_ns``, if within ``tolerance_ns``."""
        with self._lock:
            if not self._stamps:
                return None
            stamps = list(self._stamps)
            index = bisect.bisect_left(stamps, stamp_ns)
            best = None
            for candidate in (index - 1, index):
                if 0 <= candidate < len(stamps):
                    gap = abs(stamps[candidate] - stamp_ns)
                    if gap <= tolerance_ns and (best is None or gap < best[0]):
                        best = (gap, candidate)
            return None if best is None else self._values[best[1]]

    def latest(self) -> T | None:
        """The value with the newest stamp, if any."""
        with self._lock:
            return self._values[-1] if self._values else None


class StageStatistics:
    """Rolling per-stage latencies and the processing rate, for diagnostics."""

    def __init__(self, window: int = 200) -> None:
        self._window = window
        self._samples: dict[str, deque[float]] = {}
        self._done: deque[float] = deque(maxlen=window)
        self._lock = threading.Lock()

    def record(self, timings_ms: dict[str, float]) -> None:
        """Add one processed frame's stage timings (milliseconds)."""
        with self._lock:
            self._done.append(time.monotonic())
            for name, value in timings_ms.items():
                self._samples.setdefault(name, deque(maxlen=self._window)).append(value)

    def rate_hz(self, window_s: float | None = None) -> float:
        """Frames processed per second.

        With ``window_s``: frames in the last ``window_s`` seconds up to now, divided by
        ``window_s`` (0 once processing stops). Without: over the stored frames.
        """
        with self._lock:
            if window_s is not None:
                since = time.monotonic() - window_s
                return sum(1 for t in self._done if t >= since) / window_s
            if len(self._done) < 2:
                return 0.0
            span = self._done[-1] - self._done[0]
            return (len(self._done) - 1) / span if span > 0 else 0.0

    def percentiles(self, names: Iterable[str] | None = None) -> dict[str, tuple[float, float]]:
        """Median and 95th percentile per stage over the window."""
        with self._lock:
            chosen = list(self._samples) if names is None else list(names)
            return {
                name: (
                    float(np.median(self._samples[name])),
                    float(np.percentile(self._samples[name], 95)),
                )
                for name in chosen
                if self._samples.get(name)
            }
