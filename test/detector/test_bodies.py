"""The bodies' limbs: within the margin of a disc's outline the query takes the reference's
colour; inside a large body and elsewhere every departure stays.

Oracles: the limb mask against a per-pixel float64 loop; a body's disc against OpenCV's
``projectPoints`` of its centre and of points on its outline.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.bodies import BodiesError, limb_mask, take_reference_at_limbs
from allo_mrad_ros.detector.params import ParamsError
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.view import View

HEIGHT, WIDTH = 60, 100


def limb_naive(shape, discs, margin):
    mask = np.zeros(shape, bool)
    for row in range(shape[0]):
        for col in range(shape[1]):
            for x, y, radius in discs:
                distance = math.hypot(col + 0.5 - x, row + 0.5 - y)
                if margin > 0 and abs(distance - radius) <= margin:
                    mask[row, col] = True
    return mask


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("margin", [0.0, 0.5, 1.0, 3.7])
def test_the_limb_matches_the_float64_oracle(seed, margin):
    rng = np.random.default_rng(seed)
    discs = [
        (rng.uniform(-20, WIDTH + 20), rng.uniform(-20, HEIGHT + 20), rng.uniform(0, 30))
        for _ in range(3)
    ]
    np.testing.assert_array_equal(
        limb_mask((HEIGHT, WIDTH), discs, margin), limb_naive((HEIGHT, WIDTH), discs, margin)
    )


def moon_scene(query_radius):
    """Black space; the reference draws a grey disc of radius 10 at (50, 30), the query one
    of ``query_radius`` (a limb the reference places otherwise)."""
    reference = np.zeros((HEIGHT, WIDTH, 3), np.uint8)
    cv2.circle(reference, (50, 30), 10, (110, 108, 104), -1)
    query = np.zeros_like(reference)
    cv2.circle(query, (50, 30), query_radius, (120, 118, 112), -1)
    return reference, query


def test_the_query_takes_the_reference_on_the_limb_only():
    reference, query = moon_scene(12)
    query[28:33, 48:53] = (20, 200, 20)  # a green object in front of the disc's middle
    out = take_reference_at_limbs(query, reference, [(50.5, 30.5, 10.0)], 2.5)
    limb = limb_naive((HEIGHT, WIDTH), [(50.5, 30.5, 10.0)], 2.5)
    np.testing.assert_array_equal(out[limb], reference[limb])
    np.testing.assert_array_equal(out[~limb], query[~limb])
    assert (out[28:33, 48:53] == (20, 200, 20)).all()
    assert take_reference_at_limbs(query, reference, [], 2.5) is query


@pytest.mark.parametrize(("reference_size", "process_scale"), [(1, 1.0), (2, 1.0), (2, 0.5)])
def test_the_detector_compares_the_query_with_the_reference_on_the_limb(
    reference_size, process_scale
):
    """The margin is in reference pixels and the discs in the query's: detect() gives what
    it gives with the limb's pixels replaced by hand at its processing resolution."""
    reference, query = moon_scene(14)
    query[27:34, 47:54] = (20, 200, 20)  # an object on the disc stays
    size = (WIDTH // reference_size, HEIGHT // reference_size)
    small = cv2.resize(reference, size, interpolation=cv2.INTER_AREA)
    # No colour transfer: it is fitted on the query before the limb is replaced.
    params = MradParams(
        grid=4, process_scale=process_scale, body_margin=1.5, colour_transfer="none"
    )
    disc = (50.5, 30.5, 10.0)
    got = detect(query, small, params, body_discs=[disc])
    work_w, work_h = round(WIDTH * process_scale), round(HEIGHT * process_scale)
    work = cv2.resize(query, (work_w, work_h), interpolation=cv2.INTER_AREA)
    near = cv2.resize(small, (work_w, work_h), interpolation=cv2.INTER_NEAREST)
    scaled = (disc[0] * process_scale, disc[1] * process_scale, disc[2] * process_scale)
    margin = 1.5 * work_w / small.shape[1]
    limb = limb_naive((work_h, work_w), [scaled], margin)
    assert limb.any()
    by_hand = np.where(limb[..., None], near, work)
    plain = params.replace(body_margin=0.0, process_scale=1.0)
    np.testing.assert_array_equal(got.raw_score, detect(by_hand, small, plain).raw_score)
    unchanged = detect(query, small, params.replace(body_margin=0.0), body_discs=[disc])
    assert not np.array_equal(got.raw_score, unchanged.raw_score)


def test_bad_margins_and_discs_are_refused():
    with pytest.raises(ParamsError):
        MradParams(body_margin=-1.0)
    with pytest.raises(BodiesError, match="margin"):
        limb_mask((4, 4), [], -1.0)
    for disc in [(1.0, 2.0), (1.0, float("nan"), 3.0), (1.0, 2.0, -1.0)]:
        with pytest.raises(BodiesError, match="disc"):
            limb_mask((4, 4), [disc], 1.0)


# ---------------------------------------------------------------- the bodies' discs
CAMERA = CameraIntrinsics(width=640, height=360, fx=500.0, fy=500.0, cx=320.0, cy=180.0)


@pytest.mark.parametrize("seed", range(10))
def test_a_bodys_disc_matches_opencvs_projection(seed):
    rng = np.random.default_rng(seed)
    eye = rng.normal(size=3) * 30.0
    pose = look_at(eye=eye, target=eye + rng.normal(size=3))
    forward = pose[:3, 2]
    distance = rng.uniform(2e3, 4e5)
    centre = eye + distance * (forward + 0.05 * rng.normal(size=3))
    radius = distance * rng.uniform(0.005, 0.03)
    view = View(pose, [0.0, 0.0, 1.0], bodies=(CelestialBody("moon", tuple(centre), radius),))
    ((x, y, r),) = view.body_discs(CAMERA)
    rotation = pose[:3, :3].T
    rvec, _ = cv2.Rodrigues(rotation)
    tvec = -rotation @ eye
    projected, _ = cv2.projectPoints(centre[None, :], rvec, tvec, CAMERA.matrix, None)
    np.testing.assert_allclose((x, y), projected.ravel(), atol=1e-6 * max(1.0, abs(x)))
    # The outline: the tangent points' projections lie about r from the centre's (exactly
    # on the optical axis; off it the outline stretches by a few per cent at most here).
    offset = centre - eye
    side = np.cross(offset, pose[:3, 1])
    side /= np.linalg.norm(side)
    half = math.asin(radius / np.linalg.norm(offset))
    tangent = eye + math.cos(half) * (
        math.cos(half) * offset + math.sin(half) * np.linalg.norm(offset) * side
    )
    edge, _ = cv2.projectPoints(tangent[None, :], rvec, tvec, CAMERA.matrix, None)
    assert np.linalg.norm(edge.ravel() - projected.ravel()) == pytest.approx(r, rel=0.05)


def test_the_sun_and_a_body_behind_the_camera_have_no_disc():
    pose = look_at(eye=[0.0, 0.0, 0.0], target=[1.0, 0.0, 0.0])
    bodies = (
        CelestialBody("sun", (1e6, 0.0, 0.0), 5e3),
        CelestialBody("moon", (-1e5, 0.0, 0.0), 1e3),
        CelestialBody("earth", (1e5, 0.0, 0.0), 2e3),
    )
    discs = View(pose, [1.0, 0.0, 0.0], bodies=bodies).body_discs(CAMERA)
    assert len(discs) == 1
    x, y, r = discs[0]
    assert (x, y) == pytest.approx((CAMERA.cx, CAMERA.cy))
    assert r == pytest.approx(CAMERA.fx * math.tan(math.asin(2e3 / 1e5)))
