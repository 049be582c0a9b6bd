"""benchmarks.local_cues: the kinds of anomaly pixels it reports recall for."""

import numpy as np

from benchmarks.local_cues import KIND_NAMES, _kinds


def test_pixels_are_sorted_by_darkness_and_what_the_reference_shows():
    # Reference: space on the left half, lit station on the right (at half the query's size).
    reference = np.zeros((2, 4, 3), np.uint8)
    reference[:, 2:] = 150
    image = np.zeros((4, 8, 3), np.uint8)
    image[0, :] = (30, 30, 30)  # dark
    image[1, :] = (200, 200, 200)  # not dark
    image[2, :] = (4, 4, 4)  # black: as dark as space
    positive = np.zeros((4, 8), bool)
    positive[:3] = True
    kinds, black = _kinds(image, reference, positive)
    kinds = kinds.reshape(3, 8)
    black = black.reshape(3, 8)
    names = np.array(KIND_NAMES)
    assert list(names[kinds[0]]) == ["dark over space"] * 4 + ["dark over station"] * 4
    assert list(names[kinds[1]]) == ["other over space"] * 4 + ["other over station"] * 4
    assert black[2].tolist() == [True] * 4 + [False] * 4
    assert not black[:2].any()
