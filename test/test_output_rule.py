"""One rule for every command that writes: an existing output is replaced only with
``--overwrite`` and only when it is what that command writes; anything else (other files, a
file, the working folder, a parent of the input, the home folder, an empty name) is refused
with one line naming the path, exit status 2, and nothing is touched or left behind."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable, Sequence
from pathlib import Path

import cv2
import numpy as np
import pytest
from rosbag_fixtures import write_tiny_sequence

from allo_mrad_ros.allo_import import main_import
from allo_mrad_ros.staging import staged_folder
from allo_mrad_ros.synth.cli import main as synth_main
from rosbag_tools.cli import main as bag_main
from rosbag_tools.writer import write_bag

QUICK = ["--limit", "1", "--quiet"]
EVALUATE = ["evaluate", "--methods", "MRAD", "--overlays", "0", *QUICK]
ABLATE = ["ablate", *QUICK]
SMOKE = ["generate", "--preset", "smoke", "--frames", "2", "--no-references", "--quiet"]


@pytest.fixture(scope="module")
def sources(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("rule")
    sequence = write_tiny_sequence(root / "seq", train=1)
    bag = root / "bag"
    write_bag(sequence, bag)
    allo = root / "ALLO" / "test" / "Camera0"
    (allo / "images").mkdir(parents=True)
    cv2.imwrite(str(allo / "images" / "1_normal_1.png"), np.zeros((1080, 1920, 3), np.uint8))
    return {"seq": sequence, "bag": bag, "allo": allo.parent}


def exit_status(main: Callable[[Sequence[str]], int], argv: Sequence[str]) -> int:
    """``main(argv)``, or the status of the ``SystemExit`` argparse raises for a usage error."""
    try:
        return main(argv)
    except SystemExit as end:
        return int(end.code)


def hidden(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def refused(capsys, status: int, path: str) -> str:
    """Exit 2 and one error line (after argparse's usage block) that names ``path``."""
    err = capsys.readouterr().err
    lines = [
        line for line in err.splitlines() if line.strip() and not line.startswith(("usage:", " "))
    ]
    assert status == 2, err
    assert len(lines) == 1, err
    assert path in lines[0], err
    assert "Traceback" not in err
    return lines[0]


def user_folder(tmp_path: Path) -> Path:
    folder = tmp_path / "r"
    folder.mkdir()
    (folder / "thesis.tex").write_text("work")
    return folder


def report_argv(command: list[str], sources: dict[str, Path], out: str, *extra: str) -> list[str]:
    return [command[0], str(sources["bag"]), "--out", out, *command[1:], *extra]


@pytest.mark.parametrize("command", [EVALUATE, ABLATE], ids=["evaluate", "ablate"])
@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["plain", "overwrite"])
def test_report_refuses_a_folder_of_other_files(sources, tmp_path, capsys, command, overwrite):
    folder = user_folder(tmp_path)
    status = exit_status(bag_main, report_argv(command, sources, str(folder), *overwrite))
    refused(capsys, status, str(folder))
    assert sorted(p.name for p in folder.iterdir()) == ["thesis.tex"]
    assert hidden(tmp_path) == []


@pytest.mark.parametrize("command", [EVALUATE, ABLATE], ids=["evaluate", "ablate"])
def test_report_refuses_a_file(sources, tmp_path, capsys, command):
    target = tmp_path / "report"
    target.write_text("mine")
    status = exit_status(bag_main, report_argv(command, sources, str(target), "--overwrite"))
    refused(capsys, status, str(target))
    assert target.read_text() == "mine"
    assert hidden(tmp_path) == []


@pytest.mark.parametrize("command", [EVALUATE, ABLATE], ids=["evaluate", "ablate"])
@pytest.mark.parametrize("where", ["empty", "dot", "cwd", "parent of input", "home"])
def test_report_refuses_protected_folders(sources, tmp_path, capsys, monkeypatch, command, where):
    work = tmp_path / "work"
    work.mkdir()
    (work / "keep.txt").write_text("mine")
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    (tmp_path / "home").mkdir()
    (tmp_path / "home" / "keep.txt").write_text("mine")
    out = {
        "empty": "",
        "dot": ".",
        "cwd": str(work),
        "parent of input": str(sources["bag"].parent),
        "home": str(tmp_path / "home"),
    }[where]
    status = exit_status(bag_main, report_argv(command, sources, out, "--overwrite"))
    refused(capsys, status, "--out" if where == "empty" else out)
    assert (work / "keep.txt").read_text() == "mine"
    assert (tmp_path / "home" / "keep.txt").read_text() == "mine"
    assert sources["bag"].is_dir() and hidden(work) == []


