"""Building blocks of the Cycles query scene (:mod:`.cycles`): camera, world, bodies, axes.

The camera and axis conversions are plain NumPy (testable without Blender); the functions
that build Blender data take the imported ``bpy`` module as their first argument, so this
module imports nothing of Blender itself.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType

import numpy as np
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.render.bodies import CelestialBody
from allo_mrad_ros.synth.validation import SynthError

GLTF_TO_BLENDER = np.array(
    [[1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
)
"""glTF is +Y up and Blender's glTF importer turns it +Z up: ``p_blender = M @ p_gltf``.
Our station frame is the model file's own frame (as trimesh and the rasteriser read it)."""
SENSOR_WIDTH_MM = 36.0
"""Blender's sensor width; any value works, the focal length is set relative to it."""
BODY_SUBDIVISIONS = 4
"""Icosphere level of the celestial bodies (the rasteriser's)."""


class CyclesError(SynthError):
    """bpy is missing, or a Cycles render or import failed."""


@dataclass(frozen=True)
class BlenderCamera:
    """Blender camera settings that reproduce a pinhole camera matrix.

    Attributes
    ----------
    lens_mm, sensor_width_mm : float
        Focal length and sensor width (horizontal sensor fit).
    shift_x, shift_y : float
        Lens shift in units of the sensor width (Blender's unit under a horizontal fit).
    """

    lens_mm: float
    sensor_width_mm: float
    shift_x: float
    shift_y: float


def blender_camera(intrinsics: CameraIntrinsics) -> BlenderCamera:
    """Blender settings for ``intrinsics`` (square pixels; centres at integer coordinates).

    The image spans ``-0.5 .. width - 0.5``, so its centre is at ``(width - 1) / 2``; a
    principal point right of it is a negative shift (the frame moves left of the axis), and
    Blender's y axis points up where ours points down.
    """
    k = intrinsics
    return BlenderCamera(
        lens_mm=k.fx * SENSOR_WIDTH_MM / k.width,
        sensor_width_mm=SENSOR_WIDTH_MM,
        shift_x=((k.width - 1) / 2.0 - k.cx) / k.width,
        shift_y=(k.cy - (k.height - 1) / 2.0) / k.width,
    )


def set_camera(camera: object, intrinsics: CameraIntrinsics, znear: float, zfar: float) -> None:
    """Apply :func:`blender_camera` and the clipping distances to a ``bpy`` camera."""
    settings = blender_camera(intrinsics)
    camera.sensor_fit = "HORIZONTAL"
    camera.sensor_width = settings.sensor_width_mm
    camera.lens = settings.lens_mm
    camera.shift_x, camera.shift_y = settings.shift_x, settings.shift_y
    camera.clip_start, camera.clip_end = znear, zfar


@contextlib.contextmanager
def blender_output(log: Path) -> Iterator[None]:
    """Send C-level stdout and stderr (Blender's log lines) to ``log`` for the duration."""
    saved = [os.dup(1), os.dup(2)]
    try:
        with log.open("ab") as sink:
            os.dup2(sink.fileno(), 1)
            os.dup2(sink.fileno(), 2)
            yield
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)


def log_tail(log: Path, lines: int = 5) -> str:
    """The last lines of a Blender log, joined for an error message."""
    text = log.read_text(errors="replace") if log.exists() else ""
    return " | ".join(text.strip().splitlines()[-lines:])


def add_space_world(bpy: ModuleType, scene: object, ambient: float) -> None:
    """A world whose uniform ``ambient`` radiance lights surfaces, while space looks black.

    The rasteriser adds ``ambient * albedo`` to every surface and draws space black; here
    only camera rays see black, so shading rays gather the ambient level (and the path
    tracer occludes it where the rasteriser does not).
    """
    world = bpy.data.worlds.new("space")
    scene.world = world
    if world.node_tree is None:  # Blender before 5.0 made node trees on request
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    lit = nodes.new("ShaderNodeBackground")
    lit.inputs["Color"].default_value = (ambient, ambient, ambient, 1.0)
    dark = nodes.new("ShaderNodeBackground")
    dark.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    path = nodes.new("ShaderNodeLightPath")
    mix = nodes.new("ShaderNodeMixShader")
    out = nodes.new("ShaderNodeOutputWorld")
    links.new(path.outputs["Is Camera Ray"], mix.inputs[0])
    links.new(lit.outputs[0], mix.inputs[1])
    links.new(dark.outputs[0], mix.inputs[2])
    links.new(mix.outputs[0], out.inputs["Surface"])


