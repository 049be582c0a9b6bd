"""The objects bench's path-traced station: where its sequence and station model come from."""

from __future__ import annotations

import pytest

from benchmarks import objects as bench


def test_an_unknown_path_traced_mesh_is_named(tmp_path):
    mesh = tmp_path / "stations" / "outpost_nowhere.glb"
    with pytest.raises(SystemExit, match=r"--path-traced-mesh .*outpost_nowhere\.glb"):
        bench.ensure_path_traced(tmp_path / "objects_pt", mesh, 7)
    # The outposts it knows were written beside it, so a known name would have been found.
    assert sorted(p.name for p in mesh.parent.glob("*.glb")) == [
        "outpost_hub.glb",
        "outpost_ring.glb",
        "outpost_spine.glb",
    ]


def test_an_existing_path_traced_sequence_is_not_generated_again(tmp_path, monkeypatch):
    sequence = tmp_path / "objects_pt"
    sequence.mkdir()
    (sequence / "sequence.yaml").write_text("format: 2\n")

    def refuse(*args, **kwargs):
        raise AssertionError("generated again")

    monkeypatch.setattr(bench.subprocess, "run", refuse)
    bench.ensure_path_traced(sequence, tmp_path / "missing.glb", 7)


def test_a_missing_path_traced_sequence_is_generated_on_its_station(tmp_path, monkeypatch):
    mesh = tmp_path / "outpost_spine.glb"
    mesh.write_bytes(b"glTF")
    commands = []
    monkeypatch.setattr(bench.subprocess, "run", lambda command, check: commands.append(command))
    bench.ensure_path_traced(tmp_path / "objects_pt", mesh, 7)
    (command,) = commands

    def value(option: str) -> str:
        return command[command.index(option) + 1]

    assert value("generate") == "--preset" and value("--preset") == "objects-pt"
    assert value("--seed") == "7" and value("--mesh") == str(mesh)
    assert value("--out") == str(tmp_path / "objects_pt")
