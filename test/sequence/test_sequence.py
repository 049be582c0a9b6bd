"""Reader and writer of the ALLO sequence format v1."""

from __future__ import annotations

import csv
import io
import warnings
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.sequence import (
    COLUMNS,
    FRAMES_FILE,
    META_FILE,
    SequenceError,
    SequenceMeta,
    SequenceWriter,
    read_sequence,
    validate_sequence,
)

CAMERA = CameraIntrinsics(width=16, height=12, fx=20.0, fy=20.0, cx=8.0, cy=6.0)
H, W = CAMERA.height, CAMERA.width


def _meta(**changes: object) -> SequenceMeta:
    return SequenceMeta(name="unit test", camera=CAMERA, rate_hz=10.0, **changes)


def _random_unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (H, W, 3), dtype=np.uint8)


def _mask(anomalous: bool) -> np.ndarray:
    mask = np.zeros((H, W), np.uint8)
    mask[2:8, 3:12] = 1
    if anomalous:
        mask[4:6, 5:7] = 2
    return mask


def _write(root: Path, seed: int = 0, frames: int = 4, **writer_args: object) -> list:
    """Write a small sequence: alternating normal/anomalous frames with masks and bodies."""
    rng = np.random.default_rng(seed)
    written = []
    with SequenceWriter(root, _meta(), **writer_args) as writer:
        for i in range(frames):
            anomalous = i % 2 == 1
            written.append(
                writer.add_frame(
                    split="test" if i < frames - 1 else "train",
                    camera=i % 2,
                    image=_image(seed + i),
                    mask=_mask(anomalous),
                    reference=_image(seed + 100 + i) if i == 0 else None,
                    anomaly="drill" if anomalous else "",
                    position=rng.normal(scale=30.0, size=3),
                    quaternion=_random_unit(rng, 4),
                    sun_direction=_random_unit(rng, 3),
                    sun_strength=float(rng.uniform(0.1, 1.0)),
                    earth=[*rng.normal(size=3) * 2000, 35.0] if i != 2 else None,
                    moon=[*rng.normal(size=3) * 500, 180.0],
                    extra={"day": i + 1, "note": "x"} if i == 1 else None,
                )
            )
    return written


@pytest.fixture
def sequence_root(tmp_path: Path) -> Path:
    root = tmp_path / "seq"
    _write(root)
    return root


# --- round trip --------------------------------------------------------------------------


