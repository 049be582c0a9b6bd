"""What the benchmarks' caches of detections are keyed by besides their inputs: the package's
code, so that a cache made by other code is never read as this code's output."""

from __future__ import annotations

import functools
import hashlib
from pathlib import Path

import allo_mrad_ros

PACKAGE = Path(allo_mrad_ros.__file__).resolve().parent


@functools.cache
def package_digest(root: Path = PACKAGE) -> str:
    """SHA-256 (hex, 16 digits) of every Python source file below ``root``, path and content,
    in sorted order: any change to the package's code gives another digest."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()[:16]
