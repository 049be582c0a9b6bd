"""The extended path-traced bench's generator pieces: hard object kinds, their measures and
marks, the Cycles query's own materials and lamps, and the procedural outposts.

Tests marked ``needs_bpy`` run only where the optional extra is installed; the rest need
no Blender.
"""

from __future__ import annotations

import importlib.util

import cv2
import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import (
    LABEL_ANOMALY,
    LABEL_SPACE,
    LABEL_STATION,
    ExtraObject,
    ReferenceRenderer,
)
from allo_mrad_ros.render.outpost_model import (
    LAYOUTS,
    OutpostError,
    build_outpost,
)
from allo_mrad_ros.render.outpost_model import (
    MATERIALS as OUTPOST_MATERIALS,
)
from allo_mrad_ros.render.station_model import MATERIALS as STATION_MATERIALS
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.synth.config import SynthError, preset
from allo_mrad_ros.synth.cycles_light import (
    ROUGHNESS_RANGE,
    CyclesLightConfig,
    draw_material_departures,
    shifted_roughness,
)
from allo_mrad_ros.synth.hard_kinds import (
    CABLE_WIDTH_PX,
    SMALL_MAX_PX,
    classify,
    kind_columns,
    paint_like_station,
    placement_penalty,
    silhouette_width_px,
    station_palette,
    visible_fraction,
)
from allo_mrad_ros.synth.objects import DARK_TYPES, KNOWN_TYPES, build_anomaly
from allo_mrad_ros.synth.realism_config import RealismConfig
from allo_mrad_ros.synth.surfaces import as_built_station

needs_bpy = pytest.mark.skipif(
    importlib.util.find_spec("bpy") is None, reason="optional bpy not installed"
)
MESH = share_path("meshes", "station.glb")
# The bench's camera: ALLO's 25 mm lens on a 36 mm sensor, 512 x 384.
BENCH_CAMERA = CameraIntrinsics.from_fov(512, 384, focal_mm=25.0, sensor_width_mm=36.0)
# Far from the station, looking away from it: only the object is in view.
EYE = np.array([300.0, 0.0, 0.0])
T_AWAY = look_at(EYE, EYE + np.array([1.0, 0.0, 0.0]))


@pytest.fixture(scope="module")
def rasteriser():
    renderer = ReferenceRenderer(MESH, BENCH_CAMERA, scale=1.0, shadows=False)
    yield renderer
    renderer.close()


def _object_mask(rasteriser, obj, distance_m: float) -> np.ndarray:
    pose = np.eye(4)
    pose[:3, 3] = EYE + np.array([distance_m, 0.0, 0.0])
    extra = ExtraObject(obj.scene, pose, LABEL_ANOMALY, obj.kind)
    result = rasteriser.render(T_AWAY, [0.0, 0.0, 1.0], 1.0, (), [extra], labels=True)
    return result.labels == LABEL_ANOMALY


# ---------------------------------------------------------------------- measures
def _strip(width: float, angle_deg: float, supersample: int = 8) -> np.ndarray:
    """A 150 px strip ``width`` px wide, rasterised as a renderer does (a pixel is in when
    more than half of it is covered)."""
    s = supersample
    a = np.radians(angle_deg)
    d, n = np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)])
    centre, half_length, half_width = np.array([150.3, 100.2]) * s, 75.0 * s, width * s / 2
    corners = [centre + i * half_length * d + j * half_width * n for i, j in _CORNERS]
    fine = np.zeros((200 * s, 300 * s), np.uint8)
    cv2.fillPoly(fine, [np.round(corners).astype(np.int32)], 255)
    return cv2.resize(fine, (300, 200), interpolation=cv2.INTER_AREA) > 127


_CORNERS = ((-1, -1), (1, -1), (1, 1), (-1, 1))


@pytest.mark.parametrize("width", [1.0, 2.0, 3.0, 4.0, 6.0])
@pytest.mark.parametrize("angle", [0.0, 20.0, 45.0, 70.0])
def test_silhouette_width_of_rasterised_strips(width, angle):
    measured = silhouette_width_px(_strip(width, angle))
    # Pixel quantisation moves a thin strip's edges by up to half a pixel each.
    assert abs(measured - width) <= 0.7, measured


