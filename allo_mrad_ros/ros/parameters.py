"""The node's parameters: one declarative table, validated alike at start and on every change.

:data:`NODE_TABLE` lists every node parameter once, in sections: its name, default, type and
valid values (a :class:`~allo_mrad_ros.detector.params.ParameterSpec`), description and
whether it is read-only. Detector parameters are ``mrad.<field>`` and come from
:class:`~allo_mrad_ros.detector.params.MradParams`' own table
(:data:`~allo_mrad_ros.detector.params.PARAMETER_SPECS`), so the node and the library
validate with one rule set. From these two tables come the node's declarations (``node.py``),
:class:`NodeConfig`'s values, ``config/mrad.yaml`` and the docs' parameter tables
(:mod:`.parameter_table` writes both; a test compares them).
"""

from __future__ import annotations

import array
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.detector.backends import ARRAY_BACKENDS, DEFAULT_BACKEND, select_backend
from allo_mrad_ros.detector.params import PARAMETER_SPECS, MradParams, ParameterSpec, coerce_value
from allo_mrad_ros.errors import InvalidInput, one_line
from allo_mrad_ros.geometry import unit_vector
from allo_mrad_ros.objects import ObjectParams
from allo_mrad_ros.pipeline import PipelineConfig, RenderSettings
from allo_mrad_ros.render import DEFAULT_SCALE, DEFAULT_SHADOWS
from allo_mrad_ros.render.reuse import ReuseBounds
from allo_mrad_ros.render.settings import (
    DEFAULT_SUPERSAMPLING,
    MAX_SUPERSAMPLING,
    RENDER_BACKENDS,
)

_REUSE = ReuseBounds()

DETECTOR_PREFIX = "mrad."
OBJECTS_PREFIX = "objects."
# How ~/anomaly decides: the detector's verdict on each frame, or confirmed objects in view.
DECISIONS = ("frame", "objects")


class ParameterError(InvalidInput):
    """A parameter value is invalid; the message names the parameter, value and range."""


@dataclass(frozen=True)
class NodeParameter:
    """One node parameter: default, type and valid values with the description (``spec``),
    and whether it may change after start."""

    default: Any
    spec: ParameterSpec
    read_only: bool = False


@dataclass(frozen=True)
class Section:
    """Node parameters that belong together (a heading of ``config/mrad.yaml``)."""

    title: str
    parameters: dict[str, NodeParameter]


def _choice(description: str, *choices: str) -> ParameterSpec:
    return ParameterSpec(str, description, choices=choices)


def _number(description: str, low: float, high: float, **kw: bool) -> ParameterSpec:
    return ParameterSpec(float, description, low, high, **kw)


def _integer(description: str, low: int, high: int) -> ParameterSpec:
    return ParameterSpec(int, description, low, high)


def _flag(description: str) -> ParameterSpec:
    return ParameterSpec(bool, description, choices=(True, False))


def _text(description: str) -> ParameterSpec:
    return ParameterSpec(str, description)


