"""Tests of the ALLO-like generator (`allo-synth generate`) on the small `smoke` preset."""

from __future__ import annotations

import hashlib
import math
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.ephemeris import StationEphemeris
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.render import ExtraObject, ReferenceRenderer
from allo_mrad_ros.sequence import read_sequence, validate_sequence
from allo_mrad_ros.synth.cli import build_parser, main
from allo_mrad_ros.synth.config import preset
from allo_mrad_ros.synth.generator import GENERATION_FILE, generate
from allo_mrad_ros.synth.objects import build_anomaly
from allo_mrad_ros.synth.occupancy import StationOccupancy
from allo_mrad_ros.synth.planning import plan_frames
from allo_mrad_ros.synth.poses import make_base_poses

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
    assert main(["generate", "--preset", "smoke", "--out", str(out), "--quiet"]) == 2
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


def test_cli_options_reach_the_fields_they_name(monkeypatch, tmp_path, capsys):
    # Every option that overrides the preset lands in its own SynthConfig field (degrees
    # turned into radians); the generator is stopped before it writes anything.
    import allo_mrad_ros.synth.generator as generator

    seen = []

    def capture(config, *args, **kwargs):
        seen.append(config)
        raise KeyboardInterrupt

    monkeypatch.setattr(generator, "generate", capture)
    argv = ["generate", "--preset", "smoke", "--out", str(tmp_path / "s"), "--quiet"]
    argv += ["--width", "320", "--height", "180", "--no-references", "--types", "glove,wrench"]
    argv += ["--position-sigma", "0.5", "--rotation-sigma", "0.1", "--pose-error-m", "0.04"]
    argv += ["--pose-error-deg", "0.5", "--cycles-samples", "8", "--no-camera-effects"]
    assert main(argv) == 130
    capsys.readouterr()
    expected = preset("smoke").with_overrides(
        width=320,
        height=180,
        references=False,
        anomaly_types=("glove", "wrench"),
        position_sigma_m=0.5,
        rotation_sigma_rad=0.1,
        pose_error_m=0.04,
        pose_error_rad=math.radians(0.5),
        cycles_samples=8,
        camera_effects=False,
    )
    assert seen == [expected] and expected != preset("smoke")
