"""The path-traced query (Blender Cycles): settings, and against the rasteriser where bpy is.

Tests marked ``needs_bpy`` run only where the optional extra is installed
(``make bench-cycles``); ``make test`` on a clean clone skips them.
"""

from __future__ import annotations

import csv
import importlib.util
import math
import sys

import cv2
import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import LABEL_ANOMALY, ExtraObject, ReferenceRenderer
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.sequence import validate_sequence
from allo_mrad_ros.synth.cli import build_parser, main
from allo_mrad_ros.synth.config import SynthError, preset
from allo_mrad_ros.synth.cycles import CyclesError, import_bpy
from allo_mrad_ros.synth.cycles_scene import blender_camera
from allo_mrad_ros.synth.generator import generate
from allo_mrad_ros.synth.objects import build_anomaly
from allo_mrad_ros.synth.realism_config import RealismConfig
from allo_mrad_ros.synth.surfaces import worn_object
from harness.silhouettes import silhouette_iou

needs_bpy = pytest.mark.skipif(
    importlib.util.find_spec("bpy") is None, reason="optional bpy not installed"
)
MESH = share_path("meshes", "station.glb")
# Off-centre principal point, so a wrong lens shift shows.
INTRINSICS = CameraIntrinsics(320, 180, fx=250.0, fy=250.0, cx=141.3, cy=101.7)
T_VIEW = look_at([24.0, -18.0, 9.0], [0.0, 0.0, 0.0])
SUN = np.array([0.3, -0.5, 0.8])
REALISM = RealismConfig()


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.count_nonzero(a & b) / max(np.count_nonzero(a | b), 1))


# ---------------------------------------------------------------------- without bpy
def test_settings_and_cli_flags_are_validated():
    config = preset("smoke")
    assert (config.query_renderer, config.camera_effects) == ("pyrender", True)
    for bad in ({"query_renderer": "povray"}, {"camera_effects": 1}, {"cycles_samples": 0}):
        with pytest.raises(SynthError):
            config.with_overrides(**bad)
    cycles = preset("bench-cycles")
    assert cycles.query_renderer == "cycles" and not cycles.camera_effects
    test = cycles.splits["test"]
    assert test.frames >= 40 and test.anomalous == 2 * test.normal
    args = build_parser().parse_args(
        ["generate", "--query-renderer", "cycles", "--no-camera-effects", "--cycles-samples", "8"]
    )
    assert (args.query_renderer, args.camera_effects, args.cycles_samples) == ("cycles", False, 8)
    with pytest.raises(SystemExit):
        build_parser().parse_args(["generate", "--query-renderer", "povray"])


def test_centred_principal_point_needs_no_lens_shift():
    k = CameraIntrinsics(640, 360, fx=444.0, fy=444.0, cx=319.5, cy=179.5)
    camera = blender_camera(k)
    assert camera.shift_x == camera.shift_y == 0.0
    # The horizontal field of view is kept: tan(fov/2) = (w/2) / fx.
    assert math.isclose(camera.sensor_width_mm / 2 / camera.lens_mm, 320.0 / 444.0)


def test_missing_bpy_names_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "bpy", None)
    with pytest.raises(CyclesError, match="make bench-cycles"):
        import_bpy()
    out = tmp_path / "seq"
    argv = ["generate", "--preset", "smoke", "--frames", "2", "--out", str(out), "--quiet"]
    assert main([*argv, "--query-renderer", "cycles"]) == 1
    assert "bpy" in capsys.readouterr().err and not out.exists()


