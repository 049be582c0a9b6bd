"""Tolerated highlights: float64 per-pixel oracles of the specular potential, the glare halo
and the tolerated query, and what each mechanism suppresses and what it keeps.

The oracles work pixel by pixel in float64: the potential from explicit window minima and
maxima of the reference's darkest channel, the halo from a flood-fill labelling and the
Euclidean distance of every pixel to every pixel of each lit clipped component.
"""

import math

import numpy as np
import pytest
from mrad_oracle import components_naive

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.highlights import (
    CLIPPED_LEVEL,
    LIT_LEVEL,
    SPECULAR_FULL,
    SPECULAR_SPREAD,
    SPECULAR_WINDOW,
    UNLIMITED,
    HighlightsError,
    glare_halo,
    specular_potential,
    tolerate_highlights,
)
from allo_mrad_ros.detector.params import ParamsError
from allo_mrad_ros.detector.reference_cache import ReferenceCache

HEIGHT, WIDTH = 60, 80
PANEL = (70.0, 90.0, 60.0)
SPOT = (slice(22, 25), slice(32, 35))
"""The reference's own highlight (3 x 3, narrower than the top-hat's 9 x 9 window)."""
LOBE = (slice(20, 27), slice(30, 37))
"""The query's broader highlight round it (the spread's 5 x 5 reaches 2 pixels further)."""
FLAT = (slice(40, 47), slice(60, 67))
"""Panel far from any predicted highlight."""


# ---------------------------------------------------------------- oracles
def _window_side(fraction: float, shape: tuple[int, int]) -> int:
    side = max(3, round(min(shape) * fraction)) | 1
    return side


def _window_reduce(values: np.ndarray, side: int, reduce) -> np.ndarray:
    # Each pixel's window, cut to the image (the same as a replicated border for min/max).
    half = side // 2
    out = np.empty_like(values)
    for row in range(values.shape[0]):
        for col in range(values.shape[1]):
            window = values[
                max(0, row - half) : row + half + 1, max(0, col - half) : col + half + 1
            ]
            out[row, col] = reduce(window)
    return out


def potential_naive(reference: np.ndarray) -> np.ndarray:
    darkest = reference.astype(np.float64).min(axis=2)
    side = _window_side(SPECULAR_WINDOW, darkest.shape)
    opened = _window_reduce(_window_reduce(darkest, side, np.min), side, np.max)
    potential = np.minimum((darkest - opened) / SPECULAR_FULL, 1.0)
    spread = max(1, round(min(darkest.shape) * SPECULAR_SPREAD)) | 1
    return potential if spread == 1 else _window_reduce(potential, spread, np.max)


def halo_naive(query: np.ndarray, reference: np.ndarray, factor: float) -> np.ndarray:
    clipped = query.astype(np.float64).max(axis=2) >= CLIPPED_LEVEL
    lit = reference.astype(np.float64).max(axis=2)
    rows, cols = np.mgrid[0 : query.shape[0], 0 : query.shape[1]].astype(np.float64)
    halo = np.zeros(clipped.shape, bool)
    for pixels in components_naive(clipped):
        if np.mean([lit[p] for p in pixels]) < LIT_LEVEL:
            continue
        radius = factor * math.sqrt(len(pixels))
        nearest = np.full(clipped.shape, np.inf)
        for row, col in pixels:
            nearest = np.minimum(nearest, np.hypot(rows - row, cols - col))
        halo |= nearest <= radius
    return halo & ~clipped


def tolerated_naive(seen, query, reference, tolerance, factor) -> np.ndarray:
    # Whole levels: the allowance rounded half to even, as the module states.
    q = query.astype(np.float64)
    excess = np.maximum((q - reference.astype(np.float64)).min(axis=2), 0.0)
    allowed = np.zeros(excess.shape)
    if tolerance > 0:
        allowed = np.minimum(np.rint(tolerance * potential_naive(reference)), 255.0)
    if factor > 0:
        allowed[halo_naive(seen, reference, factor)] = UNLIMITED
    return q - np.minimum(excess, allowed)[..., None]


# ---------------------------------------------------------------- scenes
def panel_reference() -> np.ndarray:
    """A coloured panel with one colourless highlight the reference draws (SPOT)."""
    reference = np.empty((HEIGHT, WIDTH, 3))
    reference[:] = PANEL
    reference[:, :8] = (2.0, 2.0, 3.0)  # space
    reference[SPOT] += 60.0
    return reference.astype(np.uint8)


def brightened(reference: np.ndarray, where, amount) -> np.ndarray:
    query = reference.astype(np.float64)
    query[where] += amount
    return np.clip(np.rint(query), 0, 255).astype(np.uint8)


