"""The reference renderer: the station model seen from the arm camera's known pose.

One :class:`ReferenceRenderer` is built per camera and reused for every frame: the OpenGL
context and the station's vertex buffers are created once. Per frame only the camera, the
lights, the celestial bodies in view and any extra objects change.
"""

from __future__ import annotations

import contextlib
import math
from collections import OrderedDict
from collections.abc import Iterable, Sequence
from types import ModuleType

import numpy as np
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.geometry import optical_to_opengl_pose, validate_transform
from allo_mrad_ros.render.backend import (
    INSTALL_HINT,
    RendererError,
    choose_backend,
    import_pyrender,
    share_egl_display,
)
from allo_mrad_ros.render.bodies import CelestialBody, bodies_in_view, frustum_planes
from allo_mrad_ros.render.gl_patches import (
    bounded_scene_class,
    current_context,
    install_patches,
    release_context_data,
)
from allo_mrad_ros.render.meshes import body_mesh, mesh_from_groups
from allo_mrad_ros.render.model import MeshGroup, ModelSource, load_model
from allo_mrad_ros.render.values import (
    LABEL_SPACE,
    LABEL_STATION,
    ExtraObject,
    RenderResult,
    finite_number,
    object_pose,
    segment_colour,
    unit_vector,
    z_towards,
)

# Shipped defaults, chosen on the validation split by `make bench` (docs/evaluation.md).
DEFAULT_SCALE = 0.125
DEFAULT_SHADOWS = True
DEFAULT_ZNEAR = 0.05
DEFAULT_ZFAR = 1.0e4
# Light levels, tuned so that white MLI facing the Sun at sun_strength 1 is just below
# saturation and the spotlight lights a white surface 4 m away to about a third of that.
SUN_INTENSITY = 3.0
SPOT_INTENSITY = 25.0
SPOT_CONE_DEG = 80.0  # ALLO: full cone angle of the arm's spot lamp
AMBIENT = 0.01
SHADOW_MAP_SIZE = 2048
_EXTRA_CACHE_SIZE = 16


def scaled_keeping_aspect(intrinsics: CameraIntrinsics, scale: float) -> CameraIntrinsics:
    """The intrinsics of ``intrinsics``' camera rendered at about ``scale``, with the image's
    aspect ratio kept within a pixel: the shorter side is rounded to whole pixels (at least
    one) and the longer follows it.

    Rounding both sides on their own (:meth:`CameraIntrinsics.scaled`) distorts the aspect
    ratio of a narrow camera: 700x3 at 0.125 gives 88x1, where 700x3's aspect wants 233x1,
    and the detector refuses a reference whose aspect differs from the image's by more
    than a pixel. Where the shorter side scales to whole pixels (1920x1080 at 0.125:
    240x135), the result is :meth:`CameraIntrinsics.scaled`'s.
    """
    short = min(intrinsics.width, intrinsics.height)
    return intrinsics.scaled(max(1, round(short * scale)) / short)


