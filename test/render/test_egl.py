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

from allo_mrad_ros.render.backend import EglDisplayShare, gpu_present


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
