"""A bag folder that lost its ``metadata.yaml`` is named as such, with the file to read
instead, by every command that opens a bag."""

from __future__ import annotations

import shutil

import pytest
from rosbag_fixtures import write_tiny_sequence

from rosbag_tools.cli import main
from rosbag_tools.writer import write_bag


@pytest.fixture(scope="module")
def bag(tmp_path_factory):
    root = tmp_path_factory.mktemp("bag")
    return write_bag(write_tiny_sequence(root / "seq", train=1), root / "bag").path


@pytest.mark.parametrize("command", [["info"], ["play", "--delay", "0"], ["evaluate"]])
def test_a_bag_folder_without_metadata_is_named_as_such(bag, tmp_path, capsys, command):
    if command[0] == "play":
        pytest.importorskip("rclpy", reason="allo-bag play needs rclpy")
    copy = shutil.copytree(bag, tmp_path / "bag")
    (copy / "metadata.yaml").unlink()
    argv = [command[0], str(copy), *command[1:]]
    if command[0] == "evaluate":
        argv += ["--out", str(tmp_path / "report"), "--quiet"]
    assert main(argv) == 1
    lines = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert len(lines) == 1, lines
    assert f"{copy / 'metadata.yaml'}: not found" in lines[0]
    assert str(next(copy.glob("*.mcap"))) in lines[0]  # what can still be read
    assert "Expected metadata file" not in lines[0]
    # The storage file named there reads on its own.
    assert main(["info", str(next(copy.glob("*.mcap")))]) == 0