def test_round_trip_of_frames(tmp_path: Path) -> None:
    root = tmp_path / "seq"
    written = _write(root, seed=3)
    sequence = validate_sequence(root, decode_images=True)
    assert sequence.meta.camera == CAMERA
    assert sequence.meta.rate_hz == 10.0
    assert sequence.meta.mesh is None
    assert len(sequence) == len(written) == 4
    for a, b in zip(written, sequence.frames, strict=True):
        assert a.index == b.index
        assert a.stamp_ns == b.stamp_ns
        assert (a.split, a.camera, a.label, a.anomaly) == (b.split, b.camera, b.label, b.anomaly)
        assert a.image == b.image and a.mask == b.mask and a.reference == b.reference
        # Floats are written with repr: they read back bit for bit.
        for name in ("position", "quaternion", "sun_direction"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        for name in ("earth", "moon"):
            va, vb = getattr(a, name), getattr(b, name)
            assert (va is None and vb is None) or np.array_equal(va, vb)
        assert a.sun_strength == b.sun_strength
        np.testing.assert_array_equal(b.T_station_camera, pose_matrix(a.position, a.quaternion))
    assert [f.stamp_ns for f in sequence] == [0, 100_000_000, 200_000_000, 300_000_000]
    assert sequence.frames[2].earth is None
    assert sequence.frames[1].extra == {"day": "2", "note": "x"}
    assert sequence.frames[0].extra == {"day": "", "note": ""}
    assert sequence.frames[1].is_anomalous and not sequence.frames[0].is_anomalous
    assert sequence.splits == ("test", "train")
    assert [f.index for f in sequence.split("test")] == [0, 1, 2]
    assert sequence.split("val") == ()
    with pytest.raises(ValueError, match="split"):
        sequence.split("validation")


def test_images_masks_references_are_lossless(tmp_path: Path) -> None:
    root = tmp_path / "seq"
    _write(root, seed=5)
    sequence = read_sequence(root)
    first, second = sequence.frames[:2]
    np.testing.assert_array_equal(sequence.load_image(first), _image(5))
    np.testing.assert_array_equal(sequence.load_reference(first), _image(105))
    assert sequence.load_reference(second) is None
    np.testing.assert_array_equal(sequence.load_mask(first), _mask(False))
    np.testing.assert_array_equal(sequence.load_mask(second), _mask(True))
    assert first.image == root / "test/Camera0/images/000000.png"
    assert second.mask == root / "test/Camera1/masks/000001.png"
    assert first.reference == root / "test/Camera0/references/000000.png"


@settings(
    max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture]
)
@given(
    position=st.lists(st.floats(-1e4, 1e4, allow_nan=False), min_size=3, max_size=3),
    quaternion=st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
        lambda q: np.linalg.norm(q) > 0.1
    ),
    stamp=st.integers(0, 2**31 * 10**9 - 1),
)
def test_pose_round_trip_property(
    tmp_path_factory: pytest.TempPathFactory, position: list, quaternion: list, stamp: int
) -> None:
    q = np.asarray(quaternion) / np.linalg.norm(quaternion)
    root = tmp_path_factory.mktemp("prop")
    with SequenceWriter(root, _meta()) as writer:
        writer.add_frame(
            split="val",
            camera=7,
            image=_image(0),
            position=position,
            quaternion=q,
            sun_direction=[0.0, 0.0, 1.0],
            stamp_ns=stamp,
        )
    frame = read_sequence(root).frames[0]
    assert np.array_equal(frame.position, position)
    assert np.array_equal(frame.quaternion, q)
    assert frame.stamp_ns == stamp
    np.testing.assert_allclose(frame.T_station_camera, pose_matrix(position, q), atol=1e-12)


def _tree(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in root.rglob("*") if p.is_file()}


def test_identical_inputs_give_identical_files(tmp_path: Path) -> None:
    mesh = tmp_path / "station.glb"
    mesh.write_bytes(b"glTF fake mesh bytes")
    for name in ("a", "b"):
        root = tmp_path / name
        with SequenceWriter(root, _meta(mesh=mesh)) as writer:
            for i in range(3):
                writer.add_frame(
                    split="train",
                    camera=2,
                    image=_image(i),
                    mask=_mask(False),
                    position=[i, 2.0, 3.0],
                    quaternion=[0, 0, 0, 1],
                    sun_direction=[1, 0, 0],
                )
    first, second = _tree(tmp_path / "a"), _tree(tmp_path / "b")
    assert first == second
    assert "meshes/station.glb" in first
    assert read_sequence(tmp_path / "a").meta.mesh == tmp_path / "a" / "meshes" / "station.glb"


# --- writer behaviour --------------------------------------------------------------------


def test_mesh_reference_without_copy(tmp_path: Path) -> None:
    mesh = tmp_path / "models" / "station.glb"
    mesh.parent.mkdir()
    mesh.write_bytes(b"mesh")
    root = tmp_path / "seq"
    with SequenceWriter(root, _meta(mesh=mesh), copy_mesh=False) as writer:
        writer.add_frame(
            split="test",
            camera=0,
            image=_image(0),
            position=[0, 0, 0],
            quaternion=[0, 0, 0, 1],
            sun_direction=[0, 1, 0],
        )
    assert "mesh: ../models/station.glb" in (root / META_FILE).read_text()
    assert not (root / "meshes").exists()
    assert read_sequence(root).meta.mesh.resolve() == mesh.resolve()


