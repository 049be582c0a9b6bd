"""The one rule of every command that writes a folder: what it may replace, and when.

A command writes one kind of folder (a report, a bag, a sequence). Its ``--out`` may be a new
path or an empty folder; an existing folder is replaced only with ``--overwrite`` and only
when everything in it is what that command writes, recognised by content, not by name: a
bag's ``metadata.yaml`` must be rosbag2 metadata and every other file one it lists; every
file of a sequence must be ``sequence.yaml``, ``frames.csv``, ``generation.json``,
``objects.csv``, the mesh ``sequence.yaml`` names or an image, mask, reference or instance
mask ``frames.csv`` names. Everything else is
refused before any work starts, with one line that names the path (and, for a folder, the
first entry that is not part of the output): a file, a symbolic link, a folder with other
files (an ALLO split beside a sequence, a user's file), a sequence whose images are another
dataset's files referenced in place, the working folder or one of its parents, the home folder
or one of its parents, an input or a folder that holds an input, and an empty name.
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import posixpath
import re
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import NoReturn

import yaml

from allo_mrad_ros.errors import InvalidInput


class TargetError(InvalidInput):
    """The output path is refused: writing there could lose what it holds."""


@dataclass(frozen=True)
class OutputKind:
    """What a command writes: its name in messages and how to recognise one on disk.

    Attributes
    ----------
    name : str
        ``report``, ``bag`` or ``sequence``, as messages name it.
    foreign : Callable[[Path], str | None]
        For a non-empty folder: None when everything in it is this kind of output, else the
        first entry that is not, relative to the folder (a folder with a trailing ``/``),
        with the reason where the name alone does not say it.
    """

    name: str
    foreign: Callable[[Path], str | None]


# Metadata files larger than this are not ours (a report's JSON or a bag's metadata.yaml is
# a few kB); they are refused without being read.
_MAX_METADATA_BYTES = 16 * 2**20
# A sequence.yaml key the in-place import of a dataset writes: the images are that dataset's
# own files, referenced where they lie, so no command may replace the folder.
IMAGES_IN_PLACE_KEY = "images_in_place"


def _read_small(path: Path) -> str | None:
    """The UTF-8 text of a regular file of at most a few MB; None if it is not one."""
    try:
        if path.is_symlink() or not path.is_file() or path.stat().st_size > _MAX_METADATA_BYTES:
            return None
        return path.read_text(encoding="utf-8-sig")
    except (OSError, UnicodeDecodeError):
        return None


def _first_foreign(
    folder: Path, allowed: Callable[[str], bool], layout: Callable[[str], bool]
) -> str | None:
    """The first entry under ``folder`` (sorted, depth first) that is not part of the output.

    ``allowed(relative)`` says whether a file (or symbolic link) belongs; a folder belongs when
    everything in it does, and an empty one only where ``layout(relative)`` expects a folder.
    A folder none of whose files belongs is named itself (``train/``), not its first file.
    """

    def visit(directory: Path, prefix: str) -> tuple[str | None, bool]:
        """(first foreign entry, whether anything in ``directory`` belongs)."""
        first, owned = None, False
        for entry in sorted(directory.iterdir(), key=lambda p: p.name):
            relative = f"{prefix}{entry.name}"
            if entry.is_dir() and not entry.is_symlink():
                found, inner = visit(entry, f"{relative}/")
                if found is not None and not inner:
                    found = f"{relative}/"  # nothing in it belongs: name the folder
                elif found is None and not inner and not layout(relative):
                    found = f"{relative}/"  # an empty folder the output does not have
                owned = owned or inner
            elif allowed(relative):
                found, owned = None, True
            else:
                found = relative
            first = first if first is not None else found
        return first, owned

    try:
        return visit(folder, "")[0]
    except OSError as error:
        return f"{folder.name}/ (cannot be listed: {error.strerror})"


def _json_object(path: Path) -> dict | None:
    text = _read_small(path)
    try:
        data = json.loads(text) if text is not None else None
    except (ValueError, RecursionError):
        return None
    return data if isinstance(data, dict) else None


def _yaml_mapping(path: Path) -> dict | None:
    text = _read_small(path)
    try:
        data = yaml.safe_load(text) if text is not None else None
    except (yaml.YAMLError, RecursionError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _relative(text: object) -> str | None:
    """A path of a metadata file as the walk names it (POSIX, normalised); None if empty."""
    if not isinstance(text, str) or not text.strip():
        return None
    return posixpath.normpath(text)


def _report(files: Collection[str], main: str) -> Callable[[Path], str | None]:
    """A report: ``main`` (a JSON object) and nothing but ``files``."""

    def foreign(folder: Path) -> str | None:
        if not os.path.lexists(folder / main):
            return f"no {main}"
        if _json_object(folder / main) is None:
            return f"{main}: not a report's"
        return _first_foreign(folder, lambda relative: relative in files, lambda _: False)

    return foreign


_SQLITE_SIDECARS = ("-wal", "-shm", "-journal")


def _bag_files(metadata: dict | None) -> set[str] | None:
    """The storage files a rosbag2 ``metadata.yaml`` lists; None if it is not one."""
    info = metadata.get("rosbag2_bagfile_information") if metadata else None
    if not isinstance(info, dict):
        return None
    paths = info.get("relative_file_paths")
    if (
        not isinstance(info.get("version"), int)
        or not isinstance(info.get("storage_identifier"), str)
        or not isinstance(paths, list)
        or not all(isinstance(path, str) and path for path in paths)
    ):
        return None
    return {_relative(path) for path in paths}


def _bag_foreign(folder: Path) -> str | None:
    """A bag: rosbag2 metadata in ``metadata.yaml`` and only the storage files it lists (with
    SQLite's journal files beside them)."""
    if not os.path.lexists(folder / "metadata.yaml"):
        return "no metadata.yaml"
    listed = _bag_files(_yaml_mapping(folder / "metadata.yaml"))
    if listed is None:
        return "metadata.yaml: not rosbag2 metadata"

    def allowed(relative: str) -> bool:
        stem = next((relative[: -len(s)] for s in _SQLITE_SIDECARS if relative.endswith(s)), "")
        return relative == "metadata.yaml" or relative in listed or stem in listed

    return _first_foreign(folder, allowed, lambda _: False)


_SEQUENCE_TOP_FILES = frozenset({"sequence.yaml", "frames.csv", "generation.json", "objects.csv"})
_SEQUENCE_LAYOUT = re.compile(
    r"^(meshes|(train|val|test)(/Camera\d+(/(images|masks|references|instances))?)?)$"
)
_FILE_COLUMNS = ("image", "mask", "reference")
# Format version 2's instance masks; version 1 tables have no such column.
_OPTIONAL_FILE_COLUMNS = ("instances",)


def _frames_files(path: Path) -> set[str] | None:
    """The image, mask and reference paths ``frames.csv`` names; None if it is no frame
    table (unreadable, not CSV, no such columns)."""
    if path.is_symlink():
        return None
    try:
        with path.open(encoding="utf-8-sig", newline="") as stream:
            rows = csv.reader(stream)
            header = next(rows, [])
            if not all(column in header for column in _FILE_COLUMNS):
                return None
            where = [header.index(column) for column in _FILE_COLUMNS]
            where += [header.index(c) for c in _OPTIONAL_FILE_COLUMNS if c in header]
            return {
                relative
                for row in rows
                for index in where
                if index < len(row) and (relative := _relative(row[index])) is not None
            }
    except (OSError, UnicodeDecodeError, csv.Error):
        return None


def _sequence_foreign(folder: Path) -> str | None:
    """A sequence: ``sequence.yaml`` and ``frames.csv`` (or one of them, a write that did not
    finish), ``generation.json``, and only the files they name."""
    present = [name for name in ("sequence.yaml", "frames.csv") if os.path.lexists(folder / name)]
    if not present:
        return "no frames.csv or sequence.yaml"
    named: set[str] = set()
    meta = None
    if "sequence.yaml" in present:
        meta = _yaml_mapping(folder / "sequence.yaml")
        if meta is None or not str(meta.get("format", "")).startswith("allo-sequence/"):
            return "sequence.yaml: not a sequence's metadata"
        mesh = _relative(meta.get("mesh"))
        if mesh is not None:
            named.add(mesh)
    if "frames.csv" in present:
        files = _frames_files(folder / "frames.csv")
        if files is None:
            return "frames.csv: not a sequence's frame table"
        named |= files
    generation = folder / "generation.json"
    if os.path.lexists(generation) and _json_object(generation) is None:
        return "generation.json: not a sequence's"
    foreign = _first_foreign(
        folder,
        lambda relative: relative in _SEQUENCE_TOP_FILES or relative in named,
        lambda relative: _SEQUENCE_LAYOUT.match(relative) is not None,
    )
    if foreign is None and meta is not None and meta.get(IMAGES_IN_PLACE_KEY) is True:
        return "its images are another dataset's own files, imported in place"
    return foreign


EVALUATION_REPORT = OutputKind(
    "report",
    _report(
        frozenset({"metrics.json", "metrics.md", "roc.png", "pr.png", "overlays.png"}),
        "metrics.json",
    ),
)
OBJECTS_REPORT = OutputKind(
    "report", _report(frozenset({"objects.json", "objects.md"}), "objects.json")
)
ABLATION_REPORT = OutputKind(
    "report", _report(frozenset({"ablation.json", "ablation.md"}), "ablation.json")
)
BAG = OutputKind("bag", _bag_foreign)
SEQUENCE = OutputKind("sequence", _sequence_foreign)


EMPTY_NAME = "an empty name is not an output folder"


def output_path(text: str) -> Path:
    """``argparse`` type of an output folder: refuses an empty name (``''`` would be ``.``).

    Raises
    ------
    argparse.ArgumentTypeError
        For an empty or blank name; :class:`OutputArgumentParser` reports it in one line.
    """
    if not text.strip():
        raise argparse.ArgumentTypeError(EMPTY_NAME)
    return Path(text)


class OutputArgumentParser(argparse.ArgumentParser):
    """An ``argparse`` parser that refuses an empty output name in one line, as every other
    refused output is refused, without the usage block before it.

    Its sub-parsers are of this class too (``add_subparsers`` uses the parser's own class).
    """

    def error(self, message: str) -> NoReturn:
        """Print ``message`` and exit 2; only the usage of an empty output name is left out."""
        if message.endswith(EMPTY_NAME):
            self.exit(2, f"{self.prog}: error: {message}\n")
        super().error(message)


def _contains(folder: Path, path: Path) -> bool:
    return path == folder or path.is_relative_to(folder)


def _refuse_protected(out: Path, target: Path) -> None:
    cwd = Path.cwd().resolve()
    home = Path.home().resolve()
    if _contains(target, cwd):
        what = "is the working folder" if target == cwd else "holds the working folder"
        raise TargetError(f"{out}: {what}; choose another output folder")
    if _contains(target, home):
        what = "is the home folder" if target == home else "holds the home folder"
        raise TargetError(f"{out}: {what}; choose another output folder")


def _refuse_overlap(out: Path, target: Path, inputs: Iterable[str | PathLike[str] | None]) -> None:
    for source in inputs:
        if source is None:
            continue
        resolved = Path(source).resolve()
        if _contains(target, resolved) or _contains(resolved, target):
            raise TargetError(
                f"{out}: the output would replace or sit inside the input {source}; "
                "choose another output folder"
            )


_OLD_COPY = re.compile(r"^\.(?P<name>.+)\.old-(?P<pid>\d+)$")


def process_alive(pid: int) -> bool:
    """Whether a process ``pid`` exists (one of another user counts as alive)."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def restore_interrupted(out: str | PathLike[str]) -> Path | None:
    """Put back an old output that a process killed while replacing it left aside.

    Replacing ``out`` without an atomic exchange renames the old output to
    ``.<name>.old-<pid>`` and then the new one to ``out``: a process killed in between
    (SIGKILL, a power cut) leaves nothing at ``out`` and the old output aside. When nothing
    is at ``out`` and such a copy of a process that no longer runs is there, the newest one
    is renamed back to ``out``.

    Returns
    -------
    pathlib.Path or None
        The copy put back, or None.
    """
    out = Path(out)
    if os.path.lexists(out) or not out.parent.is_dir():
        return None
    try:
        copies = [
            entry
            for entry in out.parent.iterdir()
            if (match := _OLD_COPY.match(entry.name))
            and match["name"] == out.name
            and not process_alive(int(match["pid"]))
        ]
        if not copies:
            return None
        newest = max(copies, key=lambda entry: entry.lstat().st_mtime)
        newest.rename(out)
    except OSError:
        return None
    return newest


def check_target(
    out: str | PathLike[str],
    kind: OutputKind,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | PathLike[str] | None] = (),
) -> None:
    """Refuse ``out`` unless the command may put a new ``kind`` there.

    An old output left aside by a process killed while replacing ``out`` is put back first
    (:func:`restore_interrupted`), so the rule applies to it as to any output there.

    Parameters
    ----------
    out : path-like
        The output folder asked for.
    kind : OutputKind
        What the command writes.
    overwrite : bool
        Whether the user asked to replace an existing output of this kind.
    inputs : iterable of path-like or None
        The command's inputs (None entries are skipped): the output may not be one of them,
        hold one or lie inside one.

    Raises
    ------
    TargetError
        One line naming ``out`` and what to do instead.
    """
    if not str(out).strip():
        raise TargetError(f"'': {EMPTY_NAME}")
    out = Path(out)
    target = out.resolve()
    _refuse_protected(out, target)
    _refuse_overlap(out, target, inputs)
    restore_interrupted(out)
    if not os.path.lexists(out):
        return
    if out.is_symlink():
        raise TargetError(f"{out}: is a symbolic link; give the folder itself or a new name")
    if not out.is_dir():
        raise TargetError(f"{out}: exists and is not a folder; choose another name")
    if not any(out.iterdir()):
        return
    foreign = kind.foreign(out)
    if foreign is not None:
        raise TargetError(
            f"{out}: folder holds files that are not a {kind.name} ({foreign}); "
            "choose another folder"
        )
    if not overwrite:
        raise TargetError(
            f"{out}: folder already holds a {kind.name}; use --overwrite to replace it"
        )
