"""Outputs that appear complete or not at all: build in a hidden sibling, rename at the end.

A command that writes a folder (a bag, a report, a sequence) builds it in
``.<name>.partial-<pid>`` next to the target and renames it into place only once it is
complete; a failure, SIGINT or SIGTERM (:func:`signals_as_interrupt`) removes the partial
folder, and partial folders left by processes that no longer exist (a SIGKILL, a power cut)
are removed by the next run.

Replacing an existing output is one atomic exchange of the two folders where the kernel and
the file system have ``renameat2(RENAME_EXCHANGE)`` (Linux 3.15, glibc 2.28), else two
renames (the old output to ``.<name>.old-<pid>``, the new one to the name); SIGINT and SIGTERM
are held over the swap and the removal of the old output, so at every instant the path holds
the old output or the new one. An old output that a process killed between the two renames
(SIGKILL, power cut) left as ``.<name>.old-<pid>`` with nothing at the path is put back by
:func:`allo_mrad_ros.targets.check_target`, never deleted.
"""

from __future__ import annotations

import ctypes
import errno
import logging
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
from allo_mrad_ros.targets import process_alive

HOLD_AT = "ALLO_HOLD_AT"
"""Environment variable: the name of the :func:`hold_point` at which to hold the process."""
HOLD_MARKER = "ALLO_HOLD_MARKER"
"""Environment variable: a file created when the process reaches the held point."""
HOLD_SECONDS = 60.0

_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>partial|old)-(?P<pid>\d+)$")
_LOG = logging.getLogger(__name__)


class StagingError(BackendError):
    """The output folder cannot be created or put in place (permissions, disk, a file)."""


def staging_path(out: Path) -> Path:
    """The hidden sibling this process builds ``out`` in."""
    return out.parent / f".{out.name}.partial-{os.getpid()}"


def remove_stale(out: Path) -> list[Path]:
    """Remove partial and old copies of ``out`` left by processes that no longer run.

    An old copy with nothing at ``out`` is kept: it is the only output there is, which
    :func:`allo_mrad_ros.targets.check_target` puts back.
    """
    removed = []
    if not out.parent.is_dir():
        return removed
    for entry in out.parent.iterdir():
        match = _LEFTOVER.match(entry.name)
        if not match or match["name"] != out.name or process_alive(int(match["pid"])):
            continue
        if match["kind"] == "old" and not os.path.lexists(out):
            continue
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


def old_path(out: Path) -> Path:
    """Where this process keeps the old ``out`` while it replaces it."""
    return out.parent / f".{out.name}.old-{os.getpid()}"


_AT_FDCWD = -100
_RENAME_EXCHANGE = 2  # <linux/fs.h>
# errno values of renameat2 where the libc, kernel or file system lacks the exchange.
_NO_EXCHANGE = {errno.EINVAL, errno.ENOSYS, errno.ENOTSUP, errno.EOPNOTSUPP}


def _load_renameat2() -> Callable[..., int] | None:
    try:
        function = ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None
    function.argtypes = [
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_uint,
    ]
    function.restype = ctypes.c_int
    return function


_renameat2 = _load_renameat2()


def exchange(first: Path, second: Path) -> bool:
    """Swap two existing paths in one step (``renameat2`` with ``RENAME_EXCHANGE``).

    Returns
    -------
    bool
        False, with nothing changed, where the libc, the kernel or the file system has no
        such exchange.

    Raises
    ------
    OSError
        If the exchange is there but fails (permissions, different file systems).
    """
    if _renameat2 is None:
        return False
    paths = (os.fsencode(first), os.fsencode(second))
    if _renameat2(_AT_FDCWD, paths[0], _AT_FDCWD, paths[1], _RENAME_EXCHANGE) == 0:
        return True
    code = ctypes.get_errno()
    if code in _NO_EXCHANGE:
        return False
    raise OSError(code, os.strerror(code), str(second))