def test_referenced_images_are_stored_relative(tmp_path: Path) -> None:
    source = tmp_path / "elsewhere" / "img.png"
    source.parent.mkdir()
    cv2.imwrite(str(source), _image(1))
    root = tmp_path / "seq"
    with SequenceWriter(root, _meta()) as writer:
        writer.add_frame(
            split="test",
            camera=0,
            image=source,
            position=[0, 0, 0],
            quaternion=[0, 0, 0, 1],
            sun_direction=[0, 1, 0],
        )
    rows = list(csv.DictReader(io.StringIO((root / FRAMES_FILE).read_text())))
    # Paths in frames.csv stay inside the folder: the file outside is linked in, relative.
    assert rows[0]["image"] == "test/Camera0/images/img.png"
    assert str((root / rows[0]["image"]).readlink()) == "../../../../elsewhere/img.png"
    sequence = read_sequence(root)
    np.testing.assert_array_equal(sequence.load_image(sequence[0]), _image(1)[..., ::-1])


def test_interrupted_write_leaves_no_sequence(tmp_path: Path) -> None:
    root = tmp_path / "seq"
    with pytest.raises(RuntimeError), SequenceWriter(root, _meta()) as writer:
        writer.add_frame(
            split="test",
            camera=0,
            image=_image(0),
            position=[0, 0, 0],
            quaternion=[0, 0, 0, 1],
            sun_direction=[0, 1, 0],
        )
        raise RuntimeError("renderer crashed")
    assert (root / "test/Camera0/images/000000.png").is_file()
    assert not (root / FRAMES_FILE).exists()
    assert not (root / META_FILE).exists()
    assert not list(root.rglob(".*tmp*"))
    with pytest.raises(SequenceError, match="file not found"):
        read_sequence(root)


def test_writer_refuses_to_overwrite_unless_asked(sequence_root: Path) -> None:
    with pytest.raises(SequenceError, match="already holds a sequence") as info:
        SequenceWriter(sequence_root, _meta())
    assert info.value.file is not None and info.value.file.parent == sequence_root
    writer = SequenceWriter(sequence_root, _meta(), overwrite=True)
    # The stale metadata is gone at once: an interrupted overwrite is not a valid sequence.
    assert not (sequence_root / FRAMES_FILE).exists()
    writer.abort()


def test_writer_with_no_frames_fails(tmp_path: Path) -> None:
    writer = SequenceWriter(tmp_path / "seq", _meta())
    with pytest.raises(SequenceError, match="no frames"):
        writer.close()


def _frame_args(**changes: object) -> dict:
    args = dict(
        split="test",
        camera=0,
        image=_image(0),
        position=[0.0, 0.0, 0.0],
        quaternion=[0.0, 0.0, 0.0, 1.0],
        sun_direction=[0.0, 1.0, 0.0],
    )
    args.update(changes)
    return args


@pytest.mark.parametrize(
    ("changes", "match"),
    [
        ({"split": "validation"}, "split"),
        ({"camera": -1}, "camera"),
        ({"camera": 1.5}, "camera"),
        ({"image": np.zeros((H, W + 1, 3), np.uint8)}, "image must be uint8 of shape"),
        ({"image": np.zeros((H, W, 3), np.float32)}, "image must be uint8"),
        ({"mask": np.full((H, W), 3, np.uint8)}, "mask values"),
        ({"mask": _mask(True), "label": "normal"}, "contradicts the mask"),
        ({"mask": _mask(True)}, "needs the anomaly"),
        ({"anomaly": "drill", "label": "normal"}, "no anomaly name"),
        ({"quaternion": [0, 0, 0, 2]}, "quaternion must be a unit vector"),
        ({"sun_direction": [0, 0, 0.5]}, "sun_direction must be a unit vector"),
        ({"position": [0, np.nan, 0]}, "position must be finite"),
        ({"position": [1e300, 0, 0]}, "'tx': 1e.300 is not physical"),
        ({"quaternion": [1e300, 0, 0, 0]}, "quaternion must be a unit vector"),
        ({"moon": [0, 0, 1e14, 1]}, "'moon_z'.*not physical"),
        ({"sun_strength": -1.0}, "sun_strength"),
        ({"earth": [1, 2, 3, 0]}, "earth radius"),
        ({"name": "a/b"}, "name must be"),
        ({"name": "x.png"}, "name must be"),
        ({"stamp_ns": -5}, "stamp_ns"),
        ({"extra": {"tx": 1}}, "reserved extra column"),
        ({"image": Path("missing.png")}, "file not found"),
    ],
)
def test_writer_rejects_bad_frames(tmp_path: Path, changes: dict, match: str) -> None:
    root = tmp_path / "seq"
    writer = SequenceWriter(root, _meta())
    with pytest.raises(SequenceError, match=match):
        writer.add_frame(**_frame_args(**changes))
    assert not list(root.rglob("*.png")), "a rejected frame must not leave files"


