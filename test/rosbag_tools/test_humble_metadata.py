"""``allo-bag write --distro humble``: a ``metadata.yaml`` that Humble's rosbag2 reads as its
own recorder writes it (version 5), still carrying the custom data evaluation needs.

No Humble install exists here, so two readers check it: the rosbags library, which parses
each metadata version by its own rules (version 5 here), and a stand-in of Humble's decoder
(rosbag2 0.15.x, ``rosbag2_storage/src/rosbag2_storage/metadata_io.cpp`` and
``rosbag2_transport/src/rosbag2_transport/qos.cpp``): the keys it requires, with the types
``yaml-cpp`` converts them to, including the QoS profiles it parses from their string.
"""

from __future__ import annotations

import pytest
import yaml
from rosbag_fixtures import write_tiny_sequence
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore

from rosbag_tools.bagio import custom_data
from rosbag_tools.cli import main
from rosbag_tools.writer import write_bag

# What Humble's recorder writes, plus custom_data (a key Humble's decoder does not ask for).
HUMBLE_KEYS = {
    "version",
    "storage_identifier",
    "duration",
    "starting_time",
    "message_count",
    "topics_with_message_count",
    "compression_format",
    "compression_mode",
    "relative_file_paths",
    "files",
    "custom_data",
}


def _int(value: object, where: str) -> int:
    assert isinstance(value, int) and not isinstance(value, bool), f"{where}: {value!r}"
    return value


def _text(value: object, where: str) -> str:
    assert isinstance(value, str), f"{where}: {value!r}"
    return value


def _humble_qos(text: str, where: str) -> None:
    """``convert<Rosbag2QoS>::decode``: policies as int, durations as {sec, nsec} ints."""
    profiles = yaml.safe_load(text)
    assert isinstance(profiles, list) and profiles, where
    for profile in profiles:
        for key in ("history", "reliability", "durability", "liveliness", "depth"):
            _int(profile[key], f"{where}.{key}")
        for key in ("deadline", "lifespan", "liveliness_lease_duration"):
            _int(profile[key]["sec"], f"{where}.{key}.sec")
            _int(profile[key]["nsec"], f"{where}.{key}.nsec")
        assert isinstance(profile["avoid_ros_namespace_conventions"], bool), where


def humble_decode(info: dict) -> None:
    """A stand-in of rosbag2 0.15's ``convert<BagMetadata>::decode`` (raises on what it
    would refuse)."""
    version = _int(info["version"], "version")
    _text(info["storage_identifier"], "storage_identifier")
    _int(info["duration"]["nanoseconds"], "duration")
    _int(info["starting_time"]["nanoseconds_since_epoch"], "starting_time")
    _int(info["message_count"], "message_count")
    for index, entry in enumerate(info["topics_with_message_count"]):
        topic = entry["topic_metadata"]
        for key in ("name", "type", "serialization_format"):
            _text(topic[key], f"topic {index} {key}")
        if version >= 4:
            _humble_qos(_text(topic["offered_qos_profiles"], f"topic {index}"), topic["name"])
        _int(entry["message_count"], f"topic {index} message_count")
    assert all(isinstance(p, str) for p in info["relative_file_paths"])
    if version >= 3:
        _text(info["compression_format"], "compression_format")
        _text(info["compression_mode"], "compression_mode")
    if version >= 5:
        for entry in info["files"]:
            _text(entry["path"], "files.path")
            _int(entry["starting_time"]["nanoseconds_since_epoch"], "files.starting_time")
            _int(entry["duration"]["nanoseconds"], "files.duration")
            _int(entry["message_count"], "files.message_count")


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    return write_tiny_sequence(tmp_path_factory.mktemp("humble") / "seq", train=1)


@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_humble_bag_has_humbles_metadata_and_reads_back(sequence, tmp_path, storage):
    bag = write_bag(sequence, tmp_path / "bag", distro="humble", storage=storage).path
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 5
    assert set(info) <= HUMBLE_KEYS, sorted(set(info) - HUMBLE_KEYS)
    humble_decode(info)
    # The rosbags library reads it by the rules of version 5, every message with Humble's
    # definitions.
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    with Reader(bag) as reader:
        assert reader.message_count == info["message_count"] > 0
        for connection, _, raw in reader.messages():
            typestore.deserialize_cdr(raw, connection.msgtype)
    # The custom data evaluation needs is still there, and evaluation opens the bag.
    assert custom_data(bag)["allo.format"] == "allo-bag/1"
    argv = ["evaluate", str(bag), "--out", str(tmp_path / "r"), "--methods", "PAD"]
    assert main([*argv, "--limit", "1", "--overlays", "0", "--quiet"]) == 0


def test_other_distros_keep_their_recorders_version(sequence, tmp_path):
    bag = write_bag(sequence, tmp_path / "bag", distro="jazzy").path
    info = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert info["version"] == 9
