"""Running one command-line case of the sweep: a fresh folder, a real failure, a verdict.

Read-only folders and full disks are real, not simulated: where the machine allows a private
mount namespace (``unshare -m``, root), the case's ``locked`` folder is a read-only bind mount
and its ``disk`` folder a tiny tmpfs, so the command meets EROFS and ENOSPC from the kernel.
Elsewhere those cases are skipped (and say so). Signals are sent to the real process once its
hidden ``.partial-`` folder exists, in the middle of writing, or, for a case with ``hold``,
once the command reaches that ``hold_point`` and waits there (``ALLO_HOLD_AT``): then it cannot
finish before the signal however fast the machine is.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from fnmatch import fnmatch
from pathlib import Path

from sweep_verdicts import CLEAN, CRASH, UNCLEAR, Outcome, classify_exit

COMMANDS = {
    "allo-bag": [sys.executable, "-m", "rosbag_tools"],
    "allo-synth": [sys.executable, "-m", "allo_mrad_ros.synth.entry"],
}
TIME_LIMIT_S = 300.0


def can_mount() -> bool:
    """Whether a private mount namespace with tmpfs and read-only binds is available."""
    if shutil.which("unshare") is None:
        return False
    probe = "mount -t tmpfs -o size=4k tmpfs /mnt"
    return subprocess.run(["unshare", "-m", "sh", "-c", probe], capture_output=True).returncode == 0


@dataclass(frozen=True)
class CliCase:
    """One bad-input case of ``allo-bag`` or ``allo-synth``.

    ``argv`` is formatted with the fixture paths (``{seq}``, ``{bag}``, ...) and the case's
    folders: ``{ws}`` (its workspace), ``{locked}`` (read-only when ``mount`` is ``ro``) and
    ``{disk}`` (a tmpfs of ``disk_kb`` KiB when ``mount`` is ``full``). ``hold`` names the
    ``hold_point`` where the command waits for ``signal``; ``env`` adds variables (formatted
    like ``argv``). ``outputs`` are the top-level names (glob patterns) a command may leave;
    ``one_line`` asks for a stderr of one line in all (no usage block before the error);
    ``cleanup`` runs after the command whatever happened (to undo what ``prepare`` made
    that a plain removal cannot, an immutable file).
    """

    group: str
    name: str
    argv: tuple[str, ...]
    keyword: str = ""
    expect_error: bool = True
    mount: str = ""
    disk_kb: int = 64
    signal: int = 0
    signal_after_s: float | None = None
    prepare: Callable[[Path, dict], None] | None = None
    check: Callable[[Path, dict], str | None] | None = None
    outputs: tuple[str, ...] = ()
    quick: bool = False
    tags: tuple[str, ...] = field(default=())
    hold: str = ""
    env: tuple[tuple[str, str], ...] = ()
    one_line: bool = False
    cleanup: Callable[[Path], None] | None = None


def _listing(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


def _roots(paths: set[str]) -> list[str]:
    """The top-most of ``paths`` (a new folder, not every file in it)."""
    return sorted(p for p in paths if str(Path(p).parent) not in paths)


def _mount_script(case: CliCase, ws: Path, listing: Path) -> str:
    if case.mount == "ro":
        locked = f'"{ws}/locked"'
        setup = f"mount --bind {locked} {locked} && mount -o remount,bind,ro {locked}"
    else:
        setup = f'mount -t tmpfs -o size={case.disk_kb}k tmpfs "{ws}/disk"'
    return (
        f'{setup} || exit 97; "$@"; rc=$?; '
        f'find "{ws}" -mindepth 1 -printf "%P\\n" > "{listing}"; exit $rc'
    )


def run_case(case: CliCase, fixtures: dict, base: Path, mountable: bool) -> Outcome:
    """Run ``case`` in a fresh folder under ``base`` and classify what happened."""
    tool = case.group.split()[0]
    if case.mount and not mountable:
        return Outcome(case.group, case.name, "clean", "skipped: no private mount namespace")
    # A neutral folder name: an error line must name the problem, not echo the case's name.
    ws = base / f"case{zlib.crc32(f'{case.group}: {case.name}'.encode()):08x}"
    shutil.rmtree(ws, ignore_errors=True)
    ws.mkdir(parents=True)
    (ws / "locked").mkdir()
    (ws / "disk").mkdir()
    if case.prepare is not None:
        case.prepare(ws, fixtures)
    before = _listing(ws)
    names = {**fixtures, "ws": ws, "locked": ws / "locked", "disk": ws / "disk"}
    argv = [*COMMANDS[tool], *(a.format(**names) for a in case.argv)]
    listing = base / f"{ws.name}.listing"
    if case.mount:
        argv = ["unshare", "-m", "sh", "-c", _mount_script(case, ws, listing), "sh", *argv]
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "COLUMNS": "200"}
    env.update({key: value.format(**names) for key, value in case.env})
    marker = base / f"{ws.name}.held"
    marker.unlink(missing_ok=True)
    if case.hold:
        env.update({"ALLO_HOLD_AT": case.hold, "ALLO_HOLD_MARKER": str(marker)})
    process = subprocess.Popen(
        argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env, cwd=ws
    )
    try:
        signalled = _signal_midway(process, ws, case, marker) if case.signal else True
        try:
            _, stderr = process.communicate(timeout=TIME_LIMIT_S)
            returncode: int | None = process.returncode
        except subprocess.TimeoutExpired:
            process.kill()
            _, stderr = process.communicate()
            returncode = None
    finally:
        if case.cleanup is not None:
            case.cleanup(ws)
    if returncode == 97 and case.mount:
        return Outcome(case.group, case.name, CRASH, "harness: mount failed")
    if not signalled:
        return Outcome(case.group, case.name, UNCLEAR, "not exercised: ended before the signal")
    after = set(listing.read_text().split()) if case.mount and listing.exists() else _listing(ws)
    new = {p for p in after - before if not any(fnmatch(p.split("/")[0], o) for o in case.outputs)}
    if not case.expect_error and returncode == 0:
        new = {p for p in new if ".partial-" in p or ".old-" in p}
    wrong = None
    if case.check is not None and returncode == 0:
        wrong = case.check(ws, fixtures)
    verdict, detail = classify_exit(
        returncode, stderr, case.keyword, _roots(new), case.expect_error, wrong
    )
    lines = [line for line in stderr.splitlines() if line.strip()]
    if case.one_line and verdict == CLEAN and len(lines) != 1:
        verdict, detail = UNCLEAR, f"{len(lines)} lines on stderr: " + " | ".join(lines[:3])
    return Outcome(case.group, case.name, verdict, detail)


def _signal_midway(process: subprocess.Popen, ws: Path, case: CliCase, marker: Path) -> bool:
    """Send ``case.signal`` after ``signal_after_s``, else once the command holds at
    ``case.hold`` (``marker`` exists), else once it is writing (a ``.partial-`` folder)."""
    start = time.monotonic()
    while process.poll() is None and time.monotonic() - start < TIME_LIMIT_S / 2:
        elapsed = time.monotonic() - start
        if case.signal_after_s is not None:
            if elapsed >= case.signal_after_s:
                break
        elif case.hold:
            if marker.exists():
                break
        elif any(".partial-" in p.name for p in ws.rglob(".*")):
            time.sleep(0.05)  # inside the write, not at its first mkdir
            break
        time.sleep(0.005)
    if process.poll() is not None:
        return False
    process.send_signal(case.signal)
    return True


SIGNALS = {"SIGINT": signal.SIGINT, "SIGTERM": signal.SIGTERM}
