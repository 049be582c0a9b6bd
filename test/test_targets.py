"""What a command may replace, recognised by content: a folder is a sequence, a bag or a
report only when everything in it is; anything else in it is named in the refusal."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from allo_mrad_ros.camera import ALLO_INTRINSICS
from allo_mrad_ros.sequence import SequenceMeta, SequenceWriter
from allo_mrad_ros.targets import (
    ABLATION_REPORT,
    BAG,
    EVALUATION_REPORT,
    SEQUENCE,
    TargetError,
    check_target,
)

CAMERA = ALLO_INTRINSICS.scaled(1.0 / 48.0)
POSE = {"position": [-30.0, 0.0, 0.0], "quaternion": [0, 0, 0, 1], "sun_direction": [0, 0, 1]}


def _sequence(root: Path, *, frames: int = 2, in_place: bool = False) -> Path:
    meta = SequenceMeta(name="t", camera=CAMERA)
    with SequenceWriter(root, meta, overwrite=in_place, images_in_place=in_place) as writer:
        for index in range(frames):
            image = np.full((CAMERA.height, CAMERA.width, 3), index, np.uint8)
            mask = np.ones((CAMERA.height, CAMERA.width), np.uint8)
            writer.add_frame(split="test", camera=0, image=image, mask=mask, **POSE)
    return root


def _refusal(out: Path, kind, *, overwrite: bool = True) -> str:
    with pytest.raises(TargetError) as caught:
        check_target(out, kind, overwrite=overwrite)
    message = str(caught.value)
    assert "\n" not in message and str(out) in message
    return message


def test_a_sequence_and_nothing_else_is_replaced(tmp_path):
    out = _sequence(tmp_path / "seq")
    check_target(out, SEQUENCE, overwrite=True)
    assert "--overwrite" in _refusal(out, SEQUENCE, overwrite=False)


@pytest.mark.parametrize(
    "extra, named",
    [
        ("train/Camera0/images/1_normal_1.png", "train/"),  # an ALLO split beside it
        ("test/Camera0/images/notes.txt", "test/Camera0/images/notes.txt"),
        ("test/Camera0/images/000009.png", "test/Camera0/images/000009.png"),  # not in frames
        ("thesis.tex", "thesis.tex"),
        ("docs/", "docs/"),  # an empty folder the layout has not
    ],
)
def test_a_sequence_with_anything_else_is_refused_naming_it(tmp_path, extra, named):
    out = _sequence(tmp_path / "seq")
    path = out / extra
    if extra.endswith("/"):
        path.mkdir()
    else:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(b"mine")
    for overwrite in (False, True):
        message = _refusal(out, SEQUENCE, overwrite=overwrite)
        assert f"not a sequence ({named})" in message


def test_the_layout_s_empty_folders_are_a_sequence_s(tmp_path):
    out = _sequence(tmp_path / "seq")
    (out / "test" / "Camera0" / "references").mkdir()
    (out / "val").mkdir()
    check_target(out, SEQUENCE, overwrite=True)


def test_files_named_like_a_sequence_s_but_not_one_are_refused(tmp_path):
    out = tmp_path / "seq"
    out.mkdir()
    (out / "sequence.yaml").write_text("hello: 1\n")
    assert "sequence.yaml: not a sequence's" in _refusal(out, SEQUENCE)
    (out / "sequence.yaml").unlink()
    (out / "frames.csv").write_text("a,b\n1,2\n")
    assert "frames.csv: not a sequence's" in _refusal(out, SEQUENCE)


def test_a_sequence_importing_another_dataset_in_place_is_never_replaced(tmp_path):
    """The images of an in-place import are the download's own: refused even with
    --overwrite, although every file in the folder is named by the sequence."""
    out = tmp_path / "ALLO"
    _sequence(out)
    check_target(out, SEQUENCE, overwrite=True)  # written by the command: replaceable
    _sequence(out, in_place=True)
    assert "imported in place" in _refusal(out, SEQUENCE)


def test_a_bag_is_recognised_by_its_metadata_not_its_name(tmp_path):
    out = tmp_path / "bag"
    out.mkdir()
    (out / "metadata.yaml").write_text("hello: 1\n")
    assert "metadata.yaml: not rosbag2 metadata" in _refusal(out, BAG)
    (out / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n"
        "  relative_file_paths:\n  - bag_0.mcap\n"
    )
    (out / "bag_0.mcap").write_bytes(b"x")
    check_target(out, BAG, overwrite=True)
    (out / "other.mcap").write_bytes(b"x")  # a storage file the metadata does not list
    assert "not a bag (other.mcap)" in _refusal(out, BAG)


def test_a_sqlite_bag_keeps_its_journal_files(tmp_path):
    out = tmp_path / "bag"
    out.mkdir()
    (out / "metadata.yaml").write_text(
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: sqlite3\n"
        "  relative_file_paths: [bag_0.db3]\n"
    )
    for name in ("bag_0.db3", "bag_0.db3-wal", "bag_0.db3-shm"):
        (out / name).write_bytes(b"x")
    check_target(out, BAG, overwrite=True)


@pytest.mark.parametrize(
    "kind, main, other",
    [
        (EVALUATION_REPORT, "metrics.json", "metrics.md"),
        (ABLATION_REPORT, "ablation.json", "ablation.md"),
    ],
)
def test_a_report_is_recognised_by_its_content(tmp_path, kind, main, other):
    out = tmp_path / "report"
    out.mkdir()
    (out / main).write_text("[1, 2]\n")
    assert f"{main}: not a report's" in _refusal(out, kind)
    (out / main).write_text(json.dumps({"methods": {}}))
    (out / other).write_text("# report\n")
    check_target(out, kind, overwrite=True)
    (out / "keep.txt").write_text("mine")
    assert "not a report (keep.txt)" in _refusal(out, kind)
