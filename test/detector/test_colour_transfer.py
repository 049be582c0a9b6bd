"""The colour-transfer stage: a float64 per-pixel oracle, parameters, and the colour gap.

The colour-gap cases are those a path tracer's query shows against a rasterised reference:
a hue shift of one material, filmic and AgX-like view transforms, black shadows where the
reference is ambient-lit, and glare washing part of a panel to white. On a normal frame at
most 0.5 % of pixels may be flagged; a patch 40 DN from its background must still be found.
"""

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect, profile
from allo_mrad_ros.detector.colour_transfer import (
    ColourTransferError,
    apply_to_query,
    apply_to_reference,
    fit_colour_transfer,
)
from allo_mrad_ros.detector.pipeline import transfer_colours
from harness.perturbations import agx_like, filmic

WIDTHS = (256, 64, 32, 16, 8, 4)
EDGE_LEVELS = 48.0
SPACE_LEVEL = 8.0


# ---------------------------------------------------------------- oracle
def oracle_fit(query, reference, finest, min_count, margin):
    """Per-pixel, float64: the table of medians of query - reference per nested bin."""
    q = query.astype(np.float64)
    r = reference.astype(np.float64)
    height, width = r.shape[:2]
    half = 1 + margin
    keep = []
    for y in range(height):
        for x in range(width):
            window = r[max(0, y - half) : y + half + 1, max(0, x - half) : x + half + 1]
            spread = (window.max(axis=(0, 1)) - window.min(axis=(0, 1))).max()
            if spread <= EDGE_LEVELS:
                keep.append((y, x))
    if not keep:
        keep = [(y, x) for y in range(height) for x in range(width)]
    pairs = [(r[y, x], q[y, x] - r[y, x]) for y, x in keep]
    n_fine = 256 // finest
    lut = np.zeros((n_fine, n_fine, n_fine, 3))
    for level_width in WIDTHS[: WIDTHS.index(finest) + 1]:
        groups = {}
        for colour, offset in pairs:
            key = tuple(int(c) // level_width for c in colour)
            groups.setdefault(key, []).append(offset)
        needed = 1 if level_width == 256 else min_count
        for i in range(n_fine):
            for j in range(n_fine):
                for k in range(n_fine):
                    key = (
                        i * finest // level_width,
                        j * finest // level_width,
                        k * finest // level_width,
                    )
                    members = groups.get(key, [])
                    if len(members) >= needed:
                        lut[i, j, k] = np.median(np.array(members), axis=0)
    return lut


def oracle_query(query, reference, lut, finest, glare_level=256.0):
    """r + (q - r - lut[bin(r)]); glare (clipped, or brighter within 2 px of clipped) -> r."""
    out = np.empty(query.shape, np.float64)
    for y in range(query.shape[0]):
        for x in range(query.shape[1]):
            colour = reference[y, x].astype(np.float64)
            value = query[y, x].astype(np.float64)
            i, j, k = (int(c) // finest for c in colour)
            departure = value - colour - lut[i, j, k]
            window = query[max(0, y - 2) : y + 3, max(0, x - 2) : x + 3].astype(np.float64)
            clipped = value.min() >= glare_level
            near = window.min(axis=2).max() >= glare_level
            glare = clipped or (near and (departure >= 0).all())
            out[y, x] = colour if glare and colour.max() > SPACE_LEVEL else colour + departure
    return np.clip(np.rint(out), 0, 255)


def random_pair(seed, shape=(24, 32)):
    rng = np.random.default_rng(seed)
    # Blocks of a few materials (so there are edge-free interiors), mapped non-linearly.
    blocks = rng.integers(0, 256, (shape[0] // 6, shape[1] // 8, 3))
    reference = cv2.resize(blocks.astype(np.uint8), shape[::-1], interpolation=cv2.INTER_NEAREST)
    reference = np.clip(reference.astype(int) + rng.integers(-6, 7, reference.shape), 0, 255)
    reference = reference.astype(np.uint8)
    query = np.clip(255 * (reference / 255.0) ** 0.7 + rng.normal(0, 3, reference.shape), 0, 255)
    query[2:6, 3:9] = rng.integers(0, 256, 3)  # an object
    return query.astype(np.uint8), reference


@pytest.mark.parametrize(
    ("seed", "finest", "min_count", "margin"),
    [(0, 16, 16, 0), (1, 8, 4, 0), (2, 32, 1, 1), (3, 64, 8, 0), (4, 4, 2, 2)],
)
def test_fit_and_query_mapping_match_the_float64_oracle(seed, finest, min_count, margin):
    query, reference = random_pair(seed)
    transfer = fit_colour_transfer(query, reference, finest, min_count, margin)
    expected = oracle_fit(query, reference, finest, min_count, margin)
    np.testing.assert_allclose(transfer.lut, expected, atol=1e-4)
    mapped = apply_to_query(query, reference, transfer)
    np.testing.assert_array_equal(mapped, oracle_query(query, reference, expected, finest))


def test_glare_takes_the_reference_colour_over_station_only():
    query, reference = random_pair(5)
    reference[:, :4] = 0  # space
    query[:8] = 255  # washed out, over station and over space
    transfer = fit_colour_transfer(query, reference, 16, 16, 0)
    mapped = apply_to_query(query, reference, transfer, glare_level=250.0)
    expected = oracle_query(query, reference, transfer.lut.astype(np.float64), 16, 250.0)
    np.testing.assert_array_equal(mapped, expected)
    assert (mapped[:8, :4] == np.clip(255 - transfer.lut[0, 0, 0], 0, 255)).all()


def test_reference_mapping_adds_each_colour_offset():
    query, reference = random_pair(6)
    transfer = fit_colour_transfer(query, reference, 16, 16, 0)
    lut = transfer.lut
    bins = reference.astype(int) // 16
    expected = reference + lut[bins[..., 0], bins[..., 1], bins[..., 2]]
    np.testing.assert_array_equal(
        apply_to_reference(reference, transfer), np.clip(np.rint(expected), 0, 255)
    )


def test_a_lower_resolution_reference_is_paired_with_the_area_averaged_query():
    query, reference = random_pair(7, (48, 64))
    small = cv2.resize(reference, (32, 24), interpolation=cv2.INTER_AREA)
    averaged = cv2.resize(query, (32, 24), interpolation=cv2.INTER_AREA)
    direct = fit_colour_transfer(averaged, small)
    paired = fit_colour_transfer(query, small)
    np.testing.assert_array_equal(paired.lut, direct.lut)
    assert apply_to_query(query, small, paired).shape == query.shape


def test_float_and_uint16_inputs_use_the_8bit_scale():
    query, reference = random_pair(8)
    as_uint8 = fit_colour_transfer(query, reference)
    as_float = fit_colour_transfer(query / 255.0, reference.astype(np.float32) / 255.0)
    as_uint16 = fit_colour_transfer(query.astype(np.uint16) * 257, reference)
    np.testing.assert_allclose(as_float.lut, as_uint8.lut, atol=1e-3)
    np.testing.assert_allclose(as_uint16.lut, as_uint8.lut, atol=1e-3)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"finest_bin": 12}, "transfer_bin"),
        ({"min_count": 0}, "transfer_min_count"),
        ({"edge_margin": 17}, "transfer_edge_margin"),
        ({"edge_margin": 1.5}, "transfer_edge_margin"),
    ],
)
def test_invalid_parameters_are_refused_by_name(kwargs, message):
    query, reference = random_pair(9)
    with pytest.raises(ColourTransferError, match=message):
        fit_colour_transfer(query, reference, **kwargs)


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("colour_transfer", "both"),
        ("transfer_bin", 12),
        ("transfer_min_count", 0),
        ("transfer_edge_margin", -1),
        ("glare_level", 100.0),
        ("glare_level", float("nan")),
    ],
)
def test_mrad_params_validate_the_transfer_fields(field, value):
    with pytest.raises(ValueError, match=field):
        MradParams(**{field: value})