def test_camera_effects_off_keeps_every_draw_of_the_frame(tmp_path):
    config = preset("smoke").with_frames(3).with_overrides(references=False)
    on, off = tmp_path / "on", tmp_path / "off"
    generate(config, on, 5, progress=False)
    generate(config.with_overrides(camera_effects=False), off, 5, progress=False)
    rows_on, rows_off = (list(csv.DictReader((p / "frames.csv").open())) for p in (on, off))
    for a, b in zip(rows_on, rows_off, strict=True):
        for key in ("tx", "qw", "true_tx", "true_qw", "obj_tx", "query_sun_strength"):
            assert a.get(key) == b.get(key), key
        assert "exposure" in a and "exposure" not in b
        assert (on / a["mask"]).read_bytes() == (off / b["mask"]).read_bytes()
        image_on, image_off = (cv2.imread(str(p / r["image"])) for p, r in ((on, a), (off, b)))
        assert np.abs(image_on.astype(int) - image_off).mean() > 0.5


# ---------------------------------------------------------------------- with bpy
@pytest.fixture(scope="module")
def cycles():
    from allo_mrad_ros.synth.cycles import CyclesRenderer

    with CyclesRenderer(MESH, INTRINSICS, samples=8) as renderer:
        yield renderer


@pytest.fixture(scope="module")
def rasteriser():
    with ReferenceRenderer(MESH, INTRINSICS, scale=1.0, shadows=False) as renderer:
        yield renderer


@needs_bpy
def test_blender_camera_projects_as_opencv(cycles):
    rng = np.random.default_rng(0)
    k = INTRINSICS
    pixels = rng.uniform([0, 0], [k.width - 1, k.height - 1], (40, 2))
    depth = rng.uniform(2.0, 60.0, 40)
    rays = np.column_stack([(pixels[:, 0] - k.cx) / k.fx, (pixels[:, 1] - k.cy) / k.fy])
    optical = np.column_stack([rays * depth[:, None], depth])
    points = optical @ T_VIEW[:3, :3].T + T_VIEW[:3, 3]
    rvec, _ = cv2.Rodrigues(T_VIEW[:3, :3].T)
    tvec = -T_VIEW[:3, :3].T @ T_VIEW[:3, 3]
    expected, _ = cv2.projectPoints(points, rvec, tvec, k.matrix, None)
    got = cycles.project(T_VIEW, points)
    np.testing.assert_allclose(got, expected.reshape(-1, 2), atol=1e-3)


@needs_bpy
@pytest.mark.parametrize("kind", ["cubesat_3u", "drill", "blanket_crumpled"])
def test_silhouettes_match_the_rasterised_labels(cycles, rasteriser, kind):
    # The station and the station-frame conversion of the glTF import first.
    station = rasteriser.render(T_VIEW, SUN, labels=True).labels > 0
    assert np.count_nonzero(station) > 2000
    assert _iou(cycles.silhouette(T_VIEW, station=True), station) > 0.97
    obj = build_anomaly(kind, 7)
    pose = np.eye(4)
    pose[:3, 3] = T_VIEW[:3, :3] @ [0.4, 0.2, 4.0] + T_VIEW[:3, 3]
    extra = ExtraObject(obj.scene, pose)
    labels = rasteriser.render(T_VIEW, SUN, extra_objects=[extra], labels=True).labels
    anomaly = labels == LABEL_ANOMALY
    assert np.count_nonzero(anomaly) > 100
    assert _iou(cycles.silhouette(T_VIEW, [extra]), anomaly) > 0.9


@needs_bpy
def test_each_frame_draws_its_own_objects_colours(cycles, rasteriser):
    # Objects come and go every frame; each must be drawn with its own material, not with
    # one a Cycles cache kept from an earlier frame (it did with persistent data on).
    pose = np.eye(4)
    pose[:3, 3] = T_VIEW[:3, :3] @ [0.0, 0.0, 3.0] + T_VIEW[:3, 3]
    drawn = [("cubesat_6u", "default"), ("cable", "red"), ("cable", "green")]
    drawn += [("tether_hook", "orange"), ("wrench", "blue"), ("drill", "yellow")]
    for i, (kind, colour) in enumerate(drawn):
        worn = worn_object(build_anomaly(kind, 3, colour).scene, np.random.default_rng(i), REALISM)
        extra = ExtraObject(worn, pose)
        rasterised = rasteriser.render(T_VIEW, SUN, extra_objects=[extra], labels=True)
        where = rasterised.labels == LABEL_ANOMALY
        expected = rasterised.rgb[where].mean(axis=0)
        got = cycles.render(T_VIEW, SUN, extra_objects=[extra])[where].mean(axis=0)
        tint, traced_tint = expected - expected.mean(), got - got.mean()
        cosine = tint @ traced_tint / max(np.linalg.norm(tint) * np.linalg.norm(traced_tint), 1e-9)
        assert cosine > 0.7, (kind, colour, expected.round(), got.round())


