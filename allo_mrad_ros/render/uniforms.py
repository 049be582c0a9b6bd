"""Cut pyrender's per-draw uniform overhead without changing what reaches OpenGL's state.

pyrender's forward pass sets every camera, light and material uniform again for each
primitive, and each ``set_uniform`` first asks OpenGL for the uniform's location by name: at
the default reference size that Python and PyOpenGL work costs more CPU than the rasteriser.
A uniform's value is state of its program object and persists across draws and frames until
the program is linked again, so a call that would store the value already stored changes
nothing; skipping it, and remembering locations per linked program, leaves the GL state at
every draw exactly as pyrender would have left it.

Installed per renderer (on its program cache), never on pyrender's classes, so a renderer
built inside :func:`~.gl_patches.plain_pyrender` keeps pyrender's own behaviour.
"""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np


def _vector_function(gl: ModuleType, size: int, kind: str) -> Callable[..., Any]:
    return getattr(gl, f"glUniform{size}{kind}v")


class UniformSetter:
    """A program's ``set_uniform`` with cached locations that skips unchanged values.

    Mirrors pyrender's ``ShaderProgram.set_uniform`` for the value types pyrender's renderer
    passes (1-D arrays, 4x4 matrices, Python floats and ints); anything else goes to
    pyrender's own method. Like pyrender, uniforms the program does not have, and values
    OpenGL refuses, are ignored.
    """

    def __init__(self, program: Any, gl: ModuleType) -> None:
        self._program = program
        self._gl = gl
        self._plain = program.set_uniform
        self._program_id: int | None = None
        self._locations: dict[str, int] = {}
        self._values: dict[str, object] = {}
        self.calls = 0  # glUniform calls made (tests count them)
        self.skipped = 0  # calls skipped because the stored value was the same

    def forget(self) -> None:
        """Drop cached locations and values (the program is about to be linked anew)."""
        self._program_id = None
        self._locations = {}
        self._values = {}

    def _location(self, name: str) -> int:
        program_id = self._program._program_id
        if program_id != self._program_id:
            self.forget()
            self._program_id = program_id
        location = self._locations.get(name)
        if location is None:
            location = int(self._gl.glGetUniformLocation(program_id, name))
            self._locations[name] = location
        return location

    def __call__(self, name: str, value: object, unsigned: bool = False) -> None:
        if self._program._program_id is None:
            self._plain(name, value, unsigned)
            return
        if isinstance(value, np.ndarray) and value.ndim == 1 and value.dtype.kind == "f":
            data = np.ascontiguousarray(value, dtype=np.float32)
            key: object = data.tobytes()
            call = (_vector_function(self._gl, data.shape[0], "f"), (1, data))
        elif isinstance(value, np.ndarray) and value.shape == (4, 4):
            data = np.ascontiguousarray(value, dtype=np.float32)
            key = data.tobytes()
            call = (self._gl.glUniformMatrix4fv, (1, self._gl.GL_TRUE, data))
        elif type(value) is float or isinstance(value, np.float64):
            key = ("f", float(value))
            call = (self._gl.glUniform1f, (float(value),))
        elif type(value) is int and not unsigned:
            key = ("i", value)
            call = (self._gl.glUniform1i, (value,))
        else:
            self._values.pop(name, None)
            self._plain(name, value, unsigned)
            return
        location = self._location(name)
        if location == -1:
            return
        if self._values.get(name) == key:
            self.skipped += 1
            return
        function, args = call
        try:
            function(location, *args)
        except self._gl.GLError:
            # pyrender ignores a uniform OpenGL refuses (say an int sent to a float); so do we,
            # and remember no value, so the next call tries again.
            self._values.pop(name, None)
            return
        self._values[name] = key
        self.calls += 1


def patch_each_program(offscreen: object, patch: Callable[[object], None]) -> None:
    """Call ``patch`` on every shader program this ``OffscreenRenderer`` hands out.

    ``patch`` runs on each program the cache returns, cached or new, so it must leave an
    already patched program as it is.
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_program_cache"):
        return
    cache = renderer._program_cache
    get_program = cache.get_program

    def get_patched_program(*args: object, **kwargs: object) -> object:
        program = get_program(*args, **kwargs)
        patch(program)
        return program

    cache.get_program = get_patched_program


def install_uniform_cache(offscreen: object) -> None:
    """Give every program this ``OffscreenRenderer`` compiles a :class:`UniformSetter`."""
    import OpenGL.GL as gl

    def give_setter(program: object) -> None:
        if isinstance(program.__dict__.get("set_uniform"), UniformSetter):
            return
        setter = UniformSetter(program, gl)
        add_to_context = program._add_to_context

        def add_and_forget() -> None:
            setter.forget()
            add_to_context()

        program.set_uniform = setter
        program._add_to_context = add_and_forget

    patch_each_program(offscreen, give_setter)


def install_lighting_once_per_pass(offscreen: object) -> None:
    """Bind a pass's lights once per program instead of once per primitive.

    pyrender's ``_bind_lighting`` sets the same light uniforms and binds the same shadow
    maps to the first texture units for every primitive of a pass: what it binds depends on
    the scene, the flags and the program, not on the primitive, unless a light type has more
    lights than the shader takes (then pyrender keeps the nearest to each primitive, and
    this patch steps aside). Primitives after the first that use the same program keep the
    shadow maps on those units (material textures go to the units after them, as before).
    """
    renderer = getattr(offscreen, "_renderer", None)
    if renderer is None or not hasattr(renderer, "_bind_lighting"):
        return
    bind_lighting = renderer._bind_lighting
    forward_pass = renderer._forward_pass
    bound: dict[tuple[int, int], tuple[int, int]] = {}  # (program, flags) -> texture units

    def forward_pass_binding_once(scene: Any, flags: int, seg_node_map: object = None) -> object:
        bound.clear()
        try:
            return forward_pass(scene, flags, seg_node_map=seg_node_map)
        finally:
            bound.clear()

    def bind_lighting_once(scene: Any, program: object, node: object, flags: int) -> None:
        key = (id(program), int(flags))
        units_before = renderer._texture_alloc_idx
        if key in bound and bound[key][0] == units_before:
            renderer._texture_alloc_idx = bound[key][1]
            return
        bind_lighting(scene, program, node, flags)
        limits = renderer._compute_max_n_lights(flags)
        counts = (
            len(scene.directional_light_nodes),
            len(scene.spot_light_nodes),
            len(scene.point_light_nodes),
        )
        if all(n <= limit for n, limit in zip(counts, limits, strict=True)):
            bound[key] = (units_before, renderer._texture_alloc_idx)

    renderer._forward_pass = forward_pass_binding_once
    renderer._bind_lighting = bind_lighting_once
