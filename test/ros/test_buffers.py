"""The node's hand-over buffers, without DDS: newest-wins slot, stamped lookup, statistics."""

from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from allo_mrad_ros.ros.buffers import LatestSlot, StageStatistics, StampedBuffer


def test_latest_slot_keeps_the_newest_and_counts_drops():
    slot: LatestSlot[int] = LatestSlot()
    assert slot.put(1) is False
    assert slot.put(2) is True  # 1 was never taken
    assert slot.take(timeout=0) == 2
    assert slot.take(timeout=0) is None
    assert (slot.received, slot.dropped) == (2, 1)


def test_take_waits_for_a_put_and_close_wakes_it():
    slot: LatestSlot[str] = LatestSlot()
    threading.Timer(0.05, slot.put, args=("late",)).start()
    assert slot.take(timeout=30.0) == "late"
    # A take with no timeout, already waiting, ends only if close wakes it (else the join
    # below expires): no elapsed time to compare, which a loaded machine can stretch.
    taken = []
    waiter = threading.Thread(target=lambda: taken.append(slot.take(timeout=None)), daemon=True)
    waiter.start()
    deadline = time.monotonic() + 30.0  # until it waits in the slot (a bound, not a timing)
    while not slot._condition._waiters and time.monotonic() < deadline:
        time.sleep(0.001)
    slot.close()
    waiter.join(30.0)
    assert not waiter.is_alive() and taken == [None]


def test_stamped_buffer_orders_and_finds_the_nearest_within_tolerance():
    buffer: StampedBuffer[str] = StampedBuffer(capacity=3)
    for stamp, value in ((10, "a"), (30, "c"), (20, "b")):  # one out of order
        buffer.add(stamp, value)
    assert buffer.nearest(21, 5) == "b"
    assert buffer.nearest(26, 5) == "c"
    assert buffer.nearest(45, 5) is None
    assert buffer.latest() == "c"
    buffer.add(40, "d")  # capacity 3: the oldest (10) goes
    assert buffer.nearest(10, 5) is None and buffer.nearest(40, 0) == "d"
    with pytest.raises(ValueError, match="capacity"):
        StampedBuffer(0)


def test_stage_statistics_percentiles_and_rate():
    stats = StageStatistics(window=100)
    assert stats.rate_hz() == 0.0 and stats.percentiles() == {}
    values = np.arange(1.0, 101.0)
    for value in values:
        stats.record({"render": value})
    p50, p95 = stats.percentiles()["render"]
    assert p50 == pytest.approx(np.median(values)) and p95 == pytest.approx(
        np.percentile(values, 95)
    )
    assert stats.rate_hz() > 0
