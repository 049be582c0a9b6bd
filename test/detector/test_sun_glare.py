"""The Sun's glare: the clipped region at the Sun's computed position and its halo are
tolerated; a clipped glint elsewhere, and a coloured or dark object inside the halo, are not.

Oracles: the glare mask against a per-pixel float64 one (a flood fill of the clipped pixels,
brute-force distances); the Sun's pixel against OpenCV's ``projectPoints``.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from mrad_oracle import components_naive

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.highlights import (
    CLIPPED_LEVEL,
    LIT_LEVEL,
    SUN_GLARE_MAX_RADIUS,
    SUN_WHITE_MARGIN,
    HighlightsError,
    sun_glare,
    sun_reach,
    tolerate_highlights,
)
from allo_mrad_ros.detector.params import ParamsError
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.view import View

HEIGHT, WIDTH = 90, 160


def sun_glare_naive(query: np.ndarray, sun: tuple[float, float] | None, factor: float):
    """Every clipped component with a pixel within the reach (Chebyshev, from the pixel
    holding the Sun) and every pixel within factor * sqrt(area) of it, in float64; and the
    pixels whose distance ties with the radius (within 1e-4 pixels), where OpenCV's float32
    distance may round either way."""
    glare = np.zeros(query.shape[:2], bool)
    ties = np.zeros_like(glare)
    if sun is None or factor <= 0:
        return glare, ties
    reach = sun_reach(query.shape[:2])
    column, row = math.floor(sun[0]), math.floor(sun[1])
    brightest = query.astype(np.float64).max(axis=2)
    near = [
        brightest[r, c]
        for r in range(query.shape[0])
        for c in range(query.shape[1])
        if abs(r - row) <= reach and abs(c - column) <= reach
    ]
    if not near:
        return glare, ties
    # The camera's white: 250 where the Sun clips at 255; else the Sun's brightest pixel,
    # if it is the frame's brightest light and lit, less the same margin.
    core = max(near)
    if core >= CLIPPED_LEVEL:
        level = CLIPPED_LEVEL
    elif core >= LIT_LEVEL and core >= brightest.max() - SUN_WHITE_MARGIN:
        level = core - SUN_WHITE_MARGIN
    else:
        return glare, ties
    clipped = brightest >= level
    rows, cols = np.mgrid[0 : query.shape[0], 0 : query.shape[1]].astype(np.float64)
    for pixels in components_naive(clipped):
        if not any(abs(r - row) <= reach and abs(c - column) <= reach for r, c in pixels):
            continue
        radius = min(factor * math.sqrt(len(pixels)), SUN_GLARE_MAX_RADIUS * min(glare.shape))
        nearest = np.full(glare.shape, np.inf)
        for r, c in pixels:
            nearest = np.minimum(nearest, np.hypot(rows - r, cols - c))
        glare |= nearest <= radius
        ties |= np.abs(nearest - radius) < 1e-4
    return glare, ties


def space_with_blobs(seed: int) -> tuple[np.ndarray, list[tuple[float, float]]]:
    """Black space with a few clipped blobs of random sizes; their centres."""
    rng = np.random.default_rng(seed)
    query = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    centres = []
    for _ in range(4):
        x, y = rng.uniform(-5, WIDTH + 5), rng.uniform(-5, HEIGHT + 5)
        radius = rng.uniform(0.5, 4.0)
        cv2.circle(query, (round(x), round(y)), round(radius), (255, 255, 255), -1)
        centres.append((x, y))
    return query, centres


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("factor", [0.0, 1.0, 2.5, 16.0])
def test_the_glare_matches_the_float64_oracle(seed, factor):
    query, centres = space_with_blobs(seed)
    rng = np.random.default_rng(100 + seed)
    suns = [*centres, (rng.uniform(0, WIDTH), rng.uniform(0, HEIGHT)), (-40.0, 10.0), None]
    for sun in suns:
        got = sun_glare(query, sun, factor)
        expected, ties = sun_glare_naive(query, sun, factor)
        np.testing.assert_array_equal(got[~ties], expected[~ties])


@pytest.mark.parametrize("white", [255, 245, 208, 150])
def test_a_camera_whose_white_is_under_the_clipping_level_still_clips_the_sun(white):
    # A tone curve or view transform may map the sensor's white below 250 (a filmic
    # shoulder at 245, an AgX-like curve near 208): the Sun is still the frame's brightest.
    query, centres = space_with_blobs(3)
    scaled = (query.astype(np.float64) * white / 255.0).round().astype(np.uint8)
    sun = centres[0]
    got = sun_glare(scaled, sun, 4.0)
    expected, ties = sun_glare_naive(scaled, sun, 4.0)
    np.testing.assert_array_equal(got[~ties], expected[~ties])
    assert got.any()
    # The glare is the one a camera clipping at 255 gives.
    np.testing.assert_array_equal(got, sun_glare(query, sun, 4.0))


def test_no_glare_where_the_suns_pixel_holds_less_than_the_frames_brightest_light():
    query, centres = space_with_blobs(3)
    dimmed = query.copy()
    x, y = (round(v) for v in centres[0])
    cv2.circle(dimmed, (x, y), 6, (200, 200, 200), -1)  # a module lit at 200 hides the Sun
    cv2.circle(dimmed, (x, y), 2, (240, 240, 240), -1)  # its brightest part
    # Clipped light elsewhere (another blob, at 255) is brighter: the 240 is not the Sun.
    assert dimmed.max() == 255
    assert not sun_glare(dimmed, centres[0], 4.0).any()
    dark = np.zeros_like(query)
    cv2.circle(dark, (x, y), 3, (100, 100, 100), -1)  # the brightest, but not lit enough
    assert not sun_glare(dark, centres[0], 4.0).any()


def test_the_glare_of_a_sun_clipped_with_a_lit_surface_is_bounded():
    query = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    query[30:60, 40:110] = 255  # a clipped module the Sun sits on: one large component
    glare = sun_glare(query, (80.5, 45.5), 16.0)
    rows, cols = np.nonzero(glare)
    reach = math.floor(SUN_GLARE_MAX_RADIUS * HEIGHT)  # whole pixels straight out
    assert rows.min() == 30 - reach and cols.max() == 109 + reach and cols.min() == 40 - reach


def glare_scene():
    """Black space (the reference) and a query with the Sun clipped in a disc of radius 3 at
    (40, 45) with a grey bloom round it, and a clipped glint of the same size at (120, 45)
    with the same bloom."""
    reference = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    query = reference.copy()
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    for x in (40, 120):
        distance = np.hypot(rows - 45, cols - x)
        bloom = np.clip(120.0 - 8.0 * distance, 0, None).astype(np.uint8)
        query = cv2.max(query, cv2.merge((bloom, bloom, bloom)))
        cv2.circle(query, (x, 45), 3, (255, 255, 255), -1)
    return reference, query


def tolerate_sun(query, reference, factor, sun):
    """The highlights stage with the Sun's glare alone."""
    return tolerate_highlights(
        query,
        query,
        reference,
        specular_tolerance=0.0,
        glare_halo_factor=0.0,
        sun_glare_factor=factor,
        sun_pixel=sun,
    )


