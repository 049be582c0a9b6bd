"""What ``allo-bag write`` records in a bag's ``custom_data``: keys, splits, the mesh digest."""

from __future__ import annotations

import hashlib
import json
from collections.abc import Iterable
from pathlib import Path

import yaml

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
KEY_OBJECTS = "allo.objects"
"""Only in bags of sequences of format version 2: the text of their ``objects.csv``."""


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


KEY_FILES_SHA256 = "allo.files_sha256"
"""custom_data key: JSON ``{storage file name: hex SHA-256}``, added once the bag is closed.

rosbags writes MCAP chunks without CRCs, so this digest is what lets a reader notice a bag
whose bytes changed after writing (a bad disk, a bad copy)."""

_METADATA = "metadata.yaml"
_INFO = "rosbag2_bagfile_information"


def add_file_digests(bag: Path) -> None:
    """Record the SHA-256 of every storage file in the closed bag's ``metadata.yaml``."""
    meta_path = bag / _METADATA
    document = yaml.safe_load(meta_path.read_text())
    info = document[_INFO]
    digests = {name: file_sha256(bag / name) for name in info.get("relative_file_paths", [])}
    info.setdefault("custom_data", {})[KEY_FILES_SHA256] = json.dumps(digests, sort_keys=True)
    meta_path.write_text(yaml.safe_dump(document, sort_keys=False))


_NEWER_KEYS = {"ros_distro": 8}  # top-level keys and the metadata version that added them
_NEWER_TOPIC_KEYS = {"type_description_hash": 7}


def set_metadata_version(bag: Path, version: int) -> None:
    """Rewrite a closed bag's version-8 ``metadata.yaml`` as ``version`` (5 to 8): the keys
    later versions added go, except ``custom_data``, which older readers ignore and this
    package needs. Version 8's QoS profiles are already the string versions 4-8 use.

    Raises
    ------
    ValueError
        If the bag's metadata is not version 8 or ``version`` is outside 5-8.
    """
    meta_path = bag / _METADATA
    document = yaml.safe_load(meta_path.read_text())
    info = document[_INFO]
    if info.get("version") != 8 or not 5 <= version <= 8:
        raise ValueError(f"{meta_path}: cannot rewrite version {info.get('version')} as {version}")
    info["version"] = version
    for key, since in _NEWER_KEYS.items():
        if version < since:
            info.pop(key, None)
    for entry in info.get("topics_with_message_count", []):
        for key, since in _NEWER_TOPIC_KEYS.items():
            if version < since:
                entry["topic_metadata"].pop(key, None)
    meta_path.write_text(yaml.safe_dump(document, sort_keys=False))


def changed_files(bag: Path, custom: dict[str, str]) -> list[str]:
    """Storage files whose SHA-256 differs from the one recorded at writing (none recorded:
    nothing to compare, empty list)."""
    recorded = custom.get(KEY_FILES_SHA256)
    if not recorded:
        return []
    try:
        digests = json.loads(recorded)
    except ValueError:
        return [f"{KEY_FILES_SHA256} (malformed)"]
    return [
        name
        for name, digest in sorted(digests.items())
        if not (bag / name).is_file() or file_sha256(bag / name) != digest
    ]
