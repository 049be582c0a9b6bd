"""Tests of the query's departures from the recorded metadata and the CAD model.

Each effect of the generator's query path (light, surfaces, camera, anomaly variants) is
checked against its definition: a float64 oracle, the statistics of its draws, or a render.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from trimesh.visual.material import PBRMaterial

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.render.renderer import AMBIENT, SPOT_INTENSITY
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.synth.config import RealismConfig, SynthError, preset
from allo_mrad_ros.synth.lighting import query_lamps, query_light
from allo_mrad_ros.synth.objects import ObjectError, build_anomaly
from allo_mrad_ros.synth.planning import plan_frames
from allo_mrad_ros.synth.realism import CameraLook, apply_camera, tone_curve
from allo_mrad_ros.synth.surfaces import (
    TEXTURE_SIZE,
    as_built_station,
    box_uv,
    procedural_texture,
    worn_object,
)

# Everything but the effect under test switched off, so its result can be predicted.
BARE = RealismConfig(
    exposure_sigma=0.0,
    read_noise_dn=0.0,
    shot_noise_dn=0.0,
    blur_sigma=0.0,
    vignetting=0.0,
    bloom=0.0,
    glare=0.0,
    white_balance_sigma=0.0,
)
_GAMMA = 2.2


def _develop(rgb: np.ndarray, gains, saturation: float, contrast: float) -> np.ndarray:
    """Float64 per-pixel oracle of the camera's colour path, noise and optics off."""
    linear = (rgb / 255.0) ** _GAMMA * np.asarray(gains, dtype=np.float64)
    luma = linear @ np.array([0.2126, 0.7152, 0.0722])
    linear = luma[..., None] + saturation * (linear - luma[..., None])
    d = np.clip(linear, 0.0, 1.0) ** (1.0 / _GAMMA)
    if contrast != 1.0:
        d = d**contrast / (d**contrast + (1.0 - d) ** contrast)
    return np.clip(np.rint(255.0 * d), 0, 255)


def _patches() -> np.ndarray:
    rng = np.random.default_rng(2)
    image = np.zeros((40, 60, 3), np.uint8)
    image[5:35, 5:55] = rng.integers(20, 235, (30, 50, 3))
    return image


# ---------------------------------------------------------------------- the camera
def test_tone_curve_is_an_s_curve():
    d = np.linspace(0.0, 1.0, 1001)
    np.testing.assert_array_equal(tone_curve(d, 1.0), d)
    curve = tone_curve(d, 1.3)
    np.testing.assert_allclose(curve[[0, 500, 1000]], [0.0, 0.5, 1.0], atol=1e-12)
    assert np.all(np.diff(curve) >= 0)
    assert np.all(curve[1:500] < d[1:500]) and np.all(curve[501:1000] > d[501:1000])
    # Steeper than identity at the pivot, flatter at both ends.
    slope = np.gradient(curve, d)
    assert slope[500] > 1.1 and slope[20] < 1.0 and slope[980] < 1.0


def test_camera_colour_path_matches_a_float64_oracle():
    image = _patches()
    look = CameraLook(tone_contrast=1.3, saturation=0.8)
    realism = RealismConfig(**{**BARE.__dict__, "white_balance_sigma": 0.05})
    out, effects = apply_camera(image, np.random.default_rng(4), realism, look=look)
    red, blue = effects.white_balance
    assert (red, blue) != (1.0, 1.0) and max(abs(math.log(red)), abs(math.log(blue))) <= 0.15
    expected = _develop(image.astype(np.float64), (red, 1.0, blue), 0.8, 1.3)
    assert np.abs(out.astype(np.float64) - expected).max() <= 1.0
    # Each part of the path changes the image on its own.
    plain, _ = apply_camera(image, np.random.default_rng(4), BARE)
    np.testing.assert_allclose(plain, image, atol=1)
    for other in (CameraLook(1.3, 1.0), CameraLook(1.0, 0.8)):
        changed, _ = apply_camera(image, np.random.default_rng(4), BARE, look=other)
        assert np.abs(changed.astype(float) - image).mean() > 2.0


