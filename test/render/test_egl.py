"""EGL renderers share one display: closing one must not break the others.

The bookkeeping is tested with fake EGL calls everywhere; the real replace/close/rebuild
sequence runs in a subprocess with ``PYOPENGL_PLATFORM=egl`` where a GPU and libEGL exist
(PyOpenGL binds its platform once per process, and this suite runs on OSMesa).
"""

from __future__ import annotations

import ctypes.util
import os
import subprocess
import sys
import textwrap
from types import SimpleNamespace

import pytest

from allo_mrad_ros.render.backend import (
    EglDisplayShare,
    gpu_present,
    import_pyrender,
    pointer_address,
)
from allo_mrad_ros.render.gl_patches import install_single_sampling


class _FakeEgl:
    def __init__(self) -> None:
        self.destroyed: list[object] = []
        self.terminated: list[object] = []

    def destroy_context(self, display: object, context: object) -> None:
        self.destroyed.append(context)

    def terminate(self, display: object) -> None:
        self.terminated.append(display)


def _platform(display: int, context: str) -> SimpleNamespace:
    return SimpleNamespace(_egl_display=display, _egl_context=context)


def test_display_is_terminated_only_when_its_last_context_goes():
    egl = _FakeEgl()
    share = EglDisplayShare(egl.destroy_context, egl.terminate)
    first, second, other_gpu = _platform(7, "a"), _platform(7, "b"), _platform(9, "c")
    for platform in (first, second, other_gpu):
        share.adopt(platform)
    assert share.users(7) == 2

    first.delete_context()
    assert egl.destroyed == ["a"] and egl.terminated == []
    assert share.users(7) == 1
    first.delete_context()  # a second delete of the same platform changes nothing
    assert egl.destroyed == ["a"] and share.users(7) == 1

    replacement = _platform(7, "d")
    share.adopt(replacement)
    second.delete_context()
    assert egl.terminated == []
    replacement.delete_context()
    assert egl.terminated == [7] and share.users(7) == 0
    other_gpu.delete_context()
    assert egl.terminated == [7, 9]


_EGL_SCRIPT = textwrap.dedent(
    """
    import gc
    import numpy as np
    import trimesh
    from allo_mrad_ros.camera import CameraIntrinsics
    from allo_mrad_ros.geometry import look_at
    from allo_mrad_ros.render import ReferenceRenderer

    k = CameraIntrinsics(width=160, height=120, fx=150.0, fy=140.0, cx=80.0, cy=60.0)
    box = trimesh.creation.box(extents=(2.0, 1.5, 1.0))
    pose = look_at(np.array([4.0, -3.0, 2.5]), np.zeros(3))

    def build():
        return ReferenceRenderer(box, k, scale=1.0, shadows=True, backend="egl")

    def image(renderer):
        return renderer.render(pose, (1.0, -1.0, 0.5)).rgb

    first = build()
    expected = image(first)
    second = build()
    first.close()                      # close one while another lives
    assert np.array_equal(image(second), expected)
    third = build()
    del second; gc.collect()           # collect one while another lives
    assert np.array_equal(image(third), expected)
    third.close()                      # close the last, then rebuild from nothing
    fourth = build()
    assert np.array_equal(image(fourth), expected)
    fifth = build()
    fourth.close()
    fifth.close()
    sixth = build()                    # replace after both closed, in reverse order
    assert np.array_equal(image(sixth), expected)
    print("EGL-SHARE-OK", expected.mean())
    """
)


@pytest.mark.skipif(
    not (gpu_present() and ctypes.util.find_library("EGL")),
    reason="needs a GPU with libEGL (EGL is not available on CPU-only machines)",
)
def test_egl_renderers_replace_close_and_rebuild_in_any_order():
    env = dict(os.environ, PYOPENGL_PLATFORM="egl", ALLO_MRAD_GL_BACKEND="egl")
    done = subprocess.run(
        [sys.executable, "-c", _EGL_SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr[-3000:]
    assert "EGL-SHARE-OK" in done.stdout


def test_pointer_address_reads_an_opaque_pointer_not_its_bytes():
    class _Opaque(ctypes.Structure):
        pass

    address = 0x2EE826C0
    handle = ctypes.cast(ctypes.c_void_p(address), ctypes.POINTER(_Opaque))
    assert pointer_address(handle) == address
    assert pointer_address(ctypes.c_void_p(address)) == address
    assert pointer_address(7) == 7
    assert pointer_address(None) is None
    assert pointer_address(ctypes.POINTER(_Opaque)()) is None  # a null pointer


def test_egl_imports_pyrender_with_pyglet_headless(monkeypatch):
    # pyrender imports pyglet's windowing, which needs X11 unless pyglet runs headless.
    monkeypatch.setattr(ctypes.util, "find_library", lambda name: f"lib{name}.so")
    monkeypatch.setitem(sys.modules, "pyrender", SimpleNamespace(name="fake pyrender"))
    monkeypatch.setenv("PYOPENGL_PLATFORM", "egl")
    monkeypatch.delenv("PYGLET_HEADLESS", raising=False)
    monkeypatch.delenv("PYGLET_SHADOW_WINDOW", raising=False)
    assert import_pyrender("egl").name == "fake pyrender"
    assert os.environ["PYGLET_HEADLESS"] == "true"
    assert os.environ["PYGLET_SHADOW_WINDOW"] == "false"


class _FakeRenderer:
    """pyrender's Renderer as far as its main framebuffer goes: made when missing, made
    again when the viewport's size changes, with new buffer names each time."""

    def __init__(self) -> None:
        self.viewport_width, self.viewport_height = 64, 48
        self._main_fb_ms = self._main_cb_ms = self._main_db_ms = None
        self._main_fb_dims = (None, None)
        self._names = iter(range(10, 100))

    def _configure_main_framebuffer(self) -> None:
        size = (self.viewport_width, self.viewport_height)
        if self._main_fb_ms is not None and self._main_fb_dims != size:
            self._main_fb_ms = None
        if self._main_fb_ms is None:
            self._main_fb_ms, self._main_cb_ms, self._main_db_ms = (
                next(self._names) for _ in range(3)
            )
            self._main_fb_dims = size


def test_pyrenders_multisampled_buffers_get_0_samples_whenever_made(monkeypatch):
    from OpenGL import GL

    storage: list[tuple] = []
    bound: list[int] = []
    monkeypatch.setattr(GL, "glBindRenderbuffer", lambda target, name: bound.append(name))
    monkeypatch.setattr(
        GL,
        "glRenderbufferStorageMultisample",
        lambda target, samples, fmt, width, height: storage.append(
            (bound[-1], samples, fmt, width, height)
        ),
    )
    renderer = _FakeRenderer()
    install_single_sampling(SimpleNamespace(_renderer=renderer))

    renderer._configure_main_framebuffer()
    colour, depth = renderer._main_cb_ms, renderer._main_db_ms
    assert storage == [
        (colour, 0, GL.GL_RGBA, 64, 48),
        (depth, 0, GL.GL_DEPTH_COMPONENT24, 64, 48),
    ]
    renderer._configure_main_framebuffer()  # the same buffers: nothing to do
    assert len(storage) == 2
    renderer.viewport_width = 80  # pyrender makes new ones, multisampled again
    renderer._configure_main_framebuffer()
    assert storage[2:] == [
        (renderer._main_cb_ms, 0, GL.GL_RGBA, 80, 48),
        (renderer._main_db_ms, 0, GL.GL_DEPTH_COMPONENT24, 80, 48),
    ]
    assert renderer._main_cb_ms != colour
