"""The one exception hierarchy of the package.

Every error the package raises on purpose derives from :class:`AlloError`, so a caller can
catch all of them in one clause, and from one of two kinds:

* :class:`InvalidInput` (a :class:`ValueError`): the caller's data or options are wrong (a
  parameter out of range, a malformed file, message or frame); retrying will not help, the
  message names what to fix;
* :class:`BackendError` (a :class:`RuntimeError`): the machine could not do the work (no
  OpenGL context, a worker process died, a disk write failed).

Each module keeps one exception type of its own (``SequenceError``, ``RendererError``, ...)
derived from one of these, so messages stay specific while handlers stay simple.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TypeVar

T = TypeVar("T")


class AlloError(Exception):
    """Base of every error raised by ``allo_mrad_ros`` and ``rosbag_tools``."""


class InvalidInput(AlloError, ValueError):
    """The input (data, parameters, options) is invalid; the message names the problem."""


class BackendError(AlloError, RuntimeError):
    """A resource the work needs failed (OpenGL, worker processes, storage)."""


def one_line(error: BaseException) -> str:
    """``str(error)`` on one line: YAML and OpenCV errors span several lines (a context
    snippet, a caret), which must not break the one-line error of a command."""
    mark = getattr(error, "problem_mark", None)
    problem = getattr(error, "problem", None)
    if problem and mark is not None:  # a yaml.MarkedYAMLError
        return f"{problem} (line {mark.line + 1}, column {mark.column + 1})"
    return " ".join(str(error).split())


def lookup(table: Mapping[str, T], name: str, *, what: str, error: type[Exception]) -> T:
    """The entry of ``table`` named ``name``, or ``error`` naming the choices.

    Parameters
    ----------
    table : Mapping
        Entries by name, in the order the message lists them.
    name : str
        The name asked for.
    what : str
        What a name names, for the message (``preset``, ``outpost layout``).
    error : type
        The exception to raise, the calling module's own.

    Returns
    -------
    object
        ``table[name]``.

    Raises
    ------
    Exception
        ``error("unknown <what> '<name>'; choose from <names>")`` for a name not in ``table``.
    """
    if name not in table:
        raise error(f"unknown {what} {name!r}; choose from {', '.join(table)}")
    return table[name]
