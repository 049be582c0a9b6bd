"""allo-bag with bad input, signals and failing disks: one clear line, nothing half-written,
nothing silently wrong."""

from __future__ import annotations

import errno
import importlib.util
import os
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbag_fixtures import CAMERA, write_tiny_sequence

from allo_mrad_ros.sequence import Sequence
from allo_mrad_ros.staging import (
    StagingError,
    remove_stale,
    signals_as_interrupt,
    staged_folder,
)
from rosbag_tools import writer as writer_module
from rosbag_tools.cli import main
from rosbag_tools.writer import BagWriteError, write_bag


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return write_tiny_sequence(tmp_path_factory.mktemp("seq") / "seq", train=1)


@pytest.fixture(scope="module")
def bag(sequence, tmp_path_factory):
    out = tmp_path_factory.mktemp("bag") / "bag"
    write_bag(sequence, out)
    return out


def allo_bag(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "rosbag_tools", *arguments],
        capture_output=True,
        text=True,
        timeout=600,
    )


def one_clean_line(done: subprocess.CompletedProcess, expected: str, status: int = 1) -> None:
    assert done.returncode == status, done.stderr
    assert "Traceback" not in done.stderr
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0], done.stderr


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def test_write_under_a_file_is_one_clear_error(sequence, tmp_path):
    (tmp_path / "file").write_text("x")
    with pytest.raises(BagWriteError, match="cannot create the output folder"):
        write_bag(sequence, tmp_path / "file" / "bag")
    assert main(["write", str(sequence), str(tmp_path / "file" / "bag"), "--quiet"]) == 1


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_write_into_a_read_only_folder_is_one_clear_error(sequence, tmp_path):
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        with pytest.raises(BagWriteError, match="cannot create the output folder"):
            write_bag(sequence, locked / "bag")
    finally:
        locked.chmod(0o755)


def test_sigterm_during_write_leaves_nothing_and_stale_partials_are_cleaned(
    sequence, tmp_path, monkeypatch
):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    stale = tmp_path / f".bag.partial-{dead.pid}"
    (stale / "bag").mkdir(parents=True)
    encode = writer_module._FrameEncoder.encode
    calls = []

    def terminated_midway(self, frame):
        calls.append(frame)
        if len(calls) == 2:
            os.kill(os.getpid(), signal.SIGTERM)
        return encode(self, frame)

    monkeypatch.setattr(writer_module._FrameEncoder, "encode", terminated_midway)
    previous = signal.getsignal(signal.SIGTERM)
    with pytest.raises(KeyboardInterrupt), signals_as_interrupt():
        write_bag(sequence, tmp_path / "bag")
    assert signal.getsignal(signal.SIGTERM) is previous
    assert len(calls) == 2
    assert not (tmp_path / "bag").exists()
    assert leftovers(tmp_path) == []  # ours removed, the dead process's too


def test_partials_of_live_processes_are_kept(tmp_path):
    mine = tmp_path / f".out.partial-{os.getpid()}"
    mine.mkdir()
    assert remove_stale(tmp_path / "out") == [] and mine.is_dir()


def test_report_on_a_full_disk_leaves_no_report(tmp_path):
    out = tmp_path / "report"
    with pytest.raises(StagingError, match="No space left"), staged_folder(out) as staging:
        (staging / "metrics.json").write_text("{}")
        raise OSError(errno.ENOSPC, "No space left on device")
    assert not out.exists() and leftovers(tmp_path) == []


def test_evaluate_failing_while_writing_the_report_leaves_the_old_report(
    bag, tmp_path, monkeypatch
):
    from allo_mrad_ros.evaluation import report

    out = tmp_path / "report"
    out.mkdir()
    (out / "metrics.json").write_text('{"old": true}')

    def full_disk(result, folder):
        (Path(folder) / "metrics.md").write_text("half")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(report, "write_evaluation_report", full_disk)
    args = ["evaluate", str(bag), "--out", str(out), "--limit", "2", "--quiet", "--methods", "PAD"]
    args.append("--overwrite")
    assert main(args) == 1
    assert sorted(p.name for p in out.iterdir()) == ["metrics.json"]
    assert leftovers(tmp_path) == []


def test_evaluate_with_a_garbage_mesh_is_one_line_even_with_worker_processes(bag, tmp_path):
    garbage = tmp_path / "garbage.glb"
    garbage.write_bytes(b"not a model")
    done = allo_bag(
        "evaluate", str(bag), "--out", str(tmp_path / "r"), "--mesh", str(garbage), "--jobs", "2"
    )
    one_clean_line(done, "cannot load station model")
    assert not (tmp_path / "r").exists()