def test_a_blob_is_not_a_thin_cable():
    mask = np.zeros((100, 100), bool)
    cv2.circle(mask.view(np.uint8), (50, 50), 12, 1, -1)
    assert silhouette_width_px(mask) > CABLE_WIDTH_PX[1]
    background = np.full(mask.shape, LABEL_SPACE, np.uint8)
    assert placement_penalty("thin_cable", mask, background) > 0
    assert classify("thin_cable", mask, background) == "other"
    assert silhouette_width_px(np.zeros((5, 5), bool)) == 0.0


@pytest.mark.parametrize("seed", range(4))
def test_thin_cables_are_a_few_px_wide_and_the_rule_keeps_1_to_4(rasteriser, seed):
    obj = build_anomaly("thin_cable", seed)
    assert len(obj.parts) == 1  # a bare tube: no connector widens its silhouette
    near = _object_mask(rasteriser, obj, 4.0)
    far = _object_mask(rasteriser, obj, 8.0)
    width, far_width = silhouette_width_px(near), silhouette_width_px(far)
    # 6-22 mm radius on the bench's camera: about 1-4 px at 4 m, half as wide at 8 m.
    assert 0.8 <= width <= 4.5, width
    assert 0.35 <= far_width / width <= 0.7
    background = np.full(near.shape, LABEL_SPACE, np.uint8)
    low, high = CABLE_WIDTH_PX
    for mask, measured in ((near, width), (far, far_width)):
        inside = low <= measured <= high
        assert (placement_penalty("thin_cable", mask, background) == 0) == inside
        assert (classify("thin_cable", mask, background) == "thin_cable") == inside


@pytest.mark.parametrize("seed", range(4))
def test_small_debris_covers_at_most_100_px_at_4_m(rasteriser, seed):
    obj = build_anomaly("small_debris", seed)
    assert 0.06 <= float(np.max(obj.extents)) <= 0.14
    mask = _object_mask(rasteriser, obj, 4.0)
    area = int(np.count_nonzero(mask))
    need = 0.00015 * BENCH_CAMERA.width * BENCH_CAMERA.height  # the preset's threshold
    assert need * 0.5 <= area <= SMALL_MAX_PX
    background = np.full(mask.shape, LABEL_STATION, np.uint8)
    assert placement_penalty("small_debris", mask, background) == 0
    assert classify("small_debris", mask, background) == "small"
    # The same object close up is no longer small, and its placement is refused.
    near = _object_mask(rasteriser, obj, 1.0)
    assert placement_penalty("small_debris", near, background) > 0


def test_dark_objects_in_front_of_space_are_marked_invisible_when_as_dark_as_space():
    background = np.full((60, 80), LABEL_SPACE, np.uint8)
    background[:, :40] = LABEL_STATION
    labels = background.copy()
    labels[20:40, 50:70] = LABEL_ANOMALY  # in front of space
    clean = np.zeros((60, 80, 3), np.uint8)
    clean[:, :40] = 150  # the lit station
    clean[20:40, 50:70] = 3  # as dark as space (within the margin)
    columns = kind_columns("black_foil", labels, background, clean)
    assert columns["kind"] == "dark_over_space"
    assert columns["visible"] == 0 and columns["visible_fraction"] == 0.0
    # Lit, the same object is visible.
    clean[20:40, 50:70] = 40
    assert kind_columns("black_foil", labels, background, clean)["visible"] == 1
    # As dark, but in front of the lit station: hides it, so it is visible (over a surface).
    labels = background.copy()
    labels[20:40, 10:30] = LABEL_ANOMALY
    clean[20:40, 10:30] = 3
    columns = kind_columns("black_foil", labels, background, clean)
    assert columns["kind"] == "dark_over_surface" and columns["visible"] == 1
    # Half over each: half visible.
    mask = np.zeros_like(labels, bool)
    mask[20:40, 30:50] = True
    clean[20:40, 30:50] = 3
    assert visible_fraction(clean, mask, background) == pytest.approx(0.5)
    assert {"black_foil", "dark_visor"} <= DARK_TYPES


