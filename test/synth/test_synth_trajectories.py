"""Arm trajectories past objects: the objects table against the instance masks (OpenCV's
projectPoints as the independent camera model), the arm's speeds, anomaly-free scenes, and
the ALLO presets left as they were."""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import cv2
import numpy as np
import pytest

from allo_mrad_ros.geometry import pose_matrix, quaternion_to_matrix
from allo_mrad_ros.sequence import FORMAT_V1, FORMAT_V2, validate_sequence
from allo_mrad_ros.synth.config import SplitSpec, SynthError, TrajectoryConfig, preset
from allo_mrad_ros.synth.generator import generate
from allo_mrad_ros.synth.trajectories import speeds

SEED = 11
WIDTH, HEIGHT = 96, 64
FRAMES = 10


def _config(**trajectory: object):
    base = preset("objects")
    settings = replace(base.trajectory, frames=FRAMES, **trajectory)
    return base.with_overrides(
        width=WIDTH,
        height=HEIGHT,
        splits={"test": SplitSpec(3, 2, 5)},
        trajectory=settings,
    )


@pytest.fixture(scope="module")
def objects_sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("trajectories") / "seq"
    report = generate(_config(), root, SEED, progress=False)
    return validate_sequence(root), report


@pytest.fixture(scope="module")
def drifting_sequence(tmp_path_factory):
    # Fast drift (0.4-0.5 m/s, beyond the presets' 0.05) so that an object rendered where it
    # was at the reference time, not where its velocity takes it, misses its box.
    root = tmp_path_factory.mktemp("drifting") / "seq"
    config = _config(drift_probability=1.0, drift_m_s=(0.4, 0.5), objects=(3, 3))
    config = config.with_overrides(splits={"test": SplitSpec(0, 2, 2)})
    generate(config, root, SEED + 1, progress=False)
    return validate_sequence(root)


def _true_pose(frame) -> np.ndarray:
    extra = frame.extra
    return pose_matrix(
        [float(extra[f"true_{a}"]) for a in ("tx", "ty", "tz")],
        [float(extra[f"true_{a}"]) for a in ("qx", "qy", "qz", "qw")],
    )


def _project(points: np.ndarray, T_station_camera: np.ndarray, camera) -> np.ndarray:
    """Pixel coordinates by OpenCV's pinhole model (independent of the renderer's maths)."""
    T_camera_station = np.linalg.inv(T_station_camera)
    rvec, _ = cv2.Rodrigues(T_camera_station[:3, :3])
    pixels, _ = cv2.projectPoints(
        np.asarray(points, dtype=np.float64).reshape(-1, 1, 3),
        rvec,
        T_camera_station[:3, 3],
        camera.matrix,
        np.zeros(5),
    )
    # OpenCV's pixel centres are at integers; the array index of pixel (u, v) is (v, u).
    return pixels.reshape(-1, 2)


def _corners(item, stamp_ns: int) -> np.ndarray:
    signs = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    local = 0.5 * signs * item.size
    return local @ quaternion_to_matrix(item.quaternion).T + item.position_at(stamp_ns)


def _depths(points: np.ndarray, T_station_camera: np.ndarray) -> np.ndarray:
    return (points - T_station_camera[:3, 3]) @ T_station_camera[:3, 2]


def _check_against_masks(sequence) -> tuple[int, int]:
    """Every object pixel inside the projection of its object's box; the object's centre on
    or next to its pixels. Returns (pairs checked, pairs whose centre is near its pixels)."""
    camera = sequence.meta.camera
    objects = {item.id: item for item in sequence.objects}
    pairs = near = 0
    for frame in sequence:
        mask = sequence.load_mask(frame)
        instances = sequence.load_instances(frame, mask)
        T = _true_pose(frame)
        for object_id in (int(v) for v in np.unique(instances) if v):
            item = objects[object_id]
            assert item.extra["trajectory"] == frame.extra["trajectory"], (frame.index, object_id)
            rows, cols = np.nonzero(instances == object_id)
            corners = _corners(item, frame.stamp_ns)
            assert np.all(_depths(corners, T) > 0), (frame.index, object_id)
            box = _project(corners, T, camera)
            low, high = box.min(axis=0) - 1.0, box.max(axis=0) + 1.0
            assert np.all((cols >= low[0]) & (cols <= high[0])), (frame.index, object_id)
            assert np.all((rows >= low[1]) & (rows <= high[1])), (frame.index, object_id)
            centre = _project(item.position_at(frame.stamp_ns)[None], T, camera)[0]
            pairs += 1
            inside = (
                cols.min() - 2 <= centre[0] <= cols.max() + 2
                and rows.min() - 2 <= centre[1] <= rows.max() + 2
            )
            near += inside
        # The anomaly type names one of the objects shown (the largest), or none.
        shown = {objects[int(v)].type for v in np.unique(instances) if v}
        assert (frame.anomaly in shown) if shown else frame.anomaly == ""
    return pairs, near


