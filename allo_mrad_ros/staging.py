"""Outputs that appear complete or not at all: build in a hidden sibling, rename at the end.

A command that writes a folder (a bag, a report, a sequence) builds it in
``.<name>.partial-<pid>`` next to the target and renames it into place only once it is
complete; a failure, SIGINT or SIGTERM (:func:`signals_as_interrupt`) removes the partial
folder, and partial folders left by processes that no longer exist (a SIGKILL, a power cut)
are removed by the next run.
"""

from __future__ import annotations

import os
import re
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path

from allo_mrad_ros.errors import BackendError

HOLD_AT = "ALLO_HOLD_AT"
"""Environment variable: the name of the :func:`hold_point` at which to hold the process."""
HOLD_MARKER = "ALLO_HOLD_MARKER"
"""Environment variable: a file created when the process reaches the held point."""
HOLD_SECONDS = 60.0

_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?:partial|old)-(?P<pid>\d+)$")


class StagingError(BackendError):
    """The output folder cannot be created or put in place (permissions, disk, a file)."""


def staging_path(out: Path) -> Path:
    """The hidden sibling this process builds ``out`` in."""
    return out.parent / f".{out.name}.partial-{os.getpid()}"


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale(out: Path) -> list[Path]:
    """Remove partial and old copies of ``out`` left by processes that no longer run."""
    removed = []
    if not out.parent.is_dir():
        return removed
    for entry in out.parent.iterdir():
        match = _LEFTOVER.match(entry.name)
        if match and match["name"] == out.name and not _alive(int(match["pid"])):
            try:
                remove_path(entry)
            except OSError:
                continue
            removed.append(entry)
    return removed


def prepare_staging(out: Path) -> Path:
    """Create (empty) the staging folder of ``out`` and its parents.

    Raises
    ------
    StagingError
        Naming ``out`` (not the hidden path) and the reason.
    """
    staging = staging_path(out)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        remove_stale(out)
        shutil.rmtree(staging, ignore_errors=True)
        staging.mkdir()
    except OSError as error:
        raise StagingError(f"{out}: cannot create the output folder: {error}") from None
    return staging


def put_in_place(built: Path, out: Path) -> None:
    """Rename the complete ``built`` to ``out``, replacing an existing ``out`` only now.

    Raises
    ------
    StagingError
        If a rename fails; ``out`` is then either the old or the new complete folder.
    """
    try:
        if os.path.lexists(out):
            trash = out.parent / f".{out.name}.old-{os.getpid()}"
            out.rename(trash)
            built.rename(out)
            remove_path(trash)
        else:
            built.rename(out)
    except OSError as error:
        raise StagingError(f"{out}: cannot put the output in place: {error}") from None


def remove_path(path: Path) -> None:
    """Remove a file, a symbolic link (not what it points to) or a folder tree.

    Raises
    ------
    OSError
        If it cannot be removed.
    """
    if path.is_symlink() or not path.is_dir():
        path.unlink(missing_ok=True)
    else:
        shutil.rmtree(path)


@contextmanager
def staged_folder(out: str | PathLike[str]) -> Iterator[Path]:
    """Yield an empty staging folder; on a normal exit it becomes ``out``.

    On any exception (KeyboardInterrupt included) the staging folder is removed and ``out``
    is left as it was; an ``OSError`` while writing becomes a :class:`StagingError` naming
    ``out``.
    """
    out = Path(out)
    # Named before it exists, so a signal between its creation and the try cannot leave it
    # behind: the finally removes it whatever point was reached.
    staging = staging_path(out)
    try:
        prepare_staging(out)
        try:
            yield staging
        except OSError as error:
            raise StagingError(f"{out}: cannot write: {error}") from error
        put_in_place(staging, out)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def hold_point(name: str) -> None:
    """A point where a test holds the process, so a signal lands there whatever the speed of
    the machine: with ``ALLO_HOLD_AT=<name>`` in the environment, create the file named by
    ``ALLO_HOLD_MARKER`` (if set) and wait up to 60 s, where SIGINT or SIGTERM interrupts as
    anywhere else. Without it (always, outside tests), return at once.
    """
    if os.environ.get(HOLD_AT) != name:
        return
    marker = os.environ.get(HOLD_MARKER)
    if marker:
        Path(marker).touch()
    deadline = time.monotonic() + HOLD_SECONDS
    while time.monotonic() < deadline:
        time.sleep(0.01)


class Interrupted(KeyboardInterrupt):
    """SIGINT or SIGTERM arrived: raised in the main thread wherever it is.

    A subclass, so every ``except KeyboardInterrupt`` and ``finally`` cleans up as for
    Ctrl-C. Not ``KeyboardInterrupt`` itself: CPython remembers a ``KeyboardInterrupt`` that
    leaves code run by ``exec`` of a string (rosbags compiles its serialisers that way, and
    dataclasses their methods) even when a caller catches it, and then ends the process by
    SIGINT (status -2) instead of the exit status the command returns. CPython checks the
    exact type, so a subclass is not remembered.
    """


def _raise_interrupted(signum: int, frame: object) -> None:
    raise Interrupted(f"signal {signum}")


@contextmanager
def signals_as_interrupt() -> Iterator[None]:
    """Within the block SIGTERM, and SIGINT where it has Python's default handler, raise
    :class:`Interrupted`, so both clean up as Ctrl-C does.

    An ignored SIGINT (a command started in the background) stays ignored. Only in the main
    thread (where Python delivers signals); the previous handlers come back after the block.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    chosen = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        chosen.append(signal.SIGINT)
    previous = {signum: signal.signal(signum, _raise_interrupted) for signum in chosen}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextmanager
def interrupts_held() -> Iterator[None]:
    """Hold SIGINT and SIGTERM inside the block; one that arrived is raised on leaving it.

    For constructors whose half-built object would fail in its finaliser (tqdm's progress
    bar prints a traceback from ``__del__`` when interrupted inside ``__init__``).
    """
    held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, held)


def run_interruptible(prog: str, load: Callable[[], Callable[[], int]]) -> int:
    """Load a command with ``load()`` and run what it returns; the exit status.

    From this call on SIGINT and SIGTERM are :class:`Interrupted`: 130 and one line on stderr
    if one arrives where the command does not handle it itself. While ``load`` imports the
    command's modules they are held and arrive once it returns: an interrupt raised inside a
    library's import can be swallowed by its ``except:``, and the command would then run to
    the end. Once the command has returned, both are ignored until the process ends, so a late
    signal never ends it by the signal's default action (status -15) during the interpreter's
    exit. An entry point calls this before its heavy imports; only the interpreter's own start
    (before this call) keeps the signals' default actions.
    """
    if threading.current_thread() is not threading.main_thread():
        return load()()
    chosen = [signal.SIGTERM]
    if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        chosen.append(signal.SIGINT)
    try:
        for signum in chosen:
            signal.signal(signum, _raise_interrupted)
        held = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            command = load()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)  # a held signal raises here
        status = command()
        hold_point("command-done")
    except KeyboardInterrupt:
        _ignore(chosen)
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    _ignore(chosen)
    return status


def _ignore(signums: list[int]) -> None:
    """Ignore ``signums`` to the process's end: the command has finished and said so, and
    their default action would end the process by the signal during the interpreter's exit."""
    for signum in signums:
        signal.signal(signum, signal.SIG_IGN)