# Every node parameter but the detector's, in declaration order. Defaults the library owns
# (render scale, shadows, reuse bounds, array backend, frame name) are read from it.
NODE_TABLE: tuple[Section, ...] = (
    Section(
        "Camera pose",
        {
            "pose_source": NodeParameter(
                "tf",
                _choice(
                    "where the camera pose comes from: tf (tf2_ros, station_frame to the "
                    "image's frame) or topic (geometry_msgs/PoseStamped); the default is topic "
                    "where tf2_ros is not installed",
                    "tf",
                    "topic",
                ),
                read_only=True,
            ),
            "station_frame": NodeParameter(
                interface.STATION_FRAME,
                _text("TF frame of the station model, the poses, the Sun and the bodies"),
                read_only=True,
            ),
            "camera_frame": NodeParameter(
                "",
                _text("TF frame of the camera optical frame; empty: the image's frame_id"),
                read_only=True,
            ),
            "pose_tolerance_s": NodeParameter(
                0.05,
                _number(
                    "largest |stamp - image stamp| of a PoseStamped or Sun direction accepted",
                    0.0,
                    10.0,
                ),
            ),
            "tf_timeout_s": NodeParameter(
                0.5,
                _number("longest wait for the camera's TF transform at an image stamp", 0.0, 10.0),
            ),
        },
    ),
    Section(
        "Camera image",
        {
            "image_transport": NodeParameter(
                "raw",
                _choice(
                    "raw: sensor_msgs/Image on the image topic; compressed: sensor_msgs/"
                    "CompressedImage (jpeg, png) on <image topic>/compressed",
                    *interface.IMAGE_TRANSPORTS,
                ),
                read_only=True,
            ),
            "rectified_input": NodeParameter(
                False,
                _flag(
                    "the image is rectified (image_rect): intrinsics from camera_info P, D "
                    "ignored; false: from K, and a non-zero D is refused"
                ),
            ),
        },
    ),
    Section(
        "Reference rendering and the detector's arrays",
        {
            "mesh": NodeParameter(
                "",
                _text(
                    "station CAD model (trimesh-loadable, metres); empty: the package's "
                    "meshes/station.glb"
                ),
                read_only=True,
            ),
            "reference_scale": NodeParameter(
                DEFAULT_SCALE,
                _number(
                    "linear scale of the rendered reference (0.125: 1920x1080 -> 240x135; the "
                    "shorter side is rounded to whole pixels and the longer keeps the aspect "
                    "ratio, so 700x3 -> 233x1)",
                    0.05,
                    1.0,
                ),
                read_only=True,
            ),
            "reference_supersampling": NodeParameter(
                DEFAULT_SUPERSAMPLING,
                _integer(
                    "the reference is rendered at this many times its size along each axis and "
                    "area-averaged down, so a structure thinner than a reference pixel gets its "
                    "share of the pixel instead of breaking into dashes; 1 renders it at its "
                    "size",
                    1,
                    MAX_SUPERSAMPLING,
                ),
                read_only=True,
            ),
            "render_backend": NodeParameter(
                "",
                _choice("OpenGL backend: osmesa, egl, or empty to choose", *RENDER_BACKENDS),
                read_only=True,
            ),
            "array_backend": NodeParameter(
                DEFAULT_BACKEND,
                _choice(
                    "where the detector's per-pixel work runs: numpy (CPU), torch (PyTorch on "
                    "the first CUDA GPU, else the CPU), torch:cuda, torch:cpu; one this machine "
                    "cannot run stops the node at start with the reason",
                    *ARRAY_BACKENDS,
                ),
                read_only=True,
            ),
            "shadows": NodeParameter(
                DEFAULT_SHADOWS, _flag("render directional shadows from the Sun"), read_only=True
            ),
        },
    ),
    Section(
        "Reference reuse: a view close to the last rendered one gets that render warped to it",
        {
            "reuse_reference": NodeParameter(
                True,
                _flag(
                    "warp the last rendered reference to a nearby view instead of rendering "
                    "every frame, within the reuse_max_* bounds"
                ),
            ),
            "reuse_max_error_px": NodeParameter(
                _REUSE.max_error_px,
                _number(
                    "largest image error of a warped reference in camera pixels (parallax "
                    "bound plus uncovered border); 0 renders every frame",
                    0.0,
                    256.0,
                ),
            ),
            "reuse_max_rotation_deg": NodeParameter(
                _REUSE.max_rotation_deg,
                _number(
                    "largest camera rotation from the rendered view, degrees (the arm's "
                    "spotlight turns with the camera)",
                    0.0,
                    20.0,
                ),
            ),
            "reuse_max_age_s": NodeParameter(
                _REUSE.max_age_s,
                _number(
                    "longest a render is reused, seconds of image stamps",
                    0.0,
                    3600.0,
                    low_open=True,
                ),
            ),
            "reuse_max_sun_change_deg": NodeParameter(
                _REUSE.max_sun_change_deg,
                _number("largest change of the Sun's (or a body's) direction, degrees", 0.0, 10.0),
            ),
        },
    ),
    Section(
        "Lighting until the Sun topics arrive",
        {
            "sun_direction": NodeParameter(
                [1.0, 0.0, 0.0],
                ParameterSpec(
                    list, "station-frame vector towards the Sun until a sun topic arrives"
                ),
            ),
            "sun_strength": NodeParameter(
                1.0,
                _number("relative Sun intensity until a sun_strength topic arrives", 0.0, 100.0),
            ),
        },
    ),
    Section(
        "Processing threads and memory",
        {
            "pipelined": NodeParameter(
                True,
                _flag(
                    "render the next frame's reference while this frame is detected (two "
                    "threads, two cores at work; results still in image order); false: one "
                    "thread renders, then detects"
                ),
                read_only=True,
            ),
            "max_input_age_s": NodeParameter(
                0.1,
                _number(
                    "a frame older than this when the render thread takes it (since its image "
                    "was published: the middleware's source timestamp, else its arrival) is "
                    "dropped and counted in /diagnostics (frames_dropped_too_old), not "
                    "processed; 0: no limit. The default is three frame periods at 30 Hz",
                    0.0,
                    3600.0,
                ),
            ),
            "opencv_threads": NodeParameter(
                1,
                _integer(
                    "threads of OpenCV's parallel loops; 0: OpenCV's default (one per core). "
                    "The pipelined node keeps two threads busy itself",
                    0,
                    64,
                ),
                read_only=True,
            ),
            "keep_freed_memory_mb": NodeParameter(
                512,
                _integer(
                    "freed memory the C allocator (glibc) keeps mapped for the next frame's "
                    "buffers instead of returning it to the kernel; 0: the allocator's default",
                    0,
                    4096,
                ),
                read_only=True,
            ),
        },
    ),
    Section(
        "Outputs",
        {
            "decision": NodeParameter(
                "frame",
                _choice(
                    "what ~/anomaly says: frame, the detector's verdict on each image; objects, "
                    "whether a confirmed object (objects.*) is in view, which runs the object "
                    "tracker on every frame",
                    *DECISIONS,
                ),
            ),
            "publish_reference": NodeParameter(
                False, _flag("publish the rendered reference (~/reference, its camera_info)")
            ),
            "publish_overlay": NodeParameter(
                True, _flag("publish the image with the mask outlined (~/overlay)")
            ),
            "score_full_resolution": NodeParameter(
                False,
                _flag(
                    "publish ~/score at the image's resolution (upscaled) with the image's "
                    "camera_info; false: at the detector's processing resolution "
                    "(mrad.process_scale) with its scaled camera_info"
                ),
            ),
            "overlay_full_resolution": NodeParameter(
                False,
                _flag(
                    "publish ~/overlay at the image's resolution; false: the image "
                    "area-averaged to the detector's processing resolution (mrad.process_scale), "
                    "a sixteenth of the bytes at the default scale"
                ),
            ),
        },
    ),
    Section(
        "Diagnostics and input checks",
        {
            "diagnostics_period_s": NodeParameter(
                1.0, _number("period of /diagnostics messages", 0.1, 60.0), read_only=True
            ),
            "input_timeout_s": NodeParameter(
                2.0,
                _number(
                    "no image for this long while an output is subscribed: /diagnostics says ERROR",
                    0.1,
                    3600.0,
                ),
                read_only=True,
            ),
            "camera_info_tolerance_s": NodeParameter(
                0.0,
                _number(
                    "largest |camera_info stamp - image stamp| paired; 0: the exact stamp, as "
                    "image_transport's CameraSubscriber",
                    0.0,
                    10.0,
                ),
            ),
            "expected_rate_hz": NodeParameter(
                0.0,
                _number(
                    "image rate the camera should deliver, checked in /diagnostics' input rate "
                    "status; 0: not checked",
                    0.0,
                    1000.0,
                ),
                read_only=True,
            ),
            "rate_tolerance": NodeParameter(
                0.1,
                _number("accepted relative deviation from expected_rate_hz", 0.0, 1.0),
                read_only=True,
            ),
            "max_stamp_delay_s": NodeParameter(
                1.0,
                _number(
                    "largest accepted age of an image stamp on arrival (/diagnostics' input "
                    "stamp status)",
                    0.0,
                    3600.0,
                ),
                read_only=True,
            ),
            "hardware_id": NodeParameter(
                "",
                _text("hardware_id of /diagnostics and ~/result; empty: the image's frame_id"),
                read_only=True,
            ),
        },
    ),
)