def test_writer_rejects_duplicate_names_and_stamps(tmp_path: Path) -> None:
    writer = SequenceWriter(tmp_path / "seq", _meta())
    writer.add_frame(**_frame_args(name="a", stamp_ns=10))
    with pytest.raises(SequenceError, match="duplicate file"):
        writer.add_frame(**_frame_args(name="a", stamp_ns=20))
    with pytest.raises(SequenceError, match="increase strictly"):
        writer.add_frame(**_frame_args(name="b", stamp_ns=10))
    frame = writer.add_frame(**_frame_args(name="b"))
    assert frame.stamp_ns == 10 + 100_000_000
    writer.close()
    writer.close()  # idempotent
    with pytest.raises(SequenceError, match="closed"):
        writer.add_frame(**_frame_args(name="c"))


# --- reader validation: frames.csv ------------------------------------------------------


def _rows(root: Path) -> tuple[list[str], list[dict[str, str]]]:
    reader = csv.DictReader(io.StringIO((root / FRAMES_FILE).read_text()))
    return list(reader.fieldnames), list(reader)


def _save(root: Path, header: list[str], rows: list[dict[str, str]]) -> None:
    stream = io.StringIO()
    writer = csv.DictWriter(stream, header, lineterminator="\n", extrasaction="ignore")
    writer.writeheader()
    writer.writerows(rows)
    (root / FRAMES_FILE).write_text(stream.getvalue())


def _edit(root: Path, row: int, **cells: str) -> None:
    header, rows = _rows(root)
    rows[row - 1].update(cells)
    _save(root, header, rows)


def _expect(
    root: Path,
    row: int | None,
    column: str | None,
    match: str,
    file: str | Path = FRAMES_FILE,
    **kwargs: object,
) -> SequenceError:
    with pytest.raises(SequenceError, match=match) as info:
        read_sequence(root, **kwargs)
    error = info.value
    expected_file = root / file if isinstance(file, str) else file
    assert error.file == expected_file
    assert error.row == row
    assert error.column == column
    assert str(expected_file) in str(error)
    if row is not None:
        assert f"row {row}" in str(error)
    if column is not None:
        assert repr(column) in str(error)
    return error


