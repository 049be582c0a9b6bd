"""Tests of the ALLO-like generator (`allo-synth generate`) on the small `smoke` preset."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.ephemeris import StationEphemeris
from allo_mrad_ros.geometry import look_at, pose_matrix
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer
from allo_mrad_ros.sequence import read_sequence, validate_sequence
from allo_mrad_ros.synth import placement
from allo_mrad_ros.synth.cli import build_parser, main
from allo_mrad_ros.synth.config import (
    PRESETS,
    RealismConfig,
    SplitSpec,
    SynthConfig,
    SynthError,
    preset,
)
from allo_mrad_ros.synth.generator import GENERATION_FILE, generate
from allo_mrad_ros.synth.objects import (
    ANOMALY_TYPES,
    SHEET_TYPES,
    ObjectError,
    build_anomaly,
)
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.planning import plan_frames
from allo_mrad_ros.synth.poses import make_base_poses, perturb, pose_error
from allo_mrad_ros.synth.realism import apply_camera

SEED = 3
POSE = ("tx", "ty", "tz")
QUAT = ("qx", "qy", "qz", "qw")


def _hashes(root: Path) -> dict[str, str]:
    return {
        str(path.relative_to(root)): hashlib.sha256(path.read_bytes()).hexdigest()
        for path in sorted(root.rglob("*"))
        if path.is_file()
    }


def _pose(extra, prefix: str) -> np.ndarray:
    return pose_matrix(
        [float(extra[f"{prefix}_{a}"]) for a in POSE],
        [float(extra[f"{prefix}_{a}"]) for a in QUAT],
    )


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    root = tmp_path_factory.mktemp("smoke") / "seq"
    report = generate(preset("smoke"), root, SEED, progress=False)
    return root, report


@pytest.fixture(scope="module")
def sequence(smoke):
    return validate_sequence(smoke[0], decode_images=True)


@pytest.fixture(scope="module")
def occupancy():
    return StationOccupancy.from_model(None)


@pytest.fixture(scope="module")
def label_renderer(sequence):
    with ReferenceRenderer(sequence.meta.mesh, sequence.meta.camera, scale=1.0, shadows=False) as r:
        yield r


def _scene(frame):
    """Bodies and the anomaly of a frame, rebuilt from what the files record."""
    sky = StationEphemeris().sky_on_day(int(frame.extra["day"]))
    extras = []
    if frame.is_anomalous:
        e = frame.extra
        obj = build_anomaly(frame.anomaly, int(e["object_seed"]), e["colour"], float(e["scale"]))
        extras.append(ExtraObject(obj.scene, _pose(e, "obj")))
    return sky, extras


# ---------------------------------------------------------------------- the sequence
def test_smoke_composition(smoke, sequence):
    root, report = smoke
    config = preset("smoke")
    assert len(sequence) == report.frames == config.frames
    for split, spec in config.splits.items():
        frames = [f for f in sequence.frames if f.split == split]
        assert sum(f.is_anomalous for f in frames) == spec.anomalous
        assert report.composition[split]["anomalous"] == spec.anomalous
        assert {f.camera for f in frames} <= set(range(spec.cameras))
    assert all(f.reference is not None for f in sequence.frames)
    assert (root / GENERATION_FILE).is_file()
    assert (root / "meshes" / "station.glb").is_file()


def test_class2_pixels_are_exactly_the_anomaly(sequence, label_renderer):
    # A second, independent segmentation: where adding the object changes the depth buffer.
    for frame in sequence.frames:
        mask = cv2.imread(str(frame.mask), cv2.IMREAD_GRAYSCALE)
        sky, extras = _scene(frame)
        T = _pose(frame.extra, "true")
        with_obj = label_renderer.render(
            T, sky.sun_direction, 1.0, sky.bodies(), extras, depth=True, labels=True
        )
        without = label_renderer.render(T, sky.sun_direction, 1.0, sky.bodies(), depth=True)
        np.testing.assert_array_equal(mask == 2, with_obj.depth != without.depth)
        # The whole mask (space, station and bodies, anomaly) is reproduced from the files.
        np.testing.assert_array_equal(mask, with_obj.labels)
        assert frame.is_anomalous == bool(np.any(mask == 2))


def test_anomalous_frames_meet_the_visibility_rule(sequence, occupancy):
    k = sequence.meta.camera
    need = math.ceil(0.001 * k.width * k.height)
    anomalous = [f for f in sequence.frames if f.is_anomalous]
    assert anomalous
    for frame in anomalous:
        e = frame.extra
        mask = cv2.imread(str(frame.mask), cv2.IMREAD_GRAYSCALE)
        assert int(e["anomaly_pixels"]) == np.count_nonzero(mask == 2) >= need
        T, P = _pose(e, "true"), _pose(e, "obj")
        optical = T[:3, :3].T @ (P[:3, 3] - T[:3, 3])
        u, v = k.fx * optical[0] / optical[2] + k.cx, k.fy * optical[1] / optical[2] + k.cy
        assert optical[2] > 0 and -0.5 <= u <= k.width - 0.5 and -0.5 <= v <= k.height - 0.5
        obj = build_anomaly(frame.anomaly, int(e["object_seed"]), e["colour"], float(e["scale"]))
        points = obj.surface_points @ P[:3, :3].T + P[:3, 3]
        assert not occupancy.intersects(points)
        assert not occupancy.occluded(T[:3, 3], P[:3, 3][None])[0]
        assert float(e["occluded_fraction"]) <= 0.5
        # Offsets along the viewing axis are ALLO's; the box is 1.2 m around 4 m + depth.
        depth = float(e["depth_m"])
        assert depth in (0.0, -1.0, 1.0, -2.0, 2.0)
        assert abs(optical[2] - 4.0 - depth) <= 1.2 * math.sqrt(3) + 1e-9


def test_poses_round_trip_and_model_the_reported_pose_error(smoke, sequence):
    config = preset("smoke")
    plans = plan_frames(config, SEED)
    assert [p.name for p in plans] == [f.name for f in sequence.frames]
    for frame in sequence.frames:
        true = _pose(frame.extra, "true")
        reported = frame.T_station_camera
        np.testing.assert_allclose(reported[:3, :3] @ reported[:3, :3].T, np.eye(3), atol=1e-9)
        offset = np.linalg.norm(reported[:3, 3] - true[:3, 3])
        angle = np.arccos(np.clip((np.trace(true[:3, :3].T @ reported[:3, :3]) - 1) / 2, -1, 1))
        assert 0 < offset < 6 * math.sqrt(3) * config.pose_error_m
        assert 0 < angle < 6 * math.sqrt(3) * config.pose_error_rad
    # The stored numbers are the exact ones: rewriting the file changes nothing.
    text = (smoke[0] / "frames.csv").read_text()
    assert "nan" not in text and "inf" not in text


def test_base_poses_are_disjoint_between_splits(sequence, occupancy):
    ids = {}
    for frame in sequence.frames:
        ids.setdefault(frame.split, {}).setdefault(frame.camera, set()).add(frame.extra["pose_id"])
    per_split = {s: set().union(*cams.values()) for s, cams in ids.items()}
    assert all(len(v) == 1 for cams in ids.values() for v in cams.values())
    assert not per_split["train"] & per_split["test"]
    bench = preset("bench")
    poses = make_base_poses(
        occupancy,
        {s: spec.cameras for s, spec in bench.splits.items()},
        np.random.default_rng(0),
    )
    seen = [p.pose_id for split in poses.values() for p in split]
    assert len(seen) == len(set(seen)) == sum(s.cameras for s in bench.splits.values())
    positions = np.array([p.T_station_camera[:3, 3] for split in poses.values() for p in split])
    gaps = np.linalg.norm(positions[:, None] - positions[None], axis=2) + np.eye(len(positions))
    assert gaps.min() > 0.5
    for split in poses.values():
        for base in split:
            assert occupancy.clearance(base.T_station_camera[:3, 3]) >= 7.0
            forward = base.T_station_camera[:3, 2]
            to_target = base.target - base.T_station_camera[:3, 3]
            assert np.dot(forward, to_target) / np.linalg.norm(to_target) > 0.999


def test_same_seed_same_files_and_cli_end_to_end(smoke, tmp_path, capsys):
    out = tmp_path / "cli"
    assert (
        main(["generate", "--preset", "smoke", "--seed", str(SEED), "--out", str(out), "--quiet"])
        == 0
    )
    assert "8 frames" in capsys.readouterr().out
    assert _hashes(out) == _hashes(smoke[0])
    validate_sequence(out, decode_images=True)
    # An existing sequence is kept unless asked.
    assert main(["generate", "--preset", "smoke", "--out", str(out), "--quiet"]) == 1
    assert "overwrite" in capsys.readouterr().err
    other = tmp_path / "other"
    assert (
        main(
            [
                "generate",
                "--preset",
                "smoke",
                "--seed",
                "4",
                "--out",
                str(other),
                "--quiet",
                "--frames",
                "3",
                "--no-references",
            ]
        )
        == 0
    )
    assert (other / "frames.csv").read_bytes() != (out / "frames.csv").read_bytes()
    assert len(read_sequence(other)) == 3


def test_cli_wires_import_allo_and_rejects_bad_options(capsys):
    args = build_parser().parse_args(["import-allo", "ALLO/test", "--out", "x"])
    assert callable(args.func) and args.split_dir == Path("ALLO/test")
    for bad in (
        ["generate", "--preset", "nope"],
        ["generate", "--frames", "0"],
        ["generate", "--types", "spoon"],
    ):
        with pytest.raises(SystemExit):
            build_parser().parse_args(bad)
    capsys.readouterr()


# ---------------------------------------------------------------------- parts
@pytest.mark.parametrize("kind", list(ANOMALY_TYPES))
def test_each_object_type_builds_a_plausible_mesh(kind):
    assert len(ANOMALY_TYPES) >= 12
    for seed in range(4):
        obj = build_anomaly(kind, seed)
        assert obj.parts and all(len(p.mesh.faces) > 0 for p in obj.parts)
        for part in obj.parts:
            mesh = part.mesh
            if kind in SHEET_TYPES:
                # An open sheet: every edge on one or two faces, with a boundary.
                counts = np.bincount(mesh.edges_unique_inverse)
                assert counts.max() <= 2 and counts.min() == 1
            else:
                assert mesh.is_watertight and mesh.volume > 0
        extents = obj.extents
        assert 0.1 <= extents.max() <= 3.0, extents
        np.testing.assert_allclose(obj.mesh.bounds.mean(axis=0), 0.0, atol=1e-9)
        assert len(obj.scene.geometry) == len(obj.parts)
    again = build_anomaly(kind, 1)
    np.testing.assert_array_equal(again.mesh.vertices, build_anomaly(kind, 1).mesh.vertices)
    assert not np.array_equal(again.mesh.vertices, build_anomaly(kind, 2).mesh.vertices)


def test_object_errors_and_colour_variants():
    with pytest.raises(ObjectError):
        build_anomaly("spoon", 0)
    with pytest.raises(ObjectError):
        build_anomaly("drill", 0, "plaid")
    with pytest.raises(ObjectError):
        build_anomaly("drill", -1)
    red = build_anomaly("drill", 0, "red")
    first = next(iter(red.scene.geometry.values()))
    assert tuple(first.visual.material.baseColorFactor[:3]) != tuple(
        next(
            iter(build_anomaly("drill", 0).scene.geometry.values())
        ).visual.material.baseColorFactor[:3]
    )


def test_placement_rules_reject_bad_candidates(occupancy):
    k = CameraIntrinsics(320, 180, 222.2, 222.2, 160, 90)
    camera = look_at([0.0, -30.0, 0.0], [0.0, 0.0, 0.0])
    obj = build_anomaly("cubesat_3u", 0)

    def at(position):
        pose = np.eye(4)
        pose[:3, 3] = position
        return placement.check(obj, pose, camera, k, occupancy, 0.5)

    assert at([0.0, -26.0, 0.0]).rejected == ""
    assert at([0.0, 0.0, 0.0]).rejected == "station"  # inside the habitation module
    assert at([0.0, 10.0, 0.0]).rejected == "occluded"  # behind it
    assert at([30.0, -26.0, 0.0]).rejected == "frustum"
    assert at([0.0, -29.9, 0.0]).rejected == "range"
    rng = np.random.default_rng(0)
    for depth in (-2.0, 2.0):
        pose = placement.propose(camera, rng, 4.0, 1.2, depth)
        offset = camera[:3, :3].T @ (pose[:3, 3] - camera[:3, 3])
        assert np.all(np.abs(offset - [0, 0, 4.0 + depth]) <= 1.2)


def test_perturbation_and_pose_error_statistics():
    rng = np.random.default_rng(0)
    base = look_at([10.0, -20.0, 5.0], [0.0, 0.0, 0.0])
    moved = np.array([perturb(base, rng, 1.0, 0.2)[:3, 3] for _ in range(2000)])
    assert np.allclose(moved.std(axis=0), 1.0, atol=0.08)
    errors = [pose_error(base, rng, 0.02, 0.0035) for _ in range(500)]
    assert np.allclose(np.std([e[:3, 3] - base[:3, 3] for e in errors], axis=0), 0.02, atol=0.003)
    assert np.array_equal(pose_error(base, rng, 0.0, 0.0), base)


def test_camera_effects_are_deterministic_and_modest():
    rng_image = np.random.default_rng(1)
    clean = np.zeros((90, 160, 3), np.uint8)
    clean[20:70, 40:120] = rng_image.integers(40, 200, (50, 80, 3))
    a, ea = apply_camera(clean, np.random.default_rng(5), RealismConfig())
    b, eb = apply_camera(clean, np.random.default_rng(5), RealismConfig())
    assert np.array_equal(a, b) and ea == eb
    assert not np.array_equal(a, clean)
    assert np.abs(a.astype(float) - clean).mean() < 15.0
    off, _ = apply_camera(clean, np.random.default_rng(5), RealismConfig(enabled=False))
    assert np.array_equal(off, clean)


# ---------------------------------------------------------------------- settings
def test_presets_are_valid():
    for name in PRESETS:
        config = preset(name)
        assert config.name == name and config.frames > 0
    smoke, demo, bench = preset("smoke"), preset("demo"), preset("bench")
    assert smoke.width * smoke.height <= 320 * 180
    assert (demo.width, demo.height) == (bench.width, bench.height) == (1920, 1080)
    assert 35 <= demo.frames <= 45
    assert set(bench.splits) == {"train", "val", "test"}
    assert bench.splits["train"].anomalous == 0
    test = bench.splits["test"]
    assert test.frames >= 300 and 1.8 <= test.anomalous / test.normal <= 2.2
    plans = plan_frames(bench, 0)
    kinds = [p.anomaly for p in plans if p.split == "test" and p.anomaly]
    counts = np.unique(kinds, return_counts=True)[1]
    assert len(counts) == len(ANOMALY_TYPES) and counts.max() - counts.min() <= 1
    with pytest.raises(SynthError):
        preset("huge")


@pytest.mark.parametrize(
    "change",
    [
        {"width": 8},
        {"position_sigma_m": -1.0},
        {"rotation_sigma_rad": math.nan},
        {"depths_m": ()},
        {"days": (0, 10)},
        {"sun_weights": (1.0,)},
        {"anomaly_types": ("spoon",)},
        {"splits": {"dev": SplitSpec(1, 0, 1)}},
        {"realism": "yes"},
        {"png_compression": 12},
    ],
)
def test_config_validation(change):
    with pytest.raises(SynthError):
        preset("smoke").with_overrides(**change)


def test_config_helpers():
    with pytest.raises(SynthError):
        SplitSpec(0, 0, 1)
    with pytest.raises(SynthError):
        RealismConfig(vignetting=2.0)
    with pytest.raises(SynthError):
        preset("smoke").with_overrides(colour="red")
    scaled = preset("bench").with_frames(51)
    assert 49 <= scaled.frames <= 53 and scaled.splits["train"].anomalous == 0
    assert isinstance(SynthConfig(name="x", splits={"test": SplitSpec(1, 1, 1)}), SynthConfig)
