"""Path-traced queries: the generator's query rendered by Blender Cycles (an optional extra).

The reference MRAD compares against is rasterised (pyrender); the product is judged on
path-traced queries. :class:`CyclesRenderer` renders what the generator's query renderer
renders, with Cycles through Blender's ``bpy`` module: the same triangles and materials
(written to glTF and read by Blender's glTF importer), the same pinhole camera and pose, a
Sun lamp of the same irradiance and direction, the arm's spot lamp, the ambient level (seen
by shading rays only, so space stays black), the celestial bodies in view and the anomaly
objects. What differs is what a path tracer does: soft shadows and light bounced between
surfaces, occlusion of the ambient light, sampling noise and its denoiser, a pixel filter,
and Blender's default view transform (AgX in Blender 5.0) instead of the rasteriser's
plain gamma 2.2.

No mask is rendered here. The generator keeps the label image of its rasteriser render of
the same geometry from the same pose (same triangles, same projection);
:meth:`CyclesRenderer.silhouette` exists to check that the two agree.

``bpy`` is imported only when a renderer is built (``requirements-cycles.txt``, installed
by ``make bench-cycles``). Blender holds one scene per process: build one renderer per
process; a second one replaces the first one's scene.
"""

from __future__ import annotations

import contextlib
import math
import os
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from types import ModuleType

import cv2
import numpy as np
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import optical_to_opengl_pose
from allo_mrad_ros.render import ExtraObject
from allo_mrad_ros.render.bodies import CelestialBody, bodies_in_view, frustum_planes
from allo_mrad_ros.render.renderer import AMBIENT, SPOT_CONE_DEG, SPOT_INTENSITY, SUN_INTENSITY
from allo_mrad_ros.render.values import object_pose, unit_vector, z_towards
from allo_mrad_ros.synth.cycles_light import (
    EARTHSHINE_COLOUR,
    CyclesLightConfig,
    apply_material_departures,
    draw_material_departures,
    material_roughness,
)
from allo_mrad_ros.synth.cycles_scene import (
    GLTF_TO_BLENDER,
    CyclesError,
    add_space_world,
    as_glb,
    blender_output,
    body_object,
    configure_render,
    log_tail,
    set_camera,
)

INSTALL_HINT = (
    "install the optional extra: make bench-cycles (or pip install -r requirements-cycles.txt)"
)
SUN_ANGLE_DEG = 0.53
"""Apparent diameter of the Sun lamp (the real Sun's): the path tracer's shadows are soft."""
SPOT_RADIUS_M = 0.05
"""Radius of the arm's lamp head."""
_ZNEAR, _ZFAR = 0.05, 1.0e4  # the reference renderer's clipping distances


def import_bpy() -> ModuleType:
    """Import Blender's ``bpy`` module, or raise :class:`CyclesError` saying how to install it."""
    try:
        import bpy
    except ImportError as error:
        raise CyclesError(
            f"Blender's bpy module is not installed ({error}); {INSTALL_HINT}"
        ) from None
    return bpy


def _matrix(bpy_matrix_cls: type, array: np.ndarray) -> object:
    return bpy_matrix_cls([list(map(float, row)) for row in array])