def test_station_coloured_objects_take_the_stations_dominant_materials():
    large = trimesh.creation.box(extents=(10.0, 10.0, 1.0))
    small = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    large.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(name="hull", baseColorFactor=(0.7, 0.6, 0.5, 1.0), roughnessFactor=0.8)
    )
    small.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(name="gold", baseColorFactor=(0.9, 0.6, 0.2, 1.0), roughnessFactor=0.3)
    )
    scene = trimesh.Scene([large, small])
    palette = station_palette(scene)
    assert [entry[0] for entry in palette] == ["hull", "gold"]
    assert palette[0][4] > 0.9 and sum(entry[4] for entry in palette) == pytest.approx(1.0)
    obj = build_anomaly("station_patch", 3)
    painted = paint_like_station(obj.scene, palette, np.random.default_rng(0))
    for mesh in painted.geometry.values():
        rgb = np.asarray(mesh.visual.material.baseColorFactor[:3]) / 255.0  # stored as uint8
        np.testing.assert_allclose(rgb, (0.7, 0.6, 0.5), atol=1 / 255)
    # The object's own scene is not changed.
    assert all(
        not np.allclose(np.asarray(m.visual.material.baseColorFactor[:3]) / 255.0, (0.7, 0.6, 0.5))
        for m in obj.scene.geometry.values()
    )


def test_palette_of_a_textured_station_averages_its_maps():
    palette = station_palette(build_outpost("hub", textured=True))
    by_name = {entry[0]: entry for entry in palette}
    colour, _, roughness = OUTPOST_MATERIALS["beta_cloth"]
    _, rgb, got_metallic, got_roughness, _ = by_name["beta_cloth"]
    # Seams darken and vary the maps a little; the factors alone (1) would be far off.
    np.testing.assert_allclose(rgb, colour, rtol=0.25)
    assert got_metallic < 0.05 and abs(got_roughness - roughness) < 0.1


# ---------------------------------------------------------------------- light model
def test_material_departures_move_every_roughness_and_specular_level():
    config = CyclesLightConfig()
    names = {f"m{i}": r for i, r in enumerate(np.linspace(0.0, 1.0, 41))}
    departures = draw_material_departures(names, np.random.default_rng(5), config)
    assert set(departures) == set(names)
    low, high = ROUGHNESS_RANGE
    for name, roughness in names.items():
        d = departures[name]
        assert abs(d.roughness_shift) >= config.roughness_shift[0] - 1e-12
        assert low <= roughness + d.roughness_shift <= high
        assert config.specular_level[0] <= d.specular_level <= config.specular_level[1]
    signs = {np.sign(d.roughness_shift) for d in departures.values()}
    assert signs == {-1.0, 1.0}
    # The same seed draws the same departures.
    again = draw_material_departures(names, np.random.default_rng(5), config)
    assert again == departures


def test_a_shift_that_would_leave_the_range_goes_the_other_way():
    assert shifted_roughness(0.95, 0.3, 1.0) == pytest.approx(-0.3)
    assert shifted_roughness(0.05, 0.3, -1.0) == pytest.approx(0.3)
    assert shifted_roughness(0.5, 0.3, -1.0) == pytest.approx(-0.3)


def test_light_settings_are_validated():
    for bad in (
        {"roughness_shift": (0.2, 1.5)},
        {"specular_level": (0.0, 2.0)},
        {"earthshine": (-0.1, 0.2)},
        {"area_lamp": 1},
        {"area_lamp_size_m": 0.0},
    ):
        with pytest.raises(SynthError):
            CyclesLightConfig(**bad)
    with pytest.raises(SynthError, match="cycles_light"):
        preset("smoke").with_overrides(cycles_light="sunny")


def test_bench_pt_preset_departs_from_the_reference():
    config = preset("bench-pt")
    assert config.query_renderer == "cycles" and config.camera_effects and config.hard_kinds
    assert config.cycles_light is not None and config.cycles_light.area_lamp
    assert set(config.cycles_view_transforms) == {"AgX", "Filmic", "Standard"}
    assert {"thin_cable", "black_foil", "small_debris", "station_patch"} <= set(
        config.anomaly_types
    )
    assert set(config.anomaly_types) <= set(KNOWN_TYPES)
    assert config.colour_probability == 0 and config.scale_probability == 0
    assert (config.width, config.height, config.cycles_samples) == (512, 384, 16)
    assert config.splits["test"].frames == 24


# ---------------------------------------------------------------------- outposts
@pytest.mark.parametrize("layout", LAYOUTS)
def test_outposts_are_other_stations(layout, tmp_path):
    scene = build_outpost(layout)
    names = {g.visual.material.name for g in scene.geometry.values()}
    assert names and not names & set(STATION_MATERIALS)
    extents = np.asarray(scene.extents)
    assert 15.0 <= extents.max() <= 40.0
    station = trimesh.load(MESH, force="scene")
    assert not np.allclose(np.sort(extents), np.sort(station.extents), rtol=0.1)


