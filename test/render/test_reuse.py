"""Reference reuse: the decision rules, the warp's geometry against OpenCV's projection, and
a warped render against a fresh one."""

import math

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.render.provider import ReferenceProvider
from allo_mrad_ros.render.reuse import (
    Keyframe,
    ReferenceReuse,
    ReuseBounds,
    ReuseError,
    decide,
    keyframe_of,
)
from allo_mrad_ros.render.settings import RenderSettings
from allo_mrad_ros.render.warp import relative_motion, widened
from allo_mrad_ros.view import View

CAMERA = ALLO_INTRINSICS.scaled(0.125)  # the default reference of a 1080p camera
SCALE = CAMERA.width / ALLO_INTRINSICS.width
SUN = np.array([0.3, -0.5, 0.8])
START = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])


def turned(pose, degrees, axis=(0.3, 1.0, 0.2), shift=(0.0, 0.0, 0.0)):
    """``pose`` rotated about a camera-frame ``axis`` and moved by ``shift`` (station)."""
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    rotation, _ = cv2.Rodrigues(axis * math.radians(degrees))
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ rotation
    out[:3, 3] = pose[:3, 3] + np.asarray(shift, float)
    return out


DEFAULT_BOUNDS = ReuseBounds()


def keyframe(view=None, time_s=0.0, depth_m=(10.0, 40.0), space=True, bounds=DEFAULT_BOUNDS):
    margin = bounds.margin(CAMERA)
    wide = widened(CAMERA, margin)
    rgb = np.zeros((wide.height, wide.width, 3), np.uint8)
    depth = np.full((wide.height, wide.width), depth_m[1], np.float32)
    depth[0, 0] = depth_m[0]
    if space:
        depth[-1, -1] = 0.0
    return keyframe_of(view or View(START, SUN), time_s, rgb, depth, margin), margin


def decision(new_view, time_s=0.01, bounds=DEFAULT_BOUNDS, **kwargs):
    frame, margin = keyframe(bounds=bounds, **kwargs)
    return decide(frame, new_view, time_s, bounds, CAMERA, margin, SCALE)


@pytest.mark.parametrize(
    "field, value",
    [
        ("max_error_px", -1.0),
        ("max_error_px", float("nan")),
        ("max_rotation_deg", 21.0),
        ("max_age_s", 0.0),
        ("max_sun_change_deg", 11.0),
        ("max_error_px", True),
        ("max_age_s", "1"),
    ],
)
def test_bounds_refuse_values_outside_their_ranges_and_name_the_field(field, value):
    with pytest.raises(ReuseError, match=field):
        ReuseBounds(**{field: value})


def test_a_view_equal_to_the_keyframe_s_reuses_its_image_unwarped():
    result = decision(View(START.copy(), SUN.copy()))
    assert result.reuse and result.homography is None and result.error_px == 0.0


@pytest.mark.parametrize(
    "change, reason",
    [
        (dict(time_s=-0.5), "clock"),
        (dict(time_s=1.5), "age"),
        (dict(view=View(START, SUN + np.array([0.0, 0.01, 0.0]))), "sun"),
        (dict(view=View(START, SUN, 0.9)), "sun"),
        (
            dict(view=View(START, SUN, 1.0, (CelestialBody("earth", (1e4, 0.0, 0.0), 50.0),))),
            "bodies",
        ),
        (dict(view=View(turned(START, 2.5), SUN)), "rotation"),
        (dict(view=View(turned(START, 0.0, shift=(0.5, 0.0, 0.0)), SUN)), "error"),
        (dict(bounds=ReuseBounds(max_error_px=0.0)), "disabled"),
    ],
)
def test_each_rule_asks_for_a_new_render(change, reason):
    view = change.get("view", View(START, SUN))
    result = decision(view, change.get("time_s", 0.01), change.get("bounds", ReuseBounds()))
    assert not result.reuse and result.reason == reason


def test_no_keyframe_means_a_first_render():
    assert decide(None, View(START, SUN), 0.0, ReuseBounds(), CAMERA, 0, SCALE).reason == "first"


def test_the_error_grows_with_the_translation_and_is_zero_for_a_pure_rotation():
    rotated = decision(View(turned(START, 1.5), SUN))
    assert rotated.reuse and rotated.error_px == pytest.approx(0.0, abs=1e-9)
    small = decision(View(turned(START, 0.0, shift=(0.01, 0.0, 0.0)), SUN))
    larger = decision(View(turned(START, 0.0, shift=(0.02, 0.0, 0.0)), SUN))
    assert 0 < small.error_px < larger.error_px == pytest.approx(2 * small.error_px)


