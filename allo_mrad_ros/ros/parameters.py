"""The node's parameters: declared up front with descriptions and ranges, validated alike
at start and on every change.

Detector parameters are ``mrad.<field>`` and take their types, ranges and descriptions
from :data:`allo_mrad_ros.detector.params.PARAMETER_SPECS`, so the node and the library
validate with one rule set.
"""

from __future__ import annotations

import array
import difflib
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from allo_mrad_ros import interface
from allo_mrad_ros.detector.backends import ARRAY_BACKENDS, DEFAULT_BACKEND, select_backend
from allo_mrad_ros.detector.params import PARAMETER_SPECS, MradParams, ParameterSpec, coerce_value
from allo_mrad_ros.errors import InvalidInput, one_line
from allo_mrad_ros.geometry import unit_vector
from allo_mrad_ros.pipeline import PipelineConfig, RenderSettings
from allo_mrad_ros.render import DEFAULT_SCALE, DEFAULT_SHADOWS
from allo_mrad_ros.render.reuse import ReuseBounds

_REUSE = ReuseBounds()

DETECTOR_PREFIX = "mrad."


class ParameterError(InvalidInput):
    """A parameter value is invalid; the message names the parameter, value and range."""


@dataclass(frozen=True)
class NodeParameter:
    """One node parameter: default, description, validation and whether it may change."""

    default: Any
    spec: ParameterSpec
    read_only: bool = False


def _choice(description: str, *choices: str) -> ParameterSpec:
    return ParameterSpec(str, description, choices=choices)


def _number(description: str, low: float, high: float, **kw: bool) -> ParameterSpec:
    return ParameterSpec(float, description, low, high, **kw)


def _flag(description: str) -> ParameterSpec:
    return ParameterSpec(bool, description, choices=(True, False))


def _text(description: str) -> ParameterSpec:
    return ParameterSpec(str, description)


