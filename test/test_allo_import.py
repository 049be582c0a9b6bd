"""``import-allo`` on a tiny fake ALLO tree built by the test."""

from __future__ import annotations

import argparse
import csv
import io
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.allo_ephemeris import allo_sky
from allo_mrad_ros.allo_format import (
    AlloImportError,
    AlloName,
    allo_base_poses,
    base_pose_to_optical,
    parse_allo_name,
    parse_base_poses,
)
from allo_mrad_ros.allo_import import EPOCH_2030_NS, add_import_parser, import_allo, main_import
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import quaternion_to_matrix
from allo_mrad_ros.sequence import FRAMES_FILE, SequenceError, read_sequence

# Real ALLO renders are 1920x1080; the fake tree uses tiny images with matching intrinsics.
SMALL = CameraIntrinsics(width=24, height=16, fx=16.7, fy=16.7, cx=12.0, cy=8.0)
H, W = SMALL.height, SMALL.width

# (camera, name, anomalous)
FAKE_FILES = [
    (0, "3_normal_10.png", False),
    (0, "1_drill_5_-1_0_default.png", True),
    (0, "1_normal_1.png", False),
    (4, "1_blanket_2_10_0.5_-2_red.png", True),
    (4, "2_normal_10.png", False),
    (9, "1_normal_5.png", False),
]