def test_the_suns_glare_is_tolerated_and_a_glint_elsewhere_is_kept():
    reference, query = glare_scene()
    out = tolerate_sun(query, reference, 4.0, (40.5, 45.5))
    left, right = np.s_[:, :80], np.s_[:, 80:]
    # The Sun's disc and its bloom are what the reference shows: space.
    np.testing.assert_array_equal(out[left], reference[left])
    # The glint, not at the Sun, keeps all of its light.
    np.testing.assert_array_equal(out[right], query[right])
    # Without the Sun's position (or with the rule off) nothing is tolerated.
    for factor, sun in ((4.0, None), (0.0, (40.5, 45.5))):
        kept = tolerate_sun(query, reference, factor, sun)
        assert kept is query


def test_a_coloured_or_dark_object_in_the_suns_glare_keeps_its_departure():
    reference, query = glare_scene()
    reference[40:44, 50:54] = 90  # a lit surface the reference shows in the glare
    query[40:44, 50:54] = 30  # hidden by a dark object
    query[48:52, 50:54] = (40, 200, 40)  # a green object over the bloom
    out = tolerate_sun(query, reference, 4.0, (40.5, 45.5))
    np.testing.assert_array_equal(out[40:44, 50:54], query[40:44, 50:54])
    # The green object loses only its colourless part (the smallest channel's excess).
    green = out[48:52, 50:54].astype(int)
    assert (green[..., 1] - green[..., 0] == 160).all()