def test_identical_images_are_left_unchanged():
    _, reference = random_pair(10)
    params = profile("default", colour_transfer="query")
    query, same = transfer_colours(reference, reference, params)
    np.testing.assert_array_equal(query, reference)
    assert same is reference


# ---------------------------------------------------------------- the colour gap
HEIGHT, WIDTH = 540, 960
PATCH = (slice(250, 280), slice(700, 730))
SPACE = (slice(None), slice(0, 240))
BLUE = (slice(0, 270), slice(240, 600))
GOLD = (slice(270, 540), slice(240, 420))
SHADOW = (slice(270, 540), slice(420, 600))
GREY = (slice(0, 540), slice(600, 960))
GLARE = (slice(0, 108), slice(600, 960))  # 20 % of the grey panel


def reference_scene() -> np.ndarray:
    """Space, a blue solar panel, gold MLI, an ambient-lit shadow and a shaded grey panel."""
    image = np.zeros((HEIGHT, WIDTH, 3))
    image[SPACE] = (3, 3, 5)
    image[BLUE] = (25, 45, 150)
    image[GOLD] = (185, 140, 45)
    image[SHADOW] = (42, 42, 44)
    image[GREY] = (110, 110, 114)
    image[GREY] *= np.linspace(0.95, 1.05, WIDTH - 600)[None, :, None]
    return image


