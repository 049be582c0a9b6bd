"""OpenGL backend selection for headless rendering (OSMesa on CPU, EGL on a GPU).

PyOpenGL binds its platform (``PYOPENGL_PLATFORM``) once, when ``OpenGL`` is first imported,
so the backend must be chosen before pyrender is imported. :func:`import_pyrender` does both
in the right order; the rest of the package imports pyrender only through it.
"""

from __future__ import annotations

import ctypes.util
import os
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

from allo_mrad_ros.errors import BackendError

BACKENDS = ("egl", "osmesa")
ENV_BACKEND = "ALLO_MRAD_GL_BACKEND"
_LIBRARIES = {"egl": "EGL", "osmesa": "OSMesa"}
INSTALL_HINT = (
    "install a headless OpenGL backend: on a CPU-only machine `apt-get install libosmesa6` "
    "(and use PYOPENGL_PLATFORM=osmesa), on a GPU machine the vendor driver with EGL "
    "(libEGL, PYOPENGL_PLATFORM=egl)"
)


class RendererError(BackendError):
    """No OpenGL context could start, the backend is unsupported, or the renderer is closed.

    Invalid models, poses and parameters raise :class:`~allo_mrad_ros.errors.InvalidInput`.
    """


def gpu_present() -> bool:
    """Return True if this machine exposes a GPU render node (DRM or NVIDIA device)."""
    dri = Path("/dev/dri")
    has_render_node = dri.is_dir() and any(dri.glob("renderD*"))
    return has_render_node or Path("/dev/nvidia0").exists()


def choose_backend(requested: str | None = None) -> str:
    """Return the OpenGL backend to use, ``"egl"`` or ``"osmesa"``.

    Parameters
    ----------
    requested : str or None
        An explicit choice. None falls back to the environment variable
        ``ALLO_MRAD_GL_BACKEND``, then ``PYOPENGL_PLATFORM``, then EGL if a GPU is present
        and ``libEGL`` is installed, else OSMesa.

    Returns
    -------
    str
        The backend name.

    Raises
    ------
    RendererError
        If the name is not a supported backend, or no backend library is installed.
    """
    name = requested or os.environ.get(ENV_BACKEND) or os.environ.get("PYOPENGL_PLATFORM")
    if name:
        name = name.strip().lower()
        if name not in BACKENDS:
            raise RendererError(
                f"unsupported OpenGL backend {name!r}; use one of {', '.join(BACKENDS)}"
            )
        return name
    if gpu_present() and ctypes.util.find_library(_LIBRARIES["egl"]):
        return "egl"
    if ctypes.util.find_library(_LIBRARIES["osmesa"]):
        return "osmesa"
    raise RendererError(f"no headless OpenGL backend found; {INSTALL_HINT}")


def import_pyrender(backend: str) -> ModuleType:
    """Select ``backend`` for PyOpenGL and import pyrender.

    Parameters
    ----------
    backend : str
        ``"egl"`` or ``"osmesa"`` (see :func:`choose_backend`).

    Returns
    -------
    module
        The ``pyrender`` module.

    Raises
    ------
    RendererError
        If OpenGL was already imported for another platform in this process, the backend's
        library is missing, or pyrender fails to import.
    """
    if backend not in BACKENDS:
        raise RendererError(f"unsupported OpenGL backend {backend!r}")
    current = os.environ.get("PYOPENGL_PLATFORM")
    if "OpenGL" in sys.modules and current != backend:
        raise RendererError(
            f"OpenGL was already imported with PYOPENGL_PLATFORM={current!r}; cannot switch "
            f"to {backend!r} in this process. Set PYOPENGL_PLATFORM={backend} before starting."
        )
    if not ctypes.util.find_library(_LIBRARIES[backend]):
        raise RendererError(f"OpenGL backend {backend!r} is not installed; {INSTALL_HINT}")
    # pyrender's OffscreenRenderer reads this variable too, at context creation.
    os.environ["PYOPENGL_PLATFORM"] = backend
    if backend == "egl":
        # pyrender imports its viewer, and with it pyglet's windowing, which needs X11's
        # libraries unless pyglet runs headless (over EGL); a GPU server often has no X11.
        os.environ.setdefault("PYGLET_HEADLESS", "true")
        os.environ.setdefault("PYGLET_SHADOW_WINDOW", "false")
    try:
        import pyrender
    except Exception as error:  # ImportError, or OSError/AttributeError from PyOpenGL
        raise RendererError(
            f"pyrender failed to import with {backend}: {error}; {INSTALL_HINT}"
        ) from error
    return pyrender