CELL_CASES = [
    (2, {"stamp_ns": "abc"}, "stamp_ns", "expected an integer"),
    (2, {"stamp_ns": "1.5e8"}, "stamp_ns", "expected an integer"),
    (1, {"stamp_ns": "-1"}, "stamp_ns", "at least 0"),
    (3, {"stamp_ns": "100000000"}, "stamp_ns", "strictly increasing"),
    (4, {"stamp_ns": str(2**31 * 10**9)}, "stamp_ns", "int32"),
    (2, {"split": "validation"}, "split", "must be one of"),
    (3, {"camera": "-2"}, "camera", "at least 0"),
    (3, {"camera": "one"}, "camera", "expected an integer"),
    (1, {"image": ""}, "image", "path is empty"),
    (1, {"image": "/abs/x.png"}, "image", "relative"),
    (2, {"mask": "C:\\x.png"}, "mask", "relative"),
    (2, {"label": "weird"}, "label", "must be one of"),
    (1, {"anomaly": "drill"}, "anomaly", "empty for a normal frame"),
    (2, {"anomaly": ""}, "anomaly", "object type name"),
    (2, {"tx": "nan"}, "tx", "finite"),
    (2, {"tz": "inf"}, "tz", "finite"),
    (3, {"qx": "zero"}, "qx", "expected a number"),
    (3, {"qw": ""}, "qw", "expected a number"),
    (1, {"qx": "0.5", "qy": "0.5", "qz": "0.5", "qw": "0.6"}, "qx..qw", "not a unit vector"),
    (4, {"sun_x": "1", "sun_y": "1", "sun_z": "0"}, "sun_x..sun_z", "not a unit vector"),
    (2, {"sun_strength": "-0.5"}, "sun_strength", "negative"),
    (2, {"sun_strength": "NaN"}, "sun_strength", "finite"),
    (1, {"earth_y": ""}, "earth_y", "other columns of this body"),
    (1, {"moon_r": "0"}, "moon_r", "radius must be positive"),
    (2, {"moon_x": "1e400"}, "moon_x", "finite"),
    (2, {"tx": "1e300"}, "tx", "not physical"),
    (3, {"ty": "-1000000.5"}, "ty", "not physical"),
    (1, {"earth_x": "2e13"}, "earth_x", "not physical"),
    (2, {"moon_r": "1e300"}, "moon_r", "not physical"),
    (2, {"sun_strength": "1e300"}, "sun_strength", "not physical"),
]


@pytest.mark.parametrize(("row", "cells", "column", "match"), CELL_CASES)
def test_reader_cell_errors_name_file_row_column(
    sequence_root: Path, row: int, cells: dict, column: str, match: str
) -> None:
    _edit(sequence_root, row, **cells)
    error = _expect(sequence_root, row, column, match)
    assert error.line == row + 1


@pytest.mark.parametrize(
    "cells",
    [{"tx": "1e300"}, {"qx": "1e300"}, {"sun_x": "1e300"}, {"earth_r": "1e300"}],
    ids=["position", "quaternion", "sun", "body"],
)
def test_reader_refuses_huge_values_without_numpy_warnings(
    sequence_root: Path, cells: dict
) -> None:
    _edit(sequence_root, 2, **cells)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # an overflow warning fails the test
        with pytest.raises(SequenceError, match="row 2"):
            read_sequence(sequence_root)


def test_reader_accepts_values_at_the_physical_bounds(sequence_root: Path) -> None:
    _edit(sequence_root, 1, tx="-1000000", earth_x="1e13", earth_r="6e12", sun_strength="1000")
    frame = read_sequence(sequence_root)[0]
    assert frame.position[0] == -1e6 and frame.earth[0] == 1e13 and frame.sun_strength == 1e3


def test_reader_missing_column(sequence_root: Path) -> None:
    header, rows = _rows(sequence_root)
    header.remove("sun_strength")
    _save(sequence_root, header, rows)
    error = _expect(sequence_root, None, "sun_strength", "missing column")
    assert error.line == 1


def test_reader_duplicate_column_and_field_count(sequence_root: Path) -> None:
    text = (sequence_root / FRAMES_FILE).read_text().splitlines()
    (sequence_root / FRAMES_FILE).write_text("\n".join([text[0] + ",tx", *text[1:]]) + "\n")
    _expect(sequence_root, None, "tx", "duplicate column")
    (sequence_root / FRAMES_FILE).write_text("\n".join([text[0], text[1], text[2] + ",9"]) + "\n")
    error = _expect(sequence_root, 2, None, "fields, the header has")
    assert error.line == 3


def test_reader_extra_columns_are_kept_not_required(sequence_root: Path) -> None:
    header, rows = _rows(sequence_root)
    _save(sequence_root, [*header, "exposure"], [{**r, "exposure": "0.5"} for r in rows])
    sequence = read_sequence(sequence_root)
    assert sequence.frames[0].extra["exposure"] == "0.5"
    assert set(COLUMNS) <= set(header)


