"""What a test of a command's signal handling reads about the child process (Linux /proc)."""

from __future__ import annotations

import signal
from pathlib import Path


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