def node_parameters(tf_available: bool) -> dict[str, NodeParameter]:
    """The node's own (non-detector) parameters of :data:`NODE_TABLE`, by name;
    ``pose_source`` defaults to ``tf`` only where tf2_ros can be imported."""
    parameters = {
        name: parameter for section in NODE_TABLE for name, parameter in section.parameters.items()
    }
    if not tf_available:
        pose = parameters["pose_source"]
        parameters["pose_source"] = NodeParameter("topic", pose.spec, pose.read_only)
    return parameters


def detector_parameters() -> dict[str, NodeParameter]:
    """``mrad.<field>`` parameters with the library's defaults and specs."""
    defaults = MradParams()
    return {
        DETECTOR_PREFIX + name: NodeParameter(getattr(defaults, name), spec)
        for name, spec in PARAMETER_SPECS.items()
    }


def _object_spec(item: Any) -> ParameterSpec:
    """The :class:`ParameterSpec` of one :class:`ObjectParams` field (its metadata)."""
    meta = item.metadata
    kind = int if item.type in ("int", int) else float
    return ParameterSpec(
        kind, meta["description"], kind(meta["low"]), kind(meta["high"]), low_open=meta["low_open"]
    )


# ``objects.enabled``: the tracker's switch; the other ``objects.*`` are ObjectParams' fields.
OBJECTS_ENABLED = NodeParameter(
    False,
    _flag(
        "track objects on every frame; false: only while ~/objects or ~/objects/markers has a "
        "subscriber or decision is objects (tracking needs the reference's depth, a read back "
        "the node otherwise skips)"
    ),
)