@needs_bpy
def test_light_levels_match_the_rasteriser_under_a_plain_curve():
    from allo_mrad_ros.synth.cycles import CyclesRenderer

    plate = trimesh.creation.box(extents=[3.0, 3.0, 0.02])
    plate.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(baseColorFactor=[0.6, 0.6, 0.6, 1.0], metallicFactor=0.0)
    )
    k = CameraIntrinsics(96, 64, fx=90.0, fy=90.0, cx=47.5, cy=31.5)
    T = look_at([0.0, 0.0, 4.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
    centre = np.s_[24:40, 40:56]

    def linear(image: np.ndarray, gamma: float) -> float:
        return float((image[centre].mean() / 255.0) ** gamma)

    # Sun only, then the arm lamp only (4 m away), then the ambient level only.
    cases = [({"spot_intensity": 0.0, "ambient": 0.0}, 1.0)]
    cases += [({"ambient": 0.0}, 0.0), ({"spot_intensity": 0.0, "ambient": 0.3}, 0.0)]
    for lamps, sun_strength in cases:
        rasterised = ReferenceRenderer(plate, k, scale=1.0, shadows=False, **lamps)
        expected = linear(rasterised.render(T, [0, 0, 1], sun_strength).rgb, 2.2)
        rasterised.close()
        plain = CyclesRenderer(plate, k, samples=8, view_transform="Standard", **lamps)
        # sRGB's curve is within a few per cent of gamma 2.2 at these levels.
        got = linear(plain.render(T, [0, 0, 1], sun_strength), 2.2)
        assert got == pytest.approx(expected, rel=0.12), lamps
    # Blender's default view transform (AgX) is a different curve: the point of the bench.
    agx = CyclesRenderer(plate, k, samples=8, spot_intensity=0.0, ambient=0.0)
    assert agx.scene.view_settings.view_transform == "AgX"
    bright = agx.render(T, [0, 0, 1], 1.0)[centre].mean()
    assert abs(linear(np.full((64, 96), bright), 2.2) - expected) > 0.03


@needs_bpy
def test_generated_cycles_queries_keep_the_rasterised_frame(tmp_path):
    config = preset("smoke").with_frames(3).with_overrides(camera_effects=False, cycles_samples=4)
    twin, traced = tmp_path / "twin", tmp_path / "traced"
    generate(config, twin, 5, progress=False)
    generate(config.with_overrides(query_renderer="cycles"), traced, 5, progress=False)
    validate_sequence(traced, decode_images=True)
    rows_twin, rows = (list(csv.DictReader((p / "frames.csv").open())) for p in (twin, traced))
    for a, b in zip(rows_twin, rows, strict=True):
        assert b["query_renderer"] == "cycles"
        for key in ("tx", "qw", "true_tx", "true_qw", "obj_tx"):
            assert a.get(key) == b.get(key), key
        assert (twin / a["mask"]).read_bytes() == (traced / b["mask"]).read_bytes()
        image = cv2.imread(str(traced / b["image"]))
        assert np.abs(image.astype(int) - cv2.imread(str(twin / a["image"]))).mean() > 0.5
    # The rasterised mask is where Cycles drew the object.
    checked = silhouette_iou(traced, frames=4)
    assert checked and all(row["iou"] > 0.85 for row in checked), checked