class EglDisplayShare:
    """Reference-count the EGL display that every pyrender context of a process shares.

    EGL hands out one display per device and process, and pyrender's ``EGLPlatform``
    calls ``eglTerminate`` on it when any one context is deleted, which leaves every other
    live renderer failing with ``EGL_NOT_INITIALIZED``. :meth:`adopt` replaces a platform's
    ``delete_context`` so that deleting destroys only that platform's context, and the
    display is terminated when the last context on it is gone.

    Parameters
    ----------
    destroy_context, terminate : callable
        ``eglDestroyContext(display, context)`` and ``eglTerminate(display)``; injectable so
        the bookkeeping is testable without a GPU.
    """

    def __init__(
        self,
        destroy_context: Callable[[object, object], object],
        terminate: Callable[[object], object],
    ) -> None:
        self._destroy_context = destroy_context
        self._terminate = terminate
        self._users: dict[int, int] = {}
        self._lock = threading.Lock()

    def users(self, display: object) -> int:
        """Return how many adopted contexts live on ``display``."""
        with self._lock:
            return self._users.get(_display_key(display), 0)

    def adopt(self, platform: Any) -> None:
        """Count ``platform``'s display and make its deletion release only its own context.

        Parameters
        ----------
        platform : pyrender.platforms.egl.EGLPlatform
            A platform whose context has been initialised (``_egl_display`` set).
        """
        key = _display_key(platform._egl_display)
        with self._lock:
            self._users[key] = self._users.get(key, 0) + 1

        def delete_context() -> None:
            display, context = platform._egl_display, platform._egl_context
            if display is None:
                return
            if context is not None:
                self._destroy_context(display, context)
                platform._egl_context = None
            platform._egl_display = None
            with self._lock:
                left = self._users.get(key, 1) - 1
                if left > 0:
                    self._users[key] = left
                else:
                    self._users.pop(key, None)
            if left <= 0:
                self._terminate(display)

        platform.delete_context = delete_context


def pointer_address(pointer: object) -> int | None:
    """The address a ctypes pointer from PyOpenGL holds (an EGL display, a GL context), or
    None for a null one. PyOpenGL hands such handles over as opaque ctypes pointers, whose
    ``value`` is not the address (it may be the pointed-to bytes)."""
    if not pointer:
        return None
    if isinstance(pointer, int):
        return pointer
    try:
        return ctypes.cast(pointer, ctypes.c_void_p).value
    except (TypeError, ctypes.ArgumentError):
        value = getattr(pointer, "value", pointer)
        return value if isinstance(value, int) else None


def _display_key(display: object) -> int:
    return pointer_address(display) or 0


_EGL_SHARE: EglDisplayShare | None = None


def share_egl_display(offscreen_renderer: Any) -> None:
    """Make an EGL ``pyrender.OffscreenRenderer`` release the shared display safely.

    A no-op for any other platform (OSMesa contexts own their buffers and share nothing).
    """
    global _EGL_SHARE
    platform = getattr(offscreen_renderer, "_platform", None)
    if type(platform).__name__ != "EGLPlatform" or platform._egl_display is None:
        return
    if _EGL_SHARE is None:
        from OpenGL.EGL import eglDestroyContext, eglTerminate

        _EGL_SHARE = EglDisplayShare(eglDestroyContext, eglTerminate)
    _EGL_SHARE.adopt(platform)