def object_parameters() -> dict[str, NodeParameter]:
    """``objects.enabled`` and ``objects.<field>`` of :class:`ObjectParams`, its defaults
    and ranges (the object tracker's own table)."""
    parameters = {OBJECTS_PREFIX + "enabled": OBJECTS_ENABLED}
    for item in fields(ObjectParams):
        parameters[OBJECTS_PREFIX + item.name] = NodeParameter(item.default, _object_spec(item))
    return parameters


def declared_parameters(tf_available: bool) -> dict[str, NodeParameter]:
    """Every parameter the node declares: its own, the object tracker's, the detector's."""
    return {**node_parameters(tf_available), **object_parameters(), **detector_parameters()}


def validate(name: str, parameter: NodeParameter, value: Any) -> Any:
    """Check one value; return it normalised (int to float for float parameters).

    Raises
    ------
    ValueError
        :class:`ParameterError` (or the library's own ``InvalidInput``) naming the parameter,
        the value and what is allowed.
    """
    spec = parameter.spec
    if spec.kind is list:
        # rclpy hands a double array over as array.array, a YAML list as list.
        numbers = isinstance(value, Sequence | array.array | np.ndarray) and not isinstance(
            value, str | bytes
        )
        vector = list(value) if numbers else None
        if (
            vector is None
            or len(vector) != 3
            or not all(
                isinstance(v, int | float | np.number) and not isinstance(v, bool) for v in vector
            )
        ):
            raise ParameterError(f"{name} must be a list of 3 numbers, got {value!r}")
        try:
            direction = unit_vector(vector, name, ParameterError)
        except ParameterError as error:
            raise ParameterError(f"{error}, got {vector!r}") from None
        return [float(v) for v in direction]
    if spec.kind is str and not spec.choices:
        if not isinstance(value, str):
            raise ParameterError(f"{name} must be a string, got {value!r}")
        return value
    if spec.kind is bool and not isinstance(value, bool):
        raise ParameterError(f"{name} must be true or false, got {value!r}")
    if spec.kind in (int, float) and isinstance(value, str):
        raise ParameterError(f"{name} must be a number, got {value!r}")
    return coerce_value(name, spec, value)


def check_mesh(path: str) -> None:
    """Load the station model once at start (empty: the package's model, not checked).

    Whether the file exists is checked with the other values (:func:`node_config_from`);
    this loads it.

    Raises
    ------
    ParameterError
        For an empty or unreadable file, or one without triangles.
    """
    if not path:
        return
    from allo_mrad_ros.render.model import load_model

    try:
        load_model(path)
    except Exception as error:  # trimesh raises many kinds for garbage input
        raise ParameterError(f"mesh {path!r} is not a usable model: {one_line(error)}") from None


def detector_params_from(values: Mapping[str, Any]) -> MradParams:
    """Build validated :class:`MradParams` from ``mrad.*`` parameter values."""
    fields_ = {
        name[len(DETECTOR_PREFIX) :]: value
        for name, value in values.items()
        if name.startswith(DETECTOR_PREFIX)
    }
    return MradParams(**fields_)


def object_params_from(values: Mapping[str, Any]) -> ObjectParams:
    """Validated :class:`ObjectParams` from ``objects.*`` parameter values (raises
    ``ObjectsError``, a ValueError, for values that do not go together)."""
    return ObjectParams(
        **{
            item.name: values[OBJECTS_PREFIX + item.name]
            for item in fields(ObjectParams)
            if OBJECTS_PREFIX + item.name in values
        }
    )


@dataclass(frozen=True)
class ObjectsConfig:
    """The ``objects.*`` parameters: whether to track on every frame, and the tracker's."""

    enabled: bool = False
    params: ObjectParams = field(default_factory=ObjectParams)