def test_saturation_keeps_greys_and_shrinks_colour():
    image = np.zeros((2, 2, 3), np.uint8)
    image[0, 0] = (200, 40, 40)
    image[1, 1] = (120, 120, 120)
    out, _ = apply_camera(image, np.random.default_rng(0), BARE, look=CameraLook(1.0, 0.8))
    assert np.ptp(out[1, 1].astype(int)) == 0 and abs(int(out[1, 1, 0]) - 120) <= 1
    assert np.ptp(out[0, 0].astype(int)) < np.ptp(image[0, 0].astype(int)) - 10


def test_white_balance_draws_have_the_configured_spread():
    realism = RealismConfig(**{**BARE.__dict__, "white_balance_sigma": 0.03})
    image = np.full((2, 2, 3), 128, np.uint8)
    rng = np.random.default_rng(7)
    gains = np.log([apply_camera(image, rng, realism)[1].white_balance for _ in range(800)])
    assert np.allclose(gains.std(axis=0), 0.03, rtol=0.15)
    assert np.abs(gains).max() <= 0.09 + 1e-12 and abs(gains.mean()) < 0.01


def test_camera_look_draws_within_its_ranges():
    realism = RealismConfig()
    looks = [CameraLook.draw(np.random.default_rng(i), realism) for i in range(50)]
    contrasts = [look.tone_contrast for look in looks]
    saturations = [look.saturation for look in looks]
    assert min(contrasts) >= 1.1 and max(contrasts) <= 1.4 and np.ptp(contrasts) > 0.15
    assert min(saturations) >= 0.8 and max(saturations) <= 1.05
    assert CameraLook.draw(np.random.default_rng(0), RealismConfig(enabled=False)) == CameraLook()


# ---------------------------------------------------------------------- the light
def test_query_light_turns_and_scales_the_recorded_sun():
    realism = RealismConfig(sun_direction_sigma_deg=1.0, sun_strength_sigma=0.15)
    recorded = np.array([0.3, -0.5, 0.8])
    unit = recorded / np.linalg.norm(recorded)
    rng = np.random.default_rng(3)
    lights = [query_light(rng, realism, recorded, 0.5) for _ in range(2000)]
    directions = np.array([light.sun_direction for light in lights])
    np.testing.assert_allclose(np.linalg.norm(directions, axis=1), 1.0, atol=1e-12)
    angles = np.degrees(np.arccos(np.clip(directions @ unit, -1, 1)))
    np.testing.assert_allclose(angles, [light.angle_deg for light in lights], atol=1e-6)
    # The angle off a rotation with N(0, s) per axis: its two components across the
    # direction count, so the mean squared angle is 2 s**2.
    assert math.sqrt(np.mean(angles**2)) == pytest.approx(math.sqrt(2.0), rel=0.08)
    log_ratio = np.log([light.sun_strength / 0.5 for light in lights])
    assert log_ratio.std() == pytest.approx(0.15, rel=0.08) and abs(log_ratio.mean()) < 0.02
    off = query_light(rng, RealismConfig(enabled=False), recorded, 0.5)
    np.testing.assert_allclose(off.sun_direction, unit)
    assert off.sun_strength == 0.5 and off.angle_deg == 0.0


def test_query_lamps_scale_the_renderer_defaults():
    draws = np.array([query_lamps(np.random.default_rng(i), RealismConfig()) for i in range(200)])
    assert draws[:, 0].min() >= 0.5 * AMBIENT and draws[:, 0].max() <= 2.0 * AMBIENT
    assert draws[:, 1].min() >= 0.7 * SPOT_INTENSITY and draws[:, 1].max() <= 1.3 * SPOT_INTENSITY
    assert np.ptp(draws[:, 0]) > 0.5 * AMBIENT
    off = query_lamps(np.random.default_rng(0), RealismConfig(enabled=False))
    assert off == (AMBIENT, SPOT_INTENSITY)


