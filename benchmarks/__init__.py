"""Benchmarks that print figures and write them to ``reports/`` (run by ``make bench-*``).

Not installed: run them from the repository root as ``python -m benchmarks.<name>``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from collections.abc import Sequence
from pathlib import Path


def write_report(path: Path, report: object) -> None:
    """Write a benchmark's figures as indented JSON (creating the folder) and say where."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")
    print(f"written: {path}")


def finish(path: Path, report: object) -> int:
    """Write a command's report (:func:`write_report`) and return its exit status, 0."""
    write_report(path, report)
    return 0


def machine_facts() -> dict[str, object]:
    """CPU count, machine and Python version, for a report's figures to be read against."""
    return {
        "cpu_count": os.cpu_count(),
        "machine": platform.machine(),
        "python": platform.python_version(),
    }


def add_names_option(
    parser: argparse.ArgumentParser,
    flag: str,
    choices: Sequence[str],
    *,
    what: str,
    help: str,
    default: Sequence[str] | None = None,
    allow_empty: bool = False,
) -> None:
    """Add ``flag``: a comma-separated list of names of ``what`` (say ``"mode"``), each one of
    ``choices``; ``default`` (None: all of them) when not given. Parsed to a list in the order
    given; a name not among ``choices`` (or none, unless ``allow_empty``) is refused with
    argparse's usage error."""
    known = tuple(choices)

    def names(text: str) -> list[str]:
        given = [name.strip() for name in text.split(",") if name.strip()]
        unknown = [name for name in given if name not in known]
        if unknown or not (given or allow_empty):
            raise argparse.ArgumentTypeError(
                f"unknown {what} {unknown or text!r}; choose from {', '.join(known)}"
            )
        return given

    names.__name__ = what  # argparse names the type in its message
    parser.add_argument(
        flag,
        type=names,
        default=",".join(known if default is None else default),
        help=f"comma-separated, of {', '.join(known)}: {help}",
    )
