"""What ``frames.csv`` may say about files: a spreadsheet's byte-order mark is accepted,
paths stay inside the sequence folder, and a frame's camera is the ``Camera<N>`` folder its
image lies in."""

from __future__ import annotations

import csv
import io
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.sequence import (
    FRAMES_FILE,
    SequenceError,
    SequenceMeta,
    SequenceWriter,
    read_sequence,
)

CAMERA = CameraIntrinsics(width=16, height=12, fx=20.0, fy=20.0, cx=8.0, cy=6.0)


def _image(seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (12, 16, 3), dtype=np.uint8)


def _frame(**changes: object) -> dict:
    frame = {
        "split": "test",
        "camera": 0,
        "image": _image(0),
        "position": [0.0, 0.0, 0.0],
        "quaternion": [0.0, 0.0, 0.0, 1.0],
        "sun_direction": [0.0, 1.0, 0.0],
    }
    frame.update(changes)
    return frame


def _sequence(root: Path, frames: int = 2) -> Path:
    with SequenceWriter(root, SequenceMeta(name="paths", camera=CAMERA, rate_hz=10.0)) as writer:
        for index in range(frames):
            writer.add_frame(**_frame(camera=index % 2, image=_image(index)))
    return root


def _rows(root: Path) -> tuple[list[str], list[dict[str, str]]]:
    reader = csv.DictReader(io.StringIO((root / FRAMES_FILE).read_text()))
    return list(reader.fieldnames or []), list(reader)


def _save(root: Path, header: list[str], rows: list[dict[str, str]], bom: bool = False) -> None:
    stream = io.StringIO()
    writer = csv.DictWriter(stream, header, lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    (root / FRAMES_FILE).write_text(stream.getvalue(), encoding="utf-8-sig" if bom else "utf-8")


def test_frames_csv_with_a_byte_order_mark_is_read(tmp_path):
    root = _sequence(tmp_path / "seq")
    plain = read_sequence(root)
    header, rows = _rows(root)
    _save(root, header, rows, bom=True)
    assert (root / FRAMES_FILE).read_bytes().startswith(b"\xef\xbb\xbfstamp_ns,")
    with_bom = read_sequence(root, check_images=True)
    assert [f.stamp_ns for f in with_bom.frames] == [f.stamp_ns for f in plain.frames]


@pytest.mark.parametrize(
    "path",
    ["../../x.png", "../seq2/test/Camera0/images/x.png", "test/../../x.png", "/tmp/x.png"],
)
def test_an_image_path_that_leaves_the_sequence_is_refused(tmp_path, path):
    root = _sequence(tmp_path / "seq")
    header, rows = _rows(root)
    rows[1]["image"] = path
    _save(root, header, rows)
    with pytest.raises(SequenceError) as info:
        read_sequence(root)
    assert (info.value.row, info.value.column) == (2, "image")
    assert path in str(info.value) and FRAMES_FILE in str(info.value)


@pytest.mark.parametrize("column", ["image", "mask"])
def test_a_path_with_a_nul_character_is_refused_with_its_line(tmp_path, column):
    root = _sequence(tmp_path / "seq")
    header, rows = _rows(root)
    rows[1][column] = "test/Camera1/images/x@.png"
    _save(root, header, rows)
    table = root / FRAMES_FILE
    table.write_bytes(table.read_bytes().replace(b"x@.png", b"x\x00.png"))  # csv cannot
    with pytest.raises(SequenceError) as info:
        read_sequence(root, check_images=True)
    assert info.value.line == 3  # the header, then data rows 1 and 2
    assert "NUL" in str(info.value) and FRAMES_FILE in str(info.value)


def test_a_path_with_dots_that_stays_inside_is_accepted(tmp_path):
    root = _sequence(tmp_path / "seq")
    header, rows = _rows(root)
    rows[0]["image"] = "test/Camera0/../Camera0/images/" + Path(rows[0]["image"]).name
    _save(root, header, rows)
    assert len(read_sequence(root, check_images=True)) == 2


def test_a_camera_other_than_the_image_folder_is_refused(tmp_path):
    root = _sequence(tmp_path / "seq")
    header, rows = _rows(root)
    assert rows[0]["image"].startswith("test/Camera0/")
    rows[0]["camera"] = "7"
    _save(root, header, rows)
    with pytest.raises(SequenceError, match="Camera0") as info:
        read_sequence(root)
    assert (info.value.row, info.value.column) == (1, "camera")
    assert "7" in str(info.value)


def test_a_file_outside_the_folder_is_referenced_by_a_link_inside(tmp_path):
    source = tmp_path / "elsewhere" / "img.png"
    source.parent.mkdir()
    cv2.imwrite(str(source), _image(3))
    root = tmp_path / "seq"
    with SequenceWriter(root, SequenceMeta(name="ref", camera=CAMERA, rate_hz=10.0)) as writer:
        writer.add_frame(**_frame(image=source))
    _, rows = _rows(root)
    assert rows[0]["image"] == "test/Camera0/images/img.png"
    link = root / rows[0]["image"]
    assert link.is_symlink() and link.resolve() == source.resolve()
    sequence = read_sequence(root, check_images=True)
    np.testing.assert_array_equal(sequence.load_image(sequence[0]), _image(3)[..., ::-1])