def node_parameters(tf_available: bool) -> dict[str, NodeParameter]:
    """The node's own (non-detector) parameters; ``pose_source`` defaults to ``tf`` only
    where tf2_ros can be imported."""
    return {
        "pose_source": NodeParameter(
            "tf" if tf_available else "topic",
            _choice(
                "where the camera pose comes from: tf (tf2_ros) or topic (PoseStamped)",
                "tf",
                "topic",
            ),
            read_only=True,
        ),
        "station_frame": NodeParameter(
            interface.STATION_FRAME, _text("TF frame of the station model"), True
        ),
        "camera_frame": NodeParameter(
            "", _text("TF frame of the camera optical frame; empty: the image's frame_id"), True
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
            0.5, _number("longest wait for the camera's TF transform at an image stamp", 0.0, 10.0)
        ),
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
                "the image is rectified (image_rect): intrinsics from camera_info P, D ignored; "
                "false: from K, and a non-zero D is refused"
            ),
        ),
        "mesh": NodeParameter(
            "",
            _text("station CAD model (trimesh-loadable, metres); empty: package station.glb"),
            True,
        ),
        "reference_scale": NodeParameter(
            DEFAULT_SCALE, _number("linear scale of the rendered reference", 0.05, 1.0), True
        ),
        "render_backend": NodeParameter(
            "",
            _choice("OpenGL backend: osmesa, egl, or empty to choose", "", "osmesa", "egl"),
            True,
        ),
        "array_backend": NodeParameter(
            DEFAULT_BACKEND,
            _choice(
                "where the detector's per-pixel work runs: numpy (CPU), torch (PyTorch on the "
                "first CUDA GPU, else the CPU), torch:cuda, torch:cpu",
                *ARRAY_BACKENDS,
            ),
            True,
        ),
        "shadows": NodeParameter(
            DEFAULT_SHADOWS, _flag("render directional shadows from the Sun"), True
        ),
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
                "largest image error of a warped reference in camera pixels (parallax bound "
                "plus uncovered border); 0 renders every frame",
                0.0,
                256.0,
            ),
        ),
        "reuse_max_rotation_deg": NodeParameter(
            _REUSE.max_rotation_deg,
            _number("largest camera rotation from the rendered view, degrees", 0.0, 20.0),
        ),
        "reuse_max_age_s": NodeParameter(
            _REUSE.max_age_s,
            _number(
                "longest a render is reused, seconds of image stamps", 0.0, 3600.0, low_open=True
            ),
        ),
        "reuse_max_sun_change_deg": NodeParameter(
            _REUSE.max_sun_change_deg,
            _number("largest change of the Sun's (or a body's) direction, degrees", 0.0, 10.0),
        ),
        "sun_direction": NodeParameter(
            [1.0, 0.0, 0.0],
            ParameterSpec(list, "station-frame vector towards the Sun until a sun topic arrives"),
        ),
        "sun_strength": NodeParameter(
            1.0, _number("relative Sun intensity until a sun_strength topic arrives", 0.0, 100.0)
        ),
        "pipelined": NodeParameter(
            True,
            _flag(
                "render the next frame's reference while this frame is detected (two threads, "
                "two cores at work); false: one thread renders, then detects"
            ),
            True,
        ),
        "opencv_threads": NodeParameter(
            1,
            ParameterSpec(
                int,
                "threads of OpenCV's parallel loops; 0: OpenCV's default (one per core). "
                "The pipelined node keeps two threads busy itself",
                0,
                64,
            ),
            True,
        ),
        "keep_freed_memory_mb": NodeParameter(
            512,
            ParameterSpec(
                int,
                "freed memory the C allocator (glibc) keeps mapped for the next frame's "
                "buffers instead of returning it to the kernel; 0: the allocator's default",
                0,
                4096,
            ),
            True,
        ),
        "publish_reference": NodeParameter(False, _flag("publish the rendered reference")),
        "publish_overlay": NodeParameter(True, _flag("publish the image with the mask outlined")),
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
                "publish ~/overlay at the image's resolution; false: the image area-averaged "
                "to the detector's processing resolution (mrad.process_scale), a sixteenth "
                "of the bytes at the default scale"
            ),
        ),
        "diagnostics_period_s": NodeParameter(
            1.0, _number("period of /diagnostics messages", 0.1, 60.0), True
        ),
        "input_timeout_s": NodeParameter(
            2.0,
            _number(
                "no image for this long while an output is subscribed: /diagnostics says ERROR",
                0.1,
                3600.0,
            ),
            True,
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
            True,
        ),
        "rate_tolerance": NodeParameter(
            0.1,
            _number("accepted relative deviation from expected_rate_hz", 0.0, 1.0),
            True,
        ),
        "max_stamp_delay_s": NodeParameter(
            1.0,
            _number(
                "largest accepted age of an image stamp on arrival (/diagnostics' input stamp "
                "status)",
                0.0,
                3600.0,
            ),
            True,
        ),
        "hardware_id": NodeParameter(
            "", _text("hardware_id in /diagnostics; empty: the image's frame_id"), True
        ),
    }


def detector_parameters() -> dict[str, NodeParameter]:
    """``mrad.<field>`` parameters with the library's defaults and specs."""
    defaults = MradParams()
    return {
        DETECTOR_PREFIX + name: NodeParameter(getattr(defaults, name), spec)
        for name, spec in PARAMETER_SPECS.items()
    }


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


def command_line_parameters(argv: Sequence[str]) -> dict[str, Any]:
    """``-p name:=value`` / ``--param name:=value`` of ``--ros-args`` sections, values read as
    YAML (as rcl reads them).

    rcl drops a ``-p`` value whose type differs from the same parameter's value in a
    ``--params-file``; checking these too means no value the user typed is ignored silently.
    """
    found: dict[str, Any] = {}
    for _, given in _parameter_arguments(argv):
        name, separator, text = given.partition(":=")
        if separator:
            try:
                found[name] = yaml.safe_load(text)
            except yaml.YAMLError:
                found[name] = text
    return found


