"""Fast DDS shared-memory files that killed processes leave behind in ``/dev/shm``.

A participant on the shared-memory transport (``config/fastdds_loopback.xml``) maps a segment
file (64 MB, sparse) and port files there, and removes them when it closes. A process that
ends without closing them (a test that kills a node, a signal) leaves them, and ``/dev/shm``
is memory: over many test runs they fill it. :func:`remove_orphans` deletes those files that
no live process maps or holds open, among the ones a run made: the tests note what is there
when a session starts (:func:`present`) and remove only what appeared since, never another
program's files or an earlier run's.
"""

from __future__ import annotations

import os
import time
from collections.abc import Iterable
from pathlib import Path

PREFIXES = ("fastdds_", "fastrtps_", "sem.fastdds_", "sem.fastrtps_")
"""Names of the files Fast DDS (2.x and 3.x) makes for its shared-memory transport."""

MIN_AGE_S = 5.0
"""A file younger than this is kept even when no process maps it: a participant starting
now may have made it and not mapped it yet."""


def present(directory: Path = Path("/dev/shm")) -> frozenset[str]:
    """The names of the Fast DDS files in ``directory`` now (none when it does not exist)."""
    if not directory.is_dir():
        return frozenset()
    return frozenset(p.name for p in directory.iterdir() if p.name.startswith(PREFIXES))


def files_in_use(proc: Path = Path("/proc")) -> set[str]:
    """The paths of the files every readable live process maps or holds open."""
    used: set[str] = set()
    for entry in proc.iterdir():
        if not entry.name.isdigit():
            continue
        try:
            for line in (entry / "maps").read_text().splitlines():
                fields = line.split(None, 5)
                if len(fields) == 6:
                    used.add(fields[5].removesuffix(" (deleted)"))
            for descriptor in (entry / "fd").iterdir():
                used.add(str(descriptor.readlink()))
        except OSError:
            continue  # it ended, or is another user's
    return used


def remove_orphans(
    directory: Path = Path("/dev/shm"),
    *,
    keep: Iterable[str] = (),
    min_age_s: float = MIN_AGE_S,
    in_use: Iterable[str] | None = None,
    now: float | None = None,
) -> list[Path]:
    """Delete this user's Fast DDS files in ``directory`` that no live process uses, but
    those in ``keep``.

    Parameters
    ----------
    directory : Path
        Where the shared-memory files are (nothing is done when it does not exist).
    keep : iterable of str
        Names never removed: what was there before the run (:func:`present`).
    min_age_s : float
        Files modified more recently than this are kept.
    in_use : iterable of str, optional
        The paths live processes use (default: :func:`files_in_use`).
    now : float, optional
        The current time, seconds since the epoch (default: :func:`time.time`).

    Returns
    -------
    list of Path
        The files deleted.
    """
    if not directory.is_dir():
        return []
    used = set(files_in_use() if in_use is None else in_use)
    kept = set(keep)
    now = time.time() if now is None else now
    removed = []
    for path in sorted(directory.iterdir()):
        if not path.name.startswith(PREFIXES) or path.name in kept or str(path) in used:
            continue
        try:
            status = path.lstat()
            if status.st_uid != os.getuid() or now - status.st_mtime < min_age_s:
                continue
            path.unlink()
        except OSError:
            continue  # removed meanwhile, or not ours to remove
        removed.append(path)
    return removed