def _rgb(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _mask(anomalous: bool) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    mask[3:12, 4:20] = 1
    if anomalous:
        mask[5:8, 6:9] = 2
    return mask


def _build_tree(root: Path, files: list = FAKE_FILES, split: str = "test") -> Path:
    split_dir = root / "ALLO" / split
    for i, (camera, name, anomalous) in enumerate(files):
        folder = split_dir / f"Camera{camera}"
        (folder / "images").mkdir(parents=True, exist_ok=True)
        (folder / "masks").mkdir(exist_ok=True)
        cv2.imwrite(str(folder / "images" / name), _rgb(i))
        if name != "1_normal_5.png":  # one image without a mask
            cv2.imwrite(str(folder / "masks" / name), _mask(anomalous))
    (split_dir / f"Camera{files[0][0]}" / "images" / "notes.txt").write_text("ignored")
    (split_dir / "README").write_text("ignored")
    return split_dir


@pytest.fixture
def split_dir(tmp_path: Path) -> Path:
    return _build_tree(tmp_path)


# --- names and poses ---------------------------------------------------------------------


def test_parse_names() -> None:
    assert parse_allo_name("12_normal_10.png") == AlloName(12, "", 10.0)
    name = parse_allo_name("3_drill_5_-1_0_default.png")
    assert name == AlloName(3, "drill", 5.0, -1.0, 0.0, "default")
    assert name.is_anomalous
    assert parse_allo_name("7_cable_2_1_0.7_-2_blue").anomaly == "cable_2"
    assert parse_allo_name("7_thermal_blanket_3_10_0.3_1_red.png").anomaly == "thermal_blanket_3"


@pytest.mark.parametrize(
    ("name", "match"),
    [
        ("image.png", "not an ALLO image name"),
        ("3_normal.png", "not an ALLO image name"),
        ("3_drill_5_-1_0.png", "not an ALLO image name"),
        ("x_normal_10.png", "day 'x'"),
        ("0_normal_10.png", "day '0'"),
        ("3_normal_bright.png", "sun strength 'bright'"),
        ("3_normal_-1.png", "negative"),
        ("3_normal_10_-1_0_default.png", "invalid anomaly name 'normal'"),
        ("3__5_-1_0_default.png", "invalid anomaly name"),
        ("3_drill_5_big_0_default.png", "scale 'big'"),
        ("3_drill_5_-1_nan_default.png", "depth 'nan'"),
        ("3_drill_5_-1_0_.png", "empty colour"),
    ],
)
def test_unparsable_names_are_named(name: str, match: str) -> None:
    with pytest.raises(AlloImportError, match=match) as info:
        parse_allo_name(name, source=f"/data/ALLO/test/Camera0/images/{name}")
    assert str(info.value).startswith(f"/data/ALLO/test/Camera0/images/{name}: ")


def test_base_pose_table() -> None:
    train, test = allo_base_poses("train"), allo_base_poses("test")
    assert sorted(train) == list(range(40))
    assert sorted(test) == list(range(10))
    position, quaternion = test[0]
    np.testing.assert_allclose(position, [-26.537, 27.247, -14.353])
    # Optical z (forward) is the Blender camera's -z; optical y (down) its -y.
    rotation = quaternion_to_matrix(quaternion)
    roll, yaw = 1.73031, -3.3945
    rx = np.array([[1, 0, 0], [0, np.cos(roll), -np.sin(roll)], [0, np.sin(roll), np.cos(roll)]])
    rz = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    blender = rz @ rx  # pitch is 0 for this camera
    np.testing.assert_allclose(rotation[:, 2], -blender[:, 2], atol=1e-12)
    np.testing.assert_allclose(rotation[:, 1], -blender[:, 1], atol=1e-12)
    np.testing.assert_allclose(rotation[:, 0], blender[:, 0], atol=1e-12)
    assert quaternion[3] >= 0
    with pytest.raises(AlloImportError, match="train or test"):
        allo_base_poses("val")


def test_base_pose_to_optical_identity() -> None:
    position, quaternion = base_pose_to_optical([1, 2, 3], 0.0, 0.0, 0.0)
    np.testing.assert_allclose(quaternion_to_matrix(quaternion), np.diag([1.0, -1.0, -1.0]))
    np.testing.assert_array_equal(position, [1, 2, 3])


@pytest.mark.parametrize(
    ("text", "match"),
    [
        ("a,b\n", "header must be"),
        ("split,index,x,y,z,roll,pitch,yaw\nval,0,1,2,3,0,0,0\n", "line 2, column 'split'"),
        ("split,index,x,y,z,roll,pitch,yaw\ntest,a,1,2,3,0,0,0\n", "line 2, column 'index'"),
        ("split,index,x,y,z,roll,pitch,yaw\ntest,0,1,2,3,0,x,0\n", "line 2, column 'pitch'"),
        ("split,index,x,y,z,roll,pitch,yaw\ntest,0,1,2\n", "line 2: expected 8 fields"),
        (
            "split,index,x,y,z,roll,pitch,yaw\ntest,0,1,2,3,0,0,0\ntest,0,1,2,3,0,0,0\n",
            "line 3: duplicate pose test 0",
        ),
    ],
)
def test_base_pose_table_errors(text: str, match: str) -> None:
    with pytest.raises(AlloImportError, match=match):
        parse_base_poses(text, "poses.csv")


# --- import ------------------------------------------------------------------------------


def test_import_references_images_in_place(tmp_path: Path, split_dir: Path) -> None:
    out = tmp_path / "sequences" / "allo_test"
    sequence = import_allo(split_dir, out, intrinsics=SMALL, validate=True)
    assert sequence.meta.camera == SMALL
    assert sequence.meta.name == "ALLO test"
    assert sequence.meta.mesh is None
    names = [(f.camera, f.image.name) for f in sequence]
    # Ordered by (day, camera, name).
    assert names == [
        (0, "1_drill_5_-1_0_default.png"),
        (0, "1_normal_1.png"),
        (4, "1_blanket_2_10_0.5_-2_red.png"),
        (9, "1_normal_5.png"),
        (4, "2_normal_10.png"),
        (0, "3_normal_10.png"),
    ]
    assert [f.stamp_ns for f in sequence] == [EPOCH_2030_NS + i * 100_000_000 for i in range(6)]
    assert EPOCH_2030_NS == 1_893_456_000 * 10**9
    poses = allo_base_poses("test")
    files = {name: i for i, (_, name, _) in enumerate(FAKE_FILES)}
    for frame in sequence:
        allo = parse_allo_name(frame.image.name)
        assert frame.split == "test"
        assert frame.label == ("anomalous" if allo.is_anomalous else "normal")
        assert frame.anomaly == allo.anomaly
        assert frame.sun_strength == allo.sun_strength / 10
        np.testing.assert_array_equal(frame.position, poses[frame.camera][0])
        np.testing.assert_array_equal(frame.quaternion, poses[frame.camera][1])
        sky = allo_sky(allo.day)
        np.testing.assert_array_equal(frame.sun_direction, sky.sun_direction)
        np.testing.assert_array_equal(frame.earth, sky.earth)
        np.testing.assert_array_equal(frame.moon, sky.moon)
        assert frame.extra["allo_day"] == str(allo.day)
        assert (
            frame.image.resolve()
            == (split_dir / f"Camera{frame.camera}/images/{frame.image.name}").resolve()
        )
        np.testing.assert_array_equal(
            sequence.load_image(frame), _rgb(files[frame.image.name])[..., ::-1]
        )
    drill = sequence[0]
    assert drill.extra == {
        "allo_day": "1",
        "allo_sun_strength": "5.0",
        "allo_scale": "-1.0",
        "allo_depth": "0.0",
        "allo_colour": "default",
    }
    assert sequence[3].mask is None
    assert sequence[3].extra["allo_colour"] == ""
    rows = list(csv.DictReader(io.StringIO((out / FRAMES_FILE).read_text())))
    # Referenced in place: links inside the sequence to the ALLO files, nothing copied.
    name = "1_drill_5_-1_0_default.png"
    assert rows[0]["image"] == f"test/Camera0/images/{name}"
    assert rows[0]["mask"] == f"test/Camera0/masks/{name}"
    for kind in ("images", "masks"):
        link = out / "test" / "Camera0" / kind / name
        assert (
            link.is_symlink() and link.resolve() == (split_dir / "Camera0" / kind / name).resolve()
        )


def test_import_into_the_allo_folder_only_adds_metadata(tmp_path: Path, split_dir: Path) -> None:
    allo_root = split_dir.parent
    before = sorted(p.relative_to(allo_root) for p in allo_root.rglob("*"))
    import_allo(split_dir, allo_root, intrinsics=SMALL)
    after = sorted(p.relative_to(allo_root) for p in allo_root.rglob("*"))
    assert sorted(set(after) - set(before)) == [Path("frames.csv"), Path("sequence.yaml")]
    rows = list(csv.DictReader(io.StringIO((allo_root / FRAMES_FILE).read_text())))
    assert rows[0]["image"] == "test/Camera0/images/1_drill_5_-1_0_default.png"


def test_import_copy_is_self_contained(tmp_path: Path, split_dir: Path) -> None:
    out = tmp_path / "copied"
    sequence = import_allo(split_dir, out, intrinsics=SMALL, copy=True, rate_hz=4.0)
    for frame in sequence:
        assert frame.image.parent == out / "test" / f"Camera{frame.camera}" / "images"
        source = split_dir / f"Camera{frame.camera}" / "images" / frame.image.name
        assert frame.image.read_bytes() == source.read_bytes()
    assert sequence[1].stamp_ns - sequence[0].stamp_ns == 250_000_000
    assert ".." not in (out / FRAMES_FILE).read_text()
    # Moving the copy elsewhere keeps it valid.
    moved = tmp_path / "moved"
    out.rename(moved)
    assert len(read_sequence(moved)) == 6


def test_import_is_deterministic(tmp_path: Path, split_dir: Path) -> None:
    import_allo(split_dir, tmp_path / "a", intrinsics=SMALL)
    import_allo(split_dir, tmp_path / "b", intrinsics=SMALL)
    for name in (FRAMES_FILE, "sequence.yaml"):
        assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()


def test_import_train_split_uses_train_poses(tmp_path: Path) -> None:
    split_dir = _build_tree(tmp_path, [(39, "5_normal_10.png", False)], split="train")
    sequence = import_allo(split_dir, tmp_path / "out", intrinsics=SMALL)
    frame = sequence[0]
    assert frame.split == "train"
    np.testing.assert_array_equal(frame.position, allo_base_poses("train")[39][0])


def test_import_errors_name_the_file(tmp_path: Path, split_dir: Path) -> None:
    out = tmp_path / "out"
    bad = split_dir / "Camera0" / "images" / "oops.png"
    cv2.imwrite(str(bad), _rgb(0))
    with pytest.raises(AlloImportError, match="not an ALLO image name") as info:
        import_allo(split_dir, out, intrinsics=SMALL)
    assert str(bad) in str(info.value)
    bad.unlink()

    late = split_dir / "Camera0" / "images" / "400_normal_10.png"
    cv2.imwrite(str(late), _rgb(0))
    with pytest.raises(AlloImportError, match="ALLO day") as info:
        import_allo(split_dir, out, intrinsics=SMALL)
    assert str(late) in str(info.value)
    assert not (out / FRAMES_FILE).exists(), "a failed import leaves no sequence"
    late.unlink()

    (split_dir / "Camera12" / "images").mkdir(parents=True)
    with pytest.raises(AlloImportError, match="no base pose 12 for split 'test'") as info:
        import_allo(split_dir, out, intrinsics=SMALL, overwrite=True)
    assert "Camera12" in str(info.value)
    (split_dir / "Camera12" / "images").rmdir()
    (split_dir / "Camera12").rmdir()

    with pytest.raises(SequenceError, match="size 24x16 differs") as info:
        import_allo(split_dir, out, overwrite=True)  # real ALLO intrinsics: 1920x1080
    assert info.value.file is not None and info.value.file.suffix == ".png"


def test_import_split_must_be_known(tmp_path: Path) -> None:
    split_dir = _build_tree(tmp_path, [(0, "1_normal_10.png", False)], split="subset")
    with pytest.raises(AlloImportError, match="cannot tell the split"):
        import_allo(split_dir, tmp_path / "out", intrinsics=SMALL)
    sequence = import_allo(split_dir, tmp_path / "out", "test", intrinsics=SMALL)
    assert sequence[0].split == "test"
    with pytest.raises(AlloImportError, match="not found"):
        import_allo(tmp_path / "missing", tmp_path / "out2", "test")
    empty = tmp_path / "empty" / "test"
    empty.mkdir(parents=True)
    with pytest.raises(AlloImportError, match="no Camera<N> folders"):
        import_allo(empty, tmp_path / "out3")


def test_label_mask_disagreement_found_by_validation(tmp_path: Path, split_dir: Path) -> None:
    cv2.imwrite(str(split_dir / "Camera0" / "masks" / "3_normal_10.png"), _mask(True))
    import_allo(split_dir, tmp_path / "a", intrinsics=SMALL)  # headers only
    with pytest.raises(SequenceError, match="contradicts the mask") as info:
        import_allo(split_dir, tmp_path / "b", intrinsics=SMALL, validate=True)
    assert (info.value.row, info.value.column) == (6, "label")


# --- command line ------------------------------------------------------------------------


def test_main_import(tmp_path: Path, split_dir: Path, capsys: pytest.CaptureFixture) -> None:
    # The command line always uses ALLO's 1920x1080 intrinsics: give the fake tree that size.
    for image in split_dir.rglob("*.png"):
        data = cv2.imread(str(image), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(image), cv2.resize(data, (1920, 1080), interpolation=cv2.INTER_NEAREST))
    out = tmp_path / "cli"
    assert main_import([str(split_dir), "--out", str(out), "--quiet", "--validate"]) == 0
    assert "6 frames (4 normal, 2 anomalous)" in capsys.readouterr().out
    assert len(read_sequence(out)) == 6
    assert main_import([str(split_dir), "--out", str(out), "--quiet"]) == 2
    assert "already holds a sequence" in capsys.readouterr().err
    assert main_import([str(split_dir), "--out", str(out), "--overwrite", "--split", "test"]) == 0


def test_add_import_parser_plugs_into_a_front_end(tmp_path: Path, split_dir: Path) -> None:
    parser = argparse.ArgumentParser(prog="allo-synth")
    subparsers = parser.add_subparsers(dest="command", required=True)
    add_import_parser(subparsers)
    args = parser.parse_args(["import-allo", str(split_dir), "--out", str(tmp_path), "--copy"])
    assert args.command == "import-allo" and args.copy and args.split is None
    assert args.rate_hz == 10.0
    assert callable(args.func)
    with pytest.raises(SystemExit):
        parser.parse_args(["import-allo", str(split_dir)])  # --out is required
