"""The node's command line before rcl reads it: ``--ros-args`` parameters and params files.

rcl reports a malformed ``-p`` or params file with a traceback carrying C source positions,
drops a ``-p`` value whose type differs from a params file's silently, and ignores a params
file written for another node without a word; these checks say each in one line first.
"""

from __future__ import annotations

import difflib
import re
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

import yaml

from allo_mrad_ros.errors import one_line
from allo_mrad_ros.ros.parameters import ParameterError


class RosArgumentError(ParameterError):
    """A ``--ros-args`` parameter or a ``--params-file`` is malformed; the message names it."""


def command_line_parameters(argv: Sequence[str]) -> dict[str, Any]:
    """``-p name:=value`` / ``--param name:=value`` of ``--ros-args`` sections, values read as
    YAML (as rcl reads them).

    rcl drops a ``-p`` value whose type differs from the same parameter's value in a
    ``--params-file``; checking these too means no value the user typed is ignored silently.
    """
    found: dict[str, Any] = {}
    for _, given in _parameter_arguments(argv):
        name, separator, text = given.partition(":=")
        if separator:
            try:
                found[name] = yaml.safe_load(text)
            except yaml.YAMLError:
                found[name] = text
    return found


def unknown_parameters(given: Iterable[str], declared: Iterable[str]) -> list[str]:
    """One warning per name in ``given`` that is not a parameter of the node, with the
    closest declared name as a hint (``use_sim_time`` and QoS overrides are rclpy's own)."""
    declared = list(declared)
    warnings = []
    for name in sorted(set(given) - set(declared)):
        if name == "use_sim_time" or name.startswith("qos_overrides."):
            continue
        close = difflib.get_close_matches(name, declared, n=1)
        hint = f"; did you mean {close[0]}?" if close else ""
        warnings.append(f"unknown parameter {name} ignored{hint}")
    return warnings


def params_files(argv: Sequence[str]) -> list[Path]:
    """The ``--params-file`` paths of ``argv`` in order."""
    arguments = list(argv)
    return [
        Path(arguments[index + 1])
        for index, argument in enumerate(arguments[:-1])
        if argument == "--params-file"
    ]


def _node_entries(document: dict, path: Path, prefix: str = "") -> list[str]:
    """The node keys of a params file (namespaces nested or joined), each checked to hold a
    ``ros__parameters`` mapping as rcl requires.

    Raises
    ------
    RosArgumentError
        For an entry without ``ros__parameters`` or with one that is not a mapping.
    """
    keys: list[str] = []
    for key, value in document.items():
        name = f"{prefix}/{str(key).strip('/')}" if prefix else str(key)
        if isinstance(value, dict) and "ros__parameters" in value:
            if not isinstance(value["ros__parameters"], dict):
                raise RosArgumentError(
                    f"params file {path}: {name}: ros__parameters must map parameter names "
                    f"to values, got {type(value['ros__parameters']).__name__}"
                )
            keys.append(name)
        elif isinstance(value, dict) and value and all(isinstance(v, dict) for v in value.values()):
            keys += _node_entries(value, path, name)  # a namespace level
        else:
            raise RosArgumentError(
                f"params file {path}: node entry {name!r} has no ros__parameters (write "
                f"'{name}:' then '  ros__parameters:' then the parameters)"
            )
    return keys


def check_params_files(argv: Sequence[str]) -> dict[Path, list[str]]:
    """Check the ``--params-file`` files of ``--ros-args`` before rcl parses them; return
    each file's node keys.

    rcl reports a missing or malformed file with a log line of its own and an exception
    carrying C source positions; this says it in one line.

    Raises
    ------
    RosArgumentError
        Naming the file and the problem.
    """
    found: dict[Path, list[str]] = {}
    for path in params_files(argv):
        try:
            document = yaml.safe_load(path.read_text(encoding="utf-8"))
        except OSError as error:
            raise RosArgumentError(f"params file {path}: {error.strerror}") from None
        except yaml.YAMLError as error:
            raise RosArgumentError(f"params file {path}: invalid YAML: {one_line(error)}") from None
        if not isinstance(document, dict):
            raise RosArgumentError(
                f"params file {path}: must map node names to ros__parameters, got "
                f"{type(document).__name__}"
            )
        found[path] = _node_entries(document, path)
    return found


def check_command_line(argv: Sequence[str]) -> None:
    """Refuse ``-p name:=`` (no value) and ``-p name`` (no ``:=``) in ``--ros-args``, which rcl
    rejects with a traceback.

    Raises
    ------
    RosArgumentError
        Naming the argument.
    """
    for flag, given in _parameter_arguments(argv):
        name, separator, text = given.partition(":=")
        if not separator or not name:
            raise RosArgumentError(f"{flag} {given!r}: expected name:=value")
        if not text.strip():
            raise RosArgumentError(
                f"{flag} {name}:= has no value: give {name}:=<value> (an empty string: "
                f"{name}:=\"''\")"
            )


def _parameter_arguments(argv: Sequence[str]) -> Iterator[tuple[str, str]]:
    # (flag, the argument after it) of every -p/--param inside a --ros-args section.
    in_ros_args = False
    arguments = list(argv)
    for index, argument in enumerate(arguments):
        if argument == "--ros-args":
            in_ros_args = True
        elif argument == "--":
            in_ros_args = False
        elif in_ros_args and argument in ("-p", "--param"):
            yield argument, arguments[index + 1] if index + 1 < len(arguments) else ""


def _key_pattern(key: str) -> re.Pattern[str]:
    """rcl's node-key wildcards: ``/**`` any namespaces, ``*`` one name token."""
    key = key if key.startswith("/") else "/" + key
    parts = []
    for token in key.strip("/").split("/"):
        parts.append(
            "(/[^/]+)*" if token == "**" else "/" + re.escape(token).replace(r"\*", "[^/]*")
        )
    return re.compile("".join(parts) + "$")


def keys_for_other_nodes(files: dict[Path, list[str]], node_name: str) -> list[str]:
    """One warning per params file none of whose node keys matches the fully qualified
    ``node_name``: rcl ignores its values without a word."""
    warnings = []
    for path, keys in files.items():
        if keys and not any(_key_pattern(key).match(node_name) for key in keys):
            warnings.append(
                f"params file {path} sets parameters for {', '.join(keys)}, not for this node "
                f"({node_name}): its values are ignored; use '{node_name}:' or '/**:'"
            )
    return warnings
