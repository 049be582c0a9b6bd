"""The objects table of format version 2 (``objects.csv``): ground-truth objects in the
station frame, one row each.

Each object is a rigid body that keeps its orientation and moves at a constant velocity:
its bounding-box centre is ``position + velocity * (t - stamp_ns) / 1e9`` at time ``t``.
Its ``id`` is the value its pixels hold in the frames' instance masks.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from ..geometry import pose_matrix
from .csv_table import format_float, parse_bounded, read_table, table_text
from .model import (
    MAX_POSITION_M,
    MAX_STAMP_NS,
    UNIT_NORM_TOLERANCE,
    SequenceError,
    frozen_vector,
    read_text,
)

OBJECTS_FILE = "objects.csv"
"""The objects table, next to ``frames.csv`` (format version 2)."""

OBJECT_COLUMNS = (
    "id",
    "type",
    "stamp_ns",
    "x",
    "y",
    "z",
    "vx",
    "vy",
    "vz",
    "qx",
    "qy",
    "qz",
    "qw",
    "size_x",
    "size_y",
    "size_z",
)
"""The columns of ``objects.csv`` in the order the writer emits them."""

MAX_OBJECT_ID = 65535
"""Largest object id: instance masks are 16-bit."""
MAX_SPEED_M_S = 1.0e4
"""Largest speed of an object relative to the station: faster than anything in orbit moves
against it without having hit it already."""
MAX_SIZE_M = 1.0e3
"""Largest extent of an object's bounding box."""

_TYPE = re.compile(r"^[A-Za-z0-9_.+-]+$")


@dataclass(frozen=True, eq=False)
class GroundTruthObject:
    """One row of ``objects.csv``.

    Objects compare by identity (they hold arrays); compare fields explicitly.

    Attributes
    ----------
    id : int
        1..65535, unique in the table; the value of its pixels in the instance masks.
    type : str
        Object type name (as the ``anomaly`` column of ``frames.csv``).
    stamp_ns : int
        Reference time of ``position``, nanoseconds (the clock of ``frames.csv``).
    position : numpy.ndarray
        (3,) bounding-box centre in the station frame at ``stamp_ns``, metres.
    velocity : numpy.ndarray
        (3,) velocity in the station frame, metres per second (0 for a static object).
    quaternion : numpy.ndarray
        (4,) ``(x, y, z, w)`` orientation of the object's own frame in the station frame
        (constant).
    size : numpy.ndarray
        (3,) extents of the bounding box along the object's own axes, metres.
    extra : Mapping[str, str]
        Values of extra columns, as text.
    """

    id: int
    type: str
    stamp_ns: int
    position: np.ndarray
    velocity: np.ndarray
    quaternion: np.ndarray
    size: np.ndarray
    extra: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, length in (("position", 3), ("velocity", 3), ("quaternion", 4), ("size", 3)):
            object.__setattr__(self, name, frozen_vector(getattr(self, name), length))
        object.__setattr__(self, "extra", MappingProxyType(dict(self.extra)))

    def position_at(self, stamp_ns: int) -> np.ndarray:
        """(3,) bounding-box centre at ``stamp_ns`` (constant velocity), station frame."""
        return self.position + self.velocity * ((int(stamp_ns) - self.stamp_ns) * 1e-9)

    def pose_at(self, stamp_ns: int) -> np.ndarray:
        """(4, 4) pose of the object's frame (origin at its bounding-box centre)."""
        return pose_matrix(self.position_at(stamp_ns), self.quaternion)

    @property
    def speed(self) -> float:
        """Magnitude of the velocity, m/s."""
        return float(np.linalg.norm(self.velocity))


def _number(text: str, column: str, bound: float) -> float:
    return parse_bounded(text, column, bound, f"±{bound:g}")


def _integer(text: str, column: str, low: int, high: int) -> int:
    try:
        value = int(text.strip())
    except ValueError:
        raise SequenceError(f"expected an integer, got {text!r}", column=column) from None
    if not low <= value <= high:
        raise SequenceError(f"must be in {low}..{high}, got {value}", column=column)
    return value