def corrupt_middle(bag: Path, copy: Path) -> Path:
    import shutil

    shutil.copytree(bag, copy)
    (storage,) = copy.glob("*.mcap")
    data = bytearray(storage.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = np.random.default_rng(0).bytes(4000)
    storage.write_bytes(bytes(data))
    return copy


def damaged_message(bag: Path) -> tuple[str, int]:
    """Topic and stamp of the message holding the middle byte of the bag's storage file."""
    from rosbag_tools.integrity import _stored_messages

    (storage,) = bag.glob("*.mcap")
    middle = storage.stat().st_size // 2
    data = storage.read_bytes()
    for topic, stamp, payload in _stored_messages(storage):
        start = data.find(payload)
        if start <= middle < start + len(payload):
            return topic, stamp
    raise AssertionError("no message holds the middle byte")


NEEDS_RCLPY = pytest.mark.skipif(
    importlib.util.find_spec("rclpy") is None, reason="allo-bag play needs rclpy"
)


@pytest.mark.parametrize("command", ["info", pytest.param("play", marks=NEEDS_RCLPY), "evaluate"])
def test_a_corrupted_bag_is_refused_naming_the_topic_and_stamp(bag, tmp_path, command):
    broken = corrupt_middle(bag, tmp_path / "broken")
    topic, stamp = damaged_message(bag)
    extra = {"evaluate": ["--out", str(tmp_path / "r"), "--quiet"], "play": ["--delay", "0"]}
    done = allo_bag(command, str(broken), *extra.get(command, []))
    one_clean_line(done, f"topic {topic}, message ")
    assert f"at stamp {stamp} ns" in done.stderr
    assert "CRC-32 recorded when the bag was written" in done.stderr


def test_a_lone_corrupted_mcap_fails_its_chunk_crc(bag, tmp_path):
    # Copied without metadata.yaml: no SHA-256, but allo-bag write filled the MCAP chunk CRCs.
    import shutil

    (storage,) = bag.glob("*.mcap")
    lone = tmp_path / "lone.mcap"
    shutil.copy(storage, lone)
    assert allo_bag("info", str(lone)).returncode == 0
    data = bytearray(lone.read_bytes())
    middle = len(data) // 2
    data[middle : middle + 4000] = np.random.default_rng(0).bytes(4000)
    lone.write_bytes(bytes(data))
    done = allo_bag("evaluate", str(lone), "--out", str(tmp_path / "r"), "--quiet")
    one_clean_line(done, "fails its CRC-32 check: the bag is corrupted")
    assert "/arm_camera/image_raw" in done.stderr and " ns" in done.stderr
    assert not (tmp_path / "r").exists()


def test_chunk_crcs_are_what_other_mcap_readers_check(bag):
    from rosbags.rosbag2.storage_mcap import McapReader

    (storage,) = bag.glob("*.mcap")
    reader = McapReader(storage)
    reader.open()
    try:
        crcs = []
        with storage.open("rb") as stream:
            for chunk in reader.chunks:
                stream.seek(chunk.chunk_start_offset + 9 + 24)
                crcs.append(int.from_bytes(stream.read(4), "little"))
        assert crcs and all(crcs)
        assert sum(1 for _ in reader.messages(reader.connections)) > 0  # rosbags checks them
    finally:
        reader.close()


def test_a_bag_over_its_own_sequence_is_refused_and_the_sequence_kept(sequence, tmp_path):
    import shutil

    copy = Path(shutil.copytree(sequence, tmp_path / "seq"))
    done = allo_bag("write", str(copy), str(copy), "--overwrite")
    one_clean_line(done, "would replace or sit inside the input", status=2)
    assert (copy / "frames.csv").is_file() and not list(copy.glob("*.mcap"))
    done = allo_bag("evaluate", str(copy), "--out", str(copy / "report"), "--quiet")
    one_clean_line(done, "would replace or sit inside the input", status=2)


def test_garbage_bag_metadata_is_one_line(bag, tmp_path):
    import shutil

    copy = Path(shutil.copytree(bag, tmp_path / "bag"))
    (copy / "metadata.yaml").write_text("rosbag2_bagfile_information: [unclosed\n")
    one_clean_line(allo_bag("info", str(copy)), "metadata.yaml: cannot read bag metadata")


def test_a_mask_with_values_outside_the_labels_names_topic_and_stamp(
    sequence, tmp_path, monkeypatch
):
    load_mask = Sequence.load_mask

    def bad_mask(self, frame):
        mask = load_mask(self, frame)
        if mask is not None and frame.index == 1:
            mask = mask.copy()
            mask[0, 0] = 7
        return mask

    monkeypatch.setattr(Sequence, "load_mask", bad_mask)
    out = tmp_path / "bag"
    write_bag(sequence, out)
    monkeypatch.undo()
    meta = yaml.safe_load((out / "metadata.yaml").read_text())
    assert "allo.files_sha256" in meta["rosbag2_bagfile_information"]["custom_data"]
    done = allo_bag("evaluate", str(out), "--out", str(tmp_path / "r"), "--quiet")
    one_clean_line(done, "mask values must be 0, 1 or 2; found [7]")
    assert "/allo/ground_truth/mask" in done.stderr or "mask: frame" in done.stderr
    assert " ns: " in done.stderr


def test_overwrite_refusal_names_the_command_line_option(tmp_path):
    from allo_mrad_ros.sequence import SequenceError, SequenceMeta, SequenceWriter

    meta = SequenceMeta(name="x", camera=CAMERA, rate_hz=10.0)
    with SequenceWriter(tmp_path / "s", meta) as writer:
        writer.add_frame(
            split="train",
            camera=0,
            image=np.zeros((CAMERA.height, CAMERA.width, 3), np.uint8),
            position=[0.0, 0.0, 0.0],
            quaternion=[0.0, 0.0, 0.0, 1.0],
            sun_direction=[1.0, 0.0, 0.0],
        )
    with pytest.raises(SequenceError, match="--overwrite"), SequenceWriter(tmp_path / "s", meta):
        pass