# ---------------------------------------------------------------------- the surfaces
def test_procedural_texture_statistics_seams_and_tiling():
    texture = procedural_texture(np.random.default_rng(0), 0.1)
    assert texture.shape == (TEXTURE_SIZE, TEXTURE_SIZE) and texture.min() > 0
    assert texture.mean() == pytest.approx(1.0)
    assert np.log(texture).std() == pytest.approx(0.1, rel=0.05)
    # Tileable: the step across the wrap is like any step inside.
    inside = np.abs(np.diff(texture, axis=0)).mean()
    across = np.abs(texture[0] - texture[-1]).mean()
    assert across < 2.0 * inside
    seamed = procedural_texture(np.random.default_rng(0), 0.1, seam_darkening=0.2)
    ratio = seamed / texture
    assert ratio[0, 100] == pytest.approx(0.8 * ratio[100, 100])
    assert np.array_equal(procedural_texture(np.random.default_rng(0), 0.0), np.ones_like(texture))
    with pytest.raises(SynthError):
        procedural_texture(np.random.default_rng(0), -0.1)


def test_box_uv_keeps_geometry_and_maps_metres():
    box = trimesh.creation.box((2.0, 1.0, 0.5))
    split, uv = box_uv(box, 0.5, np.array([0.25, 0.0]))
    assert len(split.vertices) == len(uv) == 3 * len(box.faces)
    np.testing.assert_allclose(split.triangles, box.triangles)
    # Flat part: per-corner normals are the face normals.
    np.testing.assert_allclose(split.vertex_normals, np.repeat(box.face_normals, 3, axis=0))
    top = np.repeat(np.abs(box.face_normals[:, 2]) > 0.9, 3)
    np.testing.assert_allclose(np.ptp(uv[top], axis=0), [4.0, 2.0])  # 2 m x 1 m, 0.5 m tiles


@pytest.fixture(scope="module")
def station():
    return trimesh.load(share_path("meshes", "station.glb"), force="scene")


def test_as_built_station_gives_each_part_its_own_textured_material(station):
    built = as_built_station(station, np.random.default_rng(0), RealismConfig())
    assert as_built_station(station, np.random.default_rng(0), RealismConfig(enabled=False)) is (
        station
    )
    colours = set()
    for name, mesh in built.geometry.items():
        original = station.geometry[name]
        material = mesh.visual.material
        assert isinstance(material, PBRMaterial) and material.baseColorTexture is not None
        assert len(mesh.visual.uv) == len(mesh.vertices) == 3 * len(original.faces)
        np.testing.assert_allclose(mesh.triangles, original.triangles)
        # Smooth-shading normals of the file survive (a copied mesh would lose them).
        np.testing.assert_allclose(
            mesh.vertex_normals,
            original.vertex_normals[original.faces].reshape(-1, 3),
            atol=1e-6,
        )
        colours.add(tuple(np.round(_mean_albedo(material), 4)))
    assert len(colours) == len(built.geometry)  # per-part shifts: no two parts alike
    assert built.geometry.keys() == station.geometry.keys()


def _mean_albedo(material: PBRMaterial) -> np.ndarray:
    """Mean linear albedo of a material: its factor times its decoded sRGB texture."""
    factor = np.asarray(material.baseColorFactor[:3], dtype=np.float64) / 255.0
    if material.baseColorTexture is None:
        return factor
    srgb = np.asarray(material.baseColorTexture, dtype=np.float64)[..., :3] / 255.0
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return factor * linear.reshape(-1, 3).mean(axis=0)


def test_as_built_albedo_stays_near_the_cad_colours(station):
    built = as_built_station(station, np.random.default_rng(5), RealismConfig())
    ratios = []
    for name, mesh in built.geometry.items():
        nominal = _mean_albedo(station.geometry[name].visual.material)
        ratios.append(_mean_albedo(mesh.visual.material) / np.maximum(nominal, 1e-3))
    ratios = np.log(np.array(ratios))
    # Material +-8 %, part sd 6 %, clipping of bright texels: moderate, not a new station.
    assert np.abs(ratios).max() < 0.35 and ratios.std() > 0.02


def _panel_render(scene: trimesh.Scene) -> np.ndarray:
    k = CameraIntrinsics(160, 120, 200.0, 200.0, 80.0, 60.0)
    camera = look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0])
    with ReferenceRenderer(scene, k, scale=1.0, shadows=False) as renderer:
        return renderer.render(camera, [0.0, 0.0, 1.0], 1.0).rgb[30:90, 40:120].astype(float)


