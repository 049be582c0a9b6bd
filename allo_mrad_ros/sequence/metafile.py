"""Reading and writing ``sequence.yaml``, with line numbers in every error."""

from __future__ import annotations

import math
import os
from pathlib import Path

import yaml

from .. import interface
from ..camera import CameraIntrinsics
from ..errors import one_line
from ..targets import IMAGES_IN_PLACE_KEY
from .model import FORMATS, SequenceError, SequenceMeta, read_text
from .png import write_atomic

_REQUIRED = ("format", "camera", "rate_hz")
_CAMERA_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


def _key_lines(node: yaml.Node, prefix: str = "") -> dict[str, int]:
    # Map dotted keys to 1-based lines so errors can point at the offending entry.
    lines: dict[str, int] = {}
    if isinstance(node, yaml.MappingNode):
        for key_node, value_node in node.value:
            key = f"{prefix}{key_node.value}"
            lines[key] = key_node.start_mark.line + 1
            lines.update(_key_lines(value_node, f"{key}."))
    return lines


def _number(value: object, key: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SequenceError(f"must be a number, got {value!r}", column=key)
    if not math.isfinite(value):
        raise SequenceError(f"must be finite, got {value!r}", column=key)
    return value


def read_meta(path: Path) -> SequenceMeta:
    """Read and validate ``sequence.yaml``.

    Parameters
    ----------
    path : pathlib.Path
        The file; a relative ``mesh`` entry is resolved against its folder.

    Returns
    -------
    SequenceMeta
        The validated metadata.

    Raises
    ------
    SequenceError
        Naming the file, the line and the key at fault.
    """
    text = read_text(path)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as error:
        mark = getattr(error, "problem_mark", None)
        line = mark.line + 1 if mark is not None else None
        raise SequenceError(f"invalid YAML: {one_line(error)}", file=path, line=line) from None
    if not isinstance(data, dict):
        raise SequenceError("must be a YAML mapping", file=path, line=1)
    lines = _key_lines(node)
    try:
        return _meta_from_dict(data, path.parent)
    except SequenceError as error:
        line = lines.get(error.column or "")
        if line is None and error.column:
            # A missing key: point at its parent mapping if there is one.
            line = lines.get(error.column.rpartition(".")[0])
        raise error.located(file=path, line=line) from None


def _meta_from_dict(data: dict, folder: Path) -> SequenceMeta:
    for key in _REQUIRED:
        if key not in data:
            raise SequenceError("missing key", column=key)
    if data["format"] not in FORMATS:
        raise SequenceError(
            f"unsupported format {data['format']!r}, expected one of {', '.join(FORMATS)}",
            column="format",
        )
    camera = data["camera"]
    if not isinstance(camera, dict):
        raise SequenceError("must be a mapping of width, height, fx, fy, cx, cy", column="camera")
    values = {}
    for key in _CAMERA_KEYS:
        if key not in camera:
            raise SequenceError("missing key", column=f"camera.{key}")
        values[key] = _number(camera[key], f"camera.{key}")
    for key in ("width", "height"):
        if values[key] != int(values[key]):
            raise SequenceError(
                f"must be a whole number of pixels, got {values[key]!r}", column=f"camera.{key}"
            )
        values[key] = int(values[key])
    try:
        intrinsics = CameraIntrinsics(**values)
    except ValueError as error:
        # CameraIntrinsics names the field first in its message ("camera fx must be ...").
        field = next((k for k in _CAMERA_KEYS if f" {k} " in f" {error} "), None)
        raise SequenceError(str(error), column=f"camera.{field}" if field else "camera") from None
    mesh = data.get("mesh")
    if mesh is not None:
        if not isinstance(mesh, str) or not mesh:
            raise SequenceError(f"must be a relative path or null, got {mesh!r}", column="mesh")
        if Path(mesh).is_absolute():
            raise SequenceError(f"must be relative to sequence.yaml, got {mesh!r}", column="mesh")
        mesh = folder / mesh
        if not mesh.is_file():
            raise SequenceError(f"mesh file not found: {mesh}", column="mesh")
    name = data.get("name", "")
    return SequenceMeta(
        name="" if name is None else str(name),
        camera=intrinsics,
        rate_hz=_number(data["rate_hz"], "rate_hz"),
        station_frame=data.get("station_frame", interface.STATION_FRAME),
        camera_frame=data.get("camera_frame", interface.CAMERA_FRAME),
        mesh=mesh,
        format=data["format"],
    )


def write_meta(
    path: Path, meta: SequenceMeta, mesh: str | None, *, images_in_place: bool = False
) -> None:
    """Write ``sequence.yaml`` atomically.

    Parameters
    ----------
    path : pathlib.Path
        The file to write.
    meta : SequenceMeta
        The metadata; its ``mesh`` is ignored in favour of ``mesh``.
    mesh : str or None
        The mesh path to record, relative to the folder of ``path`` (POSIX separators).
    images_in_place : bool
        Record ``images_in_place: true``: the images are another dataset's own files,
        referenced where they lie, and no command may replace the folder
        (:mod:`allo_mrad_ros.targets`). Readers ignore the key.
    """
    camera = meta.camera
    document = {
        "format": meta.format,
        "name": meta.name,
        "station_frame": meta.station_frame,
        "camera_frame": meta.camera_frame,
        "mesh": mesh,
        "camera": {
            "width": int(camera.width),
            "height": int(camera.height),
            "fx": float(camera.fx),
            "fy": float(camera.fy),
            "cx": float(camera.cx),
            "cy": float(camera.cy),
        },
        "rate_hz": meta.rate_hz,
    }
    if images_in_place:
        document[IMAGES_IN_PLACE_KEY] = True
    text = yaml.safe_dump(document, sort_keys=False, default_flow_style=False, allow_unicode=True)
    write_atomic(path, text.encode("utf-8"))


def relative_posix(target: Path, start: Path) -> str:
    """Return ``target`` relative to the folder ``start`` with POSIX separators."""
    return Path(os.path.relpath(Path(target).absolute(), Path(start).absolute())).as_posix()
