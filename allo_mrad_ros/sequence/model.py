"""Data model of the ALLO sequence format (versions 1 and 2): the error type, the metadata
and one frame.

The format itself is specified in the project's design notes (``sequence-format.md``); the
constants here are its vocabulary.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

import numpy as np

from allo_mrad_ros.errors import InvalidInput

from .. import interface
from ..camera import CameraIntrinsics
from ..geometry import pose_matrix

FORMAT_V1 = "allo-sequence/1"
FORMAT_V2 = "allo-sequence/2"
"""Version 2 adds the objects table (``objects.csv``) and per-frame instance masks."""
FORMATS = (FORMAT_V1, FORMAT_V2)
META_FILE = "sequence.yaml"
FRAMES_FILE = "frames.csv"

SPLITS = ("train", "val", "test")
LABELS = ("normal", "anomalous")
NORMAL, ANOMALOUS = LABELS

# Mask classes: space background, station and celestial bodies, anomaly.
MASK_BACKGROUND, MASK_STATION, MASK_ANOMALY = 0, 1, 2
MASK_VALUES = (MASK_BACKGROUND, MASK_STATION, MASK_ANOMALY)

# Tolerance on |q| and |sun direction|: generous enough for values printed with a few
# decimals by other tools, tight enough to catch a missing normalisation.
UNIT_NORM_TOLERANCE = 1e-3

# builtin_interfaces/Time holds int32 seconds, so bag stamps must stay below 2**31 s.
MAX_STAMP_NS = 2**31 * 10**9

# Physical bounds of the numbers of a frame, so that a corrupt value (1e300) is refused with
# its row and column instead of overflowing in the pose and renderer maths.
MAX_POSITION_M = 1.0e6
"""Largest camera coordinate: 1000 km from the station, where it is far below a pixel and
the renderer's 32-bit floats no longer place it within a metre."""
MAX_BODY_M = 1.0e13
"""Largest coordinate and radius of the Earth or Moon: the distance from which the renderer
pulls bodies in (67 au, beyond any body of the Solar System's planets)."""
MAX_SUN_STRENGTH = 1.0e3
"""Largest relative Sun intensity: a thousand times the nominal Sun, where every lit pixel
has long saturated."""

POSE_COLUMNS = ("tx", "ty", "tz", "qx", "qy", "qz", "qw")
SUN_COLUMNS = ("sun_x", "sun_y", "sun_z")
EARTH_COLUMNS = ("earth_x", "earth_y", "earth_z", "earth_r")
MOON_COLUMNS = ("moon_x", "moon_y", "moon_z", "moon_r")
COLUMNS = (
    "stamp_ns",
    "split",
    "camera",
    "image",
    "mask",
    "reference",
    "label",
    "anomaly",
    *POSE_COLUMNS,
    *SUN_COLUMNS,
    "sun_strength",
    *EARTH_COLUMNS,
    *MOON_COLUMNS,
)
"""The columns of ``frames.csv`` of version 1, in the order the writer emits them."""
INSTANCES_COLUMN = "instances"
COLUMNS_V2 = (*COLUMNS, INSTANCES_COLUMN)
"""The columns of ``frames.csv`` of version 2: version 1's and the instance mask's path."""


def columns_of(version: str) -> tuple[str, ...]:
    """The standard ``frames.csv`` columns of a format version."""
    return COLUMNS_V2 if version == FORMAT_V2 else COLUMNS


class SequenceError(InvalidInput):
    """A sequence on disk, or a value about to be written to one, is not valid.

    Parameters
    ----------
    reason : str
        What is wrong, without the location.
    file : pathlib.Path or str, optional
        The file at fault (``frames.csv``, ``sequence.yaml``, an image...).
    row : int, optional
        1-based data row of ``frames.csv`` (the header is not counted).
    column : str, optional
        The ``frames.csv`` column or the ``sequence.yaml`` key (dotted, e.g. ``camera.fx``).
    line : int, optional
        1-based line number in the file.

    Attributes
    ----------
    reason, file, row, column, line
        As given, so callers and tests can inspect the location.
    """

    def __init__(
        self,
        reason: str,
        *,
        file: Path | str | None = None,
        row: int | None = None,
        column: str | None = None,
        line: int | None = None,
    ) -> None:
        self.reason = reason
        self.file = Path(file) if file is not None else None
        self.row = row
        self.column = column
        self.line = line
        super().__init__(self._message())

    def _message(self) -> str:
        where = []
        if self.file is not None:
            where.append(str(self.file))
        if self.row is not None:
            where.append(f"row {self.row}" + (f" (line {self.line})" if self.line else ""))
        elif self.line is not None:
            where.append(f"line {self.line}")
        if self.column is not None:
            where.append(f"column {self.column!r}")
        return f"{', '.join(where)}: {self.reason}" if where else self.reason

    def located(
        self,
        *,
        file: Path | str | None = None,
        row: int | None = None,
        column: str | None = None,
        line: int | None = None,
    ) -> SequenceError:
        """Return a copy with the missing parts of the location filled in."""
        return SequenceError(
            self.reason,
            file=self.file if self.file is not None else file,
            row=self.row if self.row is not None else row,
            column=self.column if self.column is not None else column,
            line=self.line if self.line is not None else line,
        )


def read_text(path: Path) -> str:
    """A sequence file's UTF-8 text, without a byte-order mark that spreadsheets write
    (raises SequenceError naming the file)."""
    try:
        return path.read_text(encoding="utf-8-sig")
    except FileNotFoundError:
        raise SequenceError("file not found", file=path) from None
    except (OSError, UnicodeDecodeError) as error:
        raise SequenceError(f"cannot read file: {error}", file=path) from None


