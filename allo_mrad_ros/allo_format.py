"""ALLO's file conventions: image names (``<day>_<object>_...png``) and the base-pose table."""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass
from importlib import resources

import numpy as np

from .errors import InvalidInput
from .geometry import blender_camera_to_optical, euler_zyx_to_matrix, matrix_to_quaternion

_POSE_COLUMNS = ("split", "index", "x", "y", "z", "roll", "pitch", "yaw")

ALLO_SPLITS = ("train", "test")


class AlloImportError(InvalidInput):
    """An ALLO tree, file name or pose table cannot be imported."""


@dataclass(frozen=True)
class AlloName:
    """The fields of an ALLO image name.

    Attributes
    ----------
    day : int
        Day of 2030, ALLO's ephemeris row (1-based).
    anomaly : str
        Anomaly object name, empty for normal images.
    sun_strength : float
        ALLO's sun lamp strength (10 by default).
    scale, depth : float or None
        Anomaly scale (-1 when not varied) and depth offset in metres; None for normal images.
    colour : str or None
        Anomaly colour (``default`` when not varied); None for normal images.
    """

    day: int
    anomaly: str
    sun_strength: float
    scale: float | None = None
    depth: float | None = None
    colour: str | None = None

    @property
    def is_anomalous(self) -> bool:
        """True for names of anomalous renders."""
        return bool(self.anomaly)


def _number(text: str, what: str, name: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value):
        raise AlloImportError(f"{name}: {what} {text!r} is not a finite number")
    return value


def parse_allo_name(name: str, source: str | None = None) -> AlloName:
    """Parse an ALLO image file name.

    Parameters
    ----------
    name : str
        ``<day>_normal_<sun_strength>.png`` or
        ``<day>_<anomaly>_<sun_strength>_<scale>_<depth>_<colour>.png`` (the suffix is
        optional; anomaly names may contain underscores).
    source : str, optional
        How to name the file in error messages (e.g. its full path); default ``name``.

    Returns
    -------
    AlloName
        The parsed fields.

    Raises
    ------
    AlloImportError
        Naming the file, if the name does not follow either pattern.
    """
    stem = name[:-4] if name.lower().endswith(".png") else name
    where = name if source is None else source
    fields = stem.split("_")
    expected = "<day>_normal_<sun>.png or <day>_<anomaly>_<sun>_<scale>_<depth>_<colour>.png"
    if len(fields) == 3 and fields[1] == "normal":
        day_text, anomaly, strength_text = fields
        scale = depth = colour = None
    elif len(fields) >= 6:
        day_text, *anomaly_parts, strength_text, scale_text, depth_text, colour = fields
        anomaly = "_".join(anomaly_parts)
        if anomaly == "normal" or not all(anomaly_parts):
            raise AlloImportError(f"{where}: invalid anomaly name {anomaly!r}; expected {expected}")
        scale = _number(scale_text, "scale", where)
        depth = _number(depth_text, "depth", where)
        if not colour:
            raise AlloImportError(f"{where}: empty colour; expected {expected}")
    else:
        raise AlloImportError(f"{where}: not an ALLO image name; expected {expected}")
    if not day_text.isdigit() or int(day_text) < 1:
        raise AlloImportError(f"{where}: day {day_text!r} is not a positive integer")
    strength = _number(strength_text, "sun strength", where)
    if strength < 0:
        raise AlloImportError(f"{where}: sun strength {strength_text!r} is negative")
    return AlloName(
        day=int(day_text),
        anomaly="" if anomaly == "normal" else anomaly,
        sun_strength=strength,
        scale=scale,
        depth=depth,
        colour=colour,
    )


def base_pose_to_optical(
    position: object, roll: float, pitch: float, yaw: float
) -> tuple[np.ndarray, np.ndarray]:
    """Convert an ALLO base pose (Blender camera, XYZ Euler) to the ROS optical convention.

    Parameters
    ----------
    position : array_like, shape (3,)
        Camera position in the station frame, metres.
    roll, pitch, yaw : float
        Blender XYZ Euler angles in radians: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

    Returns
    -------
    position : numpy.ndarray
        Shape (3,), unchanged.
    quaternion : numpy.ndarray
        ``(x, y, z, w)`` of the optical frame (x right, y down, z forward) in the station
        frame, ``w >= 0``.
    """
    rotation = blender_camera_to_optical(euler_zyx_to_matrix(roll, pitch, yaw))
    return np.asarray(position, dtype=np.float64).reshape(3), matrix_to_quaternion(rotation)


def parse_base_poses(
    text: str, source: str = "camera_base_poses.csv"
) -> dict[str, dict[int, tuple[np.ndarray, np.ndarray]]]:
    """Parse a base-pose table (``split,index,x,y,z,roll,pitch,yaw``).

    Returns
    -------
    dict
        ``{split: {index: (position, optical quaternion xyzw)}}``.

    Raises
    ------
    AlloImportError
        Naming the source, the line and the column at fault.
    """
    reader = csv.reader(io.StringIO(text))
    header = next(reader, None)
    if header is None or [h.strip() for h in header] != list(_POSE_COLUMNS):
        raise AlloImportError(f"{source}, line 1: header must be {','.join(_POSE_COLUMNS)}")
    poses: dict[str, dict[int, tuple[np.ndarray, np.ndarray]]] = {}
    for fields in reader:
        line = reader.line_num
        if not fields:
            continue
        if len(fields) != len(_POSE_COLUMNS):
            raise AlloImportError(f"{source}, line {line}: expected 8 fields, got {len(fields)}")
        record = dict(zip(_POSE_COLUMNS, (f.strip() for f in fields), strict=True))
        split = record["split"]
        if split not in ALLO_SPLITS:
            raise AlloImportError(f"{source}, line {line}, column 'split': got {split!r}")
        if not record["index"].isdigit():
            raise AlloImportError(
                f"{source}, line {line}, column 'index': not an index: {record['index']!r}"
            )
        values = {}
        for column in _POSE_COLUMNS[2:]:
            try:
                values[column] = _number(record[column], column, "")
            except AlloImportError:
                raise AlloImportError(
                    f"{source}, line {line}, column {column!r}: not a finite number: "
                    f"{record[column]!r}"
                ) from None
        index = int(record["index"])
        if index in poses.setdefault(split, {}):
            raise AlloImportError(f"{source}, line {line}: duplicate pose {split} {index}")
        poses[split][index] = base_pose_to_optical(
            [values["x"], values["y"], values["z"]], values["roll"], values["pitch"], values["yaw"]
        )
    return poses


def allo_base_poses(split: str) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Return ALLO's base poses of one split from the shipped table.

    Parameters
    ----------
    split : str
        ``train`` (cameras 0-39) or ``test`` (cameras 0-9).

    Returns
    -------
    dict of int to (position, quaternion)
        Optical-frame poses in the station frame (see :func:`base_pose_to_optical`).
    """
    if split not in ALLO_SPLITS:
        raise AlloImportError(f"split must be train or test, got {split!r}")
    resource = resources.files("allo_mrad_ros") / "data" / "camera_base_poses.csv"
    table = parse_base_poses(resource.read_text(encoding="utf-8"))
    return table.get(split, {})
