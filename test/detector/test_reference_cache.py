"""A detection through the reference cache equals a fresh one, frame after frame."""

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.pipeline import detect_pad
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived
from allo_mrad_ros.example_scene import example_pair


@pytest.fixture(scope="module")
def frames():
    """Two queries of one view (a clean one and one with an object) and its reference."""
    pair = example_pair(height=270, width=480, seed=2)
    reference = cv2.resize(pair.reference, (120, 68), interpolation=cv2.INTER_AREA)
    reference.flags.writeable = False
    return [pair.clean_query, pair.query], reference


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
    ],
)
def test_cached_detections_equal_fresh_ones_over_consecutive_frames(frames, changes):
    queries, reference = frames
    params = MradParams(**changes) if changes else MradParams()
    cache = ReferenceCache()
    for query in queries + queries:
        same(detect(query, reference, params, cache=cache), detect(query, reference, params))
    assert cache.hits > 0 and cache.misses > 0


def test_the_cache_is_used_from_the_second_frame_on(frames):
    queries, reference = frames
    cache = ReferenceCache()
    detect(queries[0], reference, cache=cache)
    misses = cache.misses
    assert misses > 0 and cache.hits > 0  # the reference's quantiles serve two fits
    hits = cache.hits
    detect(queries[1], reference, cache=cache)
    assert cache.misses == misses and cache.hits >= hits + misses


def test_a_new_reference_clears_what_the_old_one_gave(frames):
    queries, reference = frames
    cache = ReferenceCache()
    detect(queries[0], reference, cache=cache)
    other = np.ascontiguousarray(reference[:, ::-1])
    other.flags.writeable = False
    same(detect(queries[0], other, cache=cache), detect(queries[0], other))


def test_a_writable_reference_is_never_cached(frames):
    queries, reference = frames
    writable = reference.copy()
    cache = ReferenceCache()
    detect(queries[1], writable, cache=cache)
    writable[:20] = 255 - writable[:20]  # changed in place between frames
    same(detect(queries[1], writable, cache=cache), detect(queries[1], writable))
    assert cache.hits == cache.misses == 0


def test_pad_through_the_cache_equals_pad_without(frames):
    queries, reference = frames
    cache = ReferenceCache()
    for query in queries:
        same(detect_pad(query, reference, cache=cache), detect_pad(query, reference))


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