def project(points_station, pose, camera):
    """Pixel coordinates by OpenCV's own projection (an independent oracle)."""
    station_to_camera = np.linalg.inv(pose)
    rvec, _ = cv2.Rodrigues(station_to_camera[:3, :3])
    pixels, _ = cv2.projectPoints(
        points_station, rvec, station_to_camera[:3, 3], camera.matrix, np.zeros(5)
    )
    return pixels.reshape(-1, 2)


def points_at_depths(pose, camera, depths, rng):
    """Station-frame points seen inside ``camera`` from ``pose`` at the given depths."""
    pixels = rng.uniform([0, 0], [camera.width, camera.height], size=(len(depths), 2))
    rays = np.c_[(pixels - [camera.cx, camera.cy]) / [camera.fx, camera.fy], np.ones(len(depths))]
    in_camera = rays * np.asarray(depths)[:, None]
    return in_camera @ pose[:3, :3].T + pose[:3, 3]


def apply(homography, pixels):
    mapped = np.c_[pixels, np.ones(len(pixels))] @ homography.T
    return mapped[:, :2] / mapped[:, 2:3]


@pytest.mark.parametrize(
    "degrees, shift", [(1.5, (0.0, 0.0, 0.0)), (0.5, (0.05, -0.03, 0.02)), (1.0, (0.0, 0.0, 0.1))]
)
def test_the_homography_moves_keyframe_pixels_where_opencv_projects_them(degrees, shift):
    rng = np.random.default_rng(3)
    bounds = ReuseBounds(max_error_px=256.0)
    new_pose = turned(START, degrees, shift=shift)
    near, far = 10.0, 40.0
    frame, margin = keyframe(depth_m=(near, far), space=False, bounds=bounds)
    result = decide(frame, View(new_pose, SUN), 0.01, bounds, CAMERA, margin, SCALE)
    assert result.reuse and result.homography is not None
    wide = widened(CAMERA, margin)
    plane_depth = 2.0 / (1.0 / near + 1.0 / far)
    # On the plane the warp assumes, the map is exact.
    on_plane = points_at_depths(START, CAMERA, np.full(50, plane_depth), rng)
    warped = apply(result.homography, project(on_plane, START, wide))
    np.testing.assert_allclose(warped, project(on_plane, new_pose, CAMERA), atol=1e-6)
    # Off the plane, within the depth range, the error stays within the stated bound.
    anywhere = points_at_depths(START, CAMERA, rng.uniform(near, far, 200), rng)
    error = np.linalg.norm(
        apply(result.homography, project(anywhere, START, wide))
        - project(anywhere, new_pose, CAMERA),
        axis=1,
    )
    assert error.max() <= 1.05 * result.error_px * SCALE + 1e-9
    if any(shift):
        assert error.max() > 0.1 * result.error_px * SCALE  # the bound is not vacuous


def test_the_margin_covers_the_largest_rotation_allowed():
    bounds = ReuseBounds(max_rotation_deg=2.0)
    for axis in ((1, 0, 0), (0, 1, 0), (0, 0, 1), (1, 1, 1)):
        result = decision(View(turned(START, 1.99, axis=axis), SUN), bounds=bounds)
        assert result.reuse, (axis, result)


@pytest.fixture(scope="module")
def providers():
    plain = ReferenceProvider(None, ALLO_INTRINSICS, RenderSettings())
    reusing = ReferenceProvider(
        None, ALLO_INTRINSICS, RenderSettings(reuse=ReuseBounds(max_error_px=64.0))
    )
    yield plain, reusing
    plain.close()
    reusing.close()


def test_a_keyframe_without_its_margin_is_the_plain_render(providers):
    plain, reusing = providers
    view = View(look_at([-25.0, 10.0, 4.0], [0.0, 0.0, 0.0]), SUN)
    expected = plain.render(view).astype(np.int16)
    got = reusing.render(view, 100.0)
    assert reusing.reuse.last_decision.reason == "first" or not reusing.reuse.last_decision.reuse
    assert got.shape == expected.shape and not got.flags.writeable
    # The same rasterisation: a rare pixel on a silhouette may round the other way.
    assert np.mean(np.abs(got - expected) > 2) < 0.002