def test_layouts_differ_and_unknown_layouts_are_refused():
    sizes = {layout: tuple(np.round(build_outpost(layout).extents, 1)) for layout in LAYOUTS}
    assert len(set(sizes.values())) == len(LAYOUTS)
    with pytest.raises(OutpostError, match="torus"):
        build_outpost("torus")


def test_textured_outposts_keep_their_materials_in_maps(tmp_path):
    path = tmp_path / "spine.glb"
    path.write_bytes(build_outpost("spine", textured=True).export(file_type="glb"))
    scene = trimesh.load(path, force="scene")
    for mesh in scene.geometry.values():
        material = mesh.visual.material
        assert material.metallicFactor == pytest.approx(1.0)
        for slot in ("baseColorTexture", "metallicRoughnessTexture", "normalTexture"):
            assert getattr(material, slot) is not None, (material.name, slot)
        assert material.occlusionTexture is not None
        assert mesh.visual.uv is not None and len(mesh.visual.uv) == len(mesh.vertices)
        metal = np.asarray(material.metallicRoughnessTexture.convert("RGB"))[..., 2]
        _, metallic, _ = OUTPOST_MATERIALS[material.name]
        # The map, not the factor of 1, says what is metal: dielectric parts read 0.
        if metallic == 0.0:
            assert metal.max() == 0
        else:
            assert metal.max() == round(255 * metallic)
    flat = build_outpost("spine")
    assert all(g.visual.material.metallicRoughnessTexture is None for g in flat.geometry.values())


# ---------------------------------------------------------------------- with bpy
@needs_bpy
def test_cycles_query_materials_and_lamps_differ_from_the_reference(tmp_path):
    from allo_mrad_ros.synth.cycles import CyclesRenderer

    small = CameraIntrinsics(64, 48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
    outpost = tmp_path / "hub.glb"
    outpost.write_bytes(build_outpost("hub", textured=True).export(file_type="glb"))
    config = CyclesLightConfig()
    for model, textured in ((MESH, False), (outpost, True)):
        renderer = CyclesRenderer(
            model, small, samples=4, light=config, light_rng=np.random.default_rng(1)
        )
        try:
            materials = renderer.station_materials()
            assert materials and set(renderer.material_values) == {m.name for m in materials}
            for material in materials:
                node = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
                roughness = node.inputs["Roughness"]
                gltf = renderer.gltf_roughness[material.name]
                if textured:
                    # The map's roughness goes through the added offset.
                    assert roughness.is_linked
                    add = roughness.links[0].from_node
                    assert add.type == "MATH" and add.operation == "ADD"
                    assert abs(add.inputs[1].default_value) >= config.roughness_shift[0] - 1e-6
                else:
                    assert not roughness.is_linked
                    assert abs(roughness.default_value - gltf) >= config.roughness_shift[0] - 1e-6
                level = node.inputs["Specular IOR Level"].default_value
                assert config.specular_level[0] - 1e-6 <= level <= config.specular_level[1] + 1e-6
            assert renderer._spot.data.type == "AREA"
            if not textured:
                T = look_at([24.0, -18.0, 9.0], [0.0, 0.0, 0.0])
                dark = renderer.render(T, [0.3, -0.5, 0.8], 0.0, view_transform="Standard")
                lit = renderer.render(
                    T,
                    [0.3, -0.5, 0.8],
                    0.0,
                    view_transform="Standard",
                    earthshine=(np.array([24.0, -18.0, 9.0]), 1.0),
                )
                assert lit.mean() > dark.mean() + 5.0
        finally:
            renderer.close()


def test_the_as_built_station_keeps_a_textured_models_maps():
    model = build_outpost("spine", textured=True)
    built = as_built_station(model, np.random.default_rng(0), RealismConfig())
    for name, mesh in built.geometry.items():
        before, after = model.geometry[name].visual.material, mesh.visual.material
        for slot in ("metallicRoughnessTexture", "normalTexture", "occlusionTexture"):
            assert getattr(after, slot) is getattr(before, slot), (name, slot)
        assert after.baseColorTexture is before.baseColorTexture
