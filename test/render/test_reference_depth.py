"""The reference's depth: off unless asked for, metric z measured from the new camera when a
keyframe is reused, warped with the colour, and close to a fresh render of the new view."""

import math

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render.provider import ReferenceProvider
from allo_mrad_ros.render.reuse import ReferenceReuse, ReuseBounds, ReuseError, warp_depth
from allo_mrad_ros.render.settings import RenderSettings
from allo_mrad_ros.render.warp import apply_homography, depth_in_view, relative_motion
from allo_mrad_ros.view import View

SMALL = CameraIntrinsics(width=320, height=180, fx=300.0, fy=300.0, cx=160.0, cy=90.0)
SUN = np.array([0.3, -0.5, 0.8])
START = look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0])


def moved(pose, degrees=0.0, axis=(0.3, 1.0, 0.2), shift=(0.0, 0.0, 0.0)):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    rotation, _ = cv2.Rodrigues(axis * math.radians(degrees))
    out = pose.copy()
    out[:3, :3] = pose[:3, :3] @ rotation
    out[:3, 3] = pose[:3, 3] + np.asarray(shift, float)
    return out


def test_depth_in_view_is_the_z_of_each_back_projected_point_in_the_other_camera():
    rng = np.random.default_rng(3)
    camera = CameraIntrinsics(width=7, height=5, fx=6.0, fy=5.0, cx=3.2, cy=1.9)
    depth = rng.uniform(1.0, 30.0, (5, 7)).astype(np.float32)
    depth[2, 3] = 0.0  # space stays space
    motion = relative_motion(START, moved(START, 4.0, shift=(0.3, -0.2, 0.5)))
    got = depth_in_view(depth, motion, camera)
    # The slow way: each pixel's point, moved, its z.
    expected = np.zeros_like(depth, dtype=np.float64)
    inverse = np.linalg.inv(camera.matrix)
    for v in range(5):
        for u in range(7):
            if depth[v, u] > 0:
                point = float(depth[v, u]) * (inverse @ [u, v, 1.0])
                expected[v, u] = (motion[:3, :3] @ point + motion[:3, 3])[2]
    np.testing.assert_allclose(got, expected, rtol=1e-5)
    assert got[2, 3] == 0.0


def _plane_renderer(reuse, depth_m=20.0):
    """A render function of a fronto-parallel wall at ``depth_m`` in front of START's
    camera, with a strip of space on the left of the keyframe."""

    def render(view):
        wide = reuse.wide_camera
        rgb = np.full((wide.height, wide.width, 3), 9, np.uint8)
        depth = np.full((wide.height, wide.width), depth_m, np.float32)
        depth[:, :40] = 0.0
        return rgb, depth

    return render


def test_a_reused_keyframe_s_depth_is_measured_from_the_new_camera():
    reuse = ReferenceReuse(SMALL, ReuseBounds(max_error_px=32.0), 1.0)
    render = _plane_renderer(reuse)
    _, first = reuse.reference_with_depth(View(START, SUN), 0.0, render)
    margin = reuse.margin
    assert first[5, 100] == pytest.approx(20.0) and np.all(first[:, : 40 - margin] == 0)
    # One metre towards the wall along the optical axis: a pure scaling about the centre.
    closer = moved(START, shift=START[:3, 2] * 1.0)
    image, depth = reuse.reference_with_depth(View(closer, SUN), 0.05, render)
    assert reuse.last_decision.reuse and reuse.last_decision.homography is not None
    assert not depth.flags.writeable and depth.shape == image.shape[:2]
    wall = depth > 0
    np.testing.assert_allclose(depth[wall], 19.0, rtol=1e-5)
    # The edge of space moved with the image: where the colour's homography puts the
    # keyframe's edge (between its columns 39 and 40).
    homography = reuse.last_decision.homography
    edge = apply_homography(homography, np.array([[39.5, 90.0 + margin]]))[0, 0]
    assert abs(edge - (39.5 - margin)) > 0.5  # it did move
    assert abs(np.argmax(wall[90]) - 0.5 - edge) <= 1.0


