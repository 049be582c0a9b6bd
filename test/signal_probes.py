"""What a test of a command's signal handling needs: starting it as a terminal would, what it
shows of itself in Linux /proc, and the checks of an interrupted run."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest


def default_signals() -> None:
    """``preexec_fn``: what a terminal gives a command, SIGINT neither ignored nor blocked,
    so a process that ends itself by SIGINT shows as -2 (a background shell would hide it)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.pthread_sigmask(signal.SIG_SETMASK, [])


def catches_sigterm(pid: int) -> bool:
    """Whether the process has installed a SIGTERM handler."""
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("SigCgt:"):
            return bool(int(line.split()[1], 16) & (1 << (signal.SIGTERM - 1)))
    return False


def loaded_numpy(pid: int) -> bool:
    """Whether the process has NumPy's core extension mapped."""
    return "_multiarray_umath" in Path(f"/proc/{pid}/maps").read_text()


def held_at(point: str, marker: Path) -> dict[str, str]:
    """Environment that holds the command at its ``hold_point(point)`` (60 s at most, an
    interrupt ends the hold) and creates ``marker`` when it gets there: the command cannot
    finish before the signal however fast the machine is."""
    return {"ALLO_HOLD_AT": point, "ALLO_HOLD_MARKER": str(marker)}


def start_command(
    argv: list[str], cwd: Path, env: dict[str, str] | None = None
) -> subprocess.Popen:
    """``python -m <argv>`` with a terminal's signal disposition, stdout/stderr as text;
    ``env`` is added to this process's environment."""
    return subprocess.Popen(
        [sys.executable, "-m", *argv],
        cwd=cwd,
        env={**os.environ, **(env or {})},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=default_signals,
    )


def wait_for(
    process: subprocess.Popen, ready: Callable[[], bool], what: str, limit_s: float
) -> None:
    """Poll ``ready`` every millisecond; fail if the process ends or ``limit_s`` passes first."""
    start = time.monotonic()
    while not ready():
        if process.poll() is not None:
            pytest.fail(f"the command ended ({process.returncode}) before {what}")
        if time.monotonic() - start > limit_s:
            process.kill()
            pytest.fail(f"no {what} within {limit_s} s")
        time.sleep(0.001)


def assert_interrupted(process: subprocess.Popen, stderr: str) -> None:
    """Exit status 130 and a last line ending in "interrupted", with no traceback."""
    assert process.returncode == 130, stderr
    assert stderr.strip().splitlines()[-1].endswith("interrupted"), stderr
    assert "Traceback" not in stderr
