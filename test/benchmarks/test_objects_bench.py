"""The objects bench's path-traced station: where its sequence and station model come from."""

from __future__ import annotations

import pytest

from benchmarks import objects as bench


def test_an_unknown_path_traced_mesh_is_named_and_nothing_is_written(tmp_path):
    mesh = tmp_path / "stations" / "outpost_nowhere.glb"
    with pytest.raises(
        SystemExit, match=r"--path-traced-mesh .*outpost_nowhere\.glb.*outpost_spine"
    ):
        bench.ensure_path_traced(tmp_path / "objects_pt", mesh, 7)
    assert not mesh.parent.exists()  # no model written into a folder it was not asked for


def test_a_missing_outpost_model_is_written_alone(tmp_path, monkeypatch):
    stations = tmp_path / "stations"
    stations.mkdir()
    other = stations / "outpost_hub.glb"
    other.write_bytes(b"a model of the user's")
    commands = []
    monkeypatch.setattr(bench.subprocess, "run", lambda command, check: commands.append(command))
    bench.ensure_path_traced(tmp_path / "objects_pt", stations / "outpost_ring.glb", 9)
    assert (stations / "outpost_ring.glb").read_bytes()[:4] == b"glTF"
    assert other.read_bytes() == b"a model of the user's"  # left as it was
    assert sorted(p.name for p in stations.iterdir()) == ["outpost_hub.glb", "outpost_ring.glb"]
    assert len(commands) == 1


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


def test_the_station_is_read_from_the_sequence_not_from_the_command_line(tmp_path):
    sequence = tmp_path / "objects_pt_ring"
    sequence.mkdir()
    assert bench.station_of(sequence) is None  # not a generated sequence
    (sequence / "generation.json").write_text('{"mesh": "outpost_ring.glb"}')
    assert bench.station_of(sequence) == "outpost_ring"