def body_object(bpy: ModuleType, scene: object, body: CelestialBody) -> object:
    """A unit sphere for a celestial body: rough and lit, or glowing like the Sun's disc."""
    import bmesh

    mesh = bpy.data.meshes.new(f"body:{body.name}")
    bm = bmesh.new()
    bmesh.ops.create_icosphere(bm, subdivisions=BODY_SUBDIVISIONS, radius=1.0)
    bm.to_mesh(mesh)
    bm.free()
    mesh.shade_smooth()
    material = bpy.data.materials.new(f"body:{body.name}")
    if material.node_tree is None:
        material.use_nodes = True
    shader = next(n for n in material.node_tree.nodes if n.type == "BSDF_PRINCIPLED")
    colour = (*body.resolved_colour, 1.0)
    if body.is_emissive:
        shader.inputs["Base Color"].default_value = (0.0, 0.0, 0.0, 1.0)
        shader.inputs["Emission Color"].default_value = colour
        shader.inputs["Emission Strength"].default_value = 1.0
    else:
        shader.inputs["Base Color"].default_value = colour
    shader.inputs["Roughness"].default_value = 1.0
    mesh.materials.append(material)
    obj = bpy.data.objects.new(f"body:{body.name}", mesh)
    scene.collection.objects.link(obj)
    return obj


def as_glb(source: object, folder: Path, name: str) -> Path:
    """A glTF file of ``source``: the file itself, or a GLB written to ``folder``.

    Parameters
    ----------
    source : path, trimesh.Trimesh or trimesh.Scene
        A model file (glTF/GLB used as it is; other formats trimesh reads are converted) or
        a mesh or scene (e.g. the as-built station, a worn anomaly object).
    folder : pathlib.Path
        Where to write a converted model.
    name : str
        File stem of the written model, and the name in error messages.

    Returns
    -------
    pathlib.Path
        The glTF or GLB file.
    """
    if isinstance(source, (str, os.PathLike)):
        path = Path(source)
        if not path.is_file():
            raise CyclesError(f"{name}: model file not found: {path}")
        if path.suffix.lower() in (".glb", ".gltf"):
            return path
        source = trimesh.load(path, force="scene")
    if isinstance(source, trimesh.Trimesh):
        source = trimesh.Scene(source)
    if not isinstance(source, trimesh.Scene):
        raise CyclesError(f"{name}: expected a path or a trimesh scene, got {type(source)}")
    path = folder / f"{name}.glb"
    path.write_bytes(source.export(file_type="glb"))
    return path


def configure_render(
    scene: object,
    intrinsics: CameraIntrinsics,
    samples: int,
    denoise: bool,
    threads: int,
    view_transform: str | None,
    seed: int,
) -> None:
    """Cycles on the CPU at the camera's size, writing 8-bit RGB PNG (see :mod:`.cycles`)."""
    k = intrinsics
    render = scene.render
    render.engine = "CYCLES"
    render.resolution_x, render.resolution_y = k.width, k.height
    render.resolution_percentage = 100
    # Not persistent: with data kept between frames, Cycles took an object imported in a
    # later frame for one of an earlier frame and drew it with the old material.
    render.use_persistent_data = False
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "RGB"
    render.image_settings.color_depth = "8"
    if threads:
        render.threads_mode, render.threads = "FIXED", threads
    cycles = scene.cycles
    cycles.device = "CPU"
    cycles.samples = samples
    cycles.seed = seed
    cycles.use_denoising = bool(denoise)
    if denoise:
        cycles.denoiser = "OPENIMAGEDENOISE"
    if view_transform is not None:
        scene.view_settings.view_transform = view_transform
