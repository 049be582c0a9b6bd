"""Opening rosbag2 bags for reading: the reader, the metadata and the allo-bag custom data.

Bags are read with ``rosbags``' rosbag2 :class:`~rosbags.rosbag2.Reader` and deserialized with
the message definitions embedded in the bag, so bags of any distribution read the same.
A bag is a rosbag2 folder (``metadata.yaml`` plus storage files) or a single ``.mcap`` or
``.db3`` file. (``rosbags``' ``AnyReader`` is not used: it takes any path ending in ``.bag``
for a ROS 1 bag, and ``out.bag`` is a common name for a rosbag2 folder.)
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
from rosbags.interfaces import Connection, MessageDefinitionFormat
from rosbags.rosbag2 import Reader, ReaderError
from rosbags.typesys import Stores, TypesysError, get_types_from_idl, get_types_from_msg
from rosbags.typesys import get_typestore as _get_typestore
from rosbags.typesys.store import Typestore

from allo_mrad_ros.errors import InvalidInput, one_line
from allo_mrad_ros.ros.messages import MessageError, image_to_array
from rosbag_tools.bag_meta import KEY_FILES_SHA256, changed_files
from rosbag_tools.integrity import chunk_problem, find_damage, recorded_crcs
from rosbag_tools.topics import DEFAULT_TOPICS, TopicError, TopicNames

METADATA_FILE = "metadata.yaml"


class BagReadError(InvalidInput):
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
        raise BagReadError(f"{meta_path}: cannot read bag metadata: {one_line(error)}") from None
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


class BagReader:
    """An open rosbag2 bag with a typestore built from its embedded definitions.

    Attributes
    ----------
    reader : rosbags.rosbag2.Reader
        The open storage reader (topics, counts, times, raw messages).
    typestore : Typestore
        The bag's own message types.
    """

    def __init__(self, reader: Reader, typestore: Typestore) -> None:
        self.reader = reader
        self.typestore = typestore

    @property
    def connections(self) -> list[Connection]:
        """Connections (topic, type, definition, QoS) of the bag."""
        return self.reader.connections

    @property
    def topics(self) -> dict[str, Any]:
        """Topic name -> rosbags ``TopicInfo`` (msgtype, msgcount, connections)."""
        return self.reader.topics

    @property
    def start_time(self) -> int:
        """Time of the first message, ns."""
        return self.reader.start_time

    @property
    def end_time(self) -> int:
        """One past the time of the last message, ns."""
        return self.reader.end_time

    @property
    def message_count(self) -> int:
        """Messages in the bag."""
        return self.reader.message_count

    def messages(self, connections: list[Connection] | None = None) -> Iterator[tuple]:
        """Yield (connection, bag time, raw CDR) in time order."""
        return self.reader.messages(connections=connections or ())

    def deserialize(self, raw: bytes | memoryview, msgtype: str) -> Any:
        """Decode CDR bytes with the bag's definition of ``msgtype``."""
        return self.typestore.deserialize_cdr(raw, msgtype)


def _typestore(connections: list[Connection], path: Path) -> Typestore:
    types: dict = {}
    for connection in connections:
        definition = connection.msgdef
        if definition.format == MessageDefinitionFormat.MSG:
            types.update(get_types_from_msg(definition.data, connection.msgtype))
        elif definition.format == MessageDefinitionFormat.IDL:
            separator = "=" * 80 + "\n"
            if definition.data.startswith(f"{separator}IDL: "):
                for block in definition.data.split(separator)[1:]:
                    types.update(get_types_from_idl(block.split("\n", 1)[1]))
            else:
                types.update(get_types_from_idl(definition.data))
        else:
            raise BagReadError(
                f"{path}: topic {connection.topic} has no embedded message definition"
            )
    typestore = _get_typestore(Stores.EMPTY)
    typestore.register(types)
    for connection in connections:
        # rosbag2 records the type hash: a definition that does not hash to it is corrupt.
        digest = connection.digest
        if digest.startswith("RIHS01_") and typestore.hash_rihs01(connection.msgtype) != digest:
            raise BagReadError(
                f"{path}: topic {connection.topic}: embedded definition of "
                f"{connection.msgtype} does not match its type hash"
            )
    return typestore


