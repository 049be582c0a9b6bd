"""A detection through the reference cache equals a fresh one, frame after frame, and from
the second frame on with one reference nothing derived from it alone is computed again."""

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.pipeline import detect_pad
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived, read_only_cache
from allo_mrad_ros.example_scene import example_pair


@pytest.fixture(scope="module")
def frames():
    """Two queries of one view (a clean one and one with an object) and its reference."""
    pair = example_pair(height=270, width=480, seed=2)
    reference = cv2.resize(pair.reference, (120, 68), interpolation=cv2.INTER_AREA)
    reference.flags.writeable = False
    return [pair.clean_query, pair.query], reference


class CountingCache(ReferenceCache):
    """A cache that also records, apart from its own tallies, each lookup of a value derived
    from ``reference`` and each computation of one: a lookup answered from what the cache
    holds runs none. (Values of other images, such as a reference mapped into the query's
    colours, change every frame and are not counted.)"""

    def __init__(self, reference):
        super().__init__()
        self.reference = reference
        self.computed = []
        self.lookups = 0

    def value(self, image, key, compute):
        if image is not self.reference:
            return super().value(image, key, compute)
        self.lookups += 1

        def recorded():
            self.computed.append(key)
            return compute()

        return super().value(image, key, recorded)

    def frame(self, detector, *args, **kwargs):
        """Run ``detector(*args, cache=self, **kwargs)``; return its result, the keys it
        computed and its lookups."""
        computed, lookups = len(self.computed), self.lookups
        result = detector(*args, cache=self, **kwargs)
        return result, self.computed[computed:], self.lookups - lookups


def same(a, b):
    assert np.array_equal(a.score, b.score)
    assert np.array_equal(a.raw_score, b.raw_score)
    assert np.array_equal(a.mask, b.mask)
    assert a.image_score == b.image_score and a.area == b.area


@pytest.mark.parametrize(
    "changes",
    [
        {},
        {"colour_transfer": "reference"},
        {"colour_transfer": "none"},
        {"photometric": "none", "map_photometric": "cell_affine"},
        {"pixel_score": "regions", "transfer_bin": 8, "transfer_edge_margin": 2},
        {"transfer_gain": False, "grid": 4},
        {"specular_tolerance": 16.0},
        {"glare_halo": 2.0},
    ],
)
def test_cached_detections_equal_fresh_ones_over_consecutive_frames(frames, changes):
    queries, reference = frames
    params = MradParams(**changes) if changes else MradParams()
    cache = CountingCache(reference)
    for index, query in enumerate(queries + queries):
        hits = cache.hits
        result, computed, lookups = cache.frame(detect, query, reference, params)
        same(result, detect(query, reference, params))
        if index == 0:
            assert computed and len(set(computed)) == len(computed)  # each value once
        else:  # every lookup is answered from the cache: nothing is computed again
            assert lookups > 0 and computed == [] and cache.hits - hits == lookups


def test_the_cache_is_used_from_the_second_frame_on(frames):
    queries, reference = frames
    cache = CountingCache(reference)
    _, first, first_lookups = cache.frame(detect, queries[0], reference)
    assert cache.misses == len(first) > 0
    assert cache.hits == first_lookups - len(first) > 0  # the reference's quantiles serve two fits
    _, second, second_lookups = cache.frame(detect, queries[1], reference)
    assert second == [] and second_lookups == first_lookups
    assert cache.hits == 2 * first_lookups - len(first)


def test_a_new_reference_clears_what_the_old_one_gave(frames):
    queries, reference = frames
    cache = CountingCache(reference)
    _, first, _ = cache.frame(detect, queries[0], reference)
    other = np.ascontiguousarray(reference[:, ::-1])
    other.flags.writeable = False
    cache.reference = other
    result, again, _ = cache.frame(detect, queries[0], other)
    assert sorted(map(repr, again)) == sorted(map(repr, first))  # all computed anew
    same(result, detect(queries[0], other))


def test_a_writable_reference_is_never_cached(frames):
    queries, reference = frames
    writable = reference.copy()
    cache = CountingCache(writable)
    _, first, lookups = cache.frame(detect, queries[1], writable)
    assert len(first) == lookups > 0  # every lookup computed
    writable[:20] = 255 - writable[:20]  # changed in place between frames
    result, second, _ = cache.frame(detect, queries[1], writable)
    same(result, detect(queries[1], writable))
    assert second == first and cache.hits == cache.misses == 0


def test_pad_through_the_cache_equals_pad_without(frames):
    queries, reference = frames
    cache = CountingCache(reference)
    for index, query in enumerate(queries):
        result, computed, lookups = cache.frame(detect_pad, query, reference)
        same(result, detect_pad(query, reference))
        assert lookups > 0 and (computed != [] if index == 0 else computed == [])


def test_cached_values_are_read_only_and_keyed_by_their_parameters():
    reference = np.zeros((4, 4, 3), np.uint8)
    reference.flags.writeable = False
    cache = ReferenceCache()
    cache.use(reference)
    first = derived(cache, reference, ("sum", 1), lambda: np.ones(3))
    assert not first.flags.writeable
    assert derived(cache, reference, ("sum", 1), lambda: np.zeros(3)) is first
    assert derived(cache, reference, ("sum", 2), lambda: np.zeros(3))[0] == 0
    # Another image (a resized copy, say) is computed, not looked up.
    assert derived(cache, reference.copy(), ("sum", 1), lambda: np.zeros(3))[0] == 0


def test_a_read_only_cache_computes_once_per_argument_and_hands_out_read_only_arrays():
    calls = []

    @read_only_cache(maxsize=2)
    def table(size: int) -> tuple[np.ndarray, np.ndarray]:
        calls.append(size)
        return np.arange(size), np.zeros(size)

    first = table(3)
    assert table(3) is first
    assert table(4)[0].size == 4
    assert calls == [3, 4]
    for array in first:
        assert not array.flags.writeable
        with pytest.raises(ValueError, match="read-only"):
            array[0] = 7
    assert table.cache_info().currsize == 2