def test_objects_project_onto_their_instance_pixels(objects_sequence):
    sequence, _ = objects_sequence
    assert sequence.meta.format == FORMAT_V2
    assert len(sequence.objects) >= 4
    pairs, near = _check_against_masks(sequence)
    assert pairs >= 10
    # Partly hidden objects may show only a part away from their centre: most do not.
    assert near >= 0.9 * pairs, (near, pairs)


def test_drifting_objects_are_rendered_where_their_velocity_takes_them(drifting_sequence):
    sequence = drifting_sequence
    assert all(0.4 <= item.speed <= 0.5 for item in sequence.objects)
    pairs, near = _check_against_masks(sequence)
    assert pairs >= 10
    assert near >= 0.9 * pairs, (near, pairs)


def test_static_and_slow_drift_in_the_preset(objects_sequence):
    sequence, report = objects_sequence
    for item in sequence.objects:
        drifting = item.extra["drifting"] == "1"
        assert (0.01 <= item.speed <= 0.05) if drifting else item.speed == 0.0
        assert item.extra["placement"] in ("front", "space", "behind")
        trajectory_frames = [
            f for f in sequence if f.extra["trajectory"] == item.extra["trajectory"]
        ]
        assert item.stamp_ns == trajectory_frames[0].stamp_ns
    composition = report.composition["test"]
    assert composition["objects"] == len(sequence.objects)
    assert composition["trajectories"] == 5


def test_arm_moves_smoothly_at_its_speeds(objects_sequence):
    sequence, _ = objects_sequence
    rate = sequence.meta.rate_hz
    by_trajectory: dict[str, list] = {}
    for frame in sequence:
        by_trajectory.setdefault(frame.extra["trajectory"], []).append(frame)
    assert len(by_trajectory) == 5
    for frames in by_trajectory.values():
        assert [int(f.extra["step"]) for f in frames] == list(range(FRAMES))
        stamps = np.diff([f.stamp_ns for f in frames])
        assert np.all(stamps == round(1e9 / rate))
        linear, angular = speeds([_true_pose(f) for f in frames], rate)
        assert 0.05 < linear.max() <= 0.3 + 1e-9
        assert angular.max() < 10.0
        # At rest at both ends: the first and last steps are the slowest.
        assert linear[0] < 0.5 * linear.max() and linear[-1] < 0.5 * linear.max()


def test_anomaly_free_scenes(objects_sequence):
    sequence, _ = objects_sequence
    scenes = {f.extra["scene"] for f in sequence}
    assert scenes == {"objects", "glare", "bodies", "shadows"}
    camera = sequence.meta.camera
    half_fov = np.arctan(0.5 * camera.width / camera.fx)
    for frame in sequence:
        scene = frame.extra["scene"]
        if scene == "objects":
            continue
        mask = sequence.load_mask(frame)
        assert not frame.is_anomalous and not np.any(mask == 2)
        assert not np.any(sequence.load_instances(frame, mask))
        axis = _true_pose(frame)[:3, 2]
        if scene == "glare" and frame.extra["step"] == "0":
            angle = np.arccos(np.clip(axis @ frame.sun_direction, -1, 1))
            assert angle <= 1.1 * half_fov + 1e-6
    shadows = [f for f in sequence if f.extra["scene"] == "shadows"]
    turned = np.degrees(
        np.arccos(np.clip(shadows[0].sun_direction @ shadows[-1].sun_direction, -1, 1))
    )
    expected = preset("objects").trajectory.sun_turn_deg_s * (FRAMES - 1) / sequence.meta.rate_hz
    assert turned == pytest.approx(expected, rel=1e-3)