def test_the_detector_flags_a_glint_and_not_the_suns_glare():
    reference, query = glare_scene()
    only_sun = query.copy()
    only_sun[:, 80:] = 0
    params = MradParams(grid=4, process_scale=1.0, sun_glare=4.0)
    at_sun = (40.5, 45.5)
    assert not detect(only_sun, reference, params, sun_pixel=at_sun).anomalous
    assert detect(only_sun, reference, params, sun_pixel=None).anomalous
    assert detect(only_sun, reference, params.replace(sun_glare=0.0), sun_pixel=at_sun).anomalous
    # The glint is found whether or not the Sun is in view elsewhere.
    both = detect(query, reference, params, sun_pixel=at_sun)
    assert both.anomalous
    assert all(region.box[0] >= 80 for region in both.regions)


def test_the_sun_position_scales_to_the_processing_resolution():
    reference, query = glare_scene()
    # The full-resolution query, twice the size: the Sun at twice the coordinates.
    large = cv2.resize(query, (2 * WIDTH, 2 * HEIGHT), interpolation=cv2.INTER_NEAREST)
    large[:, 160:] = 0
    params = MradParams(grid=4, process_scale=0.5, sun_glare=4.0)
    assert not detect(large, reference, params, sun_pixel=(81.0, 91.0)).anomalous
    assert detect(large, reference, params, sun_pixel=(40.5, 45.5)).anomalous


def test_out_of_range_or_negative_factors_are_refused():
    with pytest.raises(ParamsError):
        MradParams(sun_glare=-1.0)
    with pytest.raises(ParamsError):
        MradParams(sun_glare=17.0)
    image = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    with pytest.raises(HighlightsError, match="sun_glare"):
        tolerate_highlights(
            image,
            image,
            image,
            specular_tolerance=0.0,
            glare_halo_factor=0.0,
            sun_glare_factor=-1.0,
            sun_pixel=(1.0, 1.0),
        )


# ---------------------------------------------------------------- the Sun's pixel
CAMERA = CameraIntrinsics(width=640, height=360, fx=500.0, fy=480.0, cx=320.5, cy=170.25)


@pytest.mark.parametrize("seed", range(20))
def test_the_suns_pixel_matches_opencvs_projection(seed):
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3) * 20.0
    target = eye + rng.normal(size=3)
    pose = look_at(eye=eye, target=target)
    # A direction near the optical axis, so the Sun is in front of the camera.
    axis = pose[:3, 2]
    direction = axis + 0.4 * rng.normal(size=3)
    view = View(pose, sun_direction=direction)
    got = view.sun_pixel(CAMERA)
    rotation = pose[:3, :3].T
    in_camera = rotation @ direction
    if in_camera[2] <= 0:
        assert got is None
        return
    # A point far along the direction, projected as OpenCV does (no distortion).
    rvec, _ = cv2.Rodrigues(rotation)
    tvec = -rotation @ eye
    point = (eye + 1e6 * direction / np.linalg.norm(direction))[None, :]
    expected, _ = cv2.projectPoints(point, rvec, tvec, CAMERA.matrix, None)
    np.testing.assert_allclose(got, expected.ravel(), rtol=0, atol=1e-3)


def test_a_sun_behind_the_camera_has_no_pixel():
    pose = look_at(eye=[10.0, 0.0, 0.0], target=[0.0, 0.0, 0.0])
    behind = -pose[:3, 2]
    assert View(pose, sun_direction=behind).sun_pixel(CAMERA) is None
    assert View(pose, sun_direction=[0.0, 0.0, 0.0]).sun_pixel(CAMERA) is None
    ahead = View(pose, sun_direction=pose[:3, 2]).sun_pixel(CAMERA)
    assert ahead == pytest.approx((CAMERA.cx, CAMERA.cy))
