"""The one rule of every command that writes a folder: what it may replace, and when.

A command writes one kind of folder (a report, a bag, a sequence). Its ``--out`` may be a new
path or an empty folder; an existing folder is replaced only with ``--overwrite`` and only
when it holds nothing but what that command writes. Everything else is refused before any
work starts, with one line that names the path: a file, a symbolic link, a folder with other
files, the working folder or one of its parents, the home folder or one of its parents, an
input or a folder that holds an input, and an empty name.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from os import PathLike
from pathlib import Path

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
    holds : Callable[[Path], bool]
        True for a non-empty folder that holds nothing but this kind of output.
    """

    name: str
    holds: Callable[[Path], bool]


def _only(folder: Path, allowed: Callable[[str], bool], required: str) -> bool:
    names = [entry.name for entry in folder.iterdir()]
    return required in names and all(allowed(name) for name in names)


def _files_of(names: frozenset[str], required: str) -> Callable[[Path], bool]:
    def holds(folder: Path) -> bool:
        return _only(folder, lambda name: name in names and (folder / name).is_file(), required)

    return holds


_BAG_SUFFIXES = (".mcap", ".db3", ".db3-wal", ".db3-shm", ".db3-journal")


def _holds_bag(folder: Path) -> bool:
    def allowed(name: str) -> bool:
        return (folder / name).is_file() and (
            name == "metadata.yaml" or name.endswith(_BAG_SUFFIXES)
        )

    return _only(folder, allowed, "metadata.yaml")


_SEQUENCE_FILES = frozenset({"sequence.yaml", "frames.csv", "generation.json"})
_SEQUENCE_FOLDERS = frozenset({"train", "val", "test", "meshes"})


def _holds_sequence(folder: Path) -> bool:
    def allowed(name: str) -> bool:
        path = folder / name
        kinds = _SEQUENCE_FOLDERS if path.is_dir() and not path.is_symlink() else _SEQUENCE_FILES
        return name in kinds

    return _only(folder, allowed, "frames.csv") or _only(folder, allowed, "sequence.yaml")


EVALUATION_REPORT = OutputKind(
    "report",
    _files_of(
        frozenset({"metrics.json", "metrics.md", "roc.png", "pr.png", "overlays.png"}),
        "metrics.json",
    ),
)
ABLATION_REPORT = OutputKind(
    "report", _files_of(frozenset({"ablation.json", "ablation.md"}), "ablation.json")
)
BAG = OutputKind("bag", _holds_bag)
SEQUENCE = OutputKind("sequence", _holds_sequence)


def output_path(text: str) -> Path:
    """``argparse`` type of an output folder: refuses an empty name (``''`` would be ``.``).

    Raises
    ------
    argparse.ArgumentTypeError
        For an empty or blank name.
    """
    if not text.strip():
        raise argparse.ArgumentTypeError("an empty name is not an output folder")
    return Path(text)


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


def check_target(
    out: str | PathLike[str],
    kind: OutputKind,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | PathLike[str] | None] = (),
) -> None:
    """Refuse ``out`` unless the command may put a new ``kind`` there.

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
        raise TargetError("'': an empty name is not an output folder")
    out = Path(out)
    target = out.resolve()
    _refuse_protected(out, target)
    _refuse_overlap(out, target, inputs)
    if not os.path.lexists(out):
        return
    if out.is_symlink():
        raise TargetError(f"{out}: is a symbolic link; give the folder itself or a new name")
    if not out.is_dir():
        raise TargetError(f"{out}: exists and is not a folder; choose another name")
    if not any(out.iterdir()):
        return
    if not kind.holds(out):
        raise TargetError(
            f"{out}: folder holds files that are not a {kind.name}; choose another folder"
        )
    if not overwrite:
        raise TargetError(
            f"{out}: folder already holds a {kind.name}; use --overwrite to replace it"
        )