def test_allo_presets_stay_version_1(tmp_path):
    root = tmp_path / "smoke"
    generate(preset("smoke").with_frames(3), root, 3, progress=False)
    sequence = validate_sequence(root)
    assert sequence.meta.format == FORMAT_V1 and not sequence.has_objects
    assert not (root / "objects.csv").exists()
    with (root / "frames.csv").open() as stream:
        header = next(csv.reader(stream))
    v1 = [
        "stamp_ns",
        "split",
        "camera",
        "image",
        "mask",
        "reference",
        "label",
        "anomaly",
        "tx",
        "ty",
        "tz",
        "qx",
        "qy",
        "qz",
        "qw",
        "sun_x",
        "sun_y",
        "sun_z",
        "sun_strength",
        "earth_x",
        "earth_y",
        "earth_z",
        "earth_r",
        "moon_x",
        "moon_y",
        "moon_z",
        "moon_r",
    ]
    assert header[: len(v1)] == v1 and "instances" not in header
    config = json.loads((root / "generation.json").read_text())["config"]
    assert "trajectory" not in config


def test_trajectory_settings_are_validated():
    with pytest.raises(SynthError, match="speed_m_s"):
        TrajectoryConfig(speed_m_s=(0.1, 2.0))
    with pytest.raises(SynthError, match="drift_m_s"):
        TrajectoryConfig(drift_m_s=(0.0, 0.9))
    with pytest.raises(SynthError, match="normal_scenes"):
        TrajectoryConfig(normal_scenes=("rain",))
    with pytest.raises(SynthError, match="cameras must be 3"):
        preset("objects").with_overrides(splits={"val": SplitSpec(1, 2, 1)})
    scaled = preset("objects").with_frames(90)
    assert scaled.trajectory.frames == 5 and scaled.frames == 90


def test_cli_generates_an_anomaly_free_trajectory_sequence(tmp_path, capsys):
    from allo_mrad_ros.synth.cli import main

    out = tmp_path / "normal"
    args = ["generate", "--preset", "objects-normal", "--seed", "2", "--quiet"]
    args += ["--width", "48", "--height", "32", "--trajectory-frames", "3", "--rate-hz", "20"]
    assert main([*args, "--out", str(out)]) == 0
    sequence = validate_sequence(out)
    assert sequence.meta.format == FORMAT_V2 and sequence.objects == ()
    assert sequence.meta.rate_hz == 20.0
    assert len(sequence) == 12 * 3
    assert not any(frame.is_anomalous for frame in sequence)
    assert capsys.readouterr().out.count("6 trajectories, 18 frames") == 2
    # A version-2 sequence (objects.csv, instance masks) is one the output rule may replace.
    assert main([*args, "--out", str(out), "--overwrite"]) == 0
    capsys.readouterr()
    demo = ["generate", "--preset", "demo", "--trajectory-frames", "3", "--quiet"]
    assert main([*demo, "--out", str(tmp_path / "demo")]) == 1
    assert "needs a trajectory preset" in capsys.readouterr().err


def test_the_path_traced_objects_preset_has_the_path_traced_benchs_queries():
    # The objects bench's second station must not share the reference's light model or
    # materials: its queries take the extended path-traced bench's departures (Cycles, the
    # query's own lamps and materials, a camera response), over the objects trajectories'
    # frames and rate, in a test split only (nothing is chosen on it).
    objects, pt_bench, pt = preset("objects"), preset("bench-pt"), preset("objects-pt")
    assert list(pt.splits) == ["test"]
    assert pt.query_renderer == "cycles" and pt.camera_effects
    assert pt.cycles_light == pt_bench.cycles_light and pt.cycles_light.area_lamp
    assert pt.realism == pt_bench.realism
    assert pt.cycles_view_transforms == pt_bench.cycles_view_transforms
    assert pt.cycles_samples == pt_bench.cycles_samples
    assert pt.trajectory == objects.trajectory and pt.rate_hz == objects.rate_hz
