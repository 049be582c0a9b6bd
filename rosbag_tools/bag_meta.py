"""What ``allo-bag write`` records in a bag's ``custom_data``: keys, splits, the mesh digest."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

from allo_mrad_ros.sequence import SPLITS

BAG_FORMAT = "allo-bag/1"
"""Value of the ``allo.format`` custom-data key of bags written here."""


# custom_data keys (rosbag2 metadata, strings only).
KEY_FORMAT = "allo.format"
KEY_NAME = "allo.sequence_name"
KEY_SPLITS = "allo.splits"
KEY_TOPICS = "allo.topics"
KEY_MESH = "allo.mesh"
KEY_MESH_SHA256 = "allo.mesh_sha256"
KEY_RATE = "allo.rate_hz"


def encode_splits(splits: Iterable[str]) -> str:
    """Run-length text of per-frame splits in playback order, e.g. ``"train:40,test:10"``."""
    runs: list[list] = []
    for split in splits:
        if runs and runs[-1][0] == split:
            runs[-1][1] += 1
        else:
            runs.append([split, 1])
    return ",".join(f"{name}:{count}" for name, count in runs)


def decode_splits(text: str) -> list[str]:
    """Inverse of :func:`encode_splits`.

    Raises
    ------
    ValueError
        If the text is malformed or names an unknown split.
    """
    splits: list[str] = []
    for run in filter(None, text.split(",")):
        name, _, count = run.partition(":")
        if name not in SPLITS or not count.isdigit():
            raise ValueError(f"malformed split run {run!r} in {KEY_SPLITS}")
        splits.extend([name] * int(count))
    return splits


def file_sha256(path: Path) -> str:
    """Hex SHA-256 of a file's bytes."""
    digest = hashlib.sha256()
    with path.open("rb") as stream:
        for block in iter(lambda: stream.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
