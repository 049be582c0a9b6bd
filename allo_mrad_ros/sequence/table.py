"""Parsing and formatting ``frames.csv``: one validated :class:`Frame` per data row."""

from __future__ import annotations

import math
import ntpath
import posixpath
import re
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePosixPath, PureWindowsPath

import numpy as np

from .csv_table import parse_bounded, parse_float, parse_int, read_table, table_text
from .model import (
    ANOMALOUS,
    EARTH_COLUMNS,
    FORMAT_V1,
    FORMAT_V2,
    INSTANCES_COLUMN,
    LABELS,
    MAX_BODY_M,
    MAX_POSITION_M,
    MAX_STAMP_NS,
    MAX_SUN_STRENGTH,
    MOON_COLUMNS,
    NORMAL,
    SPLITS,
    SUN_COLUMNS,
    UNIT_NORM_TOLERANCE,
    Frame,
    SequenceError,
    columns_of,
    read_text,
)

_POSITION = f"±{MAX_POSITION_M:g} m (1000 km from the station)"
_BODY = f"±{MAX_BODY_M:g} m (the renderer's farthest body)"
_SUN_STRENGTH = f"{MAX_SUN_STRENGTH:g} (a thousand nominal Suns)"


def _choice(text: str, column: str, choices: tuple[str, ...]) -> str:
    if text not in choices:
        raise SequenceError(f"must be one of {', '.join(choices)}; got {text!r}", column=column)
    return text


def _relative_path(text: str, column: str, root: Path, required: bool) -> Path | None:
    if not text:
        if required:
            raise SequenceError("path is empty", column=column)
        return None
    if PurePosixPath(text).is_absolute() or PureWindowsPath(text).is_absolute():
        raise SequenceError(
            f"path must be relative to the sequence root, got {text!r}", column=column
        )
    if leaves_root(text):
        raise SequenceError(
            f"path leaves the sequence folder, got {text!r}; keep files inside it",
            column=column,
        )
    return root / text


def leaves_root(relative: str) -> bool:
    """Whether a relative path climbs out of its root with ``..`` (POSIX or Windows
    separators), e.g. ``../../x.png`` or ``a/../../x.png``."""
    return any(
        module.normpath(relative).split(module.sep)[0] == ".." for module in (posixpath, ntpath)
    )


_CAMERA_FOLDER = re.compile(r"^Camera(\d+)$")


def _check_camera_folder(camera: int, image: str) -> None:
    """A frame's camera is the ``Camera<N>`` folder its image lies in, where it has one."""
    for part in PurePosixPath(posixpath.normpath(image)).parts[:-1]:
        match = _CAMERA_FOLDER.match(part)
        if match and int(match[1]) != camera:
            raise SequenceError(
                f"camera {camera} differs from the image's folder {part}", column="camera"
            )


def _unit_vector(values: list[float], columns: tuple[str, ...]) -> None:
    norm = math.sqrt(sum(v * v for v in values))
    if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
        span = f"{columns[0]}..{columns[-1]}"
        raise SequenceError(f"not a unit vector (norm {norm:.6f})", column=span)


def _body(record: Mapping[str, str], columns: tuple[str, ...]) -> np.ndarray | None:
    texts = [record[c].strip() for c in columns]
    if not any(texts):
        return None
    for column, text in zip(columns, texts, strict=True):
        if not text:
            raise SequenceError("empty while other columns of this body are set", column=column)
    values = [parse_bounded(t, c, MAX_BODY_M, _BODY) for c, t in zip(columns, texts, strict=True)]
    if values[3] <= 0:
        raise SequenceError(f"radius must be positive, got {values[3]}", column=columns[3])
    return np.array(values)


