"""``allo-bag info``: what a bag holds: topics, types, counts, duration, image sizes."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from os import PathLike
from pathlib import Path
from typing import Any

from allo_mrad_ros.errors import InvalidInput
from rosbag_tools.bag_meta import KEY_MESH, KEY_NAME, KEY_SPLITS, decode_splits
from rosbag_tools.bagio import BagReadError, custom_data, image_array, open_bag, read_metadata
from rosbag_tools.topics import IMAGE


class InfoError(InvalidInput):
    """A bag cannot be summarised."""


@dataclass(frozen=True)
class TopicSummary:
    """One topic of a bag.

    Attributes
    ----------
    name, msgtype : str
        Topic name and message type.
    count : int
        Messages on the topic.
    image : str
        ``"<width>x<height> <encoding>"`` of the first message for image topics, else empty.
    """

    name: str
    msgtype: str
    count: int
    image: str = ""


@dataclass(frozen=True)
class BagInfo:
    """Summary of a bag (see :func:`bag_info`)."""

    path: str
    storage: str
    version: int | None
    start_ns: int
    end_ns: int
    message_count: int
    topics: list[TopicSummary] = field(default_factory=list)
    custom_data: dict[str, str] = field(default_factory=dict)

    @property
    def duration_s(self) -> float:
        """Time from the first to the last message, seconds."""
        return (self.end_ns - self.start_ns) / 1e9

    def as_dict(self) -> dict[str, Any]:
        """JSON-ready dictionary."""
        data = asdict(self)
        data["duration_s"] = self.duration_s
        return data


def bag_info(path: str | PathLike[str]) -> BagInfo:
    """Summarise a bag.

    Parameters
    ----------
    path : path-like
        Bag folder or storage file.

    Returns
    -------
    BagInfo

    Raises
    ------
    InfoError
        If the bag cannot be read.
    """
    path = Path(path)
    try:
        metadata = read_metadata(path)
        with open_bag(path) as reader:
            summaries = []
            for topic, info in sorted(reader.topics.items()):
                image = ""
                if info.msgtype == IMAGE and info.msgcount:
                    connection = info.connections[0]
                    _, _, raw = next(reader.messages(connections=[connection]))
                    message = reader.deserialize(raw, IMAGE)
                    pixels = image_array(message, topic)
                    image = f"{pixels.shape[1]}x{pixels.shape[0]} {message.encoding}"
                summaries.append(TopicSummary(topic, info.msgtype or "?", info.msgcount, image))
            # rosbags' end_time is one past the last message.
            start, end = reader.start_time, max(reader.start_time, reader.end_time - 1)
            count = reader.message_count
    except BagReadError as error:
        raise InfoError(str(error)) from None
    except Exception as error:  # rosbags raises several types for damaged storage
        raise InfoError(f"{path}: cannot read bag: {error}") from None
    storage = metadata.get("storage_identifier") or path.suffix.lstrip(".") or "?"
    if not metadata and path.is_dir():
        storage = next((p.suffix.lstrip(".") for p in path.iterdir() if p.suffix), "?")
    return BagInfo(
        path=str(path),
        storage=str(storage),
        version=metadata.get("version"),
        start_ns=start,
        end_ns=end,
        message_count=count,
        topics=summaries,
        custom_data=custom_data(path),
    )


def _seconds(ns: int) -> str:
    # Exact: a float would print 1893456050.900000095 for a stamp of ...050.9 s.
    return f"{ns // 10**9}.{ns % 10**9:09d}"


def format_info(info: BagInfo) -> str:
    """Human-readable text of :func:`bag_info`'s result."""
    version = f" (rosbag2 version {info.version})" if info.version is not None else ""
    lines = [
        f"bag:       {info.path}",
        f"storage:   {info.storage}{version}",
        f"duration:  {info.duration_s:.3f} s "
        f"(first {_seconds(info.start_ns)} s, last {_seconds(info.end_ns)} s)",
        f"messages:  {info.message_count}",
    ]
    custom = info.custom_data
    if KEY_NAME in custom:
        try:
            splits = decode_splits(custom.get(KEY_SPLITS, ""))
            runs = {name: splits.count(name) for name in dict.fromkeys(splits)}
            split_text = ", ".join(f"{name} {count}" for name, count in runs.items())
        except ValueError as error:
            split_text = f"unreadable ({error})"
        lines.append(f"sequence:  {custom[KEY_NAME]!r}; frames: {split_text or 'none'}")
        lines.append(f"mesh:      {custom.get(KEY_MESH) or '(package station model)'}")
    width = max([len(t.name) for t in info.topics] + [5])
    type_width = max([len(t.msgtype) for t in info.topics] + [4])
    lines.append("topics:")
    for topic in info.topics:
        row = f"  {topic.name:<{width}}  {topic.msgtype:<{type_width}}  {topic.count:>7}"
        lines.append(f"{row}  {topic.image}".rstrip())
    return "\n".join(lines)
