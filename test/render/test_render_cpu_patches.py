"""The renderer's CPU patches (uniforms.py, shader_patches.py) draw what pyrender draws.

Each patched path is compared image for image with an unpatched renderer built inside
``plain_pyrender()`` in the same process: exactly, except for the shared-read shadow filter,
whose float rounding may move a rare pixel by one grey level. The pieces are also tested on
their own: the uniform setter against a recording fake of OpenGL, the shadow filter against a
float64 NumPy transcription of pyrender's filter.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh
from PIL import Image

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.geometry import euler_zyx_to_matrix, look_at, optical_to_opengl_pose
from allo_mrad_ros.render import DEFAULT_SCALE, ReferenceRenderer, choose_backend, shader_patches
from allo_mrad_ros.render.backend import import_pyrender
from allo_mrad_ros.render.gl_patches import install_patches, plain_pyrender
from allo_mrad_ros.render.shader_patches import _PCF_PYRENDER, shared_read_pcf
from allo_mrad_ros.render.uniforms import UniformSetter
from harness.scene import BODIES, SUN_CENTRE, viewpoints


def _programs(renderer: ReferenceRenderer) -> list:
    return list(renderer._gl._renderer._program_cache._by_source.values())


def _render_all(renderer: ReferenceRenderer, frames: list) -> list:
    return [
        renderer.render(pose, sun, bodies=BODIES, depth=True, labels=True) for pose, sun in frames
    ]


# The shared-read shadow filter's weights can differ from pyrender's in float rounding: over
# 432 frames at 240x135 (12 poses, 36 Sun directions) 2 pixels differed, by 1 grey level.
SHADOW_FILTER_MAX_DIFF = 1
SHADOW_FILTER_MAX_PIXEL_FRACTION = 1e-4


def _station_frames() -> list:
    poses = viewpoints()
    turned_sun = euler_zyx_to_matrix(0.0, 0.0, np.radians(20.0)) @ np.asarray(SUN_CENTRE)
    # Six poses under one Sun (the shadow map and uniforms are reused), then six under
    # another (both must follow), with Earth, Moon and Sun entering and leaving the view.
    first = [(poses[i], SUN_CENTRE) for i in range(6)]
    return first + [(poses[i], turned_sun) for i in range(6, 12)]


@pytest.fixture(scope="module")
def plain_station_renders() -> list:
    with plain_pyrender():
        plain = ReferenceRenderer(None, ALLO_INTRINSICS, scale=DEFAULT_SCALE, shadows=True)
    with plain:
        expected = _render_all(plain, _station_frames())
        assert not any(isinstance(p.set_uniform, UniformSetter) for p in _programs(plain))
    assert len({r.bodies_in_view for r in expected}) > 2
    assert not np.array_equal(expected[0].rgb, expected[6].rgb)
    return expected


@pytest.mark.parametrize("shadow_filter", [False, True])
def test_patched_station_renders_equal_pyrenders_over_poses_a_sun_change_and_a_rebuild(
    plain_station_renders, shadow_filter, monkeypatch
):
    if not shadow_filter:  # every other patch must give pyrender's pixels exactly
        monkeypatch.setattr(shader_patches, "shared_read_pcf", lambda text: text)
    frames = _station_frames()
    for _rebuild in range(2):  # a second renderer starts from nothing cached
        with ReferenceRenderer(None, ALLO_INTRINSICS, scale=DEFAULT_SCALE) as patched:
            results = _render_all(patched, frames)
            setters = [p.set_uniform for p in _programs(patched)]
        assert setters and all(isinstance(s, UniformSetter) for s in setters)
        assert sum(s.skipped for s in setters) > sum(s.calls for s in setters)
        differing = 0
        for got, want in zip(results, plain_station_renders, strict=True):
            np.testing.assert_array_equal(got.depth, want.depth)
            np.testing.assert_array_equal(got.labels, want.labels)
            assert got.bodies_in_view == want.bodies_in_view
            diff = np.abs(got.rgb.astype(np.int16) - want.rgb.astype(np.int16))
            if not shadow_filter:
                np.testing.assert_array_equal(got.rgb, want.rgb)
            assert diff.max() <= SHADOW_FILTER_MAX_DIFF
            differing += int(np.count_nonzero(diff.max(axis=-1)))
        pixels = sum(r.rgb.shape[0] * r.rgb.shape[1] for r in results)
        assert differing <= SHADOW_FILTER_MAX_PIXEL_FRACTION * pixels


@pytest.mark.parametrize("point_lights", [3, 5])
def test_patched_pyrender_draws_the_same_with_several_lights_per_type_and_textures(
    point_lights, monkeypatch
):
    # Five point lights exceed pyrender's limit of four: it then binds, per primitive, the
    # four nearest, and the lighting is bound per primitive again. The textured primitives
    # take texture units after the shadow maps'. Exact equality: the shadow filter, whose
    # rounding may differ, is left out here (the station test covers it).
    monkeypatch.setattr(shader_patches, "shared_read_pcf", lambda text: text)
    pr = import_pyrender(choose_backend())
    k = CameraIntrinsics(width=96, height=72, fx=90.0, fy=90.0, cx=47.5, cy=35.5)
    plate = trimesh.creation.box(extents=[4.0, 4.0, 0.1])
    checker = np.kron((np.indices((8, 8)).sum(axis=0) % 2) * 200 + 40, np.ones((4, 4)))
    texture = Image.fromarray(np.repeat(checker[..., None], 3, axis=2).astype(np.uint8))
    scene = pr.Scene(ambient_light=(0.02, 0.02, 0.02))
    scene.add(pr.Mesh.from_trimesh(plate, smooth=False))
    for x in (-1.2, 0.3, 1.4):  # placed by node poses: pyrender's nearest lights differ
        blocker = trimesh.creation.box(extents=[0.8, 0.8, 0.8])
        uv = blocker.vertices[:, :2] - blocker.vertices[:, :2].min(axis=0)
        blocker.visual = trimesh.visual.TextureVisuals(uv=uv / uv.max(), image=texture)
        pose = np.eye(4)
        pose[:3, 3] = [x, 0.4 * x, 1.0]
        scene.add(pr.Mesh.from_trimesh(blocker, smooth=False), pose=pose)
    eye = optical_to_opengl_pose(look_at([2.0, -4.0, 5.0], [0.0, 0.0, 0.0]))
    scene.add(pr.IntrinsicsCamera(k.fx, k.fy, k.cx, k.cy), pose=eye)
    for direction in ([0.0, 0.0, 1.0], [1.0, 0.2, 0.6]):
        light = pr.DirectionalLight(intensity=2.0)
        z = np.asarray(direction) / np.linalg.norm(direction)
        x = np.cross([0.0, 1.0, 0.0], z)
        pose = np.eye(4)
        pose[:3, :3] = np.c_[x / np.linalg.norm(x), np.cross(z, x / np.linalg.norm(x)), z]
        scene.add(light, pose=pose)
    positions = ([1.5, 1.0, 2.0], [-1.5, -1.0, 1.0], [0.0, 2.0, 0.5], [2.0, -2.0, 1.5], [-2, 1, 2])
    for position in positions[:point_lights]:
        pose = np.eye(4)
        pose[:3, 3] = position
        scene.add(pr.PointLight(intensity=6.0), pose=pose)
    scene.add(pr.SpotLight(intensity=20.0, outerConeAngle=0.6), pose=eye)
    flags = pr.RenderFlags.SHADOWS_DIRECTIONAL
    images = {}
    for patched in (False, True):
        offscreen = pr.OffscreenRenderer(k.width, k.height)
        try:
            if patched:
                install_patches(pr, offscreen)
            else:
                with plain_pyrender():
                    install_patches(pr, offscreen)
            images[patched] = offscreen.render(scene, flags=flags)[0]
            limits = offscreen._renderer._compute_max_n_lights(flags)
        finally:
            offscreen.delete()
        assert (limits == [2, 1, min(point_lights, 4)]) == patched
    np.testing.assert_array_equal(images[True], images[False])
    assert images[True].std() > 10


def _fake_gl(calls: list) -> SimpleNamespace:
    def record(name):
        return lambda *args: calls.append((name, *args))

    class GLError(Exception):
        pass

    def refuse(*args):
        calls.append(("refused", *args))
        raise GLError

    return SimpleNamespace(
        GL_TRUE=1,
        GLError=GLError,
        glUniform2fv=refuse,
        glGetUniformLocation=lambda program, name: (
            calls.append(("locate", program, name)) or (-1 if name == "absent" else len(name))
        ),
        glUniform1f=record("1f"),
        glUniform1i=record("1i"),
        glUniform3fv=record("3fv"),
        glUniformMatrix4fv=record("m4"),
    )


def test_uniform_setter_sends_each_changed_value_once_per_linked_program():
    calls: list = []
    plain_calls: list = []
    program = SimpleNamespace(_program_id=7, set_uniform=lambda *args: plain_calls.append(args))
    setter = UniformSetter(program, _fake_gl(calls))
    pose = np.arange(16.0).reshape(4, 4)
    setter("M", pose)
    setter("M", pose.copy())  # same value: not sent, not looked up again
    setter("cam_pos", np.array([1.0, 2.0, 3.0]))
    setter("intensity", 2.5)
    setter("n_lights", 1)
    setter("intensity", np.float64(2.5))
    setter("absent", 1.0)  # pyrender ignores uniforms a program lacks
    sent = [c for c in calls if c[0] != "locate"]
    assert [c[0] for c in sent] == ["m4", "3fv", "1f", "1i"]
    located = [c[2] for c in calls if c[0] == "locate"]
    assert located == ["M", "cam_pos", "intensity", "n_lights", "absent"]
    np.testing.assert_array_equal(sent[0][4], pose.astype(np.float32))
    assert sent[0][1:4] == (1, 1, 1)  # location len("M"), one matrix, transposed
    setter("M", pose + 1.0)
    assert calls[-1][0] == "m4"
    setter("flag", True)  # a type pyrender handles itself goes to pyrender
    setter("count", 3, unsigned=True)
    assert plain_calls == [("flag", True, False), ("count", 3, True)]
    setter("refused", np.array([1.0, 2.0]))  # OpenGL refuses: ignored, as pyrender does,
    setter("refused", np.array([1.0, 2.0]))  # and tried again the next time
    assert [c[0] for c in calls[-2:]] == ["refused", "refused"]
    calls.clear()
    program._program_id = 9  # linked again: locations and values are forgotten
    setter("M", pose + 1.0)
    assert [c[0] for c in calls] == ["locate", "m4"]
    calls.clear()
    setter.forget()  # what _add_to_context does before linking
    setter("M", pose + 1.0)
    assert [c[0] for c in calls] == ["locate", "m4"]


def _pyrender_pcf(depth: np.ndarray, uv: np.ndarray, compare: float) -> float:
    """pyrender's mesh.frag PCF, transcribed tap by tap (float64, nearest, border depth 1)."""
    size = depth.shape[0]

    def lit(x: float, y: float) -> float:
        i, j = int(np.floor(x * size)), int(np.floor(y * size))
        d = depth[j, i] if 0 <= i < size and 0 <= j < size else 1.0
        return 1.0 if compare > d else 0.0

    total = 0.0
    for x in (-1, 0, 1):
        for y in (-1, 0, 1):
            p = (uv + np.array([x, y]) / size) * size + 0.5
            f, c = p - np.floor(p), np.floor(p) / size
            t = 1.0 / size
            a = lit(c[0], c[1]) * (1 - f[1]) + lit(c[0], c[1] + t) * f[1]
            b = lit(c[0] + t, c[1]) * (1 - f[1]) + lit(c[0] + t, c[1] + t) * f[1]
            total += a * (1 - f[0]) + b * f[0]
    return total / 9.0