def hue_shift(image: np.ndarray, region, degrees: float = 15.0, lift: float = 1.15) -> np.ndarray:
    """One material's hue rotated (towards cyan for blue) and lightened."""
    out = image.copy()
    hsv = cv2.cvtColor(out[region].copy(), cv2.COLOR_RGB2HSV)
    hsv[..., 0] = (hsv[..., 0].astype(int) - round(degrees / 2)) % 180
    hsv[..., 2] = np.clip(hsv[..., 2] * lift, 0, 255)
    out[region] = cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    return out


def black_shadow(image: np.ndarray) -> np.ndarray:
    out = image.copy()
    out[SHADOW] = (2, 2, 3)
    return out


def glare(image: np.ndarray) -> np.ndarray:
    out = image.astype(np.float64)
    rows = np.arange(HEIGHT)[:, None, None]
    weight = np.clip((GLARE[0].stop + 2 - rows) / 4.0, 0.0, 1.0)  # a 4-row soft edge
    washed = out + weight * (253.0 - out)
    out[GREY] = washed[GREY]
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


COLOUR_GAP = {
    "hue 15 deg on one material": lambda im: hue_shift(im, BLUE),
    "filmic": filmic,
    "AgX-like": agx_like,
    "black shadows": black_shadow,
    "glare on 20 % of a panel": glare,
}


def with_patch(image: np.ndarray) -> np.ndarray:
    """The camera image with an object 40 DN brighter than what is behind it."""
    out = image.astype(np.float64)
    out[PATCH] += 40.0
    return np.clip(out, 0, 255).astype(np.uint8)


@pytest.fixture(scope="module")
def scenes():
    scene = reference_scene()
    reference = np.clip(np.rint(scene), 0, 255).astype(np.uint8)
    noisy = scene + np.random.default_rng(0).normal(0, 2, scene.shape)
    clean = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
    small = cv2.resize(reference, (WIDTH // 4, HEIGHT // 4), interpolation=cv2.INTER_AREA)
    return small, clean


@pytest.mark.parametrize("name", sorted(COLOUR_GAP))
def test_colour_gap_does_not_flag_a_normal_frame_and_a_40_dn_patch_is_found(scenes, name):
    reference, clean = scenes
    perturbed = COLOUR_GAP[name](clean)
    normal = detect(perturbed, reference)
    assert normal.area <= 0.005 * normal.mask.size and not normal.anomalous, normal.area
    found = detect(with_patch(perturbed), reference)
    truth = np.zeros(found.mask.shape, bool)
    truth[PATCH] = True
    assert found.anomalous
    assert np.count_nonzero(found.mask[truth]) >= 0.8 * truth.sum()
    assert np.count_nonzero(found.mask[~truth]) <= 0.005 * truth.size


def test_without_the_transfer_the_hue_shift_and_shadows_rank_above_the_patch(scenes):
    # What the stage is for: the ranking map without it puts the colour gap above an object.
    reference, clean = scenes
    perturbed = with_patch(black_shadow(hue_shift(clean, BLUE)))
    truth = np.zeros(clean.shape[:2], bool)
    truth[PATCH] = True
    with_transfer = detect(perturbed, reference).score
    without = detect(perturbed, reference, profile("default", colour_transfer="none")).score
    assert np.quantile(without[~truth], 0.99) > np.median(without[truth]) or (
        without[~truth].max() > without[truth].max()
    )
    assert np.quantile(with_transfer[~truth], 0.99) < np.median(with_transfer[truth])
