"""Pixel counts per distinct score, pooled over frames in bounded memory.

A 300-frame 1080p split holds 600 M pixels, too many to keep and sort at once, but the
metrics depend only on how many positive and negative pixels hold each distinct score.
:class:`ScoreCounts` is that table: one entry per distinct score, keyed by the score's bit
pattern mapped to an unsigned integer of the same order (float32 scores to ``uint32``,
float64 to ``uint64``), so counting is exact, with no binning and no rounding.

:class:`PooledScoreCounts` merges frames' tables into one. Their union grows with every
frame of a float map (a bilinearly upscaled 1080p map holds some 0.4-0.9 M distinct
values), so once it passes ``max_entries`` the table is coarsened (:func:`coarsen`):
neighbouring entries are merged within buckets of the key space aligned to a power of two,
as narrow as the budget allows, while the entries holding the most pixels (a map's floor, a
block of normal pixels at one value) keep their exact entry. Aligned buckets nest, so
tables coarsened apart (one per anomaly type) still merge into one without their ranges
running together. A range entry is what makes a metric inexact, and only where it holds
both classes; :mod:`allo_mrad_ros.metrics.pixel` bounds each metric's
error.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from .curves import POSITIVE_CLASS, MetricsError

DEFAULT_MAX_ENTRIES = 1 << 20
"""Entries a pooled table may hold before it is coarsened (12 to 16 bytes each)."""

_UINT32_MAX = np.iinfo(np.uint32).max


# ----------------------------------------------------------------- score <-> ordered key
def _key_dtype(wide: bool) -> type[np.unsignedinteger]:
    return np.uint64 if wide else np.uint32


def score_keys(values: np.ndarray) -> np.ndarray:
    """Unsigned integer keys in the order of the float ``values`` (float32 or float64).

    Positive floats get the sign bit set, negative floats all bits flipped, so integer
    order is float order; ``-0.0`` takes the key of ``0.0``, as the two compare equal.
    """
    values = values + values.dtype.type(0.0)  # -0.0 + 0.0 is +0.0
    bits = values.view(_key_dtype(values.dtype.itemsize == 8))
    sign = bits.dtype.type(1) << bits.dtype.type(8 * bits.itemsize - 1)
    return np.where(bits & sign, ~bits, bits | sign)


def key_scores(keys: np.ndarray) -> np.ndarray:
    """The float scores of ``keys`` (the inverse of :func:`score_keys`)."""
    sign = keys.dtype.type(1) << keys.dtype.type(8 * keys.itemsize - 1)
    bits = np.where(keys & sign, keys & ~sign, ~keys)
    return bits.view(np.float64 if keys.itemsize == 8 else np.float32)


_UINT8_KEYS = score_keys(np.arange(256, dtype=np.float32))


def _compact(counts: np.ndarray) -> np.ndarray:
    """Counts as ``uint32`` where they fit (a third less memory), else ``int64``."""
    if counts.size and int(counts.max()) > _UINT32_MAX:
        return counts.astype(np.int64, copy=False)
    return counts.astype(np.uint32, copy=False)


# ----------------------------------------------------------------- the table
@dataclass(frozen=True)
class ScoreCounts:
    """Positive and negative pixel counts per score, in increasing score order.

    Attributes
    ----------
    low, high : numpy.ndarray
        Keys (:func:`score_keys`) of the lowest and highest score of each entry, strictly
        increasing, the entries' ranges disjoint; ``high is low`` where every entry is one
        exact score.
    positives, negatives : numpy.ndarray
        Pixel counts of the entries (``uint32``, or ``int64`` past 2**32 - 1).
    pixels : int
        Pixels counted in all (the sum of both counts).
    """

    low: np.ndarray
    high: np.ndarray
    positives: np.ndarray
    negatives: np.ndarray
    pixels: int

    @property
    def size(self) -> int:
        """Number of entries."""
        return int(self.low.size)

    @property
    def wide(self) -> bool:
        """Keys of float64 scores (else float32)."""
        return self.low.dtype == np.uint64

    @property
    def exact(self) -> bool:
        """Every entry is one score, so every metric computed from the table is exact."""
        return self.high is self.low

    @property
    def nbytes(self) -> int:
        """Bytes of the table's arrays."""
        arrays = (self.low, self.positives, self.negatives)
        return sum(a.nbytes for a in arrays) + (0 if self.exact else self.high.nbytes)

    def widened(self) -> ScoreCounts:
        """The same counts keyed for float64 scores (exact: float32 widens exactly)."""
        if self.wide:
            return self
        low = score_keys(key_scores(self.low).astype(np.float64))
        high = low if self.exact else score_keys(key_scores(self.high).astype(np.float64))
        return ScoreCounts(low, high, self.positives, self.negatives, self.pixels)

    @classmethod
    def empty(cls, wide: bool = False) -> ScoreCounts:
        """A table of no pixels."""
        keys = np.zeros(0, dtype=_key_dtype(wide))
        counts = np.zeros(0, dtype=np.uint32)
        return cls(keys, keys, counts, counts, 0)

    @classmethod
    def of_frame(cls, scores: np.ndarray, mask: np.ndarray) -> ScoreCounts:
        """Exact counts of one frame.

        Parameters
        ----------
        scores : numpy.ndarray
            H x W pixel scores: float32 or float64, or integers (``uint8`` is counted
            directly; other integers and float16 are compared as floats, exactly).
        mask : numpy.ndarray
            H x W ground truth; class 2 (:data:`POSITIVE_CLASS`) is a positive pixel.

        Raises
        ------
        MetricsError
            If the shapes differ or a score is NaN or infinite.
        """
        scores, mask = np.asarray(scores), np.asarray(mask)
        if scores.shape != mask.shape:
            raise MetricsError(f"score map {scores.shape} and mask {mask.shape} differ in shape")
        positive = (mask == POSITIVE_CLASS).ravel()
        if scores.dtype == np.uint8 or scores.dtype == np.bool_:
            return _of_uint8(scores.ravel().view(np.uint8), positive)
        wide = scores.dtype.itemsize > 4 or (
            scores.dtype.kind in "iu" and scores.dtype.itemsize > 2
        )
        values = scores.astype(np.float64 if wide else np.float32, copy=False).ravel()
        if not np.isfinite(values).all():
            raise MetricsError("score map contains NaN or Inf")
        # Every pixel's runs, then the (fewer) positives' runs taken out of them: no copy of
        # the negatives is made.
        keys, counts = _runs(values)
        positives = np.zeros_like(counts)
        if positive.any():
            pos_keys, pos_counts = _runs(values[positive])
            place = np.searchsorted(keys, pos_keys)
            positives[place] = pos_counts
            counts -= positives
        return cls(keys, keys, positives, counts, values.size)