def test_reader_blank_lines_keep_row_and_line_numbers(sequence_root: Path) -> None:
    lines = (sequence_root / FRAMES_FILE).read_text().splitlines()
    lines[2] = lines[2].replace(",drill,", ",,")
    (sequence_root / FRAMES_FILE).write_text("\n".join([lines[0], lines[1], "", *lines[2:]]))
    error = _expect(sequence_root, 2, "anomaly", "object type name")
    assert error.line == 4


def test_reader_empty_and_header_only_and_missing(sequence_root: Path) -> None:
    header = (sequence_root / FRAMES_FILE).read_text().splitlines()[0]
    (sequence_root / FRAMES_FILE).write_text(header + "\n")
    _expect(sequence_root, None, None, "no frames")
    (sequence_root / FRAMES_FILE).write_text("")
    _expect(sequence_root, None, None, "empty file")
    (sequence_root / FRAMES_FILE).unlink()
    _expect(sequence_root, None, None, "file not found")
    with pytest.raises(SequenceError, match="sequence folder not found"):
        read_sequence(sequence_root / "nope")


# --- reader validation: image files ------------------------------------------------------


def test_reader_missing_image(sequence_root: Path) -> None:
    path = sequence_root / "test/Camera1/images/000001.png"
    path.unlink()
    _expect(sequence_root, 2, "image", "file not found", file=path)
    assert len(read_sequence(sequence_root, check_images=False)) == 4


def test_reader_missing_mask_and_reference(sequence_root: Path) -> None:
    reference = sequence_root / "test/Camera0/references/000000.png"
    reference.unlink()
    _expect(sequence_root, 1, "reference", "file not found", file=reference)
    _write(sequence_root, overwrite=True)
    mask = sequence_root / "test/Camera0/masks/000002.png"
    mask.unlink()
    _expect(sequence_root, 3, "mask", "file not found", file=mask)


def test_reader_image_size_differs_from_yaml(sequence_root: Path) -> None:
    path = sequence_root / "test/Camera0/images/000002.png"
    cv2.imwrite(str(path), np.zeros((H + 2, W, 3), np.uint8))
    _expect(sequence_root, 3, "image", "size 16x14 differs", file=path)
    sequence = read_sequence(sequence_root, check_images=False)
    with pytest.raises(SequenceError, match="size 16x14 differs") as info:
        sequence.load_image(sequence[2])
    assert (info.value.file, info.value.row, info.value.column) == (path, 3, "image")


def test_reader_mask_layout_and_non_png(sequence_root: Path) -> None:
    mask = sequence_root / "test/Camera1/masks/000001.png"
    cv2.imwrite(str(mask), np.zeros((H, W, 3), np.uint8))
    _expect(sequence_root, 2, "mask", "8-bit single channel", file=mask)
    cv2.imwrite(str(mask), np.zeros((H, W), np.uint16))
    _expect(sequence_root, 2, "mask", "16-bit", file=mask)
    mask.write_bytes(b"GIF89a not a png at all....")
    _expect(sequence_root, 2, "mask", "not a PNG", file=mask)
    image = sequence_root / "test/Camera0/images/000000.png"
    cv2.imwrite(str(image), np.zeros((H, W), np.uint8))
    _expect(sequence_root, 1, "image", "8-bit RGB", file=image)


def test_mask_values_checked_on_load_and_in_validation(sequence_root: Path) -> None:
    path = sequence_root / "test/Camera1/masks/000001.png"
    bad = _mask(True)
    bad[0, 0] = 7
    cv2.imwrite(str(path), bad)
    sequence = read_sequence(sequence_root)  # headers only: passes
    with pytest.raises(SequenceError, match=r"0, 1 or 2; found \[7\]") as info:
        sequence.load_mask(sequence[1])
    assert (info.value.file, info.value.row, info.value.column) == (path, 2, "mask")
    with pytest.raises(SequenceError, match="found") as info:
        validate_sequence(sequence_root)
    assert (info.value.file, info.value.row, info.value.column) == (path, 2, "mask")