def frame_from_record(
    record: Mapping[str, str],
    index: int,
    root: Path,
    extra_columns: Iterable[str] = (),
    version: str = FORMAT_V1,
) -> Frame:
    """Validate one ``frames.csv`` record (column -> text) and build its :class:`Frame`.

    ``version`` is the sequence's format: version 2 records carry the ``instances`` column.

    Raises
    ------
    SequenceError
        With ``column`` set; the caller adds the file and the row.
    """
    stamp_ns = parse_int(record["stamp_ns"], "stamp_ns")
    if stamp_ns >= MAX_STAMP_NS:
        raise SequenceError(
            f"{stamp_ns} ns does not fit builtin_interfaces/Time (int32 seconds)",
            column="stamp_ns",
        )
    split = _choice(record["split"], "split", SPLITS)
    camera = parse_int(record["camera"], "camera")
    image = _relative_path(record["image"], "image", root, required=True)
    _check_camera_folder(camera, record["image"])
    mask = _relative_path(record["mask"], "mask", root, required=False)
    reference = _relative_path(record["reference"], "reference", root, required=False)
    instances = None
    if version == FORMAT_V2:
        instances = _relative_path(record[INSTANCES_COLUMN], INSTANCES_COLUMN, root, required=False)
    label = _choice(record["label"], "label", LABELS)
    anomaly = record["anomaly"]
    if label == NORMAL and anomaly:
        raise SequenceError(f"must be empty for a normal frame, got {anomaly!r}", column="anomaly")
    if label == ANOMALOUS and not anomaly.strip():
        raise SequenceError("an anomalous frame needs the object type name", column="anomaly")
    position = [parse_bounded(record[c], c, MAX_POSITION_M, _POSITION) for c in ("tx", "ty", "tz")]
    quaternion = [parse_float(record[c], c) for c in ("qx", "qy", "qz", "qw")]
    _unit_vector(quaternion, ("qx", "qy", "qz", "qw"))
    sun = [parse_float(record[c], c) for c in SUN_COLUMNS]
    _unit_vector(sun, SUN_COLUMNS)
    sun_strength = parse_bounded(
        record["sun_strength"], "sun_strength", MAX_SUN_STRENGTH, _SUN_STRENGTH
    )
    if sun_strength < 0:
        raise SequenceError(f"must not be negative, got {sun_strength}", column="sun_strength")
    return Frame(
        index=index,
        stamp_ns=stamp_ns,
        split=split,
        camera=camera,
        image=image,
        mask=mask,
        reference=reference,
        label=label,
        anomaly=anomaly,
        position=position,
        quaternion=quaternion,
        sun_direction=sun,
        sun_strength=sun_strength,
        earth=_body(record, EARTH_COLUMNS),
        moon=_body(record, MOON_COLUMNS),
        extra={c: record[c] for c in extra_columns},
        instances=instances,
    )


def read_frames(path: Path, root: Path, version: str = FORMAT_V1) -> list[Frame]:
    """Read and validate ``frames.csv``.

    Parameters
    ----------
    path : pathlib.Path
        The file.
    root : pathlib.Path
        Sequence root the paths in the file are relative to.
    version : str
        The sequence's format (``sequence.yaml``): version 2 needs the ``instances``
        column; in version 1 a column of that name is an extra column like any other.

    Returns
    -------
    list of Frame
        The frames in playback order (at least one).

    Raises
    ------
    SequenceError
        Naming the file, the 1-based data row (and its line) and the column at fault.
    """
    extra_columns, records = read_table(read_text(path), path, columns_of(version))
    frames: list[Frame] = []
    previous_stamp = -1
    for row, line, record in records:
        try:
            frame = frame_from_record(record, len(frames), root, extra_columns, version)
        except SequenceError as error:
            raise error.located(file=path, row=row, line=line) from None
        if frame.stamp_ns <= previous_stamp:
            raise SequenceError(
                f"stamps must be strictly increasing: {frame.stamp_ns} after {previous_stamp}",
                file=path,
                row=row,
                line=line,
                column="stamp_ns",
            )
        previous_stamp = frame.stamp_ns
        frames.append(frame)
    if not frames:
        raise SequenceError("no frames", file=path, line=2)
    return frames


def write_frames_text(
    records: list[Mapping[str, str]], extra_columns: list[str], version: str = FORMAT_V1
) -> str:
    """Return the ``frames.csv`` text of records (column -> text), standard columns of the
    format ``version`` first."""
    return table_text([*columns_of(version), *extra_columns], records)