def _insert_positives(
    keys: np.ndarray,
    negatives: np.ndarray,
    pos_keys: np.ndarray,
    pos_counts: np.ndarray,
    pixels: int,
) -> ScoreCounts:
    """One exact table from the negatives' and the (fewer) positives' runs, in linear time."""
    index = np.searchsorted(keys, pos_keys)
    found = index < keys.size
    found[found] = keys[index[found]] == pos_keys[found]
    new = ~found
    # A positive's place in the merged table: its place among the negatives, moved on by
    # the new keys inserted before it (all earlier positives, as both are sorted).
    place = index + np.cumsum(new) - new
    keys = np.insert(keys, index[new], pos_keys[new])
    negatives = np.insert(negatives, index[new], 0)
    positives = np.zeros(keys.size, dtype=pos_counts.dtype)
    positives[place] = pos_counts
    return ScoreCounts(keys, keys, positives, negatives, pixels)


def _of_uint8(values: np.ndarray, positive: np.ndarray) -> ScoreCounts:
    positives = np.bincount(values[positive], minlength=256)
    negatives = np.bincount(values[~positive], minlength=256)
    present = np.flatnonzero(positives + negatives)
    keys = _UINT8_KEYS[present]
    return ScoreCounts(
        keys, keys, _compact(positives[present]), _compact(negatives[present]), values.size
    )


