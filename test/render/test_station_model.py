"""Tests of the procedural station model and its committed glTF binary."""

from __future__ import annotations

import hashlib
import io

import numpy as np
import pytest
import trimesh

from allo_mrad_ros.render.model import load_model
from allo_mrad_ros.render.station_model import MATERIALS, build_glb, export_glb, main
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


# The rebuild is compared by what it is, not by its bytes: floating-point paths differ between
# CPUs (and NumPy builds), so vertices may differ in their last bits. 0.1 mm is far above that
# (float32 rounding at 50 m is about 4 um) and far below a pixel (3 cm at 30 m for ALLO's lens).
TOLERANCE_M = 1e-4


def _instances(data: bytes) -> dict[str, dict]:
    """Every placed geometry of a GLB: node name -> world vertices, faces, material."""
    scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene")
    found = {}
    for node in scene.graph.nodes_geometry:
        transform, name = scene.graph[node]
        geometry = scene.geometry[name]
        material = geometry.visual.material
        found[node] = {
            "vertices": trimesh.transform_points(geometry.vertices, transform),
            "faces": np.asarray(geometry.faces),
            "material": (
                material.name,
                tuple(np.round(np.asarray(material.baseColorFactor, float), 6)),
                material.metallicFactor,
                material.roughnessFactor,
            ),
        }
    return found


def stale_reason(committed: bytes, rebuilt: bytes, tolerance_m: float = TOLERANCE_M) -> str:
    """Why ``rebuilt`` is not the committed model ('' when it is, within ``tolerance_m``)."""
    old, new = _instances(committed), _instances(rebuilt)
    if set(old) != set(new):
        return f"parts differ: {sorted(set(old) ^ set(new))[:5]}"
    for node in sorted(old):
        a, b = old[node], new[node]
        if a["material"] != b["material"]:
            return f"{node}: material {a['material']} is now {b['material']}"
        if a["faces"].shape != b["faces"].shape or not np.array_equal(a["faces"], b["faces"]):
            return f"{node}: triangles differ"
        if a["vertices"].shape != b["vertices"].shape:
            return f"{node}: {len(a['vertices'])} vertices, now {len(b['vertices'])}"
        gap = float(np.abs(a["vertices"] - b["vertices"]).max(initial=0.0))
        if gap > tolerance_m:
            return f"{node}: a vertex moved {gap * 1000:.3f} mm (tolerance {tolerance_m * 1000} mm)"
    return ""


def test_rebuild_matches_committed_geometry(committed, rebuilt):
    reason = stale_reason(committed, rebuilt)
    assert not reason, (
        f"meshes/station.glb is stale ({reason}): run "
        "`python -m allo_mrad_ros.render.station_model --out meshes/station.glb`"
    )


def _moved(data: bytes, shift: float, every: bool) -> bytes:
    """``data`` with its vertices moved by ``shift`` metres (all, or one of one part)."""
    scene = trimesh.load(io.BytesIO(data), file_type="glb", force="scene")
    name = sorted(scene.geometry)[0]
    for key, geometry in scene.geometry.items():
        vertices = geometry.vertices.copy()
        if every:
            vertices = vertices * (1.0 + 1e-9) + shift
        elif key == name:
            vertices[0, 0] += shift
        geometry.vertices = vertices
    return export_glb(scene)


def test_float_noise_is_not_staleness_but_a_moved_vertex_is(committed):
    again = export_glb(trimesh.load(io.BytesIO(committed), file_type="glb", force="scene"))
    assert stale_reason(committed, again) == ""
    noisy = _moved(committed, 2e-6, every=True)  # what another CPU's rounding looks like
    assert hashlib.sha256(noisy).digest() != hashlib.sha256(committed).digest()
    assert stale_reason(committed, noisy) == ""
    assert "moved 1.000 mm" in stale_reason(committed, _moved(committed, 1e-3, every=False))


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