def object_from_record(
    record: Mapping[str, str], extra_columns: Iterable[str] = ()
) -> GroundTruthObject:
    """Validate one ``objects.csv`` record (column -> text) and build its object.

    Raises
    ------
    SequenceError
        With ``column`` set; the caller adds the file and the row.
    """
    object_id = _integer(record["id"], "id", 1, MAX_OBJECT_ID)
    kind = record["type"]
    if not _TYPE.match(kind):
        raise SequenceError(
            f"must be a type name of letters, digits and _.+-, got {kind!r}", column="type"
        )
    stamp_ns = _integer(record["stamp_ns"], "stamp_ns", 0, MAX_STAMP_NS - 1)
    position = [_number(record[c], c, MAX_POSITION_M) for c in ("x", "y", "z")]
    velocity = [_number(record[c], c, MAX_SPEED_M_S) for c in ("vx", "vy", "vz")]
    quaternion = [_number(record[c], c, 2.0) for c in ("qx", "qy", "qz", "qw")]
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
        raise SequenceError(f"not a unit quaternion (norm {norm:.6f})", column="qx..qw")
    size = [_number(record[c], c, MAX_SIZE_M) for c in ("size_x", "size_y", "size_z")]
    for column, value in zip(("size_x", "size_y", "size_z"), size, strict=True):
        if value <= 0:
            raise SequenceError(f"must be positive, got {value}", column=column)
    return GroundTruthObject(
        id=object_id,
        type=kind,
        stamp_ns=stamp_ns,
        position=position,
        velocity=velocity,
        quaternion=quaternion,
        size=size,
        extra={c: record[c] for c in extra_columns},
    )


def read_objects(path: Path) -> tuple[GroundTruthObject, ...]:
    """Read and validate ``objects.csv``.

    Parameters
    ----------
    path : pathlib.Path
        The file. A header row alone is a valid, empty table (a sequence without objects).

    Returns
    -------
    tuple of GroundTruthObject
        In file order.

    Raises
    ------
    SequenceError
        Naming the file, the 1-based data row (and its line) and the column at fault:
        missing columns, malformed numbers, duplicate ids, ids outside 1..65535,
        quaternions far from unit norm, sizes that are not positive.
    """
    return parse_objects(read_text(path), path)


def parse_objects(text: str, path: Path | str = OBJECTS_FILE) -> tuple[GroundTruthObject, ...]:
    """Parse the text of ``objects.csv`` (as :func:`read_objects`; ``path`` names it in
    errors, e.g. a bag's custom data)."""
    extra_columns, records = read_table(text, path, OBJECT_COLUMNS)
    objects: list[GroundTruthObject] = []
    rows: dict[int, int] = {}
    for row, line, record in records:
        try:
            item = object_from_record(record, extra_columns)
        except SequenceError as error:
            raise error.located(file=path, row=row, line=line) from None
        if item.id in rows:
            raise SequenceError(
                f"duplicate id {item.id} (first in row {rows[item.id]})",
                file=path,
                row=row,
                line=line,
                column="id",
            )
        rows[item.id] = row
        objects.append(item)
    return tuple(objects)


def checked_objects(objects: Iterable[GroundTruthObject]) -> tuple[GroundTruthObject, ...]:
    """Objects about to be written, validated as a reader would (SequenceError naming the
    row and column)."""
    result = []
    seen: set[int] = set()
    for row, item in enumerate(objects, start=1):
        if not isinstance(item, GroundTruthObject):
            raise SequenceError(
                f"must be a GroundTruthObject, got {type(item).__name__}",
                row=row,
                file=OBJECTS_FILE,
            )
        try:
            object_from_record(object_record(item))
        except SequenceError as error:
            raise error.located(file=OBJECTS_FILE, row=row) from None
        if item.id in seen:
            raise SequenceError(f"duplicate id {item.id}", file=OBJECTS_FILE, row=row, column="id")
        seen.add(item.id)
        result.append(item)
    return tuple(result)


def object_record(item: GroundTruthObject) -> dict[str, str]:
    """The ``objects.csv`` record (column -> text) of an object, extra columns included."""
    values = (*item.position, *item.velocity, *item.quaternion, *item.size)
    numeric = OBJECT_COLUMNS[3:]
    record = {"id": str(item.id), "type": item.type, "stamp_ns": str(item.stamp_ns)}
    record.update({c: format_float(v) for c, v in zip(numeric, values, strict=True)})
    record.update(item.extra)
    return record


def write_objects_text(objects: Iterable[GroundTruthObject]) -> str:
    """Return the ``objects.csv`` text: standard columns, then every extra column seen."""
    records = [object_record(item) for item in objects]
    extra: list[str] = []
    for record in records:
        extra.extend(c for c in record if c not in OBJECT_COLUMNS and c not in extra)
    return table_text([*OBJECT_COLUMNS, *extra], records)
