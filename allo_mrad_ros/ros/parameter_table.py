"""The parameter tables as documents: the docs' Markdown tables and ``config/mrad.yaml``.

Everything here is written from the two tables, :data:`.parameters.NODE_TABLE` and
:class:`~allo_mrad_ros.detector.params.MradParams`' fields, so a default, range or
description is changed in one place and copied nowhere by hand::

    python -m allo_mrad_ros.ros.parameter_table --markdown node     # print a table
    python -m allo_mrad_ros.ros.parameter_table --yaml              # print config/mrad.yaml
    python -m allo_mrad_ros.ros.parameter_table --write             # rewrite the files
    python -m allo_mrad_ros.ros.parameter_table --check             # exit 1 if one differs

``--write`` and ``--check`` work on a source checkout (``--root``, default the current
folder): ``docs/node.md`` (tables ``node`` and ``objects``) and ``docs/detector.md`` between
their ``parameter table`` comment lines, and ``config/mrad.yaml`` whole.
``test/ros/test_parameter_table.py`` runs the check.
"""

from __future__ import annotations

import argparse
import re
import sys
import textwrap
from collections.abc import Iterable, Sequence
from dataclasses import fields
from pathlib import Path
from typing import Any

from allo_mrad_ros.detector.params import PARAMETER_SPECS, MradParams, ParameterSpec
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.ros.parameters import (
    DETECTOR_PREFIX,
    NODE_TABLE,
    OBJECTS_PREFIX,
    NodeParameter,
    object_parameters,
)

COMMAND = "python -m allo_mrad_ros.ros.parameter_table --write"
# The tables each document holds, and the file that is all generated.
DOCUMENTS = {
    "node": Path("docs", "node.md"),
    "objects": Path("docs", "node.md"),
    "detector": Path("docs", "detector.md"),
}
CONFIG = Path("config", "mrad.yaml")
END_MARKER = "<!-- end of parameter table -->"
YAML_WIDTH = 100

ROS_TYPES = {str: "string", float: "double", int: "int", bool: "bool", list: "double[3]"}
PYTHON_TYPES = {str: "str", float: "float", int: "int", bool: "bool"}


class ParameterTableError(InvalidInput):
    """A document to rewrite is missing or lacks its table's comment lines."""


def begin_marker(table: str) -> str:
    """The comment line after which ``table``'s Markdown table stands in its document."""
    return f"<!-- parameter table: {table}; {COMMAND} rewrites it -->"


def number_text(value: float) -> str:
    """A range end as people write it: 255, 0.05, 1e6."""
    return re.sub(r"e\+?0*(\d)", r"e\1", f"{value:g}")


def range_text(spec: ParameterSpec, code: str = "`") -> str:
    """The valid values: ``a, b`` for choices, ``low..high`` for a closed range, interval
    notation where an end is open, empty for a flag, free text or a vector."""
    if spec.kind is bool or (not spec.choices and spec.low is None):
        return ""
    if spec.choices:
        return ", ".join(f"{code}{c}{code}" if c != "" else "empty" for c in spec.choices)
    low, high = number_text(spec.low), number_text(spec.high)
    if not (spec.low_open or spec.high_open):
        return f"{low}..{high}"
    return f"{'(' if spec.low_open else '['}{low}, {high}{')' if spec.high_open else ']'}"


