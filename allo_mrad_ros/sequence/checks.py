"""Checks of one frame row before it is written: vectors, bodies, label, extra columns."""

from __future__ import annotations

import re
from collections.abc import Mapping
from os import PathLike

import numpy as np

from allo_mrad_ros.geometry import finite_vector

from .csv_table import format_float
from .model import (
    ANOMALOUS,
    COLUMNS_V2,
    LABELS,
    MASK_ANOMALY,
    NORMAL,
    UNIT_NORM_TOLERANCE,
    SequenceError,
)

_COLUMN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


def checked_vector(values: object, length: int, name: str) -> np.ndarray:
    """``values`` as a float array of ``length`` finite numbers (SequenceError naming it)."""
    return finite_vector(values, length, name, SequenceError)


def checked_unit_vector(values: object, length: int, name: str) -> np.ndarray:
    """:func:`checked_vector` of norm 1 (within the sequence format's tolerance)."""
    array = checked_vector(values, length, name)
    # Through the largest component, so a huge vector (1e300) cannot overflow its norm.
    largest = float(np.max(np.abs(array)))
    norm = largest * float(np.linalg.norm(array / largest)) if largest > 0 else 0.0
    if abs(norm - 1.0) > UNIT_NORM_TOLERANCE:
        raise SequenceError(f"{name} must be a unit vector, got norm {norm:.6f}")
    return array


def checked_body(values: object, name: str) -> np.ndarray | None:
    """A body's ``(x, y, z, radius)`` with a positive radius, or None for no body."""
    if values is None:
        return None
    array = checked_vector(values, 4, name)
    if array[3] <= 0:
        raise SequenceError(f"{name} radius must be positive, got {array[3]}")
    return array


def frame_label(label: str | None, anomaly: str, mask: object) -> str:
    """The frame's label, checked against the anomaly name and the mask."""
    if not isinstance(anomaly, str) or anomaly != anomaly.strip() or "\n" in anomaly:
        raise SequenceError(f"anomaly must be a name without surrounding spaces: {anomaly!r}")
    from_mask = None
    if mask is not None and not isinstance(mask, (str, PathLike)):
        from_mask = ANOMALOUS if np.any(np.asarray(mask) == MASK_ANOMALY) else NORMAL
    if label is None:
        label = from_mask or (ANOMALOUS if anomaly else NORMAL)
    if label not in LABELS:
        raise SequenceError(f"label must be one of {', '.join(LABELS)}; got {label!r}")
    if from_mask is not None and label != from_mask:
        raise SequenceError(f"label {label!r} contradicts the mask (it is {from_mask!r})")
    if label == ANOMALOUS and not anomaly:
        raise SequenceError("an anomalous frame needs the anomaly object type name")
    if label == NORMAL and anomaly:
        raise SequenceError(f"a normal frame must have no anomaly name, got {anomaly!r}")
    return label


def extra_columns(extra: Mapping[str, object]) -> dict[str, str]:
    """Extra column values as one-line texts (names checked against the reserved columns)."""
    text = {}
    for key, value in extra.items():
        if not isinstance(key, str) or not _COLUMN.match(key) or key in COLUMNS_V2:
            raise SequenceError(f"invalid or reserved extra column name {key!r}")
        text[key] = format_float(value) if isinstance(value, float) else str(value)
        if "\n" in text[key] or "\r" in text[key]:
            raise SequenceError(f"extra column {key!r} value must be one line")
    return text
