"""Checksums that let a reader name the damaged message of a corrupted bag.

Two layers, both written by ``allo-bag write``:

* MCAP chunk CRCs. The MCAP format has a CRC-32 per chunk, which rosbags' writer leaves at 0
  (unchecked); :func:`add_chunk_crcs` fills them in after the bag is closed, so any MCAP
  reader (rosbags, the mcap library, ``ros2 bag``) detects a damaged chunk, and a lone
  ``.mcap`` copied without its ``metadata.yaml`` is still checked (:func:`chunk_problem`).
* A CRC-32 per message in ``custom_data`` (:data:`KEY_MESSAGE_CRC32`, any storage): when the
  storage files no longer match their recorded SHA-256, :func:`find_damage` names the topic,
  the index and the stamp of the first message whose bytes changed.
"""

from __future__ import annotations

import json
import mmap
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from allo_mrad_ros.errors import InvalidInput

try:  # rosbags' own chunk decompressors ('', lz4, zstd); older releases: uncompressed only
    from rosbags.rosbag2.storage_mcap import DECOMPRESSORS
except ImportError:  # pragma: no cover - depends on the rosbags release
    DECOMPRESSORS = {"": lambda data, size: data}

KEY_MESSAGE_CRC32 = "allo.message_crc32"
"""custom_data key: JSON ``{topic: concatenated 8-hex-digit CRC-32 of each message's CDR
bytes, in writing order}``."""

_MAGIC = b"\x89MCAP0\r\n"
_CHUNK, _CHANNEL, _MESSAGE, _DATA_END, _FOOTER = 0x06, 0x04, 0x05, 0x0F, 0x02
_CRC_OFFSET = 1 + 8 + 24  # opcode, record length, start/end time, uncompressed size


class IntegrityError(InvalidInput):
    """An MCAP file cannot be walked (a record runs past the end of the file)."""


class MessageDigests:
    """Collects the CRC-32 of every message written, per topic."""

    def __init__(self) -> None:
        self._crcs: dict[str, list[str]] = {}

    def add(self, topic: str, data: bytes | memoryview) -> None:
        self._crcs.setdefault(topic, []).append(f"{zlib.crc32(data):08x}")

    def custom_data(self) -> str:
        """The value of :data:`KEY_MESSAGE_CRC32`."""
        return json.dumps({t: "".join(c) for t, c in sorted(self._crcs.items())})


def recorded_crcs(custom: dict[str, str]) -> dict[str, list[str]] | None:
    """Per-topic CRC lists recorded at writing, or None (not recorded, or malformed)."""
    text = custom.get(KEY_MESSAGE_CRC32)
    if not text:
        return None
    try:
        joined = json.loads(text)
        return {t: [c[i : i + 8] for i in range(0, len(c), 8)] for t, c in joined.items()}
    except (ValueError, TypeError, AttributeError):
        return None


@dataclass(frozen=True)
class _Record:
    opcode: int
    offset: int
    body: bytes


@contextmanager
def _mapped(path: Path, write: bool = False) -> Iterator[mmap.mmap]:
    """The file's bytes without reading a large bag into memory."""
    with path.open("r+b" if write else "rb") as stream:
        access = mmap.ACCESS_WRITE if write else mmap.ACCESS_READ
        with mmap.mmap(stream.fileno(), 0, access=access) as data:
            yield data


def _records(data: bytes | mmap.mmap, start: int, end: int) -> Iterator[_Record]:
    offset = start
    while offset < end:
        if offset + 9 > end:
            raise IntegrityError(f"record header at byte {offset} runs past the end")
        opcode = data[offset]
        (length,) = struct.unpack_from("<Q", data, offset + 1)
        if offset + 9 + length > end:
            raise IntegrityError(f"record at byte {offset} (length {length}) runs past the end")
        yield _Record(opcode, offset, data[offset + 9 : offset + 9 + length])
        offset += 9 + length


def _chunk_parts(body: bytes) -> tuple[int, int, int, str, bytes]:
    start, end, size, crc, name_length = struct.unpack_from("<QQQII", body, 0)
    compression = body[32 : 32 + name_length].decode()
    (length,) = struct.unpack_from("<Q", body, 32 + name_length)
    records = body[40 + name_length : 40 + name_length + length]
    if compression not in DECOMPRESSORS:
        raise IntegrityError(f"chunk compression {compression!r} is not supported")
    return start, end, crc, compression, DECOMPRESSORS[compression](records, size)


