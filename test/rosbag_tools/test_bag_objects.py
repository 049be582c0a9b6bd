"""Sequences with ground-truth objects (format version 2) as bags: the instance masks and the
objects table go into the bag and come back out of it unchanged."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from rosbags.highlevel import AnyReader

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.sequence import (
    GroundTruthObject,
    SequenceMeta,
    SequenceWriter,
    read_sequence,
)
from rosbag_tools.bag_meta import KEY_OBJECTS
from rosbag_tools.bag_source import open_source
from rosbag_tools.bagio import custom_data
from rosbag_tools.info import bag_info
from rosbag_tools.topics import MARKER_ADD, MARKER_CUBE, TopicNames
from rosbag_tools.writer import write_bag

CAMERA = CameraIntrinsics(width=32, height=24, fx=40.0, fy=41.0, cx=15.5, cy=11.5)
H, W = CAMERA.height, CAMERA.width
START_NS = 1_700_000_000 * 10**9
FRAMES = 5
T = TopicNames()

OBJECTS = (
    GroundTruthObject(
        id=1,
        type="cable",
        stamp_ns=START_NS,
        position=(0.5, -1.0, 2.0),
        velocity=(0.0, 0.0, 0.0),
        quaternion=(0.0, 0.0, 0.0, 1.0),
        size=(1.2, 0.05, 0.3),
    ),
    GroundTruthObject(
        id=40000,
        type="cubesat_3u",
        stamp_ns=START_NS + 250_000_000,
        position=(-3.0, 4.0, 1.0),
        velocity=(0.02, 0.0, -0.045),
        quaternion=(0.5, 0.5, 0.5, 0.5),
        size=(0.1, 0.1, 0.34),
        extra={"placement": "space"},
    ),
)


def _instances(index: int) -> np.ndarray:
    instances = np.zeros((H, W), np.uint16)
    if index % 2:
        instances[3 : 6 + index, 4:9] = 1
        instances[15:20, 20 + index : 26 + index] = 40000
    return instances


def _write_sequence(root: Path, objects: tuple | None) -> Path:
    rng = np.random.default_rng(7)
    meta = SequenceMeta(name="objects bag", camera=CAMERA, rate_hz=20.0)
    with SequenceWriter(root, meta, objects=objects, start_ns=START_NS) as writer:
        for index in range(FRAMES):
            instances = _instances(index)
            mask = np.ones((H, W), np.uint8)
            mask[instances > 0] = 2
            writer.add_frame(
                split="val" if index < 2 else "test",
                camera=0,
                image=rng.integers(0, 256, (H, W, 3), dtype=np.uint8),
                mask=mask,
                instances=instances if objects is not None else None,
                anomaly="cable" if index % 2 else "",
                position=(0.0, 0.05 * index, -12.0),
                quaternion=(0.0, 0.0, 0.0, 1.0),
                sun_direction=(0.0, 0.6, 0.8),
            )
    return root


@pytest.fixture(scope="module")
def v2_bag(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    base = tmp_path_factory.mktemp("objects")
    sequence = _write_sequence(base / "seq", OBJECTS)
    bag = base / "bag"
    write_bag(sequence, bag)
    return sequence, bag


def _same_objects(read: tuple, expected: tuple) -> None:
    assert [(o.id, o.type, o.stamp_ns) for o in read] == [
        (o.id, o.type, o.stamp_ns) for o in expected
    ]
    for a, b in zip(read, expected, strict=True):
        for name in ("position", "velocity", "quaternion", "size"):
            np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
        assert a.extra.get("placement", "") == b.extra.get("placement", "")


def test_round_trip_sequence_bag_source(v2_bag: tuple[Path, Path]) -> None:
    sequence_root, bag = v2_bag
    sequence = read_sequence(sequence_root)
    from_sequence = open_source(sequence_root)
    from_bag = open_source(bag)
    _same_objects(from_bag.objects, OBJECTS)
    _same_objects(from_sequence.objects, OBJECTS)
    indices = list(range(FRAMES))
    pairs = zip(from_sequence.frames(indices), from_bag.frames(indices), strict=True)
    for index, (a, b) in enumerate(pairs):
        assert b.instances is not None and b.instances.dtype == np.uint16
        np.testing.assert_array_equal(b.instances, _instances(index))
        np.testing.assert_array_equal(a.instances, b.instances)
        np.testing.assert_array_equal(a.mask, b.mask)
        np.testing.assert_array_equal(a.image, b.image)
        assert a.stamp_ns == b.stamp_ns == sequence[index].stamp_ns
        assert a.split == b.split


def test_bag_topics_carry_instances_and_object_boxes(v2_bag: tuple[Path, Path]) -> None:
    sequence_root, bag = v2_bag
    sequence = read_sequence(sequence_root)
    stamps = [f.stamp_ns for f in sequence]
    with AnyReader([bag]) as reader:
        instances, boxes = [], []
        for connection, timestamp, raw in reader.messages():
            if connection.topic == T.instances:
                instances.append((timestamp, reader.deserialize(raw, connection.msgtype)))
            elif connection.topic == T.objects:
                boxes.append((timestamp, reader.deserialize(raw, connection.msgtype)))
    assert [t for t, _ in instances] == stamps
    assert [t for t, _ in boxes] == stamps
    for index, (stamp, message) in enumerate(instances):
        assert message.encoding == "mono16" and message.is_bigendian == 0
        assert message.step == 2 * W
        pixels = np.frombuffer(bytes(message.data), "<u2").reshape(H, W)
        np.testing.assert_array_equal(pixels, _instances(index))
        assert message.header.stamp.sec * 10**9 + message.header.stamp.nanosec == stamp
    for stamp, message in boxes:
        markers = message.markers
        assert [(m.id, m.ns, m.type, m.action) for m in markers] == [
            (o.id, o.type, MARKER_CUBE, MARKER_ADD) for o in OBJECTS
        ]
        for marker, item in zip(markers, OBJECTS, strict=True):
            position = marker.pose.position
            # The drifting CubeSat's box moves with its velocity from its reference time.
            seconds = (stamp - item.stamp_ns) / 1e9
            expected = np.asarray(item.position) + np.asarray(item.velocity) * seconds
            np.testing.assert_allclose([position.x, position.y, position.z], expected, atol=1e-9)
            scale = marker.scale
            np.testing.assert_array_equal([scale.x, scale.y, scale.z], item.size)
            assert marker.header.frame_id == sequence.meta.station_frame
    assert KEY_OBJECTS in custom_data(bag)
    names = {topic.name for topic in bag_info(bag).topics}
    assert {T.instances, T.objects} <= names


def test_version_1_bag_has_no_object_topics(tmp_path: Path) -> None:
    sequence_root = _write_sequence(tmp_path / "seq", None)
    assert "allo-sequence/1" in (sequence_root / "sequence.yaml").read_text()
    bag = tmp_path / "bag"
    write_bag(sequence_root, bag)
    names = {topic.name for topic in bag_info(bag).topics}
    assert T.instances not in names and T.objects not in names
    assert KEY_OBJECTS not in custom_data(bag)
    source = open_source(bag)
    assert source.objects == ()
    frames = list(source.frames(list(range(FRAMES))))
    assert all(frame.instances is None for frame in frames)
    assert [frame.is_anomalous for frame in frames] == [bool(i % 2) for i in range(FRAMES)]