class ReferenceRenderer:
    """Render the station model as the camera would see it, for MRAD and the generator.

    Parameters
    ----------
    model : path, trimesh.Trimesh, trimesh.Scene, a list of them, or None
        The station CAD model in metres and in the station frame (see ``meshes/README.md``);
        None loads the package's ``meshes/station.glb``.
    intrinsics : CameraIntrinsics
        Full-resolution pinhole intrinsics (``sensor_msgs/CameraInfo`` without distortion).
    scale : float
        Linear output scale in (0, 4]; the default 0.125 renders 1920x1080 as 240x135
        (the shorter side is rounded to whole pixels, the longer keeps the aspect ratio:
        :func:`scaled_keeping_aspect`).
    backend : str or None
        ``"osmesa"`` or ``"egl"``; None chooses (see :func:`~.backend.choose_backend`).
    shadows : bool
        Cast directional shadows from the Sun (on by default, as chosen by the
        speed-against-error benchmark). The shadow-map pass runs only when the Sun, the
        shadow camera or the meshes inside its view volume changed since the last frame.
    znear, zfar : float
        Clipping distances in metres. Bodies beyond ``zfar`` are pulled inside it with their
        apparent size kept.
    sun_intensity, spot_intensity, ambient : float
        Light levels: Sun at ``sun_strength`` 1, the arm spotlight (candela-like, falls off
        with distance squared) and the uniform ambient term.
    spot_cone_deg : float
        Full cone angle of the spotlight at the camera.
    cull_bodies : bool
        Add celestial bodies only when they intersect the view frustum (default). False
        adds every body to every frame; it exists to measure what culling saves.

    Raises
    ------
    RendererError
        If no OpenGL backend starts.
    InvalidInput
        If the model is missing or empty, or a parameter is invalid.

    Notes
    -----
    Not thread-safe: render from one thread per renderer. The backend is fixed per process
    (PyOpenGL binds it at first import), so every renderer in a process uses the same one.
    """

    def __init__(
        self,
        model: ModelSource | Iterable[ModelSource] | None,
        intrinsics: CameraIntrinsics,
        scale: float = DEFAULT_SCALE,
        backend: str | None = None,
        shadows: bool = DEFAULT_SHADOWS,
        znear: float = DEFAULT_ZNEAR,
        zfar: float = DEFAULT_ZFAR,
        sun_intensity: float = SUN_INTENSITY,
        spot_intensity: float = SPOT_INTENSITY,
        ambient: float = AMBIENT,
        spot_cone_deg: float = SPOT_CONE_DEG,
        cull_bodies: bool = True,
    ) -> None:
        if not isinstance(intrinsics, CameraIntrinsics):
            raise InvalidInput(f"intrinsics must be a CameraIntrinsics, got {type(intrinsics)}")
        scale = finite_number(scale, "scale", 0.0, low_inclusive=False)
        if scale > 4.0:
            raise InvalidInput(f"scale must be at most 4, got {scale}")
        self._znear = finite_number(znear, "znear", 0.0, low_inclusive=False)
        self._zfar = finite_number(zfar, "zfar", self._znear, low_inclusive=False)
        self._sun_intensity = finite_number(sun_intensity, "sun_intensity", 0.0)
        spot_intensity = finite_number(spot_intensity, "spot_intensity", 0.0)
        ambient = finite_number(ambient, "ambient", 0.0)
        cone = finite_number(spot_cone_deg, "spot_cone_deg", 0.0, low_inclusive=False)
        if cone >= 180.0:
            raise InvalidInput(f"spot_cone_deg must be < 180, got {cone}")
        self.intrinsics = intrinsics
        self.output_intrinsics = scaled_keeping_aspect(intrinsics, scale)
        self.scale = scale
        self.shadows = bool(shadows)
        self.cull_bodies = bool(cull_bodies)
        if model is None:
            from allo_mrad_ros.resources import share_path

            model = share_path("meshes", "station.glb")
        groups = load_model(model)
        self.triangle_count = int(sum(len(g.faces) for g in groups))

        self.backend = choose_backend(backend)
        self._pr: ModuleType = import_pyrender(self.backend)
        pr = self._pr
        self._planes = frustum_planes(self.output_intrinsics)
        self._scene = bounded_scene_class(pr)(
            bg_color=(0.0, 0.0, 0.0, 1.0), ambient_light=(ambient, ambient, ambient)
        )
        positions = np.vstack([g.positions for g in groups])
        self._station_bounds = np.array([positions.min(axis=0), positions.max(axis=0)])
        self._station_node = self._scene.add(self._mesh_from_groups(groups), name="station")
        k = self.output_intrinsics
        # pyrender puts pixel centres at integer + 0.5; ROS/OpenCV at integers: shift by 0.5.
        camera = pr.IntrinsicsCamera(
            fx=k.fx, fy=k.fy, cx=k.cx + 0.5, cy=k.cy + 0.5, znear=self._znear, zfar=self._zfar
        )
        self._camera_node = self._scene.add(camera, name="camera")
        half_cone = math.radians(cone / 2.0)
        spot = pr.SpotLight(
            color=np.ones(3),
            intensity=spot_intensity,
            innerConeAngle=half_cone * 0.85,
            outerConeAngle=half_cone,
        )
        self._spot_node = self._scene.add(spot, name="spotlight")
        sun = pr.DirectionalLight(color=np.ones(3), intensity=self._sun_intensity)
        # Clamp-to-border with pyrender's border depth of 1.0: nothing outside the shadow
        # map's box is shadowed (the default REPEAT would tile the station's shadow).
        from OpenGL.GL import GL_CLAMP_TO_BORDER, GL_FLOAT

        sun.shadow_texture = pr.Texture(
            width=SHADOW_MAP_SIZE,
            height=SHADOW_MAP_SIZE,
            source_channels="D",
            data_format=GL_FLOAT,
            sampler=pr.Sampler(wrapS=GL_CLAMP_TO_BORDER, wrapT=GL_CLAMP_TO_BORDER),
        )
        self._sun_node = self._scene.add(sun, name="sun_light")
        self._body_meshes: dict[tuple, object] = {}
        self._extra_meshes: OrderedDict[tuple, tuple[object, object]] = OrderedDict()
        try:
            self._gl = pr.OffscreenRenderer(k.width, k.height)
        except Exception as error:  # PyOpenGL raises several types when no context starts
            raise RendererError(
                f"cannot start an OpenGL context with the {self.backend} backend: {error}; "
                f"{INSTALL_HINT}"
            ) from error
        # What PyOpenGL keeps per context is found by it when the context is gone.
        self._context = current_context()
        share_egl_display(self._gl)
        install_patches(pr, self._gl)

    # ------------------------------------------------------------------ scene content
    def _mesh_from_groups(self, groups: Sequence[MeshGroup]) -> object:
        return mesh_from_groups(self._pr, groups)

    def _body_mesh(self, body: CelestialBody) -> object:
        key = (body.resolved_colour, body.is_emissive)
        if key not in self._body_meshes:
            self._body_meshes[key] = body_mesh(self._pr, body)
        return self._body_meshes[key]

    def _extra_mesh(self, mesh: trimesh.Trimesh | trimesh.Scene) -> object:
        # Keyed by identity and content, so an unchanged object is not uploaded again.
        key = (id(mesh), hash(mesh))
        if key in self._extra_meshes:
            self._extra_meshes.move_to_end(key)
            return self._extra_meshes[key][1]
        if not isinstance(mesh, (trimesh.Trimesh, trimesh.Scene)):
            raise InvalidInput(f"extra object mesh must be a trimesh mesh, got {type(mesh)}")
        try:
            groups = load_model(mesh, two_sided=True)
        except InvalidInput as error:
            raise InvalidInput(f"extra object: {error}") from error
        pr_mesh = self._mesh_from_groups(groups)
        self._extra_meshes[key] = (mesh, pr_mesh)  # holding the mesh keeps id() unique
        if len(self._extra_meshes) > _EXTRA_CACHE_SIZE:
            self._extra_meshes.popitem(last=False)
        return pr_mesh

    def visible_bodies(
        self, T_station_camera: np.ndarray, bodies: Sequence[CelestialBody | Sequence]
    ) -> list[tuple[CelestialBody, np.ndarray, float]]:
        """Return the bodies that intersect the view frustum, moved within the far plane.

        Parameters
        ----------
        T_station_camera : array_like, shape (4, 4)
            Optical-frame camera pose in the station frame.
        bodies : sequence of CelestialBody or (name, centre, radius[, colour]) tuples
            Candidate bodies.

        Returns
        -------
        list of tuple
            ``(body, centre, radius)`` for each body in view, with the drawn centre and radius.
        """
        pose = validate_transform(T_station_camera, "T_station_camera")
        return bodies_in_view(pose, bodies, self._planes, self._znear, self._zfar, self.cull_bodies)

    # ------------------------------------------------------------------ rendering
    def render(
        self,
        T_station_camera: np.ndarray,
        sun_direction: Sequence[float],
        sun_strength: float = 1.0,
        bodies: Sequence[CelestialBody | Sequence] = (),
        extra_objects: Sequence[ExtraObject | Sequence] = (),
        depth: bool = False,
        labels: bool = False,
    ) -> RenderResult:
        """Render the station (and bodies and extra objects) from a camera pose.

        Parameters
        ----------
        T_station_camera : array_like, shape (4, 4)
            Pose of the camera's ROS optical frame (x right, y down, z forward) in the
            station frame.
        sun_direction : sequence of 3 floats
            Vector from the station towards the Sun, station frame (any non-zero length).
        sun_strength : float
            Relative Sun intensity, >= 0 (1 nominal, 0 eclipse).
        bodies : sequence
            :class:`~.bodies.CelestialBody` objects or ``(name, centre, radius[, colour])``
            tuples; only those intersecting the view frustum are drawn.
        extra_objects : sequence
            :class:`ExtraObject` or ``(mesh, pose[, label])`` tuples, drawn for this frame only.
        depth : bool
            Also return the depth image.
        labels : bool
            Also return the class and instance images (one more, unlit render pass).

        Returns
        -------
        RenderResult
            The images at :attr:`output_intrinsics` size.

        Raises
        ------
        allo_mrad_ros.geometry.PoseError
            If the camera pose is not a finite rigid transform.
        RendererError
            For an invalid Sun direction or strength, body or extra object, or after close().
        """
        if self._gl is None:
            raise RendererError("renderer is closed")
        gl_pose = optical_to_opengl_pose(T_station_camera)
        sun_dir = unit_vector(sun_direction, "sun_direction")
        strength = finite_number(sun_strength, "sun_strength", 0.0)
        extras = [e if isinstance(e, ExtraObject) else ExtraObject(*e) for e in extra_objects]
        in_view = self.visible_bodies(T_station_camera, bodies)

        pr = self._pr
        scene = self._scene
        scene.set_pose(self._camera_node, gl_pose)
        scene.set_pose(self._spot_node, gl_pose)
        scene.set_pose(self._sun_node, z_towards(sun_dir))
        self._sun_node.light.intensity = self._sun_intensity * strength

        names = ["space", "station"]
        classes = [LABEL_SPACE, LABEL_STATION]
        seg_map = {self._station_node: segment_colour(1)}
        added = []
        try:
            for body, centre, radius in in_view:
                pose = np.diag([radius, radius, radius, 1.0])
                pose[:3, 3] = centre
                node = scene.add(self._body_mesh(body), pose=pose, name=f"body:{body.name}")
                added.append(node)
                seg_map[node] = segment_colour(len(names))
                names.append(body.name)
                classes.append(LABEL_STATION)
            caster_bounds = self._station_bounds.copy()
            for i, extra in enumerate(extras):
                label = int(extra.label)
                if not 0 <= label <= 255:
                    raise InvalidInput(f"extra object label must be in 0..255, got {label}")
                pose = object_pose(extra.pose, f"extra object {i}")
                mesh = self._extra_mesh(extra.mesh)
                node = scene.add(mesh, pose=pose, name=f"extra:{i}")
                added.append(node)
                seg_map[node] = segment_colour(len(names))
                names.append(extra.name or f"extra{i}")
                classes.append(label)
                corners = trimesh.bounds.corners(mesh.bounds) @ pose[:3, :3].T + pose[:3, 3]
                caster_bounds[0] = np.minimum(caster_bounds[0], corners.min(axis=0))
                caster_bounds[1] = np.maximum(caster_bounds[1], corners.max(axis=0))
            # Fit the Sun's shadow map to the station and extra objects, not the far bodies.
            # pyrender makes the orthographic shadow camera's half-width (and a tenth of its
            # depth range) the bounds' diagonal; halving the box makes it the radius of the
            # casters' bounding sphere: twice the texel density, half the depth quantum.
            centre = caster_bounds.mean(axis=0)
            half = (caster_bounds[1] - caster_bounds[0]) / 4.0
            scene.caster_bounds = np.array([centre - half, centre + half])

            flags = pr.RenderFlags.NONE
            if self.shadows:
                flags |= pr.RenderFlags.SHADOWS_DIRECTIONAL
            rgb, depth_image = self._gl.render(scene, flags=flags)
            instances = label_image = None
            if labels:
                seg, _ = self._gl.render(scene, flags=pr.RenderFlags.SEG, seg_node_map=seg_map)
                seg = seg.astype(np.int32)
                instances = seg[..., 0] | (seg[..., 1] << 8) | (seg[..., 2] << 16)
                instances = np.minimum(instances, len(names) - 1)
                label_image = np.asarray(classes, dtype=np.uint8)[instances]
        finally:
            for node in added:
                scene.remove_node(node)
        return RenderResult(
            rgb=np.ascontiguousarray(rgb),
            depth=np.ascontiguousarray(depth_image, dtype=np.float32) if depth else None,
            labels=label_image,
            instances=None if instances is None else np.ascontiguousarray(instances),
            instance_names=tuple(names),
            bodies_in_view=tuple(body.name for body, _, _ in in_view),
            intrinsics=self.output_intrinsics,
        )

    # ------------------------------------------------------------------ bookkeeping
    @property
    def station_bounds(self) -> np.ndarray:
        """(2, 3) lowest and highest corner of the station model's bounding box, metres."""
        return self._station_bounds.copy()

    @property
    def node_count(self) -> int:
        """Number of nodes in the scene now (constant between renders)."""
        return len(self._scene.nodes)

    def close(self) -> None:
        """Free the OpenGL context and buffers, and what PyOpenGL kept for them (also done
        when the object is collected)."""
        if getattr(self, "_gl", None) is not None:
            self._gl.delete()
            self._gl = None
            release_context_data(getattr(self, "_context", None))

    def __enter__(self) -> ReferenceRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __del__(self) -> None:
        # At interpreter shutdown the GL library may already be gone.
        with contextlib.suppress(Exception):
            self.close()