def _data_records(data: bytes | mmap.mmap) -> Iterator[_Record]:
    if data[: len(_MAGIC)] != _MAGIC:
        raise IntegrityError("not an MCAP file")
    for record in _records(data, len(_MAGIC), len(data)):
        if record.opcode in (_DATA_END, _FOOTER):
            return
        yield record


def add_chunk_crcs(path: Path) -> None:
    """Write the CRC-32 of every chunk's uncompressed records into the closed MCAP file."""
    with _mapped(path, write=True) as data:
        for record in _data_records(data):  # one record in memory at a time
            if record.opcode == _CHUNK:
                _, _, _, _, records = _chunk_parts(record.body)
                struct.pack_into("<I", data, record.offset + _CRC_OFFSET, zlib.crc32(records))


def _messages(records: bytes, channels: dict[int, str]) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time, data) of the message records among ``records``."""
    for record in _records(records, 0, len(records)):
        body = record.body
        if record.opcode == _CHANNEL:
            channel, _schema, length = struct.unpack_from("<HHI", body, 0)
            channels[channel] = body[8 : 8 + length].decode(errors="replace")
        elif record.opcode == _MESSAGE:
            channel, _sequence, log_time, _publish = struct.unpack_from("<HIQQ", body, 0)
            yield channels.get(channel, f"channel {channel}"), log_time, body[22:]


def chunk_problem(path: Path) -> str | None:
    """The first damaged chunk of an MCAP file, described by its topics and stamps (the
    caller names the file)."""
    try:
        with _mapped(path) as data:
            return _first_bad_chunk(data)
    except (IntegrityError, struct.error, UnicodeDecodeError, ValueError, OSError) as error:
        return f"unreadable MCAP structure ({error}): the bag is corrupted"


def _first_bad_chunk(data: mmap.mmap) -> str | None:
    channels: dict[int, str] = {}
    for record in _data_records(data):
        if record.opcode != _CHUNK:
            continue
        start, end, crc, _, records = _chunk_parts(record.body)
        if crc and zlib.crc32(records) != crc:
            try:
                topics = sorted({t for t, _, _ in _messages(records, channels)})
            except (IntegrityError, struct.error, UnicodeDecodeError):
                topics = []
            where = f" on {', '.join(topics)}" if topics else ""
            return (
                f"the chunk of messages stamped {start} to {end} ns{where} "
                "fails its CRC-32 check: the bag is corrupted"
            )
        list(_messages(records, channels))  # channels declared in this chunk
    return None


def _stored_messages(path: Path) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time, data) of every message of one MCAP file in file order."""
    channels: dict[int, str] = {}
    with _mapped(path) as data:
        for record in _data_records(data):
            if record.opcode == _CHUNK:
                yield from _messages(_chunk_parts(record.body)[4], channels)
            elif record.opcode in (_CHANNEL, _MESSAGE):
                end = record.offset + 9 + len(record.body)
                yield from _messages(data[record.offset : end], channels)


def find_damage(bag: Path, files: list[str], crcs: dict[str, list[str]]) -> str | None:
    """The first message of ``files`` (MCAP storage files of ``bag``) whose CRC-32 differs
    from ``crcs``, or the first damaged structure; None if none is found."""
    seen: dict[str, int] = {}
    last = "the start of the bag"
    for name in files:
        path = bag / name
        if path.suffix != ".mcap":
            continue
        try:
            for topic, stamp, data in _stored_messages(path):
                index = seen.get(topic, 0)
                seen[topic] = index + 1
                expected = crcs.get(topic, [])
                if index < len(expected) and f"{zlib.crc32(data):08x}" != expected[index]:
                    return (
                        f"topic {topic}, message {index} at stamp {stamp} ns: its bytes differ "
                        "from the CRC-32 recorded when the bag was written (the bag is corrupted)"
                    )
                last = f"topic {topic} at stamp {stamp} ns"
        except (IntegrityError, struct.error, UnicodeDecodeError, ValueError, OSError) as error:
            return f"{name}: unreadable after {last} ({error}): the bag is corrupted"
    missing = [t for t, c in crcs.items() if seen.get(t, 0) < len(c)]
    if missing:
        topic = missing[0]
        lost = len(crcs[topic]) - seen.get(topic, 0)
        return f"topic {topic}: {lost} messages missing after {last} (the bag is corrupted)"
    return None
