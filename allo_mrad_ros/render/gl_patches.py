"""Patches to pyrender's offscreen renderer: bounded scenes, shader cache, shadow-map reuse.

Installed on one renderer's GL context at construction; nothing here changes pixels. The CPU
patches it also installs (:func:`install_patches`) change none either, except the shadow
filter of :mod:`.shader_patches`, whose float rounding may move a rare pixel by a grey level."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from types import ModuleType

import numpy as np
import trimesh

from allo_mrad_ros.render.backend import pointer_address
from allo_mrad_ros.render.shader_patches import (
    install_light_limits,
    install_material_shader,
    install_shadow_filter,
)
from allo_mrad_ros.render.uniforms import install_lighting_once_per_pass, install_uniform_cache

_SCENE_CLASSES: dict[int, type] = {}
_CPU_PATCHES = True


@contextlib.contextmanager
def plain_pyrender() -> Iterator[None]:
    """Build renderers in this block without :mod:`.uniforms` and the speed patches of
    :mod:`.shader_patches` (the glTF material patch stays: it says what is drawn).

    They then draw as pyrender does (with the program and shadow-map caches below, which
    change nothing drawn): the benchmark and the image-equality tests compare the two paths.
    """
    global _CPU_PATCHES
    previous, _CPU_PATCHES = _CPU_PATCHES, False
    try:
        yield
    finally:
        _CPU_PATCHES = previous


def install_patches(pr: ModuleType, offscreen: object) -> None:
    """Install the patches of this module, :mod:`.uniforms` and :mod:`.shader_patches`
    (glTF's material, :func:`~.shader_patches.install_material_shader`, on every renderer,
    also inside :func:`plain_pyrender`)."""
    install_program_cache(pr, offscreen)
    install_material_shader(pr, offscreen)
    install_single_sampling(offscreen)
    if _CPU_PATCHES:
        install_uniform_cache(offscreen)
        install_lighting_once_per_pass(offscreen)
        install_shadow_filter(offscreen)
        install_light_limits(offscreen)
    install_shadow_map_cache(pr, offscreen)


def install_single_sampling(offscreen: object) -> None:
    """Draw into single-sampled buffers, as the segmentation pass sees the scene.

    pyrender draws into a framebuffer of 4 samples per pixel and resolves it. OSMesa draws
    one sample all the same; a GPU's driver does not: its colour then blends the station
    with space, and one instance with another, at edges the labels (drawn at pixel centres)
    put elsewhere, and its depth is read at one sample's position, up to 0.7 % off the
    depth at the pixel's centre. Giving pyrender's multisampled buffers 0 samples after it
    makes them (a 0-sample multisampled buffer is a plain one) makes the references the same
    on every backend and driver; a smoother reference is what ``supersampling`` asks for.
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_configure_main_framebuffer"):
        return
    from OpenGL import GL

    configure = renderer._configure_main_framebuffer

    def configure_single_sampled() -> None:
        existed, size = renderer._main_fb_ms is not None, renderer._main_fb_dims
        configure()
        if renderer._main_fb_ms is None or (existed and renderer._main_fb_dims == size):
            return  # pyrender kept the buffers it had: already single-sampled
        width, height = renderer.viewport_width, renderer.viewport_height
        for buffer, storage in (
            (renderer._main_cb_ms, GL.GL_RGBA),
            (renderer._main_db_ms, GL.GL_DEPTH_COMPONENT24),
        ):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, buffer)
            GL.glRenderbufferStorageMultisample(GL.GL_RENDERBUFFER, 0, storage, width, height)
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, 0)

    renderer._configure_main_framebuffer = configure_single_sampled


def current_context() -> int | None:
    """The address of the OpenGL context current on this thread, or None."""
    from OpenGL import platform

    return pointer_address(platform.PLATFORM.GetCurrentContext())


def release_context_data(context: int | None) -> int:
    """Drop what PyOpenGL keeps for a deleted context (its address, as from
    :func:`current_context`); return how many entries went.

    PyOpenGL stores the pointer of every ``glVertexAttribPointer`` call (42 for the station
    model) per context, and pyrender never asks it to forget them. Under OSMesa and EGL the
    key is a new ctypes pointer object on every call, never equal to another, so even
    PyOpenGL's own ``cleanupContext`` cannot find them: they are matched by address here.
    Call it only after the context is deleted (the GL may still read the pointers before).
    """
    if context is None:
        return 0
    from OpenGL import contextdata

    dropped = 0
    for storage in contextdata.STORAGES:
        for key in list(storage):  # a copy made without running Python code: thread-safe
            if pointer_address(key) == context:
                storage.pop(key, None)
                dropped += 1
    return dropped


