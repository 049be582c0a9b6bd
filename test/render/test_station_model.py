"""Tests of the procedural station model and its committed glTF binary."""

from __future__ import annotations

import hashlib
import io

import numpy as np
import pytest
import trimesh

from allo_mrad_ros.render.model import load_model
from allo_mrad_ros.render.station_model import MATERIALS, build_glb, main
from allo_mrad_ros.resources import share_path

REQUIRED_MATERIALS = {"white_mli", "gold_foil", "solar_cells", "bare_aluminium", "dark_panel"}


@pytest.fixture(scope="module")
def committed() -> bytes:
    return share_path("meshes", "station.glb").read_bytes()


@pytest.fixture(scope="module")
def rebuilt() -> bytes:
    return build_glb()


@pytest.fixture(scope="module")
def loaded(committed) -> trimesh.Scene:
    return trimesh.load(io.BytesIO(committed), file_type="glb", force="scene")


def test_rebuild_is_bit_identical_to_committed_file(committed, rebuilt):
    assert hashlib.sha256(rebuilt).hexdigest() == hashlib.sha256(committed).hexdigest(), (
        "meshes/station.glb is stale: run "
        "`python -m allo_mrad_ros.render.station_model --out meshes/station.glb`"
    )


def test_size_triangles_and_extent(committed, loaded):
    assert len(committed) <= 5 * 1024 * 1024
    triangles = sum(len(g.faces) for g in loaded.geometry.values())
    assert 5_000 <= triangles <= 50_000
    extents = loaded.extents
    assert 30.0 <= extents.max() <= 60.0  # metres, Gateway-sized
    lo, hi = loaded.bounds
    assert np.all(lo < 0) and np.all(hi > 0)  # origin (station frame) inside the station


def test_materials_are_distinct_pbr(loaded):
    materials = {g.visual.material.name: g.visual.material for g in loaded.geometry.values()}
    assert set(materials) >= REQUIRED_MATERIALS
    assert set(materials) == set(MATERIALS)
    colours = {tuple(np.asarray(m.baseColorFactor)) for m in materials.values()}
    assert len(colours) == len(materials)
    for material in materials.values():
        assert isinstance(material, trimesh.visual.material.PBRMaterial)
        assert material.metallicFactor is not None and material.roughnessFactor is not None


def test_parts_are_closed_and_carry_normals(loaded):
    for name, mesh in loaded.geometry.items():
        assert np.allclose(np.linalg.norm(mesh.vertex_normals, axis=1), 1.0, atol=1e-3), name
        merged = mesh.copy()
        merged.merge_vertices(merge_norm=True, merge_tex=True)
        # Closed surfaces (every edge shared by an even number of faces; modules touching cap
        # to cap share edges four times): the renderer culls back faces, so no open sheets.
        _, counts = np.unique(merged.edges_sorted, axis=0, return_counts=True)
        assert np.all(counts % 2 == 0), name


def test_renderer_merges_parts_by_material(committed, tmp_path):
    path = tmp_path / "station.glb"
    path.write_bytes(committed)
    groups = load_model(path)
    assert sorted(g.name for g in groups) == sorted(MATERIALS)
    assert all(g.uv is None and g.colours is None for g in groups)


def test_build_is_deterministic_in_process(rebuilt):
    assert build_glb() == rebuilt


def test_command_line_writes_the_model(tmp_path, capsys, rebuilt):
    out = tmp_path / "sub" / "station.glb"
    assert main(["--out", str(out)]) == 0
    assert out.read_bytes() == rebuilt
    assert "triangles" in capsys.readouterr().out