def _shared_read_pcf(depth: np.ndarray, uv: np.ndarray, compare: float) -> float:
    """The replacement's arithmetic: 16 reads around the centre tap, nine bilinear mixes."""
    size = depth.shape[0]
    centre = uv * size + 0.5
    f, base = centre - np.floor(centre), np.floor(centre).astype(int)
    padded = np.pad(depth, 6, constant_values=1.0)
    block = padded[base[1] + 5 : base[1] + 9, base[0] + 5 : base[0] + 9]
    lit = (compare > block).astype(float)  # lit[j, i], texel (base + i - 1, base + j - 1)
    rows = lit[:3] * (1 - f[1]) + lit[1:] * f[1]
    return float((rows[:, :3] * (1 - f[0]) + rows[:, 1:] * f[0]).sum() / 9.0)


def test_shared_read_filter_is_pyrenders_filter():
    rng = np.random.default_rng(3)
    depth = rng.uniform(0.2, 0.8, size=(32, 32))
    for _ in range(400):
        uv = rng.uniform(-0.05, 1.05, size=2)  # edges included: the border reads depth 1
        compare = rng.uniform(0.1, 0.9)
        assert _shared_read_pcf(depth, uv, compare) == pytest.approx(
            _pyrender_pcf(depth, uv, compare), abs=1e-9
        )


def test_shader_text_is_patched_only_where_pyrenders_filter_is_found():
    pr = import_pyrender(choose_backend())
    source = (Path(pr.__file__).parent / "shaders" / "mesh.frag").read_text()
    if _PCF_PYRENDER.search(source) is None:
        pytest.skip("this pyrender's mesh.frag has another filter: it is left unpatched")
    patched = shared_read_pcf(source)
    assert patched != source and "texture2DShadowLerp(depths" not in patched
    assert patched.count("float PCF(") == 1
    assert shared_read_pcf("void main() {}") == "void main() {}"
