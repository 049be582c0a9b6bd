"""ALLO's own 2030 ephemeris table, shipped with the package, as :class:`~allo_mrad_ros.sky.Sky`."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping
from functools import cache
from importlib import resources
from os import PathLike
from pathlib import Path

import numpy as np

from allo_mrad_ros.ephemeris import EphemerisError
from allo_mrad_ros.sky import (
    Sky,
)

ALLO_TABLE_COLUMNS = (
    "moon_r",
    "moon_x",
    "moon_y",
    "moon_z",
    "sun_r",
    "sun_x",
    "sun_y",
    "sun_z",
    "earth_r",
    "earth_x",
    "earth_y",
    "earth_z",
)
"""Columns of ALLO's ``ephemeris_2030.csv`` (Blender units = metres, station frame)."""


def _allo_table_error(source: str, line: int, column: str | None, reason: str) -> EphemerisError:
    where = f"{source}, line {line}" + (f", column {column!r}" if column else "")
    return EphemerisError(f"{where}: {reason}")


def parse_allo_ephemeris(text: str, source: str = "ephemeris_2030.csv") -> dict[int, Sky]:
    """Parse the text of ALLO's ephemeris table.

    Parameters
    ----------
    text : str
        CSV text: one row per day, 12 numbers (:data:`ALLO_TABLE_COLUMNS`). Row 0 holds
        uninitialised memory in ALLO's file and is skipped (only its field count is checked).
    source : str
        Name used in error messages.

    Returns
    -------
    dict of int to Sky
        Keyed by day (the row number, from 1), in the station frame, metres.

    Raises
    ------
    EphemerisError
        Naming the source, the line and the column at fault.
    """
    rows = list(enumerate(csv.reader(io.StringIO(text)), start=1))
    while rows and not rows[-1][1]:
        rows.pop()  # trailing blank lines; a blank line inside would shift the days
    if len(rows) < 2:
        raise _allo_table_error(source, len(rows) + 1, None, "need row 0 and at least one day")
    skies: dict[int, Sky] = {}
    for day, (line, fields) in enumerate(rows):
        if len(fields) != len(ALLO_TABLE_COLUMNS):
            raise _allo_table_error(
                source, line, None, f"expected {len(ALLO_TABLE_COLUMNS)} fields, got {len(fields)}"
            )
        if day == 0:
            continue
        values = {}
        for column, field in zip(ALLO_TABLE_COLUMNS, fields, strict=True):
            try:
                value = float(field)
            except ValueError:
                raise _allo_table_error(source, line, column, f"not a number: {field!r}") from None
            if not math.isfinite(value):
                raise _allo_table_error(source, line, column, f"not finite: {field!r}")
            values[column] = value
        bodies = {}
        for body in ("moon", "sun", "earth"):
            centre = np.array([values[f"{body}_{axis}"] for axis in "xyz"])
            radius = values[f"{body}_r"]
            if not 0 < radius < np.linalg.norm(centre):
                raise _allo_table_error(
                    source,
                    line,
                    f"{body}_r",
                    f"radius must be positive and below the distance {np.linalg.norm(centre):g}",
                )
            bodies[body] = np.append(centre, radius)
        sun_direction = bodies["sun"][:3] / np.linalg.norm(bodies["sun"][:3])
        skies[day] = Sky(sun_direction=sun_direction, **bodies)
    return skies


def read_allo_ephemeris(path: str | PathLike[str] | None = None) -> dict[int, Sky]:
    """Read ALLO's ephemeris table, by default the copy shipped in the package.

    Parameters
    ----------
    path : path-like, optional
        A table in ALLO's format; None for the package's ``data/ephemeris_2030.csv``.

    Returns
    -------
    dict of int to Sky
        Keyed by ALLO day (1-364 for the shipped table).
    """
    if path is None:
        return dict(_shipped_allo_table())
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as error:
        raise EphemerisError(f"{path}: cannot read: {error.strerror}") from None
    return parse_allo_ephemeris(text, str(path))


@cache
def _shipped_allo_table() -> Mapping[int, Sky]:
    resource = resources.files("allo_mrad_ros") / "data" / "ephemeris_2030.csv"
    return parse_allo_ephemeris(resource.read_text(encoding="utf-8"), "ephemeris_2030.csv")


def allo_sky(day: int) -> Sky:
    """Return the :class:`Sky` of ALLO's shipped table for one ALLO day (1-364)."""
    table = _shipped_allo_table()
    if isinstance(day, bool) or not isinstance(day, (int, np.integer)) or int(day) not in table:
        raise EphemerisError(f"ALLO day must be an integer in 1-{max(table)}, got {day!r}")
    return table[int(day)]