def bounded_scene_class(pr: ModuleType) -> type:
    """A pyrender Scene whose bounds (used only to fit shadow maps) can be pinned."""
    if id(pr) not in _SCENE_CLASSES:

        class BoundedScene(pr.Scene):
            caster_bounds: np.ndarray | None = None

            @property
            def bounds(self) -> np.ndarray:
                if self.caster_bounds is not None:
                    return self.caster_bounds
                return super().bounds

        _SCENE_CLASSES[id(pr)] = BoundedScene
    return _SCENE_CLASSES[id(pr)]


def install_program_cache(pr: ModuleType, offscreen: object) -> None:
    """Make pyrender reuse compiled shader programs across frames.

    pyrender keys its program cache by ``OpenGL.contextdata.getContext()``, which under
    OSMesa (and EGL) returns a new ctypes pointer object on every call; those never compare
    equal, so every primitive's shaders were recompiled on every frame and the cache grew
    without bound. Each ReferenceRenderer owns one context, so the key needs no context.
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_program_cache"):
        return
    base = pr.shader_program.ShaderProgramCache

    class StableProgramCache(base):
        def __init__(self) -> None:
            super().__init__()
            self._by_source: dict[tuple, object] = {}

        def get_program(
            self,
            vertex_shader: str,
            fragment_shader: str,
            geometry_shader: str | None = None,
            defines: dict | None = None,
        ) -> object:
            key = (
                vertex_shader,
                fragment_shader,
                geometry_shader,
                tuple(sorted((defines or {}).items())),
            )
            if key not in self._by_source:
                self._by_source[key] = super().get_program(
                    vertex_shader, fragment_shader, geometry_shader, defines
                )
            return self._by_source[key]

        def clear(self) -> None:
            super().clear()
            self._by_source = {}

    renderer._program_cache.clear()
    renderer._program_cache = StableProgramCache()


def _shadow_map_inputs(renderer: object, scene: object, light_node: object, flags: int) -> tuple:
    """Everything a light's shadow map depends on.

    The flags, the shadow texture, the light camera (its pose and projection follow from the
    light's pose and the scene bounds) and every mesh that reaches the light camera's view
    volume, with its pose. Meshes wholly outside that volume are clipped from the map: the
    Sun disc, Earth and Moon, which move with the camera, never invalidate it. Meshes are
    held by reference, so an entry never matches a new mesh that reused a freed object's id.
    """
    view, projection = renderer._get_light_cam_matrices(scene, light_node, flags)
    to_clip = projection @ view
    casters = []
    for node in scene.mesh_nodes:
        if not node.mesh.is_visible:
            continue
        pose = scene.get_pose(node)
        corners = trimesh.bounds.corners(node.mesh.bounds)
        clip = np.c_[corners, np.ones(8)] @ (to_clip @ pose).T
        ndc = clip[:, :3] / clip[:, 3:]
        if ((ndc > 1.0).all(axis=0) | (ndc < -1.0).all(axis=0)).any():
            continue
        casters.append((node.mesh, pose.tobytes()))
    return (int(flags), light_node.light.shadow_texture, to_clip.tobytes(), frozenset(casters))


def install_shadow_map_cache(pr: ModuleType, offscreen: object) -> None:
    """Skip a light's shadow-map pass when nothing it depends on has changed.

    The Sun moves about a degree a day relative to the station, so consecutive frames of a
    stream share its shadow map; the pass renders the casters into a 2048x2048 depth map
    and is most of what shadows cost at the default reference size. The forward pass reads
    the map from the light's texture, which persists in the context between frames.
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_shadow_mapping_pass"):
        return
    render_shadow_map = renderer._shadow_mapping_pass
    drawn: dict[object, tuple] = {}

    def shadow_mapping_pass(scene: object, light_node: object, flags: int) -> None:
        if not isinstance(light_node.light, pr.DirectionalLight):
            render_shadow_map(scene, light_node, flags)
            return
        inputs = _shadow_map_inputs(renderer, scene, light_node, flags)
        if drawn.get(light_node) == inputs:
            return
        drawn.pop(light_node, None)  # a pass that fails leaves the texture in doubt
        render_shadow_map(scene, light_node, flags)
        drawn[light_node] = inputs

    renderer._shadow_mapping_pass = shadow_mapping_pass
