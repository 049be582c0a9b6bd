"""Opening rosbag2 bags for reading: the reader, the metadata and the allo-bag custom data.

Bags are read with ``rosbags``' :class:`~rosbags.highlevel.AnyReader`, which deserializes with
the message definitions embedded in the bag, so bags of any distribution read the same.
A bag is a rosbag2 folder (``metadata.yaml`` plus storage files) or a single ``.mcap`` or
``.db3`` file.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from contextlib import contextmanager
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError

from rosbag_tools.topics import DEFAULT_TOPICS, TopicError, TopicNames

METADATA_FILE = "metadata.yaml"


class BagReadError(RuntimeError):
    """A bag cannot be opened or does not hold what is needed (the message names it)."""


def is_bag(path: str | PathLike[str]) -> bool:
    """True for a rosbag2 folder or a single ``.mcap``/``.db3`` file."""
    path = Path(path)
    if path.is_dir():
        return (path / METADATA_FILE).is_file() or any(
            p.suffix in (".mcap", ".db3") for p in path.iterdir()
        )
    return path.is_file() and path.suffix in (".mcap", ".db3")


def read_metadata(path: str | PathLike[str]) -> dict[str, Any]:
    """Return ``rosbag2_bagfile_information`` of a bag folder's ``metadata.yaml``.

    A single storage file, or a folder without ``metadata.yaml``, gives an empty dict.

    Raises
    ------
    BagReadError
        If ``metadata.yaml`` exists but cannot be parsed.
    """
    meta_path = Path(path) / METADATA_FILE
    if not meta_path.is_file():
        return {}
    try:
        document = yaml.safe_load(meta_path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError) as error:
        raise BagReadError(f"{meta_path}: cannot read bag metadata: {error}") from None
    info = document.get("rosbag2_bagfile_information") if isinstance(document, dict) else None
    if not isinstance(info, dict):
        raise BagReadError(f"{meta_path}: no rosbag2_bagfile_information mapping")
    return info


def custom_data(path: str | PathLike[str]) -> dict[str, str]:
    """The bag's ``custom_data`` (empty if it has none)."""
    data = read_metadata(path).get("custom_data") or {}
    return {str(k): str(v) for k, v in data.items()}


def bag_topics(path: str | PathLike[str]) -> TopicNames:
    """The topic names a bag was written with (``allo.topics``), else the defaults.

    Raises
    ------
    BagReadError
        If the recorded names are malformed.
    """
    text = custom_data(path).get("allo.topics")
    if not text:
        return DEFAULT_TOPICS
    try:
        names = json.loads(text)
        known = {k: v for k, v in names.items() if k in TopicNames.roles()}
        return TopicNames(**known)
    except (ValueError, TypeError, AttributeError, TopicError) as error:
        raise BagReadError(f"{path}: malformed allo.topics in custom_data: {error}") from None


@contextmanager
def open_bag(path: str | PathLike[str]) -> Iterator[AnyReader]:
    """Open a bag for reading with the definitions it embeds.

    Yields
    ------
    rosbags.highlevel.AnyReader
        The open reader.

    Raises
    ------
    BagReadError
        If the path is missing or not a readable rosbag2 bag.
    """
    path = Path(path)
    if not path.exists():
        raise BagReadError(f"{path}: bag not found")
    if path.is_file() and path.suffix == ".bag":
        raise BagReadError(f"{path}: ROS 1 bags are not supported, only rosbag2")
    try:
        reader = AnyReader([path])
        reader.open()
    except (AnyReaderError, ReaderError, FileNotFoundError, OSError, KeyError) as error:
        raise BagReadError(f"{path}: cannot open bag: {error}") from None
    try:
        yield reader
    finally:
        reader.close()


def image_array(message: Any, topic: str) -> np.ndarray:
    """Pixels of a ``sensor_msgs/Image``: (H, W, 3) RGB for colour, (H, W) for mono8.

    Raises
    ------
    BagReadError
        For an encoding other than rgb8, bgr8 and mono8, or a data size that does not match.
    """
    height, width, step = int(message.height), int(message.width), int(message.step)
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1}.get(message.encoding)
    if channels is None:
        raise BagReadError(f"topic {topic}: unsupported image encoding {message.encoding!r}")
    data = np.asarray(message.data, dtype=np.uint8)
    if step < width * channels or data.size != step * height:
        raise BagReadError(
            f"topic {topic}: image data of {data.size} bytes does not match "
            f"{width}x{height} {message.encoding} with step {step}"
        )
    rows = data.reshape(height, step)[:, : width * channels]
    if channels == 1:
        return rows.reshape(height, width).copy()
    pixels = rows.reshape(height, width, 3)
    return (pixels[..., ::-1] if message.encoding == "bgr8" else pixels).copy()


def stamp_ns(header: Any) -> int:
    """Nanoseconds of a ``std_msgs/Header`` stamp."""
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)