@contextmanager
def open_bag(path: str | PathLike[str]) -> Iterator[BagReader]:
    """Open a rosbag2 bag for reading with the definitions it embeds.

    Yields
    ------
    BagReader
        The open bag.

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
    if path.is_dir() and not (path / METADATA_FILE).is_file():
        raise BagReadError(_no_metadata(path))
    digests_recorded = False
    if (path / "metadata.yaml").is_file():
        custom = custom_data(path)
        digests_recorded = KEY_FILES_SHA256 in custom
        changed = changed_files(path, custom)
        if changed:
            raise BagReadError(f"{path}: {_damage(path, changed, custom)}")
    try:
        reader = Reader(path)
        reader.open()
    except (ReaderError, FileNotFoundError, OSError, KeyError, ValueError) as error:
        raise BagReadError(f"{path}: cannot open bag: {one_line(error)}") from None
    if not digests_recorded:
        # No SHA-256 to compare (a lone .mcap, another tool's bag): check the chunk CRCs.
        storage = [path] if path.is_file() else sorted(path.glob("*.mcap"))
        problems = ((f, chunk_problem(f)) for f in storage if f.suffix == ".mcap")
        damaged = next(((f, p) for f, p in problems if p), None)
        if damaged:
            reader.close()
            raise BagReadError(f"{damaged[0]}: {damaged[1]}")
    try:
        try:
            typestore = _typestore(reader.connections, path)
        except (TypesysError, KeyError, ValueError) as error:
            raise BagReadError(f"{path}: unreadable message definitions: {error}") from None
        yield BagReader(reader, typestore)
    finally:
        reader.close()


def _no_metadata(folder: Path) -> str:
    """The error of a bag folder without ``metadata.yaml``, naming a storage file to read."""
    entries = sorted(folder.iterdir())
    if not entries:
        return f"{folder}: empty folder, not a rosbag2 bag"
    storage = [p for p in entries if p.suffix in (".mcap", ".db3")]
    hint = f"; read a storage file on its own instead: {storage[0]}" if storage else ""
    return f"{folder / METADATA_FILE}: not found: not a complete rosbag2 folder{hint}"


def _damage(path: Path, changed: list[str], custom: dict[str, str]) -> str:
    """What changed in a bag whose storage files differ from their recorded SHA-256: the
    first damaged message (topic, index, stamp) where the per-message CRCs tell, else the
    first damaged chunk, else the files."""
    found = find_damage(path, changed, recorded_crcs(custom) or {})
    for name in changed:
        if found is None and (path / name).suffix == ".mcap" and (path / name).is_file():
            problem = chunk_problem(path / name)
            found = f"{name}: {problem}" if problem else None
    return found or (
        f"{', '.join(changed)} differs from the SHA-256 recorded when the bag was written: "
        "the bag is corrupted or was modified"
    )


def image_array(message: Any, topic: str) -> np.ndarray:
    """Pixels of a ``sensor_msgs/Image`` or ``CompressedImage``: (H, W, 3) RGB, (H, W) mono.

    Decoded by :func:`allo_mrad_ros.ros.messages.image_to_array`, the node's decoder, so a
    bag the node accepts reads here too (every encoding the node takes, jpeg and png).

    Raises
    ------
    BagReadError
        Naming the topic, for an encoding the node refuses or data that does not match.
    """
    try:
        return image_to_array(message)
    except MessageError as error:
        raise BagReadError(f"topic {topic}: {error}") from None


def stamp_ns(header: Any) -> int:
    """Nanoseconds of a ``std_msgs/Header`` stamp."""
    return int(header.stamp.sec) * 10**9 + int(header.stamp.nanosec)