def test_report_replaces_a_report_only_with_overwrite(sources, tmp_path, capsys):
    out = tmp_path / "report"
    assert bag_main(report_argv(EVALUATE, sources, str(out))) == 0
    first = json.loads((out / "metrics.json").read_text())["methods"]
    capsys.readouterr()
    refused(capsys, bag_main(report_argv(EVALUATE, sources, str(out))), str(out))
    # An ablation report is not what evaluate writes, and the other way round.
    refused(capsys, bag_main(report_argv(ABLATE, sources, str(out), "--overwrite")), str(out))
    assert bag_main(report_argv(EVALUATE, sources, str(out), "--overwrite")) == 0
    assert json.loads((out / "metrics.json").read_text())["methods"] == first
    assert hidden(tmp_path) == []


def test_report_into_an_empty_folder(sources, tmp_path):
    out = tmp_path / "report"
    out.mkdir()
    assert bag_main(report_argv(ABLATE, sources, str(out))) == 0
    assert (out / "ablation.json").is_file() and hidden(tmp_path) == []


@pytest.mark.parametrize("overwrite", [[], ["--overwrite"]], ids=["plain", "overwrite"])
def test_bag_write_refuses_a_folder_of_other_files(sources, tmp_path, capsys, overwrite):
    folder = user_folder(tmp_path)
    status = exit_status(
        bag_main, ["write", str(sources["seq"]), str(folder), "--quiet", *overwrite]
    )
    refused(capsys, status, str(folder))
    assert sorted(p.name for p in folder.iterdir()) == ["thesis.tex"]
    assert hidden(tmp_path) == []