def test_a_warped_keyframe_is_close_to_a_fresh_render_and_counts_as_reused(providers):
    plain, reusing = providers
    first = View(look_at([-28.0, -10.0, 5.0], [0.0, 0.0, 0.0]), SUN)
    reusing.render(first, 200.0)
    rendered, reused = reusing.reuse.rendered, reusing.reuse.reused
    near = View(turned(first.T_station_camera, 0.8, shift=(0.02, 0.0, 0.0)), SUN)
    warped = reusing.render(near, 200.05).astype(np.int16)
    assert reusing.reuse.last_decision.reuse
    assert (reusing.reuse.rendered, reusing.reuse.reused) == (rendered, reused + 1)
    fresh = plain.render(near).astype(np.int16)
    stale = plain.render(first).astype(np.int16)  # the keyframe, not warped
    differences = np.abs(warped - fresh)
    # Nearest-neighbour resampling moves an edge by up to half a pixel: the warp differs
    # from a fresh render less than a one-pixel shift of it does, and far less than the
    # keyframe left where it was.
    shifted = np.abs(np.roll(fresh, 1, axis=1) - fresh)
    assert differences.mean() < shifted.mean()
    assert differences.mean() < 0.5 * np.abs(stale - fresh).mean()
    assert np.mean(differences.max(axis=2) > 40) < 0.03


def test_a_still_camera_gets_the_same_array_object_until_the_age_bound():
    calls = []

    def render(view):
        calls.append(view)
        margin = reuse.margin
        rgb = np.full((CAMERA.height + 2 * margin, CAMERA.width + 2 * margin, 3), 7, np.uint8)
        return rgb, np.full(rgb.shape[:2], 20.0, np.float32)

    reuse = ReferenceReuse(CAMERA, ReuseBounds(max_age_s=1.0), SCALE)
    view = View(START, SUN)
    first = reuse.reference(view, 0.0, render)
    assert reuse.reference(View(START.copy(), SUN), 0.5, render) is first
    assert len(calls) == 1 and (reuse.rendered, reuse.reused) == (1, 1)
    later = reuse.reference(view, 1.5, render)
    assert later is not first and len(calls) == 2
    assert reuse.last_decision.reason == "age"


def test_relative_motion_maps_points_between_camera_frames():
    rng = np.random.default_rng(0)
    new_pose = turned(START, 3.0, shift=(0.4, -0.2, 0.1))
    points = rng.normal(size=(10, 3)) * 5
    in_start = (points - START[:3, 3]) @ START[:3, :3]
    in_new = (points - new_pose[:3, 3]) @ new_pose[:3, :3]
    motion = relative_motion(START, new_pose)
    np.testing.assert_allclose(in_start @ motion[:3, :3].T + motion[:3, 3], in_new, atol=1e-9)


def test_a_keyframe_s_depth_range_counts_space_as_infinitely_far():
    frame, _ = keyframe(depth_m=(5.0, 50.0), space=True)
    assert isinstance(frame, Keyframe)
    assert frame.inverse_depth == pytest.approx((0.2, 0.0))
    closed, _ = keyframe(depth_m=(5.0, 50.0), space=False)
    assert closed.inverse_depth == pytest.approx((0.2, 0.02))


def test_widened_keeps_the_focal_length_and_shifts_the_principal_point():
    camera = CameraIntrinsics(100, 80, 90.0, 91.0, 49.5, 39.5)
    wide = widened(camera, 5)
    assert (wide.width, wide.height, wide.fx, wide.fy) == (110, 90, 90.0, 91.0)
    assert (wide.cx, wide.cy) == (54.5, 44.5)


def test_a_warp_stands_for_the_next_view_when_it_shows_it_within_a_quarter_pixel():
    calls = []

    def render(view):
        calls.append(view)
        wide = reuse.wide_camera
        rgb = np.random.default_rng(0).integers(0, 255, (wide.height, wide.width, 3), np.uint8)
        return rgb, np.full(rgb.shape[:2], 30.0, np.float32)

    reuse = ReferenceReuse(CAMERA, ReuseBounds(max_error_px=8.0), SCALE)
    reuse.reference(View(START, SUN), 0.0, render)
    first = reuse.reference(View(turned(START, 0.3), SUN), 0.01, render)  # ~0.9 px: warped
    assert not first.flags.writeable
    # 0.01 degree more moves the content by ~0.03 px: the same image stands for it.
    assert reuse.reference(View(turned(START, 0.31), SUN), 0.02, render) is first
    # 0.3 degree more (~0.9 px): warped anew.
    second = reuse.reference(View(turned(START, 0.6), SUN), 0.03, render)
    assert second is not first and len(calls) == 1 and reuse.reused == 3
