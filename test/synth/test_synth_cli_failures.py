"""allo-synth generate / import-allo: nothing half-written on bad output paths, a bad mesh,
a full disk or a signal; a rerun replaces, never mixes."""

from __future__ import annotations

import errno
import os
import signal
from pathlib import Path

import cv2
import numpy as np
import pytest

from allo_mrad_ros.allo_import import main_import
from allo_mrad_ros.synth import generator
from allo_mrad_ros.synth.cli import main

SMOKE = ["generate", "--preset", "smoke", "--frames", "2", "--no-references", "--quiet"]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if ".partial-" in p.name or ".old-" in p.name)


def one_line(capsys, expected: str) -> None:
    err = capsys.readouterr().err
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1 and expected in lines[0], err
    assert "Traceback" not in err


def test_generate_under_a_file_is_one_line(tmp_path, capsys):
    (tmp_path / "file").write_text("x")
    assert main([*SMOKE, "--out", str(tmp_path / "file" / "seq")]) == 1
    one_line(capsys, "cannot create the output folder")


def test_generate_with_a_garbage_mesh_is_one_line_and_leaves_nothing(tmp_path, capsys):
    garbage = tmp_path / "garbage.glb"
    garbage.write_bytes(b"not a model")
    assert main([*SMOKE, "--out", str(tmp_path / "seq"), "--mesh", str(garbage)]) == 1
    one_line(capsys, "cannot load station model")
    assert not (tmp_path / "seq").exists() and leftovers(tmp_path) == []


def fake_generate(action):
    def run(config, out, seed, **options):
        for name in ("meshes", "train", "test"):
            (Path(out) / name).mkdir()
            (Path(out) / name / "x.png").write_bytes(b"half")
        action()

    return run


def test_sigterm_during_generate_leaves_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(generator, "generate", fake_generate(lambda: os.kill(os.getpid(), 15)))
    previous = signal.getsignal(signal.SIGTERM)
    assert main([*SMOKE, "--out", str(tmp_path / "seq")]) == 130
    assert signal.getsignal(signal.SIGTERM) is previous
    one_line(capsys, "interrupted; nothing written")
    assert not (tmp_path / "seq").exists() and leftovers(tmp_path) == []


def test_full_disk_during_generate_keeps_the_old_sequence(tmp_path, capsys, monkeypatch):
    out = tmp_path / "seq"
    assert main([*SMOKE, "--out", str(out)]) == 0
    before = sorted(p.relative_to(out) for p in out.rglob("*"))
    capsys.readouterr()

    def full():
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(generator, "generate", fake_generate(full))
    assert main([*SMOKE, "--out", str(out), "--overwrite"]) == 1
    one_line(capsys, "No space left on device")
    assert sorted(p.relative_to(out) for p in out.rglob("*")) == before
    assert leftovers(tmp_path) == []


def test_rerun_with_overwrite_keeps_no_stale_files(tmp_path, capsys):
    out = tmp_path / "seq"
    longer = [*SMOKE[:4], "6", *SMOKE[5:]]
    assert main([*longer, "--out", str(out)]) == 0
    first = {p.relative_to(out) for p in out.rglob("*.png")}
    assert main([*SMOKE, "--out", str(out)]) == 2
    one_line(capsys, "use --overwrite")
    assert main([*SMOKE, "--out", str(out), "--overwrite"]) == 0
    second = {p.relative_to(out) for p in out.rglob("*.png")}
    gone = first - second  # the first run's frames the second has not
    assert gone and not any((out / path).exists() for path in gone)
    assert (out / "frames.csv").is_file()


def test_a_file_the_sequence_does_not_name_is_never_replaced(tmp_path, capsys):
    out = tmp_path / "seq"
    assert main([*SMOKE, "--out", str(out)]) == 0
    (out / "train" / "stale.png").write_bytes(b"mine")
    assert main([*SMOKE, "--out", str(out), "--overwrite"]) == 2
    one_line(capsys, "not a sequence (train/stale.png)")
    assert (out / "train" / "stale.png").read_bytes() == b"mine"


def test_generate_refuses_a_folder_of_other_files(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me")
    assert main([*SMOKE, "--out", str(out), "--overwrite"]) == 2
    one_line(capsys, "not a sequence")
    assert (out / "notes.txt").read_text() == "keep me"


def allo_tree(root: Path) -> Path:
    folder = root / "ALLO" / "test" / "Camera0"
    (folder / "images").mkdir(parents=True)
    (folder / "masks").mkdir()
    for index, name in enumerate(["1_normal_1.png", "2_normal_10.png"]):
        image = np.full((1080, 1920, 3), 30 * index, np.uint8)
        cv2.imwrite(str(folder / "images" / name), image)
        cv2.imwrite(str(folder / "masks" / name), np.ones((1080, 1920), np.uint8))
    return root / "ALLO" / "test"


def test_import_allo_validate_finds_a_truncated_image_in_one_line(tmp_path, capsys):
    split = allo_tree(tmp_path)
    image = split / "Camera0" / "images" / "2_normal_10.png"
    data = image.read_bytes()
    image.write_bytes(data[: len(data) // 2])
    out = tmp_path / "seq"
    assert main_import([str(split), "--out", str(out), "--validate", "--quiet"]) == 1
    one_line(capsys, "2_normal_10.png, row 2, column 'image': cannot decode image")
    assert not out.exists() and leftovers(tmp_path) == []


def test_import_allo_under_a_file_is_one_line(tmp_path, capsys):
    split = allo_tree(tmp_path)
    (tmp_path / "file").write_text("x")
    assert main_import([str(split), "--out", str(tmp_path / "file" / "seq")]) == 1
    one_line(capsys, "cannot create the output folder")


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into read-only folders")
def test_import_allo_into_a_read_only_folder_is_one_line(tmp_path, capsys):
    split = allo_tree(tmp_path)
    locked = tmp_path / "locked"
    locked.mkdir()
    locked.chmod(0o555)
    try:
        assert main_import([str(split), "--out", str(locked / "seq")]) == 1
    finally:
        locked.chmod(0o755)
    one_line(capsys, "cannot create the output folder")