@pytest.mark.parametrize("out", ["", ".", "file"])
def test_bag_write_refuses_empty_name_working_folder_and_file(
    sources, tmp_path, capsys, monkeypatch, out
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("mine")
    status = exit_status(bag_main, ["write", str(sources["seq"]), out, "--overwrite", "--quiet"])
    refused(capsys, status, out or "out")
    assert (tmp_path / "file").read_text() == "mine"
    assert hidden(tmp_path) == []


def test_bag_write_replaces_a_bag_only_with_overwrite(sources, tmp_path, capsys):
    out = tmp_path / "bag"
    assert bag_main(["write", str(sources["seq"]), str(out), "--quiet"]) == 0
    capsys.readouterr()
    refused(capsys, bag_main(["write", str(sources["seq"]), str(out), "--quiet"]), str(out))
    assert bag_main(["write", str(sources["seq"]), str(out), "--quiet", "--overwrite"]) == 0
    assert (out / "metadata.yaml").is_file() and hidden(tmp_path) == []


@pytest.mark.parametrize("out", ["", ".", "home", "other files", "sequence"])
def test_synth_commands_follow_the_same_rule(sources, tmp_path, capsys, monkeypatch, out):
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    monkeypatch.setenv("HOME", str(tmp_path))
    other = user_folder(tmp_path)
    path = {
        "": "",
        ".": ".",
        "home": str(tmp_path),
        "other files": str(other),
        "sequence": str(sources["seq"]),
    }[out]
    extra = [] if out == "sequence" else ["--overwrite"]
    for run in (
        lambda: exit_status(synth_main, [*SMOKE, "--out", path, *extra]),
        lambda: exit_status(main_import, [str(sources["allo"]), "--out", path, "--quiet", *extra]),
    ):
        refused(capsys, run(), path or "--out")
    assert (other / "thesis.tex").read_text() == "work"
    assert hidden(tmp_path) == [] and hidden(work) == []


@pytest.mark.parametrize("kind", ["file", "link"])
def test_staged_folder_replacing_a_file_or_link_leaves_nothing_behind(tmp_path, kind):
    out = tmp_path / "out"
    if kind == "file":
        out.write_text("old")
    else:
        (tmp_path / "elsewhere").mkdir()
        out.symlink_to(tmp_path / "elsewhere")
    with staged_folder(out) as staging:
        (staging / "new.txt").write_text("new")
    assert (out / "new.txt").read_text() == "new"
    assert hidden(tmp_path) == []


def test_a_sequence_with_other_files_beside_it_is_not_replaced(sources, tmp_path, capsys):
    sequence = tmp_path / "seq"
    shutil.copytree(sources["seq"], sequence)
    (sequence / "notes.txt").write_text("mine")
    status = exit_status(synth_main, [*SMOKE, "--out", str(sequence), "--overwrite"])
    assert "not a sequence" in refused(capsys, status, str(sequence))
    assert (sequence / "notes.txt").read_text() == "mine"


def _allo_download(root: Path) -> list[Path]:
    """``root/{test,train}/Camera0/{images,masks}/*.png``, as ALLO ships them: 12 PNGs."""
    files = []
    for split in ("test", "train"):
        for index, name in enumerate(["1_normal_1.png", "2_normal_10.png", "3_normal_5.png"]):
            for kind, pixels in (
                ("images", np.full((1080, 1920, 3), 30 * index, np.uint8)),
                ("masks", np.ones((1080, 1920), np.uint8)),
            ):
                path = root / split / "Camera0" / kind / name
                path.parent.mkdir(parents=True, exist_ok=True)
                cv2.imwrite(str(path), pixels)
                files.append(path)
    return files


@pytest.mark.parametrize("splits", ["both", "test only"])
def test_an_allo_download_imported_in_place_is_never_replaced(tmp_path, capsys, splits):
    allo = tmp_path / "ALLO"
    pngs = _allo_download(allo)
    if splits == "test only":
        shutil.rmtree(allo / "train")
        pngs = [p for p in pngs if "train" not in p.parts]
    contents = {path: path.read_bytes() for path in pngs}
    assert main_import([str(allo / "test"), "--out", str(allo), "--quiet"]) == 0
    capsys.readouterr()
    for argv in ([*SMOKE, "--out", str(allo), "--overwrite"], [*SMOKE, "--out", str(allo)]):
        line = refused(capsys, exit_status(synth_main, argv), str(allo))
        assert "train/" in line if splits == "both" else "imported in place" in line
    # Another split imported over it from elsewhere is refused too.
    other = tmp_path / "elsewhere" / "test"
    _allo_download(other.parent)
    argv = [str(other), "--out", str(allo), "--overwrite", "--quiet"]
    refused(capsys, exit_status(main_import, argv), str(allo))
    assert sorted(allo.rglob("*.png")) == sorted(contents)
    assert all(path.read_bytes() == data for path, data in contents.items())
    assert hidden(tmp_path) == []
    # Importing in place again still only rewrites its own two files.
    assert main_import([str(allo / "test"), "--out", str(allo), "--quiet", "--overwrite"]) == 0
    assert sorted(allo.rglob("*.png")) == sorted(contents)


def test_bag_write_refuses_a_metadata_yaml_that_is_not_a_bag_s(sources, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "metadata.yaml").write_text("hello: 1\n")
    argv = ["write", str(sources["seq"]), str(out), "--quiet", "--overwrite"]
    line = refused(capsys, exit_status(bag_main, argv), str(out))
    assert "metadata.yaml" in line and "not a bag" in line
    assert (out / "metadata.yaml").read_text() == "hello: 1\n"
    assert sorted(p.name for p in out.iterdir()) == ["metadata.yaml"] and hidden(tmp_path) == []


@pytest.mark.parametrize("blank", ["", "   "], ids=["empty", "blank"])
@pytest.mark.parametrize(
    "command",
    ["write", "evaluate", "ablate", "generate", "import-allo", "import-allo alone", "demo"],
)
def test_an_empty_output_name_is_one_line_without_the_usage_block(sources, capsys, command, blank):
    from allo_mrad_ros.demo import main as demo_main

    main, argv = {
        "write": (bag_main, ["write", str(sources["seq"]), blank]),
        "evaluate": (bag_main, report_argv(EVALUATE, sources, blank)),
        "ablate": (bag_main, report_argv(ABLATE, sources, blank)),
        "generate": (synth_main, [*SMOKE, "--out", blank]),
        "import-allo": (synth_main, ["import-allo", str(sources["allo"]), "--out", blank]),
        "import-allo alone": (main_import, [str(sources["allo"]), "--out", blank]),
        "demo": (demo_main, ["--builtin", "--out", blank]),
    }[command]
    assert exit_status(main, argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "usage" not in err, err
    assert err.endswith(": an empty name is not an output folder\n"), err
    assert "--out" in err or "argument out" in err, err
