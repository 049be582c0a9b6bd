"""Tests of the reference renderer against analytic projections (small images, OSMesa on CPU)."""

from __future__ import annotations

import os
import sys

import cv2
import numpy as np
import pytest
import trimesh

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.geometry import PoseError, look_at, pose_matrix
from allo_mrad_ros.render import (
    LABEL_ANOMALY,
    LABEL_SPACE,
    LABEL_STATION,
    CelestialBody,
    ExtraObject,
    ReferenceRenderer,
    RendererError,
    choose_backend,
)
from allo_mrad_ros.render.backend import import_pyrender
from allo_mrad_ros.render.bodies import frustum_planes, pull_within, sphere_in_view

# Off-centre principal point and unequal focal lengths catch axis and half-pixel mix-ups.
K_SMALL = CameraIntrinsics(width=160, height=120, fx=150.0, fy=140.0, cx=83.2, cy=57.1)
BOX_EXTENTS = np.array([2.0, 1.5, 1.0])
BOX_CENTRE = np.array([0.2, -0.1, 0.05])
EYE = np.array([4.0, -3.0, 2.5])
SUN = (1.0, -1.0, 0.5)


def _box_model() -> trimesh.Trimesh:
    box = trimesh.creation.box(extents=BOX_EXTENTS)
    box.apply_translation(BOX_CENTRE)
    return box


@pytest.fixture(scope="module")
def box_renderer():
    with ReferenceRenderer(_box_model(), K_SMALL, scale=1.0, shadows=False) as renderer:
        yield renderer


@pytest.fixture(scope="module")
def camera_pose() -> np.ndarray:
    return look_at(EYE, BOX_CENTRE + np.array([0.3, 0.2, -0.1]))