def _runs(values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distinct values' keys and counts: sort, then the lengths of runs of equal values."""
    if values.size == 0:
        return np.zeros(0, dtype=_key_dtype(values.dtype.itemsize == 8)), np.zeros(0, np.uint32)
    ordered = np.sort(values)
    starts = np.flatnonzero(np.concatenate([[True], ordered[1:] != ordered[:-1]]))
    counts = np.diff(np.append(starts, ordered.size))
    return score_keys(ordered[starts]), _compact(counts)


def group_sums(counts: np.ndarray, starts: np.ndarray, total: int) -> np.ndarray:
    """Sums of ``counts`` over the groups beginning at ``starts``, as :func:`_compact` keeps
    them: in ``uint32`` when no sum can pass it (NumPy would otherwise widen them)."""
    if counts.dtype == np.uint32 and total <= _UINT32_MAX:
        return np.add.reduceat(counts, starts, dtype=np.uint32)
    return _compact(np.add.reduceat(counts.astype(np.int64, copy=False), starts))


def _narrow_counts(table: ScoreCounts) -> bool:
    return table.positives.dtype == np.uint32 and table.negatives.dtype == np.uint32


_LOW_32 = np.uint64(_UINT32_MAX)
_SHIFT_32 = np.uint64(32)


def _merge_class(tables: list[ScoreCounts], name: str) -> tuple[np.ndarray, np.ndarray]:
    """Keys and summed counts of one class over exact ``uint32``-keyed tables.

    Each nonzero count is packed with its key into one ``uint64`` (key high), so a plain
    sort of the values orders them (no index array, no gathers) and equal keys meet.
    """
    packed = []
    for table in tables:
        counts = getattr(table, name)
        present = counts > 0
        keys, counts = (
            (table.low, counts) if present.all() else (table.low[present], counts[present])
        )
        packed.append((keys.astype(np.uint64) << _SHIFT_32) | counts)
    values = np.concatenate(packed)
    del packed
    if not values.size:
        return np.zeros(0, np.uint32), np.zeros(0, np.uint32)
    values.sort()
    keys = (values >> _SHIFT_32).astype(np.uint32)
    last = np.flatnonzero(np.concatenate([keys[1:] != keys[:-1], [True]]))
    counts = values & _LOW_32
    del values
    if last.size == keys.size:
        return keys, counts.astype(np.uint32)
    # Sums over runs of equal keys: differences of the running sum at each run's end.
    total = np.cumsum(counts)[last]
    total[1:] -= total[:-1].copy()
    return keys[last], _compact(total)


def _merge_into(big: ScoreCounts, small: ScoreCounts) -> ScoreCounts:
    """``big`` (exact or coarsened) and an exact ``small`` merged by adding each entry of
    ``small`` to the entry of ``big`` that holds its score, or inserting it."""
    index = np.searchsorted(big.low, small.low, side="right") - 1
    found = index >= 0
    found[found] = small.low[found] <= big.high[index[found]]
    new = ~found
    index[new] += 1  # where a new entry goes: before the first entry above it
    # Where each entry of small lands: its index moved on by the new entries before it.
    place = index + np.cumsum(new) - new
    pixels = big.pixels + small.pixels
    any_new = bool(new.any())
    if any_new:
        low = np.insert(big.low, index[new], small.low[new])
        high = low if big.exact else np.insert(big.high, index[new], small.low[new])
    else:
        low, high = big.low, big.high
    targets = place[found]
    counts = []
    for name in ("positives", "negatives"):
        mine, theirs = getattr(big, name), getattr(small, name)
        if not any_new and not theirs.any():
            counts.append(mine)  # nothing to add (a normal frame's positives): share
            continue
        if pixels > _UINT32_MAX:
            mine, theirs = mine.astype(np.int64), theirs.astype(np.int64)
        merged = np.insert(mine, index[new], theirs[new]) if any_new else mine.copy()
        np.add.at(merged, targets, theirs[found])  # several may land in one range
        counts.append(_compact(merged) if pixels > _UINT32_MAX else merged)
    return ScoreCounts(low, high, *counts, pixels)


def _merge_packed(tables: list[ScoreCounts]) -> ScoreCounts:
    neg_keys, negatives = _merge_class(tables, "negatives")
    pos_keys, positives = _merge_class(tables, "positives")
    pixels = sum(t.pixels for t in tables)
    return _insert_positives(neg_keys, negatives, pos_keys, positives, pixels)


def merge(tables: Iterable[ScoreCounts]) -> ScoreCounts:
    """One table holding the pixels of all ``tables``.

    Equal scores add up; an entry whose score lies in another's range, or two overlapping
    ranges, become one entry spanning both (exactness is lost only where a table was
    already coarsened).
    """
    tables = [t for t in tables if t.size]
    if not tables:
        return ScoreCounts.empty()
    if any(t.wide for t in tables):
        tables = [t.widened() for t in tables]
    if len(tables) == 1:
        return tables[0]
    coarse = [t for t in tables if not t.exact]
    exact = not coarse
    # Exact entries into a coarsened table's ranges, or few entries into many: insert
    # them rather than sort everything again.
    big = coarse[0] if len(coarse) == 1 else max(tables, key=lambda t: t.size)
    rest = [t for t in tables if t is not big]
    if len(coarse) == 1 or (exact and big.size >= 4 * sum(t.size for t in rest)):
        return _merge_into(big, rest[0] if len(rest) == 1 else merge(rest))
    if exact and not tables[0].wide and all(_narrow_counts(t) for t in tables):
        return _merge_packed(tables)
    low = np.concatenate([t.low for t in tables])
    order = np.argsort(low, kind="stable")  # timsort: near linear on a few sorted runs
    low = low[order]
    if exact:
        starts = np.flatnonzero(np.concatenate([[True], low[1:] != low[:-1]]))
        high = low = low[starts]
    else:
        high = np.concatenate([t.high for t in tables])[order]
        # An entry starts a new one unless it begins within the ranges before it.
        reach = np.maximum.accumulate(high)
        starts = np.flatnonzero(np.concatenate([[True], low[1:] > reach[:-1]]))
        del reach
        low, high = low[starts], np.maximum.reduceat(high, starts)
        if np.array_equal(low, high):
            high = low
    total = sum(t.pixels for t in tables)

    def summed(name: str) -> np.ndarray:
        counts = np.concatenate([getattr(t, name) for t in tables])[order]
        if starts.size == counts.size:  # no two entries met
            return _compact(counts) if counts.dtype != np.uint32 else counts
        return group_sums(counts, starts, total)

    return ScoreCounts(low, high, summed("positives"), summed("negatives"), total)


def coarsen(table: ScoreCounts, target: int) -> ScoreCounts:
    """Merge adjacent entries into at most ``target`` entries, in one pass.

    Entries are merged within buckets of the key space aligned to a power of two (all keys
    equal but for their lowest ``shift`` bits: a relative width of ``2**(shift - 23)`` of a
    float32 score), with the smallest shift that leaves few enough buckets. Because every
    table's ranges lie inside such aligned buckets, two coarsened tables merge without
    their ranges chaining into one another: two aligned buckets either nest or are apart,
    so a range of the merge never reaches past the bucket of the coarser table that holds
    it. The ``target // 8`` entries holding the most pixels stay as they are where they
    hold more than an average entry's share (a heavily tied score keeps its exact entry),
    and split their bucket around them.
    """
    if target < 2:
        raise MetricsError(f"cannot coarsen a table to {target} entries")
    if table.size <= target:
        return table
    weight = table.positives.astype(np.int64) + table.negatives
    kept = np.zeros(table.size, dtype=bool)
    kept_budget = (target - 1) // 8
    if kept_budget:
        heaviest = np.argpartition(weight, table.size - kept_budget)[table.size - kept_budget :]
        kept[heaviest] = True
        kept &= weight > -(-int(weight.sum()) // target)
    # A kept entry splits its bucket in three at most: two entries more than its bucket.
    shift = bucket_shift(table, target - 2 * int(np.count_nonzero(kept)))
    bits = 8 * table.low.itemsize
    bucket = table.low >> table.low.dtype.type(shift) if shift < bits else np.zeros_like(table.low)
    starts = np.ones(table.size, dtype=bool)
    starts[1:] = kept[1:] | kept[:-1] | (bucket[1:] != bucket[:-1])
    starts = np.flatnonzero(starts)
    ends = np.append(starts[1:], table.size) - 1
    return ScoreCounts(
        table.low[starts],
        table.high[ends],
        group_sums(table.positives, starts, table.pixels),
        group_sums(table.negatives, starts, table.pixels),
        table.pixels,
    )


def bucket_shift(table: ScoreCounts, buckets: int) -> int:
    """The smallest shift whose aligned buckets (keys ``>> shift``) number at most
    ``buckets`` and each hold every range of ``table`` whole."""
    bits = 8 * table.low.itemsize
    lowest = 0
    if not table.exact:
        spread = int(np.bitwise_xor(table.low, table.high).max())
        lowest = spread.bit_length()

    def count(shift: int) -> int:
        if shift >= bits:
            return 1
        keys = table.low >> table.low.dtype.type(shift)
        return 1 + int(np.count_nonzero(keys[1:] != keys[:-1]))

    high = bits
    low = lowest
    while low < high:  # the count falls as the shift grows
        middle = (low + high) // 2
        if count(middle) <= max(1, buckets):
            high = middle
        else:
            low = middle + 1
    return low


# ----------------------------------------------------------------- pooling frames
class PooledScoreCounts:
    """The counts of many frames, exact up to ``max_entries`` distinct scores.

    Each frame's table is merged into the pooled table as it comes (inserted, where the
    pooled table is the larger); a pooled table past ``max_entries`` is coarsened to half
    of it, after which a frame's scores that fall in one of its ranges are added to that
    range. The pooled table, at most ``max_entries`` entries of 12 to 16 bytes, is all
    that is kept; a merge works on a copy of it and the frame's table.

    Parameters
    ----------
    max_entries : int
        Entries the pooled table may hold (at least 4).
    """

    def __init__(self, *, max_entries: int = DEFAULT_MAX_ENTRIES) -> None:
        if max_entries < 4:
            raise MetricsError(f"max_entries must be at least 4, got {max_entries}")
        self.max_entries = max_entries
        self._pooled = ScoreCounts.empty()

    def update(self, scores: np.ndarray, mask: np.ndarray) -> None:
        """Add one frame: ``scores`` H x W and its ground-truth ``mask`` (class 2 = anomaly)."""
        self.add(ScoreCounts.of_frame(scores, mask))

    def add(self, table: ScoreCounts) -> None:
        """Add a frame's table (or any other)."""
        if not table.size:
            return
        pooled = merge([self._pooled, table])
        if pooled.size > self.max_entries:
            pooled = coarsen(pooled, self.max_entries // 2)
        self._pooled = pooled

    def add_pool(self, other: PooledScoreCounts) -> None:
        """Add every frame of ``other``."""
        self.add(other.table())

    def table(self) -> ScoreCounts:
        """The pooled table of every frame added so far."""
        return self._pooled

    @property
    def nbytes(self) -> int:
        """Bytes of the pooled table."""
        return self._pooled.nbytes