def random_pair(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    reference = rng.integers(0, 256, (HEIGHT // 2, WIDTH // 2, 3)).astype(np.uint8)
    reference[rng.random(reference.shape[:2]) < 0.7] = (60, 80, 50)
    reference[5:9, 10:14] = (200, 210, 190)
    query = np.clip(reference.astype(int) + rng.integers(-40, 60, reference.shape), 0, 255)
    query[rng.random(query.shape[:2]) < 0.05] = 255  # clipped specks and blobs
    query[12:16, 20:25] = 252
    return query.astype(np.uint8), reference


# ---------------------------------------------------------------- the oracles agree
@pytest.mark.parametrize("seed", range(3))
def test_the_potential_matches_the_float64_oracle(seed):
    _, reference = random_pair(seed)
    np.testing.assert_allclose(
        specular_potential(reference), potential_naive(reference), rtol=0, atol=1e-6
    )


@pytest.mark.parametrize(("seed", "factor"), [(0, 0.7), (1, 1.3), (2, 2.9)])
def test_the_halo_matches_the_float64_oracle(seed, factor):
    query, reference = random_pair(seed)
    halo = glare_halo(query, reference, factor)
    expected = halo_naive(query, reference, factor)
    assert expected.any() and (~expected).any()
    np.testing.assert_array_equal(halo, expected)


@pytest.mark.parametrize(
    ("seed", "tolerance", "factor"), [(0, 16.0, 0.0), (1, 0.0, 1.5), (2, 64.0, 2.0)]
)
def test_the_tolerated_query_matches_the_float64_oracle(seed, tolerance, factor):
    query, reference = random_pair(seed)
    seen = query.copy()
    out = tolerate_highlights(
        seen, query, reference, specular_tolerance=tolerance, glare_halo_factor=factor
    )
    expected = tolerated_naive(seen, query, reference, tolerance, factor)
    assert not np.array_equal(expected, query)  # something was tolerated
    np.testing.assert_array_equal(out, expected)


def test_a_clipped_object_the_reference_does_not_light_makes_no_halo():
    reference = np.full((HEIGHT, WIDTH, 3), 40, np.uint8)  # a dim panel
    query = brightened(reference, FLAT, 215.0)  # clipped, where nothing is lit
    assert not glare_halo(query, reference, 3.0).any()
    lit = reference.copy()
    lit[FLAT] = 200
    assert glare_halo(query, lit, 3.0).any()


# ---------------------------------------------------------------- specular: what it keeps
def tolerate_specular(query: np.ndarray, reference: np.ndarray, tolerance: float = 64.0):
    return tolerate_highlights(
        query, query, reference, specular_tolerance=tolerance, glare_halo_factor=0.0
    ).astype(np.float64)


def test_the_reference_predicts_its_highlight_and_not_the_flat_panel():
    potential = specular_potential(panel_reference())
    assert potential[LOBE].min() == 1.0
    assert potential[FLAT].max() == 0.0


def test_a_colourless_highlight_at_a_predicted_pixel_is_tolerated():
    reference = panel_reference()
    query = brightened(reference, LOBE, 50.0)
    out = tolerate_specular(query, reference)
    np.testing.assert_array_equal(out[LOBE], reference[LOBE])


def test_the_tolerance_is_proportional_and_capped():
    reference = panel_reference()
    query = brightened(reference, LOBE, 50.0)
    out = tolerate_specular(query, reference, tolerance=16.0)
    np.testing.assert_array_equal(out[LOBE], query[LOBE].astype(np.float64) - 16.0)


def test_a_coloured_anomaly_at_a_predicted_pixel_keeps_its_colour_departure():
    reference = panel_reference()
    query = brightened(reference, LOBE, (60.0, 0.0, 0.0))
    out = tolerate_specular(query, reference)
    np.testing.assert_array_equal(out[LOBE], query[LOBE])
    # A bright coloured one loses only its colourless share.
    query = brightened(reference, LOBE, (80.0, 20.0, 30.0))
    out = tolerate_specular(query, reference)
    np.testing.assert_array_equal(out[LOBE], query[LOBE].astype(np.float64) - 20.0)


def test_a_dark_anomaly_at_a_predicted_pixel_is_kept():
    reference = panel_reference()
    query = reference.copy()
    query[SPOT] = (15, 15, 15)
    out = tolerate_specular(query, reference)
    np.testing.assert_array_equal(out[SPOT], query[SPOT])


def test_a_colourless_highlight_where_none_is_predicted_is_kept():
    reference = panel_reference()
    query = brightened(reference, FLAT, 50.0)
    out = tolerate_specular(query, reference)
    np.testing.assert_array_equal(out, query)


def test_the_detector_scores_an_unpredicted_highlight_and_not_a_predicted_one():
    # The raw cross score at the processing resolution (the whole image here).
    reference = panel_reference()
    off = MradParams(process_scale=1.0, grid=4)
    on = off.replace(specular_tolerance=255.0)

    def peak(query, params, where):
        return float(detect(query, reference, params).raw_score[where].max())

    predicted = brightened(reference, LOBE, 60.0)
    assert peak(predicted, off, LOBE) > 50.0
    assert peak(predicted, on, LOBE) == 0.0
    for kept, where in (
        (brightened(reference, FLAT, 60.0), FLAT),  # no highlight predicted there
        (brightened(reference, LOBE, (0.0, 0.0, 80.0)), LOBE),  # coloured
        (brightened(reference, LOBE, -50.0), LOBE),  # dark
    ):
        assert peak(kept, on, where) == peak(kept, off, where) > 10.0


# ---------------------------------------------------------------- glare halo: what it keeps
def glare_scene(amount):
    """A lit panel the camera clipped in a 5 x 5 block, brightened by ``amount`` round it."""
    reference = panel_reference()
    reference[30:35, 40:45] = 200  # lit: the camera clips it
    query = reference.astype(np.float64)
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    distance = np.hypot(rows - 32, cols - 42)
    near = (distance <= 9.0)[..., None]
    query = np.where(near, query + np.asarray(amount, np.float64), query)
    query[30:35, 40:45] = 255
    # Each pixel's distance to the clipped block's nearest pixel.
    block = np.clip(rows, 30, 34), np.clip(cols, 40, 44)
    to_block = np.hypot(rows - block[0], cols - block[1])
    return reference, np.clip(np.rint(query), 0, 255).astype(np.uint8), distance, to_block


def tolerate_glare(query, reference, factor):
    return tolerate_highlights(
        query, query, reference, specular_tolerance=0.0, glare_halo_factor=factor
    ).astype(np.float64)


def test_a_colourless_halo_within_the_size_scaled_radius_is_tolerated():
    reference, query, distance, to_block = glare_scene(40.0)
    # 25 clipped pixels: factor 2 reaches 10 pixels from the block, factor 1 only 5.
    out = tolerate_glare(query, reference, 2.0)
    ring = (distance <= 9.0) & (to_block > 0.0)
    np.testing.assert_array_equal(out[ring], reference[ring])
    short = tolerate_glare(query, reference, 1.0)
    within, beyond = ring & (to_block <= 5.0), ring & (to_block > 5.0)
    assert within.any() and beyond.any()
    np.testing.assert_array_equal(short[within], reference[within])
    np.testing.assert_array_equal(short[beyond], query[beyond])


def test_a_coloured_or_dark_departure_in_the_halo_is_kept():
    for amount in ((0.0, 60.0, 0.0), (-50.0, -50.0, -50.0)):
        reference, query, distance, to_block = glare_scene(amount)
        out = tolerate_glare(query, reference, 2.0)
        ring = (distance <= 9.0) & (to_block > 0.0)
        np.testing.assert_array_equal(out[ring], query[ring])


def test_a_highlight_far_from_any_clipped_region_is_kept():
    reference, query, _, _ = glare_scene(0.0)
    query = brightened(query, FLAT, 50.0)
    out = tolerate_glare(query, reference, 2.0)
    np.testing.assert_array_equal(out[FLAT], query[FLAT])


# ---------------------------------------------------------------- parameters and the cache
def test_off_returns_the_query_itself():
    reference = panel_reference()
    query = brightened(reference, LOBE, 50.0)
    assert (
        tolerate_highlights(query, query, reference, specular_tolerance=0.0, glare_halo_factor=0.0)
        is query
    )


@pytest.mark.parametrize(
    "changes", [{"specular_tolerance": -1.0}, {"specular_tolerance": 256.0}, {"glare_halo": 17.0}]
)
def test_out_of_range_parameters_are_refused(changes):
    with pytest.raises(ParamsError):
        MradParams(**changes)


def test_the_stage_refuses_a_negative_tolerance_or_mismatched_sizes():
    reference = panel_reference()
    with pytest.raises(HighlightsError, match="specular_tolerance"):
        tolerate_highlights(
            reference, reference, reference, specular_tolerance=-1.0, glare_halo_factor=0.0
        )
    with pytest.raises(HighlightsError, match="differ in size"):
        tolerate_highlights(
            reference[:10], reference, reference, specular_tolerance=1.0, glare_halo_factor=0.0
        )


def test_a_reused_reference_gives_the_same_result_from_the_cache():
    reference = panel_reference()[::2, ::2].copy()
    reference.flags.writeable = False
    query = brightened(panel_reference(), LOBE, 50.0)
    cache = ReferenceCache()
    cache.use(reference)
    fresh = tolerate_highlights(
        query, query, reference, specular_tolerance=64.0, glare_halo_factor=0.0
    )
    for _ in range(2):
        cached = tolerate_highlights(
            query, query, reference, specular_tolerance=64.0, glare_halo_factor=0.0, cache=cache
        )
        np.testing.assert_array_equal(cached, fresh)
    assert cache.misses == 2 and cache.hits == 2