def _ray_box_depth(pose: np.ndarray, k: CameraIntrinsics) -> np.ndarray:
    """Analytic z-depth of the box per pixel centre (0 where the ray misses)."""
    u, v = np.meshgrid(np.arange(k.width), np.arange(k.height))
    rays_cam = np.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, np.ones_like(u, float)], -1)
    rays = rays_cam @ pose[:3, :3].T  # z-component 1 in the camera: t is the depth
    lo = BOX_CENTRE - BOX_EXTENTS / 2 - pose[:3, 3]
    hi = BOX_CENTRE + BOX_EXTENTS / 2 - pose[:3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = lo / rays, hi / rays
    t_near = np.minimum(t0, t1).max(axis=-1)
    t_far = np.maximum(t0, t1).min(axis=-1)
    return np.where((t_near <= t_far) & (t_near > 0), t_near, 0.0)


def _ray(pose: np.ndarray, k: CameraIntrinsics, u: float, v: float) -> np.ndarray:
    """Unit station-frame direction of the ray through pixel (u, v)."""
    ray = pose[:3, :3] @ [(u - k.cx) / k.fx, (v - k.cy) / k.fy, 1.0]
    return ray / np.linalg.norm(ray)


def _near_edge(mask: np.ndarray) -> np.ndarray:
    """Pixels within one pixel of the boundary of ``mask``."""
    kernel = np.ones((3, 3), np.uint8)
    m = mask.astype(np.uint8)
    return (cv2.dilate(m, kernel) - cv2.erode(m, kernel)).astype(bool)


def test_silhouette_and_depth_match_analytic_projection(box_renderer, camera_pose):
    result = box_renderer.render(camera_pose, SUN, depth=True, labels=True)
    expected = _ray_box_depth(camera_pose, K_SMALL)
    rendered = result.depth > 0
    hit = expected > 0
    assert hit.sum() > 2000
    # Every disagreement lies on the analytic silhouette's 1-pixel border.
    wrong = rendered != hit
    assert not np.any(wrong & ~_near_edge(hit))
    inner = hit & rendered & ~_near_edge(hit)
    np.testing.assert_allclose(result.depth[inner], expected[inner], rtol=2e-3)
    # The labels pass sees the same silhouette.
    np.testing.assert_array_equal(result.labels == LABEL_STATION, rendered)


def test_corners_match_cv2_project_points(box_renderer, camera_pose):
    result = box_renderer.render(camera_pose, SUN, depth=True)
    corners = trimesh.bounds.corners(_box_model().bounds)
    camera_from_station = np.linalg.inv(camera_pose)
    rvec, _ = cv2.Rodrigues(camera_from_station[:3, :3])
    points, _ = cv2.projectPoints(corners, rvec, camera_from_station[:3, 3], K_SMALL.matrix, None)
    points = points.reshape(-1, 2)
    rows, cols = np.nonzero(result.depth > 0)
    hull = cv2.convexHull(points.astype(np.float32))
    # Signed distance (pixels) of every pixel centre (integer coordinates, as in OpenCV and
    # ROS) to the projected outline: positive inside.
    distance = np.array(
        [
            [cv2.pointPolygonTest(hull, (float(u), float(v)), True) for u in range(K_SMALL.width)]
            for v in range(K_SMALL.height)
        ]
    )
    rendered = result.depth > 0
    assert np.all(rendered[distance > 1.0]) and not np.any(rendered[distance < -1.0])
    moments = cv2.moments(hull)
    centroid = np.array([moments["m10"], moments["m01"]]) / moments["m00"]
    np.testing.assert_allclose([cols.mean(), rows.mean()], centroid, atol=0.25)
    assert abs(len(rows) - moments["m00"]) / moments["m00"] < 0.03


def test_reduced_scale_keeps_aspect_ratio_and_geometry(camera_pose):
    with ReferenceRenderer(_box_model(), ALLO_INTRINSICS, scale=0.1, shadows=False) as r:
        result = r.render(camera_pose, SUN)
        assert result.rgb.shape == (108, 192, 3)
        assert result.intrinsics == ALLO_INTRINSICS.scaled(0.1)
        assert result.rgb.shape[1] / result.rgb.shape[0] == pytest.approx(16 / 9)
        assert result.depth is None and result.labels is None
    with ReferenceRenderer(_box_model(), ALLO_INTRINSICS, scale=0.05, shadows=False) as r:
        assert r.render(camera_pose, SUN).rgb.shape == (54, 96, 3)


def test_repeated_renders_are_identical(box_renderer, camera_pose):
    first = box_renderer.render(camera_pose, SUN, depth=True, labels=True)
    box_renderer.render(look_at([-3.0, 2.0, 1.0], [0, 0, 0]), (0, 0, 1), sun_strength=0.3)
    again = box_renderer.render(camera_pose, SUN, depth=True, labels=True)
    np.testing.assert_array_equal(first.rgb, again.rgb)
    np.testing.assert_array_equal(first.depth, again.depth)
    np.testing.assert_array_equal(first.instances, again.instances)


def test_shader_programs_are_compiled_once(box_renderer, camera_pose):
    # pyrender's own cache misses on every frame under OSMesa; ours must not grow.
    box_renderer.render(camera_pose, SUN, labels=True)
    cache = box_renderer._gl._renderer._program_cache
    size = len(cache._program_cache)
    for _ in range(3):
        box_renderer.render(camera_pose, SUN, labels=True)
    assert len(cache._program_cache) == size


def test_sun_lights_the_faces_towards_it(box_renderer, camera_pose):
    lit = box_renderer.render(camera_pose, SUN).rgb.astype(int)
    dark = box_renderer.render(camera_pose, SUN, sun_strength=0.0).rgb.astype(int)
    assert lit.sum() > dark.sum() * 1.5
    assert box_renderer.render(camera_pose, (-1.0, 1.0, -0.5)).rgb.sum() < lit.sum()


def test_body_behind_camera_is_not_added(box_renderer, camera_pose, monkeypatch):
    built = []
    original = box_renderer._body_mesh
    monkeypatch.setattr(
        box_renderer, "_body_mesh", lambda body: built.append(body.name) or original(body)
    )
    nodes = box_renderer.node_count
    forward = camera_pose[:3, 2]
    behind = CelestialBody("moon", tuple(EYE - 50.0 * forward), 10.0)
    result = box_renderer.render(camera_pose, SUN, bodies=[behind], labels=True)
    assert result.bodies_in_view == ()
    assert built == []
    assert result.instance_names == ("space", "station")
    assert box_renderer.node_count == nodes

    # Towards the top-left corner, clear of the box.
    ahead = CelestialBody("earth", tuple(EYE + 60.0 * _ray(camera_pose, K_SMALL, 20, 15)), 4.0)
    result = box_renderer.render(camera_pose, SUN, bodies=[behind, ahead], labels=True)
    assert result.bodies_in_view == ("earth",)
    assert built == ["earth"]
    assert result.instance_names == ("space", "station", "earth")
    assert np.any(result.instances == 2)
    assert set(np.unique(result.labels)) == {LABEL_SPACE, LABEL_STATION}
    assert box_renderer.node_count == nodes


def test_far_body_keeps_its_apparent_size(box_renderer, camera_pose):
    direction = _ray(camera_pose, K_SMALL, 25.0, 22.0)  # clear of the box
    distance, radius = 3.0e6, 1.0e5  # far beyond the 1e4 m far plane
    body = CelestialBody("sun", tuple(EYE + distance * direction), radius)
    result = box_renderer.render(camera_pose, SUN, bodies=[body], labels=True)
    assert result.bodies_in_view == ("sun",)
    disc = result.instances == 2
    # A pixel sees the sphere iff its ray is within asin(r / d) of the centre direction.
    u, v = np.meshgrid(np.arange(K_SMALL.width), np.arange(K_SMALL.height))
    rays = (
        np.stack(
            [(u - K_SMALL.cx) / K_SMALL.fx, (v - K_SMALL.cy) / K_SMALL.fy, np.ones(u.shape)], -1
        )
        @ camera_pose[:3, :3].T
    )
    rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
    expected = rays @ direction >= np.cos(np.arcsin(radius / distance))
    assert expected.sum() > 60
    assert not np.any((disc != expected) & ~_near_edge(expected))
    assert np.all(result.rgb[disc].min(axis=1) > 200)  # the Sun disc glows


def test_frustum_test_and_pull_within():
    planes = frustum_planes(K_SMALL)
    assert sphere_in_view(np.array([0.0, 0.0, 10.0]), 1.0, planes, 0.05, 1e4)
    assert not sphere_in_view(np.array([0.0, 0.0, -10.0]), 1.0, planes, 0.05, 1e4)
    assert sphere_in_view(np.array([0.0, 0.0, -0.5]), 1.0, planes, 0.05, 1e4)  # around eye
    assert not sphere_in_view(np.array([100.0, 0.0, 10.0]), 1.0, planes, 0.05, 1e4)
    right_edge_x = 10.0 * (K_SMALL.width - 0.5 - K_SMALL.cx) / K_SMALL.fx
    assert sphere_in_view(np.array([right_edge_x + 0.9, 0.0, 10.0]), 1.0, planes, 0.05, 1e4)
    assert not sphere_in_view(np.array([right_edge_x + 1.5, 0.0, 10.0]), 1.0, planes, 0.05, 1e4)
    eye = np.zeros(3)
    near_c, near_r = pull_within(np.array([0.0, 0.0, 500.0]), 20.0, eye, 1e4)
    assert near_r == 20.0 and near_c[2] == 500.0
    c1, r1 = pull_within(np.array([0.0, 0.0, 1.5e11]), 7e8, eye, 1e4)
    c2, r2 = pull_within(np.array([0.0, 0.0, 3.8e8]), 1.7e6, eye, 1e4)
    assert c1[2] + r1 < 1e4 and c2[2] + r2 < c1[2] - r1  # within far, depth order kept
    assert r1 / c1[2] == pytest.approx(7e8 / 1.5e11)


def test_extra_objects_are_labelled_and_removed(box_renderer, camera_pose):
    nodes = box_renderer.node_count
    cube = trimesh.creation.box(extents=[0.4, 0.4, 0.4])
    in_front = pose_matrix(EYE + 2.0 * camera_pose[:3, 2], [0, 0, 0, 1])
    # An open, single-sided sheet seen from behind must still be drawn and labelled.
    sheet = trimesh.Trimesh(
        vertices=[[0, 0, 0], [0.5, 0, 0], [0.5, 0.5, 0], [0, 0.5, 0]], faces=[[0, 1, 2], [0, 2, 3]]
    )
    sheet_pose = camera_pose.copy()
    sheet_pose[:3, 3] = EYE + 2.5 * camera_pose[:3, 2] + 0.5 * camera_pose[:3, 0]
    sheet_pose[:3, :3] = camera_pose[:3, :3] @ np.diag([-1.0, 1.0, -1.0])  # normal away
    extras = [ExtraObject(cube, in_front, name="cube"), (sheet, sheet_pose, 7)]
    result = box_renderer.render(camera_pose, SUN, extra_objects=extras, labels=True, depth=True)
    assert result.instance_names == ("space", "station", "cube", "extra1")
    assert np.count_nonzero(result.labels == LABEL_ANOMALY) > 50
    assert np.count_nonzero(result.labels == 7) > 50
    assert np.all(result.depth[result.instances == 2] < 2.5)
    assert box_renderer.node_count == nodes
    after = box_renderer.render(camera_pose, SUN, labels=True)
    assert not np.any(after.labels >= LABEL_ANOMALY)
    # Back again (re-uploaded after pyrender freed it): the same image.
    again = box_renderer.render(camera_pose, SUN, extra_objects=extras, labels=True, depth=True)
    np.testing.assert_array_equal(again.rgb, result.rgb)
    np.testing.assert_array_equal(again.instances, result.instances)
    # A mesh edited in place is not served stale from the cache.
    cube.apply_translation(0.3 * camera_pose[:3, 0])
    shifted = box_renderer.render(camera_pose, SUN, extra_objects=extras, labels=True)
    assert not np.array_equal(shifted.instances == 2, result.instances == 2)


def test_directional_shadows_fall_on_the_station_only():
    plate = trimesh.creation.box(extents=[6.0, 6.0, 0.1])
    blocker = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    blocker.apply_translation([0.0, 0.0, 2.0])
    model = trimesh.Scene([plate, blocker])
    sun = (0.0, 0.0, 1.0)
    plate_view = look_at([0.5, -4.0, 6.0], [0.0, 0.0, 0.0])
    # A body beside the shadow map's box but within its depth range: with pyrender's default
    # REPEAT wrap it would receive a tiled copy of the plate's shadow.
    earth = CelestialBody("earth", (20.0, 0.0, -20.0), 3.0)
    body_view = look_at([20.0, -15.0, -17.0], [20.0, 0.0, -20.0])
    results = {}
    for shadows in (False, True):
        with ReferenceRenderer(model, K_SMALL, scale=1.0, shadows=shadows) as r:
            results[shadows] = (
                r.render(plate_view, sun, labels=True),
                r.render(body_view, sun, bodies=[earth], labels=True),
            )
    (plain, plain_body), (shaded, shaded_body) = results[False], results[True]
    camera_from_station = np.linalg.inv(plate_view)
    p = camera_from_station[:3, :3] @ [0.0, 0.0, 0.05] + camera_from_station[:3, 3]
    u = round(K_SMALL.fx * p[0] / p[2] + K_SMALL.cx)
    v = round(K_SMALL.fy * p[1] / p[2] + K_SMALL.cy)
    assert shaded.instances[v, u] == 1  # the plate centre, right below the blocker
    assert shaded.rgb[v, u].sum() < 0.6 * plain.rgb[v, u].sum()
    body = shaded_body.instances == 2
    assert body.sum() > 100 and plain_body.rgb[body].max() > 100
    np.testing.assert_array_equal(shaded_body.rgb[body], plain_body.rgb[body])


def test_shadow_map_is_reused_exactly_while_nothing_it_depends_on_changes(monkeypatch):
    pr = import_pyrender(choose_backend())
    passes = []
    original = pr.renderer.Renderer._shadow_mapping_pass

    def counted(self, scene, light_node, flags):
        passes.append(light_node.name)
        return original(self, scene, light_node, flags)

    monkeypatch.setattr(pr.renderer.Renderer, "_shadow_mapping_pass", counted)
    plate = trimesh.creation.box(extents=[6.0, 6.0, 0.1])
    blocker = trimesh.creation.box(extents=[1.0, 1.0, 1.0])
    blocker.apply_translation([0.0, 0.0, 2.0])
    model = trimesh.Scene([plate, blocker])
    near = look_at([0.5, -4.0, 6.0], [0.0, 0.0, 0.0])
    far = look_at([-3.0, -6.0, 7.0], [0.5, 0.0, 0.0])
    # Far outside the shadow camera's box: it must not invalidate the map.
    earth = CelestialBody("earth", (200.0, 50.0, 60.0), 30.0)
    caster = ExtraObject(
        trimesh.creation.box(extents=[0.5, 0.5, 0.5]),
        pose_matrix([1.5, 1.0, 1.0], [0.0, 0.0, 0.0, 1.0]),
    )
    frames = [  # (pose, sun, bodies, extras, shadow pass expected)
        (near, (0.0, 0.0, 1.0), [], [], True),
        (far, (0.0, 0.0, 1.0), [], [], False),
        (far, (0.0, 0.0, 1.0), [earth], [], False),
        (far, (0.3, 0.0, 1.0), [earth], [], True),
        (far, (0.3, 0.0, 1.0), [], [caster], True),
        (near, (0.3, 0.0, 1.0), [], [caster], False),
        (near, (0.3, 0.0, 1.0), [], [], True),
    ]
    with ReferenceRenderer(model, K_SMALL, scale=1.0, shadows=True) as cached:
        for pose, sun, bodies, extras, expect_pass in frames:
            before = len(passes)
            image = cached.render(pose, sun, bodies=bodies, extra_objects=extras).rgb
            assert (len(passes) > before) == expect_pass
            with ReferenceRenderer(model, K_SMALL, scale=1.0, shadows=True) as fresh:
                expected = fresh.render(pose, sun, bodies=bodies, extra_objects=extras).rgb
            np.testing.assert_array_equal(image, expected)


def test_backend_choice(monkeypatch):
    monkeypatch.setenv("ALLO_MRAD_GL_BACKEND", "OSMesa")
    assert choose_backend() == "osmesa"
    assert choose_backend("egl") == "egl"
    monkeypatch.setenv("ALLO_MRAD_GL_BACKEND", "vulkan")
    with pytest.raises(RendererError, match="unsupported"):
        choose_backend()
    monkeypatch.delenv("ALLO_MRAD_GL_BACKEND")
    monkeypatch.delenv("PYOPENGL_PLATFORM", raising=False)
    assert choose_backend() in ("egl", "osmesa")


def test_switching_backend_after_opengl_import_is_refused(box_renderer, monkeypatch):
    assert "OpenGL" in sys.modules  # the fixture's renderer imported it
    other = "egl" if os.environ["PYOPENGL_PLATFORM"] == "osmesa" else "osmesa"
    with pytest.raises(RendererError, match="already imported"):
        import_pyrender(other)


@pytest.mark.parametrize(
    ("model", "message"),
    [
        ("no/such/station.glb", "not found"),
        (trimesh.Trimesh(), "no triangles"),
        (trimesh.Scene(), "no triangles"),
        # What trimesh makes of Draco-compressed glTF geometry it cannot decode.
        (trimesh.Trimesh(np.zeros((3, 3)), [[0, 1, 2]], process=False), "did not decode"),
    ],
)
def test_bad_models_raise(model, message):
    with pytest.raises(InvalidInput, match=message):
        ReferenceRenderer(model, K_SMALL)


def test_unreadable_model_file_raises(tmp_path):
    path = tmp_path / "station.glb"
    path.write_bytes(b"not a gltf file")
    with pytest.raises(InvalidInput, match="cannot load"):
        ReferenceRenderer(path, K_SMALL)


def test_bad_poses_and_parameters_raise(box_renderer, camera_pose):
    bad = camera_pose.copy()
    bad[0, 3] = np.nan
    with pytest.raises(PoseError, match="non-finite"):
        box_renderer.render(bad, SUN)
    with pytest.raises(PoseError, match="zero norm"):
        pose_matrix([0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 0.0])
    with pytest.raises(PoseError, match="rotation"):
        box_renderer.render(np.diag([2.0, 1.0, 1.0, 1.0]), SUN)
    with pytest.raises(InvalidInput, match="sun_direction"):
        box_renderer.render(camera_pose, (0.0, 0.0, 0.0))
    with pytest.raises(InvalidInput, match="sun_strength"):
        box_renderer.render(camera_pose, SUN, sun_strength=-1.0)
    with pytest.raises(InvalidInput, match="pose"):
        box_renderer.render(camera_pose, SUN, extra_objects=[(_box_model(), np.eye(3))])
    with pytest.raises(InvalidInput, match="label"):
        box_renderer.render(camera_pose, SUN, extra_objects=[(_box_model(), np.eye(4), 300)])
    with pytest.raises(InvalidInput, match="radius"):
        CelestialBody("moon", (0.0, 0.0, 100.0), 0.0)


@pytest.mark.parametrize(
    "kwargs",
    [
        {"fx": 0.0},
        {"fy": -10.0},
        {"width": 0},
        {"height": 0},
    ],
)
def test_bad_intrinsics_raise(kwargs):
    values = {"width": 64, "height": 48, "fx": 50.0, "fy": 50.0, "cx": 32.0, "cy": 24.0}
    with pytest.raises(ValueError, match="camera"):
        CameraIntrinsics(**{**values, **kwargs})


@pytest.mark.parametrize("scale", [0.0, -0.25, float("nan"), 5.0])
def test_bad_scale_raises(scale):
    with pytest.raises(InvalidInput, match="scale"):
        ReferenceRenderer(_box_model(), K_SMALL, scale=scale)


def test_committed_station_renders(camera_pose):
    with ReferenceRenderer(None, ALLO_INTRINSICS, scale=0.1, shadows=True) as renderer:
        assert renderer.shadows
        result = renderer.render(look_at([20, -35, 18], [5, 0, 0]), SUN, labels=True)
    assert 0.02 < np.mean(result.labels == LABEL_STATION) < 0.6
    assert result.rgb[result.labels == LABEL_STATION].mean() > 30
    assert result.rgb[result.labels == LABEL_SPACE].max() == 0
