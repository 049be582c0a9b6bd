"""glTF's metallic-roughness material, drawn whole: each texture and mode on a quad of a GLB
written here, rendered under OSMesa, against an oracle that needs no texture (the same quad
with factors alone, vertex normals tilted as the normal map tilts them, or the shader's
arithmetic done in NumPy)."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest
from gltf_quad import GlbWriter, halves, quad_file, uniform

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.render.gltf_materials import MaterialParams
from allo_mrad_ros.render.model import load_model, vertex_tangents

K = CameraIntrinsics(width=64, height=48, fx=60.0, fy=60.0, cx=31.5, cy=23.5)
# 3 m in front of the quad: image right is +x, image up +y; the quad spans +-20 px.
FRONT = look_at([0.0, 0.0, 3.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
BACK = look_at([0.0, 0.0, -3.0], [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))
SUN = (0.5, -0.4, 1.0)
# Pixels of each half, clear of the texture's seam (filtered over a texel) and the edges.
ROWS = slice(16, 32)
LEFT = (ROWS, slice(15, 25))
RIGHT = (ROWS, slice(39, 49))
WHOLE = (ROWS, slice(15, 49))
TOLERANCE = 2  # grey levels: texture filtering and float rounding


def render(path, *, pose=FRONT, sun_strength=1.0, ambient=0.05, spot=4.0, depth=False):
    with ReferenceRenderer(
        path, K, scale=1.0, shadows=False, ambient=ambient, spot_intensity=spot
    ) as renderer:
        return renderer.render(pose, SUN, sun_strength=sun_strength, depth=depth)


def pixels(result, region) -> np.ndarray:
    return result.rgb[region].astype(np.int32)


def max_difference(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.abs(a.astype(np.int32) - b.astype(np.int32)).max())


def srgb_to_linear(level: float) -> float:
    c = level / 255.0
    return c / 12.92 if c < 0.04045 else ((c + 0.055) / 1.055) ** 2.4


def material(colour=(0.8, 0.6, 0.4, 1.0), metallic=0.0, roughness=0.5, **more) -> dict:
    pbr = {"baseColorFactor": list(colour), "metallicFactor": metallic}
    pbr["roughnessFactor"] = roughness
    return {"name": more.pop("name", "m"), "pbrMetallicRoughness": pbr, **more}


def test_metallic_roughness_texture_marks_dielectric_and_metal(tmp_path):
    # B = metallic, G = roughness (R unused: 255 catches a channel mix-up), factors 1.0:
    # the left half is rough paint, the right polished metal.
    texture = halves((255, 230, 0), (255, 60, 255))
    textured = render(
        quad_file(
            tmp_path / "mr.glb",
            material(metallic=1.0, roughness=1.0),
            {"metallicRoughnessTexture": texture},
        )
    )
    paint = render(quad_file(tmp_path / "paint.glb", material(metallic=0.0, roughness=230 / 255)))
    metal = render(quad_file(tmp_path / "metal.glb", material(metallic=1.0, roughness=60 / 255)))
    assert max_difference(pixels(paint, LEFT), pixels(metal, LEFT)) > 30  # the oracle can tell
    assert max_difference(pixels(textured, LEFT), pixels(paint, LEFT)) <= TOLERANCE
    assert max_difference(pixels(textured, RIGHT), pixels(metal, RIGHT)) <= TOLERANCE


# Looking along the Sun's mirror direction at the quad's centre: a highlight in view.
MIRROR = look_at(2.4 * np.array([-0.5, 0.4, 1.0]), [0.0, 0.0, 0.0], up=(0.0, 1.0, 0.0))


@pytest.mark.parametrize(("level", "factor"), [(20, 1.0), (128, 40 / 255)])
def test_roughness_is_green_times_the_factor(tmp_path, level, factor):
    # Metallic 0 (B = 0; R = 255 unused): only G times the factor sets the highlight.
    texture = uniform((255, level, 0))
    textured = render(
        quad_file(
            tmp_path / "r.glb", material(roughness=factor), {"metallicRoughnessTexture": texture}
        ),
        pose=MIRROR,
        spot=0.0,
    )
    smooth = render(
        quad_file(tmp_path / "s.glb", material(roughness=level / 255 * factor)),
        pose=MIRROR,
        spot=0.0,
    )
    rough = render(quad_file(tmp_path / "q.glb", material(roughness=1.0)), pose=MIRROR, spot=0.0)
    assert max_difference(pixels(smooth, WHOLE), pixels(rough, WHOLE)) > 30
    assert max_difference(pixels(textured, WHOLE), pixels(smooth, WHOLE)) <= TOLERANCE


def test_base_colour_texture_times_factor(tmp_path):
    factor = (0.9, 0.5, 0.2, 1.0)
    texture = halves((255, 255, 255, 255), (128, 128, 128, 255))
    textured = render(
        quad_file(tmp_path / "b.glb", material(factor), {"baseColorTexture": texture})
    )
    grey = srgb_to_linear(128)
    full = render(quad_file(tmp_path / "f.glb", material(factor)))
    dim = render(quad_file(tmp_path / "d.glb", material((*np.multiply(factor[:3], grey), 1.0))))
    assert max_difference(pixels(full, LEFT), pixels(dim, LEFT)) > 30
    assert max_difference(pixels(textured, LEFT), pixels(full, LEFT)) <= TOLERANCE
    assert max_difference(pixels(textured, RIGHT), pixels(dim, RIGHT)) <= TOLERANCE


@pytest.mark.parametrize("strength", [1.0, 0.5])
def test_occlusion_darkens_only_the_ambient_light(tmp_path, strength):
    # R = occlusion; G and B opposite, to catch a channel mix-up. Left fully occluded.
    texture = halves((0, 255, 255), (255, 0, 0))
    occluded = render(
        quad_file(
            tmp_path / "ao.glb",
            material(),
            {"occlusionTexture": (texture, {"strength": strength})},
        ),
        ambient=0.4,
    )
    plain = tmp_path / "plain.glb"
    quad_file(plain, material())
    lit = render(plain, ambient=0.4)
    # The ambient term is linear in the ambient light: occlusion ao at strength s leaves
    # (1 - s + s * ao) of it.
    kept = render(plain, ambient=0.4 * (1.0 - strength))
    assert max_difference(pixels(lit, LEFT), pixels(kept, LEFT)) > 10
    assert max_difference(pixels(occluded, LEFT), pixels(kept, LEFT)) <= TOLERANCE
    assert max_difference(pixels(occluded, RIGHT), pixels(lit, RIGHT)) <= TOLERANCE


@pytest.mark.parametrize("strength", [None, 2.0])
def test_emissive_texture_times_factor_in_the_dark(tmp_path, strength):
    factor = np.array([1.0, 0.5, 0.25])
    extra = {}
    if strength is not None:  # KHR_materials_emissive_strength multiplies the factor
        factor_in_file = factor / strength
        extra["extensions"] = {"KHR_materials_emissive_strength": {"emissiveStrength": strength}}
    else:
        factor_in_file = factor
    levels = ((255, 255, 255), (128, 64, 200))
    dark = render(
        quad_file(
            tmp_path / "e.glb",
            material((0.0, 0.0, 0.0, 1.0), emissiveFactor=list(factor_in_file), **extra),
            {"emissiveTexture": halves(*levels)},
        ),
        sun_strength=0.0,
        ambient=0.0,
        spot=0.0,
    )
    for region, level in zip((LEFT, RIGHT), levels, strict=True):
        linear = factor * [srgb_to_linear(c) for c in level]
        expected = 255.0 * np.clip(linear, 0.0, 1.0) ** (1.0 / 2.2)
        np.testing.assert_allclose(
            pixels(dark, region), np.broadcast_to(expected, (16, 10, 3)), atol=1.5
        )


def _mask_scene(tmp_path, cutoff: float | None, name: str, front: bool = True, mode: str = "MASK"):
    """A red quad 3 m from the camera (alpha 60/255 left, 200/255 right) in front of a
    blue one 4 m away."""
    writer = GlbWriter()
    if front:
        texture = writer.texture(halves((255, 255, 255, 60), (255, 255, 255, 200)))
        mask = material((1.0, 0.1, 0.1, 1.0), name="cut", alphaMode=mode)
        mask["pbrMetallicRoughness"]["baseColorTexture"] = {"index": texture}
        if cutoff is not None:
            mask["alphaCutoff"] = cutoff
        writer.quad(writer.material(mask))
    blue = writer.material(material((0.1, 0.2, 1.0, 1.0), name="back"))
    writer.quad(blue, offset=(0.0, 0.0, -1.0), extent=3.0)
    return writer.write(tmp_path / name)


def test_alpha_mask_cuts_out_below_the_cutoff(tmp_path):
    cut = render(_mask_scene(tmp_path, None, "cut.glb"), depth=True)  # cutoff 0.5 (default)
    behind = render(_mask_scene(tmp_path, None, "behind.glb", front=False), depth=True)
    # Left (alpha 0.24 < 0.5): the quad behind shows, at its depth.
    assert max_difference(pixels(cut, LEFT), pixels(behind, LEFT)) <= TOLERANCE
    np.testing.assert_allclose(cut.depth[LEFT], 4.0, atol=1e-3)
    # Right (alpha 0.78): the red quad, opaque, at 3 m.
    assert max_difference(pixels(cut, RIGHT), pixels(behind, RIGHT)) > 50
    assert (pixels(cut, RIGHT)[..., 0] > pixels(cut, RIGHT)[..., 2]).all()
    np.testing.assert_allclose(cut.depth[RIGHT], 3.0, atol=1e-3)
    # A lower cutoff keeps both halves: the cutoff is read from the file.
    kept = render(_mask_scene(tmp_path, 0.2, "kept.glb"), depth=True)
    opaque = render(_mask_scene(tmp_path, None, "opaque.glb", mode="OPAQUE"))
    np.testing.assert_allclose(kept.depth[LEFT], 3.0, atol=1e-3)
    assert max_difference(pixels(kept, WHOLE), pixels(opaque, WHOLE)) <= TOLERANCE


def test_alpha_blend_mixes_with_what_is_behind(tmp_path):
    opaque = render(quad_file(tmp_path / "o.glb", material((0.8, 0.6, 0.4, 1.0))))
    half = render(quad_file(tmp_path / "h.glb", material((0.8, 0.6, 0.4, 0.5), alphaMode="BLEND")))
    # Over black space: half the opaque colour (blending works on the encoded values).
    expected = pixels(opaque, WHOLE) * 0.5
    assert np.abs(pixels(half, WHOLE) - expected).max() <= 1.0


def _tangent_space(tilt: str, degrees: float) -> np.ndarray:
    angle = np.radians(degrees)
    return {
        "x": np.array([np.sin(angle), 0.0, np.cos(angle)]),
        "y": np.array([0.0, np.sin(angle), np.cos(angle)]),
    }[tilt]


@pytest.mark.parametrize(
    ("tilt", "scale", "pose"),
    [("x", 1.0, "front"), ("y", 1.0, "front"), ("x", 0.5, "front"), ("y", 1.0, "back")],
)
def test_normal_map_shades_like_tilted_normals(tmp_path, tilt, scale, pose):
    # A uniform normal map tilting the normal by 35 degrees towards +x or +y (tangent space:
    # +x along u, +y up the image). The oracle: the same quad without a normal map, its
    # vertex normals the decoded, scaled normal (tangent +x, bitangent +y, normal +z).
    level = np.round((_tangent_space(tilt, 35.0) + 1.0) / 2.0 * 255.0).astype(np.uint8)
    decoded = level / 255.0 * 2.0 - 1.0
    decoded[:2] *= scale
    camera = FRONT if pose == "front" else BACK
    mapped = render(
        quad_file(
            tmp_path / "n.glb",
            material(doubleSided=True),
            {"normalTexture": (uniform(tuple(level)), {"scale": scale})},
        ),
        pose=camera,
    )
    tilted = render(
        quad_file(tmp_path / "t.glb", material(doubleSided=True), normal=tuple(decoded)),
        pose=camera,
    )
    flat = render(quad_file(tmp_path / "f.glb", material(doubleSided=True)), pose=camera)
    assert max_difference(pixels(tilted, WHOLE), pixels(flat, WHOLE)) > 10
    assert max_difference(pixels(mapped, WHOLE), pixels(tilted, WHOLE)) <= TOLERANCE


def test_every_texture_and_mode_reaches_the_shader(tmp_path):
    path = quad_file(
        tmp_path / "all.glb",
        material(alphaMode="MASK", alphaCutoff=0.3, doubleSided=True, emissiveFactor=[1, 1, 1]),
        {
            "baseColorTexture": uniform((200, 200, 200, 255)),
            "metallicRoughnessTexture": uniform((0, 128, 0)),
            "normalTexture": (uniform((128, 128, 255)), {"scale": 0.7}),
            "occlusionTexture": (uniform((200, 200, 200)), {"strength": 0.4}),
            "emissiveTexture": uniform((10, 10, 10)),
        },
    )
    (group,) = load_model(path)
    assert group.params == MaterialParams(normal_scale=0.7, occlusion_strength=0.4)
    assert group.tangents is not None and group.tangents.shape == (len(group.positions), 4)
    with ReferenceRenderer(path, K, scale=1.0, shadows=False) as renderer:
        renderer.render(FRONT, SUN)
        cache = renderer._gl._renderer._program_cache
        defines = [dict(key[3]) for key in cache._by_source if key[1] == "mesh.frag"]
    assert len(defines) == 1
    for name in (
        "HAS_BASE_COLOR_TEX",
        "HAS_METALLIC_ROUGHNESS_TEX",
        "HAS_NORMAL_TEX",
        "HAS_OCCLUSION_TEX",
        "HAS_EMISSIVE_TEX",
        "TANGENT_LOC",
        "ALPHA_MASK",
    ):
        assert name in defines[0], name


def test_ignored_extensions_are_named_once_per_file(tmp_path, caplog):
    texture = uniform((200, 200, 200, 255))
    transform = {"extensions": {"KHR_texture_transform": {"scale": [2.0, 2.0]}}, "texCoord": 1}
    path = quad_file(
        tmp_path / "ext.glb",
        material(extensions={"KHR_materials_clearcoat": {"clearcoatFactor": 1.0}}),
        {"baseColorTexture": (texture, transform)},
    )
    with caplog.at_level(logging.WARNING):
        load_model(path)
        load_model(path)
    messages = [r.getMessage() for r in caplog.records if r.levelno == logging.WARNING]
    for feature in ("KHR_texture_transform", "KHR_materials_clearcoat", "texture coordinate"):
        named = [m for m in messages if feature in m]
        assert len(named) == 1, (feature, messages)
        assert str(path) in named[0]


def test_vertex_tangents_follow_u_and_v():
    positions = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    normals = np.tile([0.0, 0.0, 1.0], (4, 1))
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)  # v up, as trimesh stores
    np.testing.assert_allclose(vertex_tangents(positions, normals, uv, faces), [[1, 0, 0, 1]] * 4)
    mirrored = uv * [-1, 1]  # u runs the other way: tangent -x, bitangent still +y
    np.testing.assert_allclose(
        vertex_tangents(positions, normals, mirrored, faces), [[-1, 0, 0, -1]] * 4, atol=1e-12
    )
    degenerate = vertex_tangents(positions, normals, np.zeros((4, 2)), faces)
    np.testing.assert_allclose(np.linalg.norm(degenerate[:, :3], axis=1), 1.0)
    np.testing.assert_allclose(degenerate[:, :3] @ [0.0, 0.0, 1.0], 0.0, atol=1e-12)


def test_material_shader_edits_apply_to_pyrender_text_only():
    import pyrender

    from allo_mrad_ros.render.shader_patches import gltf_material_shader

    source = (Path(pyrender.__path__[0]) / "shaders" / "mesh.frag").read_text(encoding="utf-8")
    patched = gltf_material_shader(source)
    assert patched is not None and "material.normal_scale" in patched
    assert "#ifdef ALPHA_MASK" in patched and "emissive * material.emissive_factor" not in patched
    assert gltf_material_shader(source.replace("color.xyz *= ao;", "color.xyz *= ao * ao;")) is None