def unknown_parameters(given: Iterable[str], declared: Iterable[str]) -> list[str]:
    """One warning per name in ``given`` that is not a parameter of the node, with the
    closest declared name as a hint (``use_sim_time`` and QoS overrides are rclpy's own)."""
    declared = list(declared)
    warnings = []
    for name in sorted(set(given) - set(declared)):
        if name == "use_sim_time" or name.startswith("qos_overrides."):
            continue
        close = difflib.get_close_matches(name, declared, n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        warnings.append(f"unknown parameter {name} ignored{hint}")
    return warnings


def params_files(argv: Sequence[str]) -> list[Path]:
    """The ``--params-file`` paths of ``argv`` in order."""
    arguments = list(argv)
    return [
        Path(arguments[index + 1])
        for index, argument in enumerate(arguments[:-1])
        if argument == "--params-file"
    ]


def _node_entries(document: dict, path: Path, prefix: str = "") -> list[str]:
    """The node keys of a params file (namespaces nested or joined), each checked to hold a
    ``ros__parameters`` mapping as rcl requires.

    Raises
    ------
    ParameterError
        For an entry without ``ros__parameters`` or with one that is not a mapping.
    """
    keys: list[str] = []
    for key, value in document.items():
        name = f"{prefix}/{str(key).strip('/')}" if prefix else str(key)
        if isinstance(value, dict) and "ros__parameters" in value:
            if not isinstance(value["ros__parameters"], dict):
                raise ParameterError(
                    f"params file {path}: {name}: ros__parameters must map parameter names "
                    f"to values, got {type(value['ros__parameters']).__name__}"
                )
            keys.append(name)
        elif isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
            keys += _node_entries(value, path, name)  # a namespace level
        else:
            raise ParameterError(
                f"params file {path}: node entry {name!r} has no ros__parameters (write "
                f"'{name}:' then '  ros__parameters:' then the parameters)"
            )
    return keys


def check_params_files(argv: Sequence[str]) -> dict[Path, list[str]]:
    """Check the ``--params-file`` files of ``--ros-args`` before rcl parses them; return
    each file's node keys.

    rcl reports a missing or malformed file with a log line of its own and an exception
    carrying C source positions; this says it in one line.

    Raises
    ------
    ParameterError
        Naming the file and the problem.
    """
    found: dict[Path, list[str]] = {}
    for path in params_files(argv):
        try:
            document = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError as error:
            raise ParameterError(f"params file {path}: {error.strerror}") from None
        except yaml.YAMLError as error:
            raise ParameterError(f"params file {path}: invalid YAML: {one_line(error)}") from None
        if not isinstance(document, dict):
            raise ParameterError(
                f"params file {path}: must map node names to ros__parameters, got "
                f"{type(document).__name__}"
            )
        found[path] = _node_entries(document, path)
    return found


def check_command_line(argv: Sequence[str]) -> None:
    """Refuse ``-p name:=`` (no value) and ``-p name`` (no ``:=``) in ``--ros-args``, which rcl
    rejects with a traceback.

    Raises
    ------
    ParameterError
        Naming the argument.
    """
    for flag, given in _parameter_arguments(argv):
        name, separator, text = given.partition(":=")
        if not separator or not name:
            raise ParameterError(f"{flag} {given!r}: expected name:=value")
        if not text.strip():
            raise ParameterError(
                f"{flag} {name}:= has no value: give {name}:=<value> (an empty string: "
                f"{name}:=\"''\")"
            )


def _parameter_arguments(argv: Sequence[str]) -> Iterator[tuple[str, str]]:
    # (flag, the argument after it) of every -p/--param inside a --ros-args section.
    in_ros_args = False
    arguments = list(argv)
    for index, argument in enumerate(arguments):
        if argument == "--ros-args":
            in_ros_args = True
        elif argument == "--":
            in_ros_args = False
        elif in_ros_args and argument in ("-p", "--param"):
            yield argument, arguments[index + 1] if index + 1 < len(arguments) else ""


def _key_pattern(key: str) -> re.Pattern[str]:
    """rcl's node-key wildcards: ``/**`` any namespaces, ``*`` one name token."""
    key = key if key.startswith("/") else "/" + key
    parts = []
    for token in key.strip("/").split("/"):
        parts.append(
            "(/[^/]+)*" if token == "**" else "/" + re.escape(token).replace(r"\*", "[^/]*")
        )
    return re.compile("".join(parts) + "$")


def keys_for_other_nodes(files: dict[Path, list[str]], node_name: str) -> list[str]:
    """One warning per params file none of whose node keys matches the fully qualified
    ``node_name``: rcl ignores its values without a word."""
    warnings = []
    for path, keys in files.items():
        if keys and not any(_key_pattern(key).match(node_name) for key in keys):
            warnings.append(
                f"params file {path} sets parameters for {', '.join(keys)}, not for this node "
                f"({node_name}): its values are ignored; use '{node_name}:' or '/**:'"
            )
    return warnings


def check_mesh(path: str) -> None:
    """Load the station model once at start (empty: the package's model, not checked).

    Raises
    ------
    ParameterError
        For a missing, empty or unreadable file, or one without triangles.
    """
    if not path:
        return
    if not Path(path).is_file():
        raise ParameterError(f"mesh must be an existing model file, got {path!r}")
    from allo_mrad_ros.render.model import load_model

    try:
        load_model(path)
    except Exception as error:  # trimesh raises many kinds for garbage input
        raise ParameterError(f"mesh {path!r} is not a usable model: {one_line(error)}") from None


def detector_params_from(values: dict[str, Any]) -> MradParams:
    """Build validated :class:`MradParams` from ``mrad.*`` parameter values."""
    fields = {
        name[len(DETECTOR_PREFIX) :]: value
        for name, value in values.items()
        if name.startswith(DETECTOR_PREFIX)
    }
    return MradParams(**fields)


@dataclass(frozen=True)
class NodeConfig:
    """The node's validated settings, one immutable snapshot (replaced on a change).

    Every field is named as its parameter; ``pipeline`` gathers ``reference_scale``,
    ``shadows``, ``render_backend``, the ``reuse_*`` bounds and the ``mrad.*`` parameters.
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
    opencv_threads: int
    keep_freed_memory_mb: int
    publish_reference: bool
    publish_overlay: bool
    diagnostics_period_s: float
    input_timeout_s: float
    hardware_id: str
    pipeline: PipelineConfig
    camera_info_tolerance_s: float = 0.0
    expected_rate_hz: float = 0.0
    rate_tolerance: float = 0.1
    max_stamp_delay_s: float = 1.0
    score_full_resolution: bool = False
    overlay_full_resolution: bool = False


def node_config_from(values: dict[str, Any]) -> NodeConfig:
    """A :class:`NodeConfig` from validated parameter values (raises ValueError)."""
    # Built here, at start, so that a backend this machine cannot run stops the node with
    # its reason (library or GPU missing) instead of failing every frame.
    select_backend(values["array_backend"])
    if values["mesh"] and not Path(values["mesh"]).is_file():
        # Checked here, at start: else the node would run and report it per camera_info.
        raise ParameterError(f"mesh must be an existing model file, got {values['mesh']!r}")
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
        shadows=values["shadows"],
        render_backend=values["render_backend"],
        reuse=reuse,
    )
    return NodeConfig(
        pose_source=values["pose_source"],
        station_frame=values["station_frame"],
        camera_frame=values["camera_frame"],
        pose_tolerance_s=float(values["pose_tolerance_s"]),
        tf_timeout_s=float(values["tf_timeout_s"]),
        image_transport=values["image_transport"],
        rectified_input=values["rectified_input"],
        mesh=values["mesh"],
        sun_direction=tuple(float(v) for v in values["sun_direction"]),
        sun_strength=float(values["sun_strength"]),
        pipelined=values["pipelined"],
        opencv_threads=int(values["opencv_threads"]),
        keep_freed_memory_mb=int(values["keep_freed_memory_mb"]),
        publish_reference=values["publish_reference"],
        publish_overlay=values["publish_overlay"],
        diagnostics_period_s=float(values["diagnostics_period_s"]),
        input_timeout_s=float(values["input_timeout_s"]),
        hardware_id=values["hardware_id"],
        pipeline=PipelineConfig(
            render, detector_params_from(values), array_backend=values["array_backend"]
        ),
        camera_info_tolerance_s=float(values["camera_info_tolerance_s"]),
        expected_rate_hz=float(values["expected_rate_hz"]),
        rate_tolerance=float(values["rate_tolerance"]),
        max_stamp_delay_s=float(values["max_stamp_delay_s"]),
        score_full_resolution=values["score_full_resolution"],
        overlay_full_resolution=values["overlay_full_resolution"],
    )