@dataclass(frozen=True)
class NodeConfig:
    """The node's validated settings, one immutable snapshot (replaced on a change).

    Every field is named as its parameter in :data:`NODE_TABLE` (a test checks they match);
    ``pipeline`` gathers ``reference_scale``, ``reference_supersampling``, ``shadows``,
    ``render_backend``, ``array_backend``, the ``reuse_*`` parameters and the ``mrad.*``
    parameters (:func:`pipeline_config_from`); ``objects`` the ``objects.*`` parameters.
    """

    pose_source: str
    station_frame: str
    camera_frame: str
    pose_tolerance_s: float
    tf_timeout_s: float
    image_transport: str
    rectified_input: bool
    mesh: str
    sun_direction: tuple[float, float, float]
    sun_strength: float
    pipelined: bool
    max_input_age_s: float
    opencv_threads: int
    keep_freed_memory_mb: int
    decision: str
    publish_reference: bool
    publish_overlay: bool
    score_full_resolution: bool
    overlay_full_resolution: bool
    diagnostics_period_s: float
    input_timeout_s: float
    camera_info_tolerance_s: float
    expected_rate_hz: float
    rate_tolerance: float
    max_stamp_delay_s: float
    hardware_id: str
    pipeline: PipelineConfig
    objects: ObjectsConfig = field(default_factory=ObjectsConfig)

    @property
    def tracks_every_frame(self) -> bool:
        """Whether the object tracker runs whoever subscribes (``objects.enabled``, or
        ``decision: objects``, which needs it for ``~/anomaly``)."""
        return self.objects.enabled or self.decision == "objects"


def pipeline_config_from(values: Mapping[str, Any]) -> PipelineConfig:
    """The :class:`PipelineConfig` of validated parameter values: render settings, reuse
    bounds (None without ``reuse_reference``), array backend and ``mrad.*`` parameters."""
    reuse = None
    if values["reuse_reference"]:
        reuse = ReuseBounds(
            max_error_px=float(values["reuse_max_error_px"]),
            max_rotation_deg=float(values["reuse_max_rotation_deg"]),
            max_age_s=float(values["reuse_max_age_s"]),
            max_sun_change_deg=float(values["reuse_max_sun_change_deg"]),
        )
    render = RenderSettings(
        reference_scale=values["reference_scale"],
        supersampling=values["reference_supersampling"],
        shadows=values["shadows"],
        render_backend=values["render_backend"],
        reuse=reuse,
    )
    return PipelineConfig(
        render, detector_params_from(values), array_backend=values["array_backend"]
    )


def _field_value(spec: ParameterSpec, value: Any) -> Any:
    """A validated value as :class:`NodeConfig` holds it (a vector as a tuple)."""
    if spec.kind is list:
        return tuple(float(v) for v in value)
    if spec.kind in (int, float):
        return spec.kind(value)
    return value


def node_config_from(values: Mapping[str, Any]) -> NodeConfig:
    """A :class:`NodeConfig` from validated parameter values (raises ValueError)."""
    # Built here, at start, so that a backend this machine cannot run stops the node with
    # its reason (library or GPU missing) instead of failing every frame.
    select_backend(values["array_backend"])
    if values["mesh"] and not Path(values["mesh"]).is_file():
        # Checked here, at start: else the node would run and report it per camera_info.
        raise ParameterError(f"mesh must be an existing model file, got {values['mesh']!r}")
    specs = {name: parameter.spec for name, parameter in node_parameters(True).items()}
    own = {
        item.name: _field_value(specs[item.name], values[item.name])
        for item in fields(NodeConfig)
        if item.name not in ("pipeline", "objects")
    }
    objects = ObjectsConfig(
        enabled=bool(values.get(OBJECTS_PREFIX + "enabled", False)),
        params=object_params_from(values),
    )
    return NodeConfig(**own, pipeline=pipeline_config_from(values), objects=objects)


def default_values(tf_available: bool) -> dict[str, Any]:
    """Every declared parameter's default, by name."""
    return {
        name: parameter.default for name, parameter in declared_parameters(tf_available).items()
    }


def default_config(tf_available: bool = False) -> NodeConfig:
    """The :class:`NodeConfig` of the defaults (``pose_source`` ``topic`` unless
    ``tf_available``); change fields with :func:`dataclasses.replace`."""
    return node_config_from(default_values(tf_available))