def yaml_value(value: Any) -> str:
    """``value`` as ``config/mrad.yaml`` writes it (read back as the same value)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        return repr(value)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(yaml_value(v) for v in value) + "]"
    return f'"{value}"' if value == "" else str(value)


def _default_cell(value: Any) -> str:
    if value == "" and isinstance(value, str):
        return "empty"
    if isinstance(value, str):
        return f"`{value}`"
    return yaml_value(value)


def _cell(text: str) -> str:
    # A bar would end the cell, an angle bracket start an HTML tag (<image topic>).
    return text.replace("|", "\\|").replace("<", "&lt;")


def _rows(parameters: Iterable[tuple[str, NodeParameter]], types: dict[type, str]) -> list[str]:
    lines = [
        "| parameter | type | default | range | meaning |",
        "|---|---|---|---|---|",
    ]
    for name, parameter in parameters:
        spec = parameter.spec
        meaning = spec.description + ("; read-only" if parameter.read_only else "")
        cells = (f"`{name}`", types[spec.kind], _default_cell(parameter.default))
        lines.append("| " + " | ".join((*cells, _cell(range_text(spec)), _cell(meaning))) + " |")
    return lines


def _detector_parameters() -> list[tuple[str, NodeParameter]]:
    defaults = {item.name: item.default for item in fields(MradParams)}
    return [(name, NodeParameter(defaults[name], spec)) for name, spec in PARAMETER_SPECS.items()]


def markdown_table(table: str) -> str:
    """The Markdown table ``node`` (every node parameter but ``mrad.*`` and ``objects.*``,
    ROS types), ``objects`` (``objects.*``, ROS types) or ``detector`` (every
    :class:`MradParams` field, Python types)."""
    if table == "node":
        parameters = [(n, p) for section in NODE_TABLE for n, p in section.parameters.items()]
        return "\n".join(_rows(parameters, ROS_TYPES)) + "\n"
    if table == "objects":
        return "\n".join(_rows(object_parameters().items(), ROS_TYPES)) + "\n"
    if table == "detector":
        return "\n".join(_rows(_detector_parameters(), PYTHON_TYPES)) + "\n"
    raise ParameterTableError(f"no parameter table {table!r}; choose one of {list(DOCUMENTS)}")


def _comment(text: str, indent: str) -> list[str]:
    return textwrap.wrap(
        text,
        YAML_WIDTH,
        initial_indent=f"{indent}# ",
        subsequent_indent=f"{indent}# ",
        break_on_hyphens=False,
    )


def _yaml_entry(name: str, parameter: NodeParameter, indent: str) -> list[str]:
    notes = [
        n for n in (range_text(parameter.spec, code=""), parameter.read_only and "read-only") if n
    ]
    note = f" ({'; '.join(notes)})" if notes else ""
    return [
        *_comment(parameter.spec.description + note, indent),
        f"{indent}{name}: {yaml_value(parameter.default)}",
    ]


def yaml_document() -> str:
    """``config/mrad.yaml``: every parameter at its default, each with its description."""
    lines = [
        "# Parameters of the mrad_detector node (ROS 2 parameter file), each at its default,",
        "# with its description and valid values (`ros2 param describe /mrad_detector <name>`",
        "# prints them too). Read-only parameters can only be set at start. Written from the",
        "# parameter tables (allo_mrad_ros/ros/parameters.py, allo_mrad_ros/detector/params.py)",
        f"# by `{COMMAND}`.",
        "/**:",
        "  ros__parameters:",
    ]
    indent = " " * 4
    for section in NODE_TABLE:
        lines += ["", f"{indent}# --- {section.title} ---"]
        for name, parameter in section.parameters.items():
            lines += _yaml_entry(name, parameter, indent)
    lines += [
        "",
        f"{indent}# --- Objects in the station frame (docs/objects.md describes the tracker) ---",
        f"{indent}{OBJECTS_PREFIX.rstrip('.')}:",
    ]
    for name, parameter in object_parameters().items():
        lines += _yaml_entry(name[len(OBJECTS_PREFIX) :], parameter, indent + "  ")
    lines += [
        "",
        f'{indent}# --- Detector (docs/detector.md, "Parameters", gives the reasons for each '
        "value) ---",
        f"{indent}{DETECTOR_PREFIX.rstrip('.')}:",
    ]
    for name, parameter in _detector_parameters():
        lines += _yaml_entry(name, parameter, indent + "  ")
    return "\n".join(lines) + "\n"


def with_table(text: str, table: str, where: Path | str = "the document") -> str:
    """``text`` with the lines between ``table``'s comment lines replaced by the table.

    Raises
    ------
    ParameterTableError
        When the comment lines are missing.
    """
    begin = begin_marker(table)
    start = text.find(begin + "\n")
    end = text.find(END_MARKER, start)
    if start < 0 or end < 0:
        raise ParameterTableError(
            f"{where}: no lines {begin!r} ... {END_MARKER!r} around the {table} parameter table"
        )
    start += len(begin) + 1
    return text[:start] + markdown_table(table) + text[end:]


def expected_files(root: Path) -> dict[Path, str]:
    """Each generated file under ``root`` with the text it should have.

    Raises
    ------
    ParameterTableError
        For a missing document, or one without its table's comment lines.
    """
    expected: dict[Path, str] = {}
    for table, relative in DOCUMENTS.items():
        path = root / relative
        if path not in expected:  # a document may hold several tables
            try:
                expected[path] = path.read_text(encoding="utf-8")
            except OSError as error:
                raise ParameterTableError(f"{path}: {error.strerror}") from None
        expected[path] = with_table(expected[path], table, path)
    expected[root / CONFIG] = yaml_document()
    return expected


def stale_files(root: Path) -> list[Path]:
    """The generated files under ``root`` that differ from what the tables give."""
    stale = []
    for path, text in expected_files(root).items():
        current = path.read_text(encoding="utf-8") if path.is_file() else None
        if current != text:
            stale.append(path)
    return stale


def main(argv: Sequence[str] | None = None) -> int:
    """Print or rewrite the generated documents; 0, 1 (``--check`` found a stale file) or
    2 (one line on stderr: a file or its comment lines missing)."""
    parser = argparse.ArgumentParser(
        prog="python -m allo_mrad_ros.ros.parameter_table", description=__doc__.split("\n")[0]
    )
    action = parser.add_mutually_exclusive_group(required=True)
    action.add_argument("--markdown", choices=sorted(DOCUMENTS), help="print a Markdown table")
    action.add_argument("--yaml", action="store_true", help="print config/mrad.yaml")
    action.add_argument("--write", action="store_true", help="rewrite the generated files")
    action.add_argument("--check", action="store_true", help="exit 1 if a file is stale")
    parser.add_argument("--root", type=Path, default=Path(), help="source checkout")
    args = parser.parse_args(argv)
    if args.markdown:
        sys.stdout.write(markdown_table(args.markdown))
        return 0
    if args.yaml:
        sys.stdout.write(yaml_document())
        return 0
    try:
        if args.check:
            stale = stale_files(args.root)
            for path in stale:
                print(f"{path}: differs from the parameter table; run {COMMAND}", file=sys.stderr)
            return 1 if stale else 0
        for path, text in expected_files(args.root).items():
            path.write_text(text, encoding="utf-8")
    except ParameterTableError as error:
        print(f"parameter_table: {error}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
