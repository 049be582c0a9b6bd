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
from dataclasses import dataclass
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
)
from allo_mrad_ros.render.bodies import (
    CelestialBody,
    as_bodies,
    frustum_planes,
    pull_within,
    sphere_in_view,
)
from allo_mrad_ros.render.model import MeshGroup, ModelSource, load_model

# Per-pixel classes, as in ALLO's masks.
LABEL_SPACE = 0
LABEL_STATION = 1  # the station and the celestial bodies
LABEL_ANOMALY = 2  # default class of extra objects

# Shipped defaults, chosen on the validation split by `make bench` (README, speed against error).
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
# Icosphere subdivisions of body spheres: level 4 keeps the silhouette within 0.1 % of the
# radius (under a pixel for a Moon filling the image).
_BODY_SUBDIVISIONS = 4
_EXTRA_CACHE_SIZE = 16


@dataclass(frozen=True)
class ExtraObject:
    """An object added for one render only, e.g. an anomaly placed by the generator.

    Parameters
    ----------
    mesh : trimesh.Trimesh or trimesh.Scene
        The object in its own frame, metres. Thin open sheets are fine: extra objects are
        always drawn two-sided.
    pose : array_like, shape (4, 4)
        Object frame in the station frame; rotation, translation and positive scale.
    label : int
        Class written to the label image (0..255, default :data:`LABEL_ANOMALY`).
    name : str
        Name in :attr:`RenderResult.instance_names` (default ``extra<i>``).
    """

    mesh: trimesh.Trimesh | trimesh.Scene
    pose: np.ndarray
    label: int = LABEL_ANOMALY
    name: str = ""


@dataclass(frozen=True)
class RenderResult:
    """One rendered reference frame.

    Attributes
    ----------
    rgb : numpy.ndarray
        (h, w, 3) uint8 image.
    depth : numpy.ndarray or None
        (h, w) float32 distance along the optical axis in metres, 0 where nothing was hit.
        Bodies pulled inside the far plane report their pulled distance.
    labels : numpy.ndarray or None
        (h, w) uint8 class per pixel: 0 space, 1 station and celestial bodies, extra objects
        their ``label`` (2 by default).
    instances : numpy.ndarray or None
        (h, w) int32 object index per pixel into :attr:`instance_names`.
    instance_names : tuple of str
        ``("space", "station", <bodies in view>..., <extra objects>...)``.
    bodies_in_view : tuple of str
        Names of the celestial bodies that intersected the frustum and were drawn.
    intrinsics : CameraIntrinsics
        The intrinsics of the output image (the input ones at the output scale).
    """

    rgb: np.ndarray
    depth: np.ndarray | None
    labels: np.ndarray | None
    instances: np.ndarray | None
    instance_names: tuple[str, ...]
    bodies_in_view: tuple[str, ...]
    intrinsics: CameraIntrinsics


def _number(value: float, name: str, low: float = -math.inf, low_inclusive: bool = True) -> float:
    """Return ``value`` as a finite float not below ``low`` (strictly above if exclusive)."""
    number = float(value)
    too_low = number < low if low_inclusive else number <= low
    if not math.isfinite(number) or too_low:
        bound = "" if low == -math.inf else f" and {'>=' if low_inclusive else '>'} {low}"
        raise InvalidInput(f"{name} must be finite{bound}, got {value!r}")
    return number


def _unit_vector(value: object, name: str) -> np.ndarray:
    vector = np.asarray(value, dtype=np.float64)
    if vector.shape != (3,) or not np.all(np.isfinite(vector)):
        raise InvalidInput(f"{name} must be 3 finite numbers, got {value!r}")
    norm = float(np.linalg.norm(vector))
    if norm < 1e-12:
        raise InvalidInput(f"{name} must not be zero")
    return vector / norm