@pytest.mark.parametrize(("row", "mask"), [(1, _mask(True)), (2, _mask(False))])
def test_label_inconsistent_with_mask(sequence_root: Path, row: int, mask: np.ndarray) -> None:
    sequence = read_sequence(sequence_root)
    cv2.imwrite(str(sequence[row - 1].mask), mask)
    with pytest.raises(SequenceError, match="contradicts the mask") as info:
        validate_sequence(sequence_root)
    error = info.value
    assert (error.file, error.row, error.column) == (sequence_root / FRAMES_FILE, row, "label")


def test_corrupt_image_data_found_by_full_validation(sequence_root: Path) -> None:
    path = sequence_root / "test/Camera0/images/000000.png"
    data = path.read_bytes()
    path.write_bytes(data[:40])  # header intact, pixel data gone
    validate_sequence(sequence_root)
    with pytest.raises(SequenceError, match="cannot decode") as info:
        validate_sequence(sequence_root, decode_images=True)
    assert (info.value.file, info.value.row, info.value.column) == (path, 1, "image")


# --- reader validation: sequence.yaml ----------------------------------------------------


YAML_CASES = [
    ("format: allo-sequence/1", "format: allo-sequence/3", "format", 1, "unsupported format"),
    ("  fx: 20.0", "  fx: -20.0", "camera.fx", 9, "positive"),
    ("  fy: 20.0", "  fy: fast", "camera.fy", 10, "must be a number"),
    ("  width: 16", "  width: 16.5", "camera.width", 7, "whole number"),
    ("  cy: 6.0", "", "camera.cy", 6, "missing key"),
    ("rate_hz: 10.0", "rate_hz: 0", "rate_hz", 13, "positive"),
    ("rate_hz: 10.0", "rate_hz: .nan", "rate_hz", 13, "finite"),
    ("rate_hz: 10.0", "", "rate_hz", None, "missing key"),
    ("mesh: null", "mesh: meshes/none.glb", "mesh", 5, "mesh file not found"),
    ("mesh: null", "mesh: /abs/station.glb", "mesh", 5, "relative"),
    ("station_frame: station", "station_frame: my station", "station_frame", 3, "TF frame"),
]


@pytest.mark.parametrize(("old", "new", "key", "line", "match"), YAML_CASES)
def test_yaml_errors_name_file_line_key(
    sequence_root: Path, old: str, new: str, key: str, line: int | None, match: str
) -> None:
    path = sequence_root / META_FILE
    text = path.read_text()
    assert old + "\n" in text
    path.write_text(text.replace(old + "\n", new + "\n" if new else ""))
    error = _expect(sequence_root, None, key, match, file=META_FILE)
    assert error.line == line
    if line is not None:
        assert f"line {line}" in str(error)


def test_yaml_syntax_error_and_missing_file(sequence_root: Path) -> None:
    path = sequence_root / META_FILE
    path.write_text("format: allo-sequence/1\ncamera: [1, 2\n")
    error = _expect(sequence_root, None, None, "invalid YAML", file=META_FILE)
    assert error.line is not None
    path.write_text("- a list\n")
    _expect(sequence_root, None, None, "mapping", file=META_FILE)
    path.unlink()
    _expect(sequence_root, None, None, "file not found", file=META_FILE)


def test_yaml_written_layout(sequence_root: Path) -> None:
    lines = (sequence_root / META_FILE).read_text().splitlines()
    assert lines[0] == "format: allo-sequence/1"
    assert lines[4] == "mesh: null"
    assert lines[8] == "  fx: 20.0"


def test_meta_validation() -> None:
    with pytest.raises(SequenceError, match="positive") as info:
        SequenceMeta(name="x", camera=CAMERA, rate_hz=0)
    assert info.value.column == "rate_hz"
    with pytest.raises(SequenceError, match="CameraIntrinsics"):
        SequenceMeta(name="x", camera=(16, 12))
    with pytest.raises(SequenceError, match="unsupported"):
        SequenceMeta(name="x", camera=CAMERA, format="allo-sequence/3")