def test_texture_shows_on_a_rendered_panel():
    panel = trimesh.creation.box((4.0, 4.0, 0.1))
    panel.visual = trimesh.visual.TextureVisuals(
        material=PBRMaterial(
            name="paint", baseColorFactor=(0.5, 0.5, 0.5, 1.0), roughnessFactor=0.9
        )
    )
    scene = trimesh.Scene({"panel": panel})
    flat = _panel_render(scene)
    plain = RealismConfig(material_variation=0.0, part_variation=0.0, texture_contrast=0.0)
    untextured = _panel_render(as_built_station(scene, np.random.default_rng(1), plain))
    textured = _panel_render(
        as_built_station(
            scene,
            np.random.default_rng(1),
            RealismConfig(material_variation=0.0, part_variation=0.0),
        )
    )
    np.testing.assert_allclose(untextured, flat, atol=1.0)
    grain = textured - cv2_blur(textured)
    assert np.abs(grain).mean() > 3.0 * np.abs(untextured - cv2_blur(untextured)).mean() + 0.2
    assert abs(textured.mean() - flat.mean()) < 0.15 * flat.mean()


def cv2_blur(image: np.ndarray) -> np.ndarray:
    import cv2

    return cv2.GaussianBlur(image, (0, 0), 6.0)


def test_worn_object_keeps_the_shape_and_changes_the_surface():
    obj = build_anomaly("cubesat_3u", 4)
    worn = worn_object(obj.scene, np.random.default_rng(0), RealismConfig())
    assert worn_object(obj.scene, np.random.default_rng(0), RealismConfig(enabled=False)) is (
        obj.scene
    )
    np.testing.assert_allclose(worn.bounds, obj.scene.bounds)
    for name, mesh in worn.geometry.items():
        before = obj.scene.geometry[name].visual.material
        after = mesh.visual.material
        assert after.baseColorTexture is not None and len(mesh.visual.uv) == len(mesh.vertices)
        ratio = _mean_albedo(after) / np.maximum(_mean_albedo(before), 1e-3)
        assert not np.allclose(ratio, 1.0, atol=0.005) and np.all(ratio < 1.6)


# ---------------------------------------------------------------------- anomaly variants
def test_scale_variant_scales_the_object_and_is_planned_at_its_rate():
    whole, half = build_anomaly("drill", 3), build_anomaly("drill", 3, scale=0.5)
    np.testing.assert_allclose(half.extents, 0.5 * whole.extents)
    assert half.scale == 0.5 and half.radius == pytest.approx(0.5 * whole.radius)
    for bad in (0.0, 1.5, True):
        with pytest.raises(ObjectError):
            build_anomaly("drill", 3, scale=bad)
    config = preset("bench")
    plans = [p for p in plan_frames(config, 0) if p.is_anomalous]
    scaled = [p.scale for p in plans if p.scale != 1.0]
    assert set(scaled) == {0.3, 0.5, 0.7}
    assert len(scaled) / len(plans) == pytest.approx(config.scale_probability, abs=0.06)
    assert all(p.scale == 1.0 for p in plan_frames(config, 0) if not p.is_anomalous)
    with pytest.raises(SynthError):
        config.with_overrides(scales=(0.0,))


def test_new_realism_settings_are_validated():
    for change in (
        {"tone_contrast": (1.4, 1.1)},
        {"tone_contrast": (1.0, 9.0)},
        {"saturation": (-0.1, 1.0)},
        {"white_balance_sigma": 1.0},
        {"sun_direction_sigma_deg": -1.0},
        {"ambient_gain": (2.0, 1.0)},
        {"texture_tile_m": 0.0},
        {"seam_darkening": 1.0},
    ):
        with pytest.raises(SynthError):
            RealismConfig(**change)


def test_camera_effects_are_deterministic_and_modest():
    rng_image = np.random.default_rng(1)
    clean = np.zeros((90, 160, 3), np.uint8)
    clean[20:70, 40:120] = rng_image.integers(40, 200, (50, 80, 3))
    a, ea = apply_camera(clean, np.random.default_rng(5), RealismConfig())
    b, eb = apply_camera(clean, np.random.default_rng(5), RealismConfig())
    assert np.array_equal(a, b) and ea == eb
    assert not np.array_equal(a, clean)
    assert np.abs(a.astype(float) - clean).mean() < 15.0
    off, _ = apply_camera(clean, np.random.default_rng(5), RealismConfig(enabled=False))
    assert np.array_equal(off, clean)