def _object_pose(value: object, name: str) -> np.ndarray:
    """A finite 4x4 affine pose with positive determinant (scaling is allowed)."""
    pose = np.asarray(value, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise InvalidInput(f"{name} pose must be a finite 4x4 matrix")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0]) or np.linalg.det(pose[:3, :3]) <= 0:
        raise InvalidInput(f"{name} pose must be affine with a positive determinant")
    return pose


def _z_towards(direction: np.ndarray, position: np.ndarray | None = None) -> np.ndarray:
    """A pose whose local +z axis is ``direction`` (pyrender lights shine along -z)."""
    z = direction
    helper = np.array([0.0, 0.0, 1.0]) if abs(z[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.column_stack([x, np.cross(z, x), z])
    if position is not None:
        pose[:3, 3] = position
    return pose


def _segment_colour(index: int) -> np.ndarray:
    # 24-bit object index spread over RGB; the 8-bit colour buffer returns it exactly.
    return np.array([index & 0xFF, (index >> 8) & 0xFF, (index >> 16) & 0xFF], dtype=np.float64)


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
        Linear output scale in (0, 4]; the default 0.125 renders 1920x1080 as 240x135.
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
        scale = _number(scale, "scale", 0.0, low_inclusive=False)
        if scale > 4.0:
            raise InvalidInput(f"scale must be at most 4, got {scale}")
        self._znear = _number(znear, "znear", 0.0, low_inclusive=False)
        self._zfar = _number(zfar, "zfar", self._znear, low_inclusive=False)
        self._sun_intensity = _number(sun_intensity, "sun_intensity", 0.0)
        spot_intensity = _number(spot_intensity, "spot_intensity", 0.0)
        ambient = _number(ambient, "ambient", 0.0)
        cone = _number(spot_cone_deg, "spot_cone_deg", 0.0, low_inclusive=False)
        if cone >= 180.0:
            raise InvalidInput(f"spot_cone_deg must be < 180, got {cone}")
        self.intrinsics = intrinsics
        self.output_intrinsics = intrinsics.scaled(scale)
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
        self._scene = _bounded_scene_class(pr)(
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
        _install_program_cache(pr, self._gl)
        _install_shadow_map_cache(pr, self._gl)

    # ------------------------------------------------------------------ scene content
    def _material(self, group: MeshGroup) -> object:
        pr = self._pr
        m = group.material
        if m is None:
            colour = (1.0, 1.0, 1.0, 1.0) if group.colours is not None else (0.5, 0.5, 0.5, 1.0)
            return pr.MetallicRoughnessMaterial(
                baseColorFactor=colour, metallicFactor=0.0, roughnessFactor=0.8, alphaMode="OPAQUE"
            )
        colour = np.asarray(m.baseColorFactor if m.baseColorFactor is not None else [1.0] * 4)
        if np.issubdtype(colour.dtype, np.integer):
            colour = colour / 255.0
        return pr.MetallicRoughnessMaterial(
            name=m.name,
            baseColorFactor=colour,
            baseColorTexture=m.baseColorTexture if group.uv is not None else None,
            metallicFactor=1.0 if m.metallicFactor is None else float(m.metallicFactor),
            roughnessFactor=1.0 if m.roughnessFactor is None else float(m.roughnessFactor),
            emissiveFactor=m.emissiveFactor,
            alphaMode=m.alphaMode or "OPAQUE",
            # Two-sided parts already carry reversed faces (see model.load_model).
            doubleSided=False,
        )

    def _mesh_from_groups(self, groups: Sequence[MeshGroup]) -> object:
        pr = self._pr
        primitives = [
            pr.Primitive(
                positions=g.positions,
                normals=g.normals,
                texcoord_0=g.uv,
                color_0=g.colours,
                indices=g.faces,
                material=self._material(g),
                mode=pr.constants.GLTF.TRIANGLES,
            )
            for g in groups
        ]
        return pr.Mesh(primitives=primitives)

    def _body_mesh(self, body: CelestialBody) -> object:
        key = (body.resolved_colour, body.is_emissive)
        if key not in self._body_meshes:
            pr = self._pr
            colour = (*body.resolved_colour, 1.0)
            if body.is_emissive:
                material = pr.MetallicRoughnessMaterial(
                    baseColorFactor=(0.0, 0.0, 0.0, 1.0),
                    emissiveFactor=body.resolved_colour,
                    metallicFactor=0.0,
                    roughnessFactor=1.0,
                    alphaMode="OPAQUE",
                )
            else:
                material = pr.MetallicRoughnessMaterial(
                    baseColorFactor=colour,
                    metallicFactor=0.0,
                    roughnessFactor=1.0,
                    alphaMode="OPAQUE",
                )
            sphere = trimesh.creation.icosphere(subdivisions=_BODY_SUBDIVISIONS, radius=1.0)
            self._body_meshes[key] = pr.Mesh.from_trimesh(sphere, material=material, smooth=True)
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
        eye = pose[:3, 3]
        world_to_camera = pose[:3, :3].T
        result = []
        for body in as_bodies(bodies):
            centre, radius = pull_within(body.centre_array, body.radius, eye, self._zfar)
            optical = world_to_camera @ (centre - eye)
            in_view = sphere_in_view(optical, radius, self._planes, self._znear, self._zfar)
            if in_view or not self.cull_bodies:
                result.append((body, centre, radius))
        return result

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
        sun_dir = _unit_vector(sun_direction, "sun_direction")
        strength = _number(sun_strength, "sun_strength", 0.0)
        extras = [e if isinstance(e, ExtraObject) else ExtraObject(*e) for e in extra_objects]
        in_view = self.visible_bodies(T_station_camera, bodies)

        pr = self._pr
        scene = self._scene
        scene.set_pose(self._camera_node, gl_pose)
        scene.set_pose(self._spot_node, gl_pose)
        scene.set_pose(self._sun_node, _z_towards(sun_dir))
        self._sun_node.light.intensity = self._sun_intensity * strength

        names = ["space", "station"]
        classes = [LABEL_SPACE, LABEL_STATION]
        seg_map = {self._station_node: _segment_colour(1)}
        added = []
        try:
            for body, centre, radius in in_view:
                pose = np.diag([radius, radius, radius, 1.0])
                pose[:3, 3] = centre
                node = scene.add(self._body_mesh(body), pose=pose, name=f"body:{body.name}")
                added.append(node)
                seg_map[node] = _segment_colour(len(names))
                names.append(body.name)
                classes.append(LABEL_STATION)
            caster_bounds = self._station_bounds.copy()
            for i, extra in enumerate(extras):
                label = int(extra.label)
                if not 0 <= label <= 255:
                    raise InvalidInput(f"extra object label must be in 0..255, got {label}")
                pose = _object_pose(extra.pose, f"extra object {i}")
                mesh = self._extra_mesh(extra.mesh)
                node = scene.add(mesh, pose=pose, name=f"extra:{i}")
                added.append(node)
                seg_map[node] = _segment_colour(len(names))
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
    def node_count(self) -> int:
        """Number of nodes in the scene now (constant between renders)."""
        return len(self._scene.nodes)

    def close(self) -> None:
        """Free the OpenGL context and buffers (also done when the object is collected)."""
        if getattr(self, "_gl", None) is not None:
            self._gl.delete()
            self._gl = None

    def __enter__(self) -> ReferenceRenderer:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    def __del__(self) -> None:
        # At interpreter shutdown the GL library may already be gone.
        with contextlib.suppress(Exception):
            self.close()


_SCENE_CLASSES: dict[int, type] = {}


def _bounded_scene_class(pr: ModuleType) -> type:
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


def _install_program_cache(pr: ModuleType, offscreen: object) -> None:
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


def _install_shadow_map_cache(pr: ModuleType, offscreen: object) -> None:
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