def test_the_depth_of_a_still_view_is_the_keyframe_s_own_crop():
    reuse = ReferenceReuse(SMALL, ReuseBounds(), 1.0)
    render = _plane_renderer(reuse, 12.5)
    _, first = reuse.reference_with_depth(View(START, SUN), 0.0, render)
    _, again = reuse.reference_with_depth(View(START.copy(), SUN), 0.1, render)
    np.testing.assert_array_equal(first, again)
    assert first.shape == (SMALL.height, SMALL.width)


def test_warp_depth_needs_the_keyframe_s_depth():
    reuse = ReferenceReuse(SMALL, ReuseBounds(), 1.0)
    render = _plane_renderer(reuse)
    reuse.reference(View(START, SUN), 0.0, render)
    keyframe = reuse._keyframe
    stripped = type(keyframe)(
        keyframe.view, keyframe.time_s, keyframe.wide, keyframe.image, keyframe.inverse_depth
    )
    with pytest.raises(ReuseError, match="without its depth"):
        warp_depth(stripped, None, keyframe.view, SMALL, reuse.margin)


@pytest.fixture(scope="module")
def providers():
    settings = RenderSettings(reference_scale=0.5, shadows=False)
    plain = ReferenceProvider(None, SMALL, settings)
    reusing = ReferenceProvider(
        None, SMALL, RenderSettings(0.5, shadows=False, reuse=ReuseBounds(max_error_px=64.0))
    )
    yield plain, reusing
    plain.close()
    reusing.close()


def test_a_warped_depth_is_close_to_a_fresh_render_s_depth(providers):
    plain, reusing = providers
    first = View(START, SUN)
    reusing.render_with_depth(first, 10.0)
    near = View(moved(START, 0.8, shift=(0.3, 0.2, 0.4)), SUN)
    _, warped = reusing.render_with_depth(near, 10.05)
    assert reusing.reuse.last_decision.reuse
    _, fresh = plain.render_with_depth(near)
    _, stale = plain.render_with_depth(first)
    both = (warped > 0) & (fresh > 0)
    assert both.mean() > 0.05  # the station is in view
    # Away from silhouettes (where a nearest-pixel warp may take the other side's value).
    interior = cv2.erode(both.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    error = np.abs(warped[interior] - fresh[interior]) / fresh[interior]
    assert np.median(error) < 2e-3
    # The stale keyframe's depth is further off: the warp did move and re-measure it.
    stale_both = interior & (stale > 0)
    stale_error = np.abs(stale[stale_both] - fresh[stale_both]) / fresh[stale_both]
    assert np.median(stale_error) > 5 * np.median(error)
    # Where space is in view moved with the image too (the silhouettes are off by the
    # warp's parallax error, far less than the keyframe's own are).
    mismatch = np.mean((warped > 0) != (fresh > 0))
    print(f"space mismatch: warped {mismatch:.4f}, stale {np.mean((stale > 0) != (fresh > 0)):.4f}")
    assert mismatch < 0.5 * np.mean((stale > 0) != (fresh > 0))


def test_the_depth_without_reuse_is_the_renderer_s(providers):
    plain, _ = providers
    rgb, depth = plain.render_with_depth(View(START, SUN))
    camera = plain.reference_camera
    assert rgb.shape == (camera.height, camera.width, 3)
    assert depth.shape == (camera.height, camera.width) and depth.dtype == np.float32
    # The package's station spans some tens of metres, seen from about 33 m away.
    assert 0 < depth[depth > 0].min() < depth.max() < 80.0
    np.testing.assert_array_equal(rgb, plain.render(View(START, SUN)))


def test_a_pipeline_returns_the_reference_depth_only_when_asked():
    config = PipelineConfig(RenderSettings(0.5, shadows=False))
    image = np.zeros((SMALL.height, SMALL.width, 3), np.uint8)
    with Pipeline.open(SMALL, config=config) as pipeline:
        plain = pipeline.process(image, View(START, SUN))
        with_depth = pipeline.process(image, View(START, SUN), depth=True)
    assert plain.reference_depth is None
    assert with_depth.reference_depth.shape == with_depth.reference.shape[:2]
    assert np.any(with_depth.reference_depth > 0)
    np.testing.assert_array_equal(plain.reference, with_depth.reference)