def _between_steps(out: Path) -> None:
    """Nothing: tests replace it to hold or signal the process between the two steps of
    replacing ``out`` (after the swap, before the old output is removed; between the two
    renames where there is no exchange)."""


between_swap_steps: Callable[[Path], None] = _between_steps
"""Called between the two steps of :func:`put_in_place`'s replacement, with ``out``."""

_INTERRUPTS = (signal.SIGINT, signal.SIGTERM)


@contextmanager
def _interrupts_deferred() -> Iterator[list[int]]:
    """Hold SIGINT and SIGTERM over the block; yield the list of those that arrived.

    Python's handlers are swapped for one that only records, so a signal delivered to any
    thread (OpenCV's, tqdm's) cannot raise inside the block. After it, an interrupt whose
    handler raises :class:`Interrupted` or ``KeyboardInterrupt`` is dropped: the output is in
    place, the work is done, and the command finishes as if the signal had come after it.
    Any other handler (the default action, a library's) gets the signal then. Outside the
    main thread, where Python runs no handler, the block runs as it is.
    """
    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {}
    try:
        for signum in _INTERRUPTS:
            handler = signal.getsignal(signum)
            if handler is None or handler is signal.SIG_IGN:
                continue  # ignored, or a handler from C that Python cannot put back
            previous[signum] = handler
            signal.signal(signum, lambda signum, frame: received.append(signum))
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)
        for signum in dict.fromkeys(received):
            if previous[signum] not in (_raise_interrupted, signal.default_int_handler):
                signal.raise_signal(signum)


def put_in_place(built: Path, out: Path) -> Path | None:
    """Rename the complete ``built`` to ``out``, replacing an existing ``out`` only now.

    At every instant ``out`` is the old output or the new one, whatever signal arrives:
    SIGINT and SIGTERM wait until the new output is in place and the old one removed (see
    :func:`_interrupts_deferred`).

    Returns
    -------
    pathlib.Path or None
        None once the old output is removed; where it was left if it could not be (a file in
        it is immutable, say): the new output is in place all the same, and a warning names
        both.

    Raises
    ------
    StagingError
        If the new output cannot be put in place; ``out`` is then the old complete output.
    """
    with _interrupts_deferred() as received:
        try:
            if not os.path.lexists(out):
                built.rename(out)
                return None
            old = old_path(out)
            if exchange(built, out):
                between_swap_steps(out)
                hold_point("swap", until=lambda: bool(received))
                try:
                    built.rename(old)  # a name that says what it is, if it has to stay
                except OSError:
                    old = built
            else:
                out.rename(old)
                between_swap_steps(out)
                hold_point("swap", until=lambda: bool(received))
                try:
                    built.rename(out)
                except OSError:
                    old.rename(out)
                    raise
        except OSError as error:
            raise StagingError(f"{out}: cannot put the output in place: {error}") from None
        return _remove_old(old, out)


def _remove_old(old: Path, out: Path) -> Path | None:
    try:
        remove_path(old)
    except OSError as error:
        _LOG.warning(
            "warning: %s: the new output is in place, but the old one could not be removed "
            "(%s); it is left at %s",
            out,
            error.strerror or error,
            old,
        )
        return old
    return None


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


def hold_point(name: str, *, until: Callable[[], bool] | None = None) -> None:
    """A point where a test holds the process, so a signal lands there whatever the speed of
    the machine: with ``ALLO_HOLD_AT=<name>`` in the environment, create the file named by
    ``ALLO_HOLD_MARKER`` (if set) and wait up to 60 s, where SIGINT or SIGTERM interrupts as
    anywhere else, or until ``until()`` is true (a signal held there has arrived). Without
    it (always, outside tests), return at once.
    """
    if os.environ.get(HOLD_AT) != name:
        return
    marker = os.environ.get(HOLD_MARKER)
    if marker:
        Path(marker).touch()
    deadline = time.monotonic() + HOLD_SECONDS
    while time.monotonic() < deadline and not (until is not None and until()):
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