def _check_frame_id(value: object, key: str) -> None:
    if not isinstance(value, str) or not value or any(c.isspace() for c in value):
        raise SequenceError(
            f"must be a non-empty TF frame name without spaces, got {value!r}", column=key
        )


@dataclass(frozen=True)
class SequenceMeta:
    """The contents of ``sequence.yaml``.

    Parameters
    ----------
    name : str
        Free text.
    camera : CameraIntrinsics
        Pinhole intrinsics of every image in the sequence.
    rate_hz : float
        Nominal frame rate, positive and finite.
    station_frame, camera_frame : str
        TF frame names of the station model and of the camera (ROS optical convention).
    mesh : pathlib.Path or None
        The station model. After :func:`read_sequence` it is resolved against the folder of
        ``sequence.yaml``; when handed to :class:`SequenceWriter` it is the file to copy or
        refer to.
    format : str
        :data:`FORMAT_V1` or :data:`FORMAT_V2` (a sequence with an objects table and
        instance masks).

    Raises
    ------
    SequenceError
        If a field is invalid (``column`` names the ``sequence.yaml`` key).
    """

    name: str
    camera: CameraIntrinsics
    rate_hz: float = 10.0
    station_frame: str = interface.STATION_FRAME
    camera_frame: str = interface.CAMERA_FRAME
    mesh: Path | None = None
    format: str = FORMAT_V1

    def __post_init__(self) -> None:
        if self.format not in FORMATS:
            raise SequenceError(
                f"unsupported format {self.format!r}, expected one of {', '.join(FORMATS)}",
                column="format",
            )
        if not isinstance(self.name, str):
            raise SequenceError(f"must be text, got {self.name!r}", column="name")
        _check_frame_id(self.station_frame, "station_frame")
        _check_frame_id(self.camera_frame, "camera_frame")
        if not isinstance(self.camera, CameraIntrinsics):
            raise SequenceError(
                f"must be CameraIntrinsics, got {type(self.camera).__name__}", column="camera"
            )
        rate = self.rate_hz
        if isinstance(rate, bool) or not isinstance(rate, (int, float)):
            raise SequenceError(f"must be a number, got {rate!r}", column="rate_hz")
        if not math.isfinite(rate) or rate <= 0:
            raise SequenceError(f"must be positive and finite, got {rate!r}", column="rate_hz")
        object.__setattr__(self, "rate_hz", float(rate))
        if self.mesh is not None:
            object.__setattr__(self, "mesh", Path(self.mesh))


def frozen_vector(values: object, length: int) -> np.ndarray:
    """``values`` as a read-only float64 array of shape ``(length,)``."""
    array = np.array(values, dtype=np.float64).reshape(length)
    array.setflags(write=False)
    return array


@dataclass(frozen=True, eq=False)
class Frame:
    """One row of ``frames.csv``, with paths joined to the sequence root.

    Frames compare by identity (they hold arrays); compare fields explicitly.

    Attributes
    ----------
    index : int
        0-based position in playback order (data row ``index + 1`` of ``frames.csv``).
    stamp_ns : int
        Frame time in nanoseconds.
    split : str
        ``train``, ``val`` or ``test``.
    camera : int
        Camera index ``N`` of the ``Camera<N>`` folder.
    image, mask, reference : pathlib.Path or None
        Files joined to the sequence root (not resolved, so symbolic links are kept).
        ``mask`` and ``reference`` may be None.
    label : str
        ``normal`` or ``anomalous``.
    anomaly : str
        Object type name, empty for normal frames.
    position : numpy.ndarray
        Camera optical frame origin in the station frame, metres, shape (3,).
    quaternion : numpy.ndarray
        Orientation ``(x, y, z, w)`` of the optical frame in the station frame, shape (4,).
    sun_direction : numpy.ndarray
        Unit vector towards the Sun in the station frame, shape (3,).
    sun_strength : float
        Relative sun intensity, 1.0 nominal.
    earth, moon : numpy.ndarray or None
        ``(x, y, z, r)`` of the scaled-down body in the station frame, metres.
    instances : pathlib.Path or None
        Instance mask (format version 2): 16-bit, one channel, the id of the object of the
        objects table each anomaly pixel belongs to, 0 elsewhere. None in version 1.
    extra : Mapping[str, str]
        Values of extra ``frames.csv`` columns, as text.
    """

    index: int
    stamp_ns: int
    split: str
    camera: int
    image: Path
    mask: Path | None
    reference: Path | None
    label: str
    anomaly: str
    position: np.ndarray
    quaternion: np.ndarray
    sun_direction: np.ndarray
    sun_strength: float
    earth: np.ndarray | None = None
    moon: np.ndarray | None = None
    extra: Mapping[str, str] = field(default_factory=dict)
    instances: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "position", frozen_vector(self.position, 3))
        object.__setattr__(self, "quaternion", frozen_vector(self.quaternion, 4))
        object.__setattr__(self, "sun_direction", frozen_vector(self.sun_direction, 3))
        for body in ("earth", "moon"):
            value = getattr(self, body)
            if value is not None:
                object.__setattr__(self, body, frozen_vector(value, 4))
        object.__setattr__(self, "extra", MappingProxyType(dict(self.extra)))

    @property
    def T_station_camera(self) -> np.ndarray:
        """4x4 pose of the camera optical frame in the station frame."""
        return pose_matrix(self.position, self.quaternion)

    @property
    def is_anomalous(self) -> bool:
        """True for frames labelled ``anomalous``."""
        return self.label == ANOMALOUS

    @property
    def name(self) -> str:
        """The image file name without its suffix (ALLO's naming key)."""
        return self.image.stem
