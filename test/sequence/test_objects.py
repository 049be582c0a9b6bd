"""Format version 2: the objects table, instance masks, and version 1 still read."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.sequence import (
    FORMAT_V1,
    FORMAT_V2,
    GroundTruthObject,
    SequenceError,
    SequenceMeta,
    SequenceWriter,
    read_sequence,
    validate_sequence,
)

CAMERA = CameraIntrinsics(width=16, height=12, fx=20.0, fy=20.0, cx=8.0, cy=6.0)
H, W = CAMERA.height, CAMERA.width
START_NS = 1_000_000_000


def _objects() -> list[GroundTruthObject]:
    return [
        GroundTruthObject(
            id=3,
            type="cubesat_1u",
            stamp_ns=START_NS,
            position=(1.0, 2.0, 3.0),
            velocity=(0.0, 0.0, 0.0),
            quaternion=(0.0, 0.0, 0.0, 1.0),
            size=(0.1, 0.1, 0.1),
            extra={"placement": "space"},
        ),
        GroundTruthObject(
            id=700,
            type="drill",
            stamp_ns=START_NS + 50_000_000,
            position=(-4.0, 0.5, 2.25),
            velocity=(0.03, -0.04, 0.0),
            quaternion=(0.0, 0.6, 0.0, 0.8),
            size=(0.3, 0.12, 0.08),
        ),
    ]


def _frame(index: int) -> dict:
    mask = np.ones((H, W), np.uint8)
    instances = np.zeros((H, W), np.uint16)
    anomaly = ""
    if index % 2:
        mask[2:4, 2:5] = 2
        instances[2:4, 2:5] = 3
        mask[6:9, 10:12] = 2
        instances[6:9, 10:12] = 700
        anomaly = "drill"
    image = np.full((H, W, 3), 40 * index, np.uint8)
    return {
        "split": "test",
        "camera": 0,
        "image": image,
        "mask": mask,
        "instances": instances,
        "anomaly": anomaly,
        "position": (0.0, 0.0, -10.0 - index),
        "quaternion": (0.0, 0.0, 0.0, 1.0),
        "sun_direction": (1.0, 0.0, 0.0),
    }


def _write_v2(root: Path, frames: int = 3) -> None:
    meta = SequenceMeta(name="v2", camera=CAMERA, rate_hz=10.0)
    with SequenceWriter(root, meta, objects=_objects(), start_ns=START_NS) as writer:
        for index in range(frames):
            writer.add_frame(**_frame(index))


def test_v2_round_trip_objects_and_instances(tmp_path: Path) -> None:
    _write_v2(tmp_path / "seq")
    sequence = validate_sequence(tmp_path / "seq")
    assert sequence.meta.format == FORMAT_V2
    assert sequence.has_objects
    written = _objects()
    assert [o.id for o in sequence.objects] == [o.id for o in written]
    for read, original in zip(sequence.objects, written, strict=True):
        assert read.type == original.type
        assert read.stamp_ns == original.stamp_ns
        for name in ("position", "velocity", "quaternion", "size"):
            np.testing.assert_array_equal(getattr(read, name), getattr(original, name))
    assert dict(sequence.objects[0].extra) == {"placement": "space"}
    assert dict(sequence.objects[1].extra) == {"placement": ""}
    for frame in sequence:
        expected = _frame(frame.index)["instances"]
        instances = sequence.load_instances(frame, sequence.load_mask(frame))
        assert instances.dtype == np.uint16
        np.testing.assert_array_equal(instances, expected)
    # The file itself is a 16-bit one-channel PNG that OpenCV decodes to the same ids.
    decoded = cv2.imread(str(sequence[1].instances), cv2.IMREAD_UNCHANGED)
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, _frame(1)["instances"])


def test_drifting_object_follows_its_velocity() -> None:
    drifting = _objects()[1]
    for seconds in (-2.0, 0.0, 0.1, 7.5):
        stamp = drifting.stamp_ns + round(seconds * 1e9)
        expected = np.array([-4.0 + 0.03 * seconds, 0.5 - 0.04 * seconds, 2.25])
        np.testing.assert_allclose(drifting.position_at(stamp), expected, atol=1e-12)
        np.testing.assert_allclose(drifting.pose_at(stamp)[:3, 3], expected, atol=1e-12)
    assert drifting.speed == pytest.approx(0.05)


def test_writer_without_objects_writes_version_1(tmp_path: Path) -> None:
    meta = SequenceMeta(name="v1", camera=CAMERA)
    with SequenceWriter(tmp_path / "seq", meta) as writer:
        frame = _frame(0)
        del frame["instances"]
        writer.add_frame(**frame)
    text = (tmp_path / "seq" / "sequence.yaml").read_text()
    assert "format: allo-sequence/1" in text
    header = (tmp_path / "seq" / "frames.csv").read_text().splitlines()[0]
    assert "instances" not in header.split(",")
    assert not (tmp_path / "seq" / "objects.csv").exists()
    with SequenceWriter(tmp_path / "other", meta) as writer:
        with pytest.raises(SequenceError, match="version 2"):
            writer.add_frame(**_frame(1))
        writer.add_frame(**{k: v for k, v in _frame(0).items() if k != "instances"})


def test_empty_objects_table_is_version_2(tmp_path: Path) -> None:
    meta = SequenceMeta(name="normal", camera=CAMERA)
    with SequenceWriter(tmp_path / "seq", meta, objects=()) as writer:
        writer.add_frame(**_frame(0))
    sequence = validate_sequence(tmp_path / "seq")
    assert sequence.meta.format == FORMAT_V2
    assert sequence.objects == ()
    assert (tmp_path / "seq" / "objects.csv").read_text().startswith("id,type,stamp_ns,x,")


# A version-1 sequence as the version-1 code wrote it: the column list and files are spelled
# out here, not taken from the package, so a change to the reader cannot move the fixture.
V1_HEADER = (
    "stamp_ns,split,camera,image,mask,reference,label,anomaly,tx,ty,tz,qx,qy,qz,qw,"
    "sun_x,sun_y,sun_z,sun_strength,earth_x,earth_y,earth_z,earth_r,moon_x,moon_y,moon_z,"
    "moon_r,day"
)
V1_ROWS = (
    "100,test,0,test/Camera0/images/a.png,test/Camera0/masks/a.png,,normal,,1.0,2.0,3.0,"
    "0.0,0.0,0.0,1.0,0.0,0.0,1.0,1.0,,,,,,,,,4",
    "200,test,0,test/Camera0/images/b.png,test/Camera0/masks/b.png,,anomalous,drill,1.5,2.0,"
    "3.0,0.0,0.0,0.0,1.0,0.0,0.0,1.0,0.5,10.0,0.0,0.0,2.0,,,,,5",
)


def _write_v1_fixture(root: Path) -> None:
    (root / "test" / "Camera0" / "images").mkdir(parents=True)
    (root / "test" / "Camera0" / "masks").mkdir(parents=True)
    (root / "sequence.yaml").write_text(
        "format: allo-sequence/1\nname: old\ncamera:\n  width: 16\n  height: 12\n"
        "  fx: 20.0\n  fy: 20.0\n  cx: 8.0\n  cy: 6.0\nrate_hz: 10\n"
    )
    (root / "frames.csv").write_text("\n".join((V1_HEADER, *V1_ROWS)) + "\n")
    for name, anomalous in (("a", False), ("b", True)):
        mask = np.ones((H, W), np.uint8)
        if anomalous:
            mask[3:5, 3:5] = 2
        cv2.imwrite(str(root / f"test/Camera0/masks/{name}.png"), mask)
        cv2.imwrite(str(root / f"test/Camera0/images/{name}.png"), np.zeros((H, W, 3), np.uint8))


def test_version_1_fixture_still_read(tmp_path: Path) -> None:
    _write_v1_fixture(tmp_path)
    sequence = validate_sequence(tmp_path)
    assert sequence.meta.format == FORMAT_V1
    assert not sequence.has_objects
    assert sequence.objects == ()
    assert [f.stamp_ns for f in sequence] == [100, 200]
    assert [f.instances for f in sequence] == [None, None]
    assert sequence.load_instances(sequence[1]) is None
    assert sequence[1].anomaly == "drill"
    assert dict(sequence[1].extra) == {"day": "5"}
    np.testing.assert_array_equal(sequence[1].earth, [10.0, 0.0, 0.0, 2.0])


def test_version_1_column_named_instances_is_an_extra_column(tmp_path: Path) -> None:
    _write_v1_fixture(tmp_path)
    path = tmp_path / "frames.csv"
    lines = path.read_text().splitlines()
    lines = [lines[0] + ",instances", *(line + ",whatever" for line in lines[1:])]
    path.write_text("\n".join(lines) + "\n")
    sequence = read_sequence(tmp_path)
    assert sequence[0].instances is None
    assert sequence[0].extra["instances"] == "whatever"


def _rewrite_objects(root: Path, row: int, column: str, value: str) -> None:
    path = root / "objects.csv"
    records = list(csv.DictReader(io.StringIO(path.read_text())))
    records[row - 1][column] = value
    stream = io.StringIO()
    writer = csv.DictWriter(stream, fieldnames=list(records[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(records)
    path.write_text(stream.getvalue())


@pytest.mark.parametrize(
    ("row", "column", "value", "reason"),
    [
        (1, "id", "0", "must be in 1..65535"),
        (2, "id", "65536", "must be in 1..65535"),
        (2, "id", "3", "duplicate id 3"),
        (1, "id", "two", "expected an integer"),
        (2, "type", "power drill", "type name"),
        (1, "stamp_ns", "-5", "must be in 0.."),
        (2, "x", "abc", "expected a number"),
        (1, "vy", "inf", "must be finite"),
        (2, "vz", "1e9", "not physical"),
        (1, "qw", "0.5", "not a unit quaternion"),
        (2, "size_y", "0", "must be positive"),
        (1, "size_x", "-0.1", "must be positive"),
    ],
)
def test_bad_object_rows_name_row_and_column(
    tmp_path: Path, row: int, column: str, value: str, reason: str
) -> None:
    _write_v2(tmp_path, frames=1)
    _rewrite_objects(tmp_path, row, column, value)
    with pytest.raises(SequenceError, match=reason) as caught:
        read_sequence(tmp_path)
    error = caught.value
    assert error.file == tmp_path / "objects.csv"
    assert error.row == row
    expected_column = "qx..qw" if column == "qw" else column
    assert error.column == expected_column
    assert f"row {row}" in str(error) and "objects.csv" in str(error)


def test_missing_objects_column_and_file(tmp_path: Path) -> None:
    _write_v2(tmp_path, frames=1)
    path = tmp_path / "objects.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    drop = header.index("vy")
    path.write_text(
        "\n".join(",".join(c for i, c in enumerate(line.split(",")) if i != drop) for line in lines)
    )
    with pytest.raises(SequenceError, match="missing column") as caught:
        read_sequence(tmp_path)
    assert caught.value.column == "vy"
    path.unlink()
    with pytest.raises(SequenceError, match="file not found") as caught:
        read_sequence(tmp_path)
    assert caught.value.file == path


def test_instance_ids_not_in_table_refused(tmp_path: Path) -> None:
    _write_v2(tmp_path)
    sequence = read_sequence(tmp_path)
    frame = sequence[1]
    instances = _frame(1)["instances"]
    instances[instances == 700] = 701
    cv2.imwrite(str(frame.instances), instances)
    with pytest.raises(SequenceError, match=r"ids \[701\] are not in objects.csv") as caught:
        validate_sequence(tmp_path)
    assert caught.value.row == 2 and caught.value.column == "instances"


def test_instances_must_match_the_mask(tmp_path: Path) -> None:
    _write_v2(tmp_path)
    frame = read_sequence(tmp_path)[1]
    instances = _frame(1)["instances"]
    instances[0, 0] = 3  # a station pixel claimed by an object
    cv2.imwrite(str(frame.instances), instances)
    with pytest.raises(SequenceError, match="1 pixels differ") as caught:
        validate_sequence(tmp_path)
    assert caught.value.row == 2 and caught.value.column == "instances"


def test_instances_must_be_16_bit(tmp_path: Path) -> None:
    _write_v2(tmp_path)
    frame = read_sequence(tmp_path)[1]
    cv2.imwrite(str(frame.instances), np.zeros((H, W), np.uint8))
    with pytest.raises(SequenceError, match="16-bit single channel") as caught:
        read_sequence(tmp_path)
    assert caught.value.column == "instances"


def test_writer_refuses_bad_instances(tmp_path: Path) -> None:
    meta = SequenceMeta(name="v2", camera=CAMERA)
    with SequenceWriter(tmp_path / "seq", meta, objects=_objects()) as writer:
        frame = _frame(1)
        frame["instances"] = frame["instances"].astype(np.uint8)
        with pytest.raises(SequenceError, match="uint16"):
            writer.add_frame(**frame)
        frame = _frame(1)
        frame["instances"][frame["instances"] == 3] = 4
        with pytest.raises(SequenceError, match=r"ids \[4\] are not in the objects table"):
            writer.add_frame(**frame)
        frame = _frame(1)
        frame["instances"][0, 0] = 3
        with pytest.raises(SequenceError, match="differ from the mask"):
            writer.add_frame(**frame)
        writer.add_frame(**_frame(1))
    duplicate = [*_objects(), _objects()[0]]
    with pytest.raises(SequenceError, match="duplicate id 3") as caught:
        SequenceWriter(tmp_path / "dup", meta, objects=duplicate)
    assert caught.value.row == 3


@pytest.mark.parametrize("table", ["frames.csv", "objects.csv"])
def test_both_tables_report_structure_faults_alike(tmp_path: Path, table: str) -> None:
    _write_v2(tmp_path, frames=2)
    path = tmp_path / table
    header, first, second = path.read_text().splitlines()
    # A blank line is no row but is a line: row 2, one field too many, stands on line 4.
    path.write_text("\n".join([header, first, "", second + ",9"]) + "\n")
    with pytest.raises(SequenceError, match="fields, the header has") as caught:
        read_sequence(tmp_path)
    assert (caught.value.file, caught.value.row, caught.value.line) == (path, 2, 4)
    # Two columns repeated, the second one first: the first repeat read is the one named.
    columns = header.split(",")
    path.write_text(",".join([*columns, columns[1], columns[0]]) + "\n")
    with pytest.raises(SequenceError, match="duplicate column") as caught:
        read_sequence(tmp_path)
    assert (caught.value.file, caught.value.line, caught.value.column) == (path, 1, columns[1])
