"""The format's CSV tables (``frames.csv``, ``objects.csv``): reading one (the header checked
against the standard columns, then each data row with its 1-based row and line numbers),
parsing and formatting its cells, and writing one."""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from .model import SequenceError


def parse_int(text: str, column: str, minimum: int = 0) -> int:
    """Parse a whole number not below ``minimum``."""
    try:
        value = int(text.strip())
    except ValueError:
        raise SequenceError(f"expected an integer, got {text!r}", column=column) from None
    if value < minimum:
        raise SequenceError(f"must be at least {minimum}, got {value}", column=column)
    return value


def parse_float(text: str, column: str) -> float:
    """Parse a finite number."""
    try:
        value = float(text)
    except ValueError:
        raise SequenceError(f"expected a number, got {text!r}", column=column) from None
    if not math.isfinite(value):
        raise SequenceError(f"must be finite, got {text!r}", column=column)
    return value


def parse_bounded(text: str, column: str, bound: float, limit: str) -> float:
    """Parse a finite number of magnitude at most ``bound``; ``limit`` says what that is."""
    value = parse_float(text, column)
    if abs(value) > bound:
        raise SequenceError(f"{text.strip()} is not physical: beyond {limit}", column=column)
    return value


def format_float(value: float) -> str:
    """Shortest text that reads back as exactly ``value``."""
    return repr(float(value))


class Record(NamedTuple):
    """One data row of a table.

    Attributes
    ----------
    row : int
        1-based data row (blank lines are not rows).
    line : int
        1-based line of the file it starts on.
    values : dict
        Column -> text, for every column of the header.
    """

    row: int
    line: int
    values: dict[str, str]


def read_table(
    text: str, path: Path | str, columns: Sequence[str]
) -> tuple[list[str], Iterator[Record]]:
    """Check the header of a table's ``text`` and return its extra columns and its records.

    Parameters
    ----------
    text : str
        The file's text.
    path : pathlib.Path or str
        What errors name as the file.
    columns : sequence of str
        The standard columns; each must be in the header, in any order.

    Returns
    -------
    extra_columns : list of str
        The header's other columns, in header order.
    records : iterator of Record
        The data rows, read as they are asked for: a malformed row is reported when it is
        reached, after every row before it.

    Raises
    ------
    SequenceError
        Naming the file and the line (and the column at fault): an empty file, a NUL
        character, malformed CSV, a duplicate or missing column; while iterating, malformed
        CSV or a row whose field count differs from the header's.
    """
    if "\x00" in text:
        # Refused here, the same on every Python: before 3.11 the csv module stops at a NUL
        # ("line contains NUL"), from 3.11 it passes it on into a value.
        line = text.count("\n", 0, text.index("\x00")) + 1
        raise SequenceError("holds a NUL character", file=path, line=line)
    reader = csv.reader(io.StringIO(text, newline=""))
    try:
        header = next(reader)
    except StopIteration:
        raise SequenceError("empty file, expected a header row", file=path, line=1) from None
    except csv.Error as error:
        raise SequenceError(f"malformed CSV: {error}", file=path, line=1) from None
    seen: set[str] = set()
    for name in header:
        if name in seen:
            raise SequenceError("duplicate column", file=path, line=1, column=name)
        seen.add(name)
    missing = [c for c in columns if c not in seen]
    if missing:
        raise SequenceError(
            f"missing column(s): {', '.join(missing)}", file=path, line=1, column=missing[0]
        )
    return [c for c in header if c not in columns], _records(reader, header, path)


def _records(reader: Any, header: list[str], path: Path | str) -> Iterator[Record]:
    # reader: a csv.reader (its type is not public); line_num is the last line it read.
    row = 0
    line = reader.line_num + 1
    while True:
        try:
            fields = next(reader)
        except StopIteration:
            return
        except csv.Error as error:
            raise SequenceError(f"malformed CSV: {error}", file=path, line=line) from None
        if not fields:  # blank line
            line = reader.line_num + 1
            continue
        row += 1
        if len(fields) != len(header):
            raise SequenceError(
                f"has {len(fields)} fields, the header has {len(header)}",
                file=path,
                row=row,
                line=line,
            )
        yield Record(row, line, dict(zip(header, fields, strict=True)))
        line = reader.line_num + 1


def table_text(header: Sequence[str], records: Iterable[Mapping[str, str]]) -> str:
    """The text of a table: the ``header`` row, then each record's value per header column
    (empty where it has none)."""
    stream = io.StringIO(newline="")
    writer = csv.writer(stream, lineterminator="\n")
    writer.writerow(header)
    for record in records:
        writer.writerow([record.get(c, "") for c in header])
    return stream.getvalue()
