"""Range evidence of one region against known geometry: a synthetic depth and the package's
renderer's real depth (a box under OSMesa), and visibility decided from that depth."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from objects_scene import CAMERA, SPACE, project, region_at, scene_params

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.objects import ObjectsError, ObjectTracker, region_rays
from allo_mrad_ros.render import ReferenceRenderer

POSE = look_at([0.0, -10.0, 0.0], [0.0, 0.0, 0.0])


def test_a_region_against_space_gets_the_stated_interval_and_rays_through_its_pixels():
    region = region_at(300.0, 200.0, extent=16)
    rays = region_rays(region, POSE, CAMERA, SPACE, min_range=0.4, max_range=30.0)
    assert (rays.min_range, rays.max_range, rays.over_surface) == (0.4, 30.0, False)
    np.testing.assert_allclose(rays.origin, POSE[:3, 3])
    # Each ray projects back inside the region's box; the centre ray onto its centroid.
    x, y, w, h = region.box
    for direction in rays.directions:
        u, v, _ = project(POSE[:3, 3] + 5.0 * direction, POSE)
        assert x - 4 <= u <= x + w + 4 and y - 4 <= v <= y + h + 4  # a depth pixel is 8 px
    u, v, _ = project(POSE[:3, 3] + 7.0 * rays.centre, POSE)
    assert (u, v) == pytest.approx((300.0, 200.0))
    assert rays.extent_rad == pytest.approx(16 / 500.0)


def test_over_a_wall_the_range_is_below_the_wall_s_range_behind_the_region():
    depth = SPACE.copy()
    depth[20:40, 30:50] = 6.0  # a fronto-parallel panel 6 m away
    region = region_at(320.0, 240.0, extent=40)
    rays = region_rays(region, POSE, CAMERA, depth, surface_quantile=0.0)
    assert rays.over_surface
    # The nearest surface range behind the region: z over the cosine of its pixel's ray.
    x, _, w, _ = region.box
    corner = max(abs(x - CAMERA.cx), abs(x + w - CAMERA.cx)) / CAMERA.fx
    assert 6.0 <= rays.max_range <= 6.0 * np.sqrt(1 + 2 * corner**2)


def test_the_mask_limits_the_region_to_its_own_pixels():
    depth = SPACE.copy()
    depth[:, :40] = 3.0  # the left half of the view is near surface
    region = region_at(320.0, 240.0, extent=80)  # straddles both halves
    mask = np.zeros((CAMERA.height, CAMERA.width), np.uint8)
    mask[200:280, 330:360] = 255  # the object's pixels lie over space
    with_mask = region_rays(region, POSE, CAMERA, depth, mask=mask, max_range=40.0)
    without = region_rays(region, POSE, CAMERA, depth, max_range=40.0)
    assert not with_mask.over_surface and with_mask.max_range == 40.0
    assert without.over_surface and without.max_range < 4.0


def test_malformed_inputs_are_refused():
    region = region_at(300.0, 200.0)
    with pytest.raises(ObjectsError, match="camera pose"):
        region_rays(region, np.eye(4)[:3], CAMERA, SPACE)
    with pytest.raises(ObjectsError, match="aspect"):
        region_rays(region, POSE, CAMERA, np.zeros((10, 80)))
    with pytest.raises(ObjectsError, match="mask"):
        region_rays(region, POSE, CAMERA, SPACE, mask=np.zeros((3, 3)))
    with pytest.raises(ObjectsError, match="min_range"):
        region_rays(region, POSE, CAMERA, SPACE, min_range=5.0, max_range=1.0)


# A small scene rendered by the package's renderer: a 2 m cube 8 m in front of the camera.
SMALL = CameraIntrinsics(width=160, height=120, fx=140.0, fy=140.0, cx=79.5, cy=59.5)
CUBE_CENTRE = np.array([0.0, -1.0, 0.0])  # its front face at y = -2, 8 m from the camera


@pytest.fixture(scope="module")
def cube_depth():
    cube = trimesh.creation.box(extents=(2.0, 2.0, 2.0))
    cube.apply_translation(CUBE_CENTRE)
    with ReferenceRenderer(cube, SMALL, scale=0.5, shadows=False) as renderer:
        result = renderer.render(POSE, (0.3, -1.0, 0.5), depth=True)
    return result.depth


def test_the_renderer_s_depth_bounds_a_region_over_the_cube_at_its_face(cube_depth):
    assert cube_depth.shape == (60, 80)
    region = region_at(79.5, 59.5, extent=10)
    rays = region_rays(region, POSE, SMALL, cube_depth, surface_quantile=0.0)
    assert rays.over_surface
    # The face is 8 m away along the axis; the region's corners see it a little farther.
    assert 8.0 * 0.999 <= rays.max_range <= 8.0 * np.sqrt(1 + 2 * (6 / 140) ** 2) * 1.001
    beside = region_rays(region_at(10.0, 59.5, 6), POSE, SMALL, cube_depth)
    assert not beside.over_surface


def test_visibility_follows_the_renderer_s_depth(cube_depth):
    # Two confirmed objects seen from a sweep in front of the cube, then a frame with the
    # cube's depth and no regions: the one behind the cube is hidden, not missed; the one
    # in front of it is in view and missed.
    params = scene_params(end_misses=1)
    tracker = ObjectTracker(params, SMALL)
    behind = np.array([0.2, 3.0, 0.1])  # 13 m away, behind the cube
    front = np.array([-0.3, -5.0, 0.2])  # 5 m away, before it
    for k in range(40):
        t = k / 10.0
        pose = look_at([-1.0 + 0.05 * k, -10.0, 0.0], [-1.0 + 0.05 * k, 0.0, 0.0])
        regions = [region_at(*project(p, pose, SMALL)[:2], extent=4) for p in (behind, front)]
        objects = tracker.update(regions, pose, np.zeros((60, 80), np.float32), t)
    assert [o.state for o in objects] == ["confirmed", "confirmed"]
    objects = tracker.update([], POSE, cube_depth, 4.0)
    hidden, seen = objects
    assert (hidden.state, hidden.in_view) == ("confirmed", False)
    assert (seen.state, seen.in_view) == ("ended", True)