class CyclesRenderer:
    """Render the generator's query scene with Blender Cycles on the CPU.

    Parameters
    ----------
    station : path or trimesh.Scene
        The station model (a glTF/GLB file, or a scene such as the as-built station).
    intrinsics : CameraIntrinsics
        Pinhole intrinsics of the output image (square pixels).
    samples : int
        Path-tracing samples per pixel (adaptive sampling may stop earlier).
    denoise : bool
        Denoise with OpenImageDenoise.
    threads : int
        CPU threads; 0 uses all.
    ambient, spot_intensity, sun_intensity, spot_cone_deg : float
        Light levels in the reference renderer's units (see
        :class:`~allo_mrad_ros.render.ReferenceRenderer`): the Sun's irradiance at strength
        1, the lamp's radiant intensity and the ambient radiance.
    view_transform : str or None
        Blender view transform; None keeps Blender's default (AgX). ``"Standard"`` is the
        plain sRGB curve (close to the rasteriser's gamma 2.2).
    seed : int
        Cycles' sampling seed.
    light : CyclesLightConfig or None
        Materials and lamps that depart from the reference's (:mod:`.cycles_light`): the
        station's materials changed once here, an Earth-shine lamp, and a disc area light
        instead of the spot lamp. None keeps the reference's materials and lamps.
    light_rng : numpy.random.Generator or None
        Source of the material draws (required with ``light``).

    Raises
    ------
    CyclesError
        If bpy is missing or the station cannot be imported.
    """

    def __init__(
        self,
        station: str | os.PathLike[str] | trimesh.Scene,
        intrinsics: CameraIntrinsics,
        samples: int = 32,
        denoise: bool = True,
        threads: int = 0,
        ambient: float = AMBIENT,
        spot_intensity: float = SPOT_INTENSITY,
        sun_intensity: float = SUN_INTENSITY,
        spot_cone_deg: float = SPOT_CONE_DEG,
        view_transform: str | None = None,
        seed: int = 0,
        light: CyclesLightConfig | None = None,
        light_rng: np.random.Generator | None = None,
    ) -> None:
        if not isinstance(intrinsics, CameraIntrinsics):
            raise CyclesError(f"intrinsics must be a CameraIntrinsics, got {type(intrinsics)}")
        if not math.isclose(intrinsics.fx, intrinsics.fy, rel_tol=1e-9):
            raise CyclesError(f"square pixels only: fx {intrinsics.fx} != fy {intrinsics.fy}")
        if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
            raise CyclesError(f"samples must be a positive integer, got {samples!r}")
        if isinstance(threads, bool) or not isinstance(threads, int) or threads < 0:
            raise CyclesError(f"threads must be an integer >= 0, got {threads!r}")
        for name, value in (("ambient", ambient), ("spot_intensity", spot_intensity)):
            if not math.isfinite(value) or value < 0:
                raise CyclesError(f"{name} must be finite and >= 0, got {value!r}")
        self.intrinsics = intrinsics
        self._sun_intensity = float(sun_intensity)
        self._planes = frustum_planes(intrinsics)
        self._tmp = tempfile.TemporaryDirectory(prefix="allo-cycles-")
        self._dir = Path(self._tmp.name)
        self._log = self._dir / "blender.log"
        with blender_output(self._log):  # bpy's import prints notices (NumPy ABI, audio)
            self.bpy = bpy = import_bpy()
            bpy.ops.wm.read_factory_settings(use_empty=True)
        from mathutils import Matrix

        self._Matrix = Matrix
        scene = self.scene = bpy.context.scene
        configure_render(scene, intrinsics, samples, denoise, threads, view_transform, seed)
        add_space_world(bpy, scene, ambient)
        self._camera = self._add("camera", bpy.data.cameras.new("camera"))
        scene.camera = self._camera
        set_camera(self._camera.data, intrinsics, _ZNEAR, _ZFAR)
        if light is not None and light.area_lamp:
            # A Lambertian disc of power P sends P / pi W/sr along its axis; the spread
            # keeps its light within the spot lamp's cone.
            spot = bpy.data.lights.new("spot", "AREA")
            spot.shape = "DISK"
            spot.size = light.area_lamp_size_m
            spot.energy = math.pi * float(spot_intensity)
            spot.spread = math.radians(spot_cone_deg)
        else:
            spot = bpy.data.lights.new("spot", "SPOT")
            spot.energy = 4.0 * math.pi * float(spot_intensity)  # W over the sphere -> W/sr
            spot.spot_size = math.radians(spot_cone_deg)
            spot.spot_blend = 0.15  # the rasteriser's inner cone is 0.85 of the outer
            spot.shadow_soft_size = SPOT_RADIUS_M
        self._spot = self._add("spot", spot)
        sun = bpy.data.lights.new("sun", "SUN")
        sun.angle = math.radians(SUN_ANGLE_DEG)
        self._sun = self._add("sun", sun)
        self._earthshine = None
        if light is not None:
            earth = bpy.data.lights.new("earthshine", "SUN")
            earth.angle = math.radians(light.earthshine_angle_deg)
            earth.color = EARTHSHINE_COLOUR
            earth.energy = 0.0
            self._earthshine = self._add("earthshine", earth)
        station_path = as_glb(station, self._dir, "station")
        self._station = self._import(station_path)
        if not any(o.type == "MESH" for o in self._station):
            raise CyclesError(f"station model {station!r} has no mesh Blender could import")
        self._bodies: dict[str, object] = {}
        self.gltf_roughness: dict[str, float] = {}
        self.material_values: dict[str, tuple[float, float]] = {}
        if light is not None:
            if light_rng is None:
                raise CyclesError("light needs light_rng, the source of the material draws")
            materials = self.station_materials()
            self.gltf_roughness = material_roughness(materials)
            departures = draw_material_departures(self.gltf_roughness, light_rng, light)
            self.material_values = apply_material_departures(materials, departures)

    # ------------------------------------------------------------------ scene set-up
    def station_materials(self) -> list:
        """The Blender materials of the station's meshes, each once, in name order."""
        found = {}
        for obj in self._station:
            for slot in getattr(obj, "material_slots", ()):
                if slot.material is not None:
                    found[slot.material.name] = slot.material
        return [found[name] for name in sorted(found)]

    def _add(self, name: str, data: object) -> object:
        obj = self.bpy.data.objects.new(name, data)
        self.scene.collection.objects.link(obj)
        return obj

    def _import(self, path: Path) -> list:
        """Import a glTF file in the station frame; returns the new objects."""
        bpy = self.bpy
        before = set(bpy.data.objects)
        with blender_output(self._log):
            result = bpy.ops.import_scene.gltf(filepath=str(path), loglevel=50)
        if "FINISHED" not in result:
            raise CyclesError(
                f"Blender's glTF importer failed on {path.name}: {log_tail(self._log)}"
            )
        new = [o for o in bpy.data.objects if o not in before]
        undo = self._Matrix([list(r) for r in np.linalg.inv(GLTF_TO_BLENDER)])
        for obj in new:
            if obj.parent is None:
                obj.matrix_world = undo @ obj.matrix_world
        return new

    def _body(self, body: CelestialBody) -> object:
        if body.name not in self._bodies:
            self._bodies[body.name] = body_object(self.bpy, self.scene, body)
        return self._bodies[body.name]

    # ------------------------------------------------------------------ per frame
    def _pose_frame(self, T_station_camera: np.ndarray, bodies: Sequence) -> None:
        camera = optical_to_opengl_pose(T_station_camera)  # Blender's camera: OpenGL axes
        self._camera.matrix_world = _matrix(self._Matrix, camera)
        self._spot.matrix_world = _matrix(self._Matrix, camera)
        pose = np.asarray(T_station_camera, dtype=np.float64)
        shown = set()
        for body, centre, radius in bodies_in_view(pose, bodies, self._planes, _ZNEAR, _ZFAR):
            scaled = np.diag([radius, radius, radius, 1.0])
            scaled[:3, 3] = centre
            self._body(body).matrix_world = _matrix(self._Matrix, scaled)
            shown.add(body.name)
        for name, obj in self._bodies.items():
            obj.hide_render = name not in shown

    @contextlib.contextmanager
    def _extras(self, extra_objects: Sequence[ExtraObject | Sequence]) -> Iterator[list]:
        """Import the frame's extra objects at their poses; removed again afterwards."""
        bpy = self.bpy
        data = (bpy.data.meshes, bpy.data.materials, bpy.data.images)
        before = [set(c) for c in data]
        added: list = []
        try:
            for i, extra in enumerate(extra_objects):
                extra = extra if isinstance(extra, ExtraObject) else ExtraObject(*extra)
                pose = object_pose(extra.pose, f"extra object {i}")
                holder = self._add(f"extra:{i}", None)
                added.append(holder)
                holder.matrix_world = _matrix(self._Matrix, pose)
                for obj in self._import(as_glb(extra.mesh, self._dir, f"extra{i}")):
                    added.append(obj)
                    if obj.parent is None:
                        local = np.array(obj.matrix_world)
                        obj.parent = holder
                        obj.matrix_parent_inverse = self._Matrix.Identity(4)
                        obj.matrix_basis = _matrix(self._Matrix, local)
            yield added
        finally:
            for obj in added:
                bpy.data.objects.remove(obj, do_unlink=True)
            for collection, old in zip(data, before, strict=True):
                for block in [b for b in collection if b not in old]:
                    collection.remove(block)

    def _render(self, name: str) -> np.ndarray:
        path = self._dir / f"{name}.png"
        self.scene.render.filepath = str(path)
        try:
            with blender_output(self._log):
                self.bpy.ops.render.render(write_still=True)
        except RuntimeError as error:
            raise CyclesError(f"Cycles render failed: {error}; {log_tail(self._log)}") from None
        image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if image is None:
            raise CyclesError(f"Cycles wrote no image: {log_tail(self._log)}")
        order = [2, 1, 0, 3] if image.shape[2] == 4 else [2, 1, 0]
        return np.ascontiguousarray(image[..., order])

    def render(
        self,
        T_station_camera: np.ndarray,
        sun_direction: Sequence[float],
        sun_strength: float = 1.0,
        bodies: Sequence[CelestialBody | Sequence] = (),
        extra_objects: Sequence[ExtraObject | Sequence] = (),
        *,
        view_transform: str | None = None,
        exposure_ev: float = 0.0,
        earthshine: tuple[Sequence[float], float] | None = None,
    ) -> np.ndarray:
        """Path-trace one query, as :meth:`ReferenceRenderer.render` rasterises it.

        Parameters
        ----------
        T_station_camera : array_like, shape (4, 4)
            Pose of the camera's optical frame (x right, y down, z forward), station frame.
        sun_direction : sequence of 3 floats
            Vector towards the Sun, station frame.
        sun_strength : float
            Relative Sun strength, >= 0.
        bodies : sequence
            Celestial bodies; those in view are drawn.
        extra_objects : sequence
            :class:`~allo_mrad_ros.render.ExtraObject` for this frame only.
        view_transform : str or None
            Blender view transform of this frame; None keeps the renderer's.
        exposure_ev : float
            Exposure of the view, stops (finite).
        earthshine : (sequence of 3 floats, float) or None
            Direction towards the Earth (station frame) and the Earth-shine lamp's
            irradiance relative to the Sun's at strength 1; needs a renderer built with
            ``light``. None leaves the lamp off.

        Returns
        -------
        numpy.ndarray
            (h, w, 3) uint8 display image (the view transform applied).
        """
        direction = unit_vector(sun_direction, "sun_direction")
        if not math.isfinite(sun_strength) or sun_strength < 0:
            raise CyclesError(f"sun_strength must be finite and >= 0, got {sun_strength!r}")
        if not math.isfinite(exposure_ev):
            raise CyclesError(f"exposure_ev must be finite, got {exposure_ev!r}")
        view = self.scene.view_settings
        if view_transform is not None:
            try:
                view.view_transform = view_transform
            except TypeError as error:
                raise CyclesError(f"unknown view transform {view_transform!r}: {error}") from None
        view.exposure = float(exposure_ev)
        self._pose_frame(T_station_camera, bodies)
        self._sun.matrix_world = _matrix(self._Matrix, z_towards(direction))  # shines along -z
        self._sun.data.energy = self._sun_intensity * float(sun_strength)
        if earthshine is not None and self._earthshine is None:
            raise CyclesError("earthshine needs a renderer built with a light model")
        if self._earthshine is not None:
            level = 0.0
            if earthshine is not None:
                towards, level = earthshine
                if not math.isfinite(level) or level < 0:
                    raise CyclesError(f"earthshine level must be finite and >= 0, got {level!r}")
                self._earthshine.matrix_world = _matrix(
                    self._Matrix, z_towards(unit_vector(towards, "earthshine direction"))
                )
            self._earthshine.data.energy = self._sun_intensity * float(level)
        with self._extras(extra_objects):
            return self._render("query")

    def silhouette(
        self,
        T_station_camera: np.ndarray,
        extra_objects: Sequence[ExtraObject | Sequence] = (),
        station: bool = False,
    ) -> np.ndarray:
        """Pixels covered by the extra objects (or the station), as Cycles projects them.

        The station still hides what is behind it. For checking that Cycles' geometry
        matches the rasteriser's labels.

        Returns
        -------
        numpy.ndarray
            (h, w) bool, True where more than half of a pixel is covered.
        """
        scene, cycles = self.scene, self.scene.cycles
        saved = (cycles.samples, cycles.use_denoising, scene.render.film_transparent)
        scene.render.film_transparent = True
        scene.render.image_settings.color_mode = "RGBA"
        cycles.samples, cycles.use_denoising = 16, False
        for obj in self._station:
            obj.is_holdout = not station
        self._pose_frame(T_station_camera, ())
        try:
            with self._extras(extra_objects):
                rgba = self._render("silhouette")
        finally:
            for obj in self._station:
                obj.is_holdout = False
            cycles.samples, cycles.use_denoising, scene.render.film_transparent = saved
            scene.render.image_settings.color_mode = "RGB"
        return rgba[..., 3] > 127

    def project(self, T_station_camera: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Pixel coordinates (centres at integers) of station-frame points, by Blender's camera.

        Parameters
        ----------
        T_station_camera : array_like, shape (4, 4)
            Optical-frame camera pose.
        points : array_like, shape (n, 3)
            Points in front of the camera.

        Returns
        -------
        numpy.ndarray
            (n, 2) float64 ``(u, v)``.
        """
        from bpy_extras.object_utils import world_to_camera_view
        from mathutils import Vector

        self._pose_frame(T_station_camera, ())
        self.bpy.context.view_layer.update()
        k = self.intrinsics
        result = []
        for p in np.asarray(points, dtype=np.float64).reshape(-1, 3):
            x, y, _ = world_to_camera_view(self.scene, self._camera, Vector(p.tolist()))
            result.append((x * k.width - 0.5, (1.0 - y) * k.height - 0.5))
        return np.array(result, dtype=np.float64)

    def close(self) -> None:
        """Remove the temporary files (Blender's scene stays until the process ends)."""
        self._tmp.cleanup()

    def __enter__(self) -> CyclesRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()
