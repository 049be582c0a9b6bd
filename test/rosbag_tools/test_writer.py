"""allo-bag write, info and play: bags read back with rosbags and with the independent mcap
reader, in both storage formats and for several distributions; corrupt inputs; DDS replay."""

from __future__ import annotations

import csv
import io
import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from rosbags.highlevel import AnyReader

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.resources import share_path
from allo_mrad_ros.sequence import FRAMES_FILE, SequenceMeta, SequenceWriter, read_sequence
from allo_mrad_ros.targets import TargetError
from rosbag_tools.bag_meta import decode_splits, encode_splits, file_sha256
from rosbag_tools.cli import main
from rosbag_tools.info import InfoError, bag_info, format_info
from rosbag_tools.topics import (
    MARKER_ADD,
    MARKER_DELETE,
    MARKER_SPHERE,
    RECORDER_VERSIONS,
    TopicError,
    TopicNames,
    typestore_for,
)
from rosbag_tools.writer import BagWriteError, write_bag

REPO = Path(__file__).resolve().parents[2]
CAMERA = CameraIntrinsics(width=32, height=24, fx=40.0, fy=41.0, cx=15.5, cy=11.5)
FRAMES = 6
T = TopicNames()


def _unit(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=n)
    return v / np.linalg.norm(v)


def _write_sequence(root: Path, frames: int = FRAMES) -> Path:
    """Random pixels (any decoding slip shows), alternating labels, a frame without mask,
    bodies that come and go, three splits."""
    rng = np.random.default_rng(7)
    meta = SequenceMeta(
        name="bag test",
        camera=CAMERA,
        rate_hz=20.0,
        station_frame="gateway",
        camera_frame="arm_cam_optical",
        mesh=share_path("meshes", "station.glb"),
    )
    with SequenceWriter(root, meta, start_ns=5_000_000_000) as writer:
        for i in range(frames):
            anomalous = i % 2 == 1
            mask = np.zeros((CAMERA.height, CAMERA.width), np.uint8)
            mask[3:12, 4:20] = 1
            if anomalous:
                mask[6:9, 8:12] = 2
            writer.add_frame(
                split=("train", "val", "test")[min(i // 2, 2)],
                camera=i % 3,
                image=rng.integers(0, 256, (CAMERA.height, CAMERA.width, 3), dtype=np.uint8),
                mask=None if i == 4 else mask,
                anomaly="drill" if anomalous else "",
                position=rng.normal(scale=20.0, size=3),
                quaternion=_unit(rng, 4),
                sun_direction=_unit(rng, 3),
                sun_strength=float(rng.uniform(0.2, 1.0)),
                earth=[1000.0, 200.0, -300.0, 35.0] if i != 2 else None,
                moon=[-50.0, 400.0, 10.0, 12.5] if i >= 1 else None,
            )
    return root


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = _write_sequence(tmp_path_factory.mktemp("seq") / "seq")
    return read_sequence(root)


def _by_topic(path: Path) -> dict[str, list[tuple[int, object]]]:
    out: dict[str, list[tuple[int, object]]] = {}
    with AnyReader([path]) as reader:
        for connection, timestamp, raw in reader.messages():
            message = reader.deserialize(raw, connection.msgtype)
            out.setdefault(connection.topic, []).append((timestamp, message))
    return out


def _stamp(header) -> int:
    return header.stamp.sec * 10**9 + header.stamp.nanosec


def _check_frames_rosbags(path: Path, sequence) -> None:
    frames, meta = sequence.frames, sequence.meta
    topics = _by_topic(path)
    stamps = [f.stamp_ns for f in frames]
    for topic in (T.image, T.camera_info, T.tf, T.pose, T.sun_direction, T.sun_strength):
        assert [t for t, _ in topics[topic]] == stamps, topic
    for topic in (T.bodies, T.label):
        assert [t for t, _ in topics[topic]] == stamps, topic
    with_mask = [f for f in frames if f.mask is not None]
    assert [t for t, _ in topics[T.mask]] == [f.stamp_ns for f in with_mask]
    for frame, (_, msg) in zip(frames, topics[T.image], strict=True):
        assert (msg.encoding, msg.width, msg.height, msg.step) == ("rgb8", 32, 24, 96)
        assert _stamp(msg.header) == frame.stamp_ns and msg.header.frame_id == meta.camera_frame
        pixels = np.asarray(msg.data).reshape(24, 32, 3)
        np.testing.assert_array_equal(pixels, sequence.load_image(frame))
    for frame, (_, msg) in zip(with_mask, topics[T.mask], strict=True):
        assert msg.encoding == "mono8" and msg.header.frame_id == meta.camera_frame
        np.testing.assert_array_equal(
            np.asarray(msg.data).reshape(24, 32), sequence.load_mask(frame)
        )
    for frame, (_, msg) in zip(frames, topics[T.pose], strict=True):
        assert msg.header.frame_id == meta.station_frame
        p, q = msg.pose.position, msg.pose.orientation
        assert [p.x, p.y, p.z] == frame.position.tolist()
        assert [q.x, q.y, q.z, q.w] == frame.quaternion.tolist()
    for frame, (_, msg) in zip(frames, topics[T.tf], strict=True):
        (transform,) = msg.transforms
        assert transform.header.frame_id == meta.station_frame
        assert transform.child_frame_id == meta.camera_frame
        assert _stamp(transform.header) == frame.stamp_ns
        r = transform.transform.rotation
        assert [r.x, r.y, r.z, r.w] == frame.quaternion.tolist()
    for frame, (_, msg) in zip(frames, topics[T.sun_direction], strict=True):
        v = msg.vector
        assert [v.x, v.y, v.z] == frame.sun_direction.tolist()
        assert msg.header.frame_id == meta.station_frame
    for frame, (_, msg) in zip(frames, topics[T.sun_strength], strict=True):
        assert msg.data == pytest.approx(frame.sun_strength, rel=1e-6)
    for frame, (_, msg) in zip(frames, topics[T.label], strict=True):
        assert msg.data == (frame.anomaly if frame.is_anomalous else "normal")
    for _, msg in topics[T.camera_info]:
        assert msg.distortion_model == "plumb_bob" and not np.any(msg.d)
        assert list(msg.k) == [40.0, 0.0, 15.5, 0.0, 41.0, 11.5, 0.0, 0.0, 1.0]
        assert list(msg.p) == [40.0, 0.0, 15.5, 0.0, 0.0, 41.0, 11.5, 0.0, 0.0, 0.0, 1.0, 0.0]
        assert (msg.width, msg.height) == (32, 24)
    # Bodies: spheres while present, a DELETE when one disappears.
    shown: set[str] = set()
    for frame, (_, msg) in zip(frames, topics[T.bodies], strict=True):
        present = {n: v for n, v in (("earth", frame.earth), ("moon", frame.moon)) if v is not None}
        adds = {m.ns: m for m in msg.markers if m.action == MARKER_ADD}
        deletes = {m.ns for m in msg.markers if m.action == MARKER_DELETE}
        assert set(adds) == set(present) and deletes == shown - set(present)
        for name, marker in adds.items():
            assert marker.type == MARKER_SPHERE and marker.header.frame_id == meta.station_frame
            centre = [marker.pose.position.x, marker.pose.position.y, marker.pose.position.z]
            assert centre == present[name][:3].tolist()
            assert marker.scale.x == marker.scale.y == marker.scale.z == 2 * present[name][3]
        shown = set(present)


def _check_frames_mcap(path: Path, sequence) -> None:
    """The independent reader: mcap + mcap_ros2 decode with the schemas in the file."""
    # Test-only; rosdep's key for them is a pip one, which Ubuntu 24.04 refuses system-wide:
    # `make test` installs them (requirements-dev.txt), a distro may not.
    reason = "the independent MCAP reader (pip: mcap, mcap-ros2-support) is not installed"
    mcap_reader = pytest.importorskip("mcap.reader", reason=reason)
    mcap_decoder = pytest.importorskip("mcap_ros2.decoder", reason=reason)

    (storage,) = path.glob("*.mcap")
    frames = sequence.frames
    seen: dict[str, list] = {}
    with storage.open("rb") as stream:
        reader = mcap_reader.make_reader(stream, decoder_factories=[mcap_decoder.DecoderFactory()])
        assert reader.get_header().profile == "ros2"
        summary = reader.get_summary()
        for channel in summary.channels.values():
            assert channel.message_encoding == "cdr"
            assert summary.schemas[channel.schema_id].encoding == "ros2msg"
        for _, channel, message, decoded in reader.iter_decoded_messages():
            seen.setdefault(channel.topic, []).append((message.log_time, decoded))
    images = seen[T.image]
    assert [t for t, _ in images] == [f.stamp_ns for f in frames]  # each frame exactly once
    for frame, (_, msg) in zip(frames, images, strict=True):
        assert _stamp(msg.header) == frame.stamp_ns
        pixels = np.frombuffer(bytes(msg.data), np.uint8).reshape(24, 32, 3)
        np.testing.assert_array_equal(pixels, sequence.load_image(frame))
    masks = seen[T.mask]
    with_mask = [f for f in frames if f.mask is not None]
    assert len(masks) == len(with_mask)
    for frame, (_, msg) in zip(with_mask, masks, strict=True):
        pixels = np.frombuffer(bytes(msg.data), np.uint8).reshape(24, 32)
        np.testing.assert_array_equal(pixels, sequence.load_mask(frame))
    assert [m.data for _, m in seen[T.label]] == ["normal", "drill"] * 3
    poses = [m.pose.position for _, m in seen[T.pose]]
    assert [[p.x, p.y, p.z] for p in poses] == [f.position.tolist() for f in frames]


@pytest.mark.parametrize("distro", ["humble", "jazzy", "kilted"])
@pytest.mark.parametrize("storage", ["mcap", "sqlite3"])
def test_bag_holds_every_frame_once_with_identical_pixels(tmp_path, sequence, storage, distro):
    out = tmp_path / "bag"
    summary = write_bag(sequence.root, out, storage=storage, distro=distro)
    assert summary.frames == FRAMES and summary.messages[T.image] == FRAMES
    assert summary.messages[T.mask] == FRAMES - 1
    _check_frames_rosbags(out, sequence)
    if storage == "mcap":
        _check_frames_mcap(out, sequence)
    else:
        assert list(out.glob("*.db3")) and not list(out.glob("*.mcap"))
    metadata = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert metadata["version"] == RECORDER_VERSIONS[distro]  # what that distro records
    assert metadata["storage_identifier"] == storage
    custom = metadata["custom_data"]
    assert decode_splits(custom["allo.splits"]) == [f.split for f in sequence.frames]
    assert (out / custom["allo.mesh"]).resolve() == sequence.meta.mesh.resolve()
    assert custom["allo.mesh_sha256"] == file_sha256(sequence.meta.mesh)
    # The embedded definitions are the chosen distribution's.
    typestore = typestore_for(distro)
    with AnyReader([out]) as reader:
        for connection in reader.connections:
            # Type hashes came after Humble: its metadata (version 5) has none.
            hashed = distro != "humble"
            assert connection.digest == (
                typestore.hash_rihs01(connection.msgtype) if hashed else ""
            )
            definition, _ = typestore.generate_msgdef(connection.msgtype, ros_version=2)
            assert connection.msgdef.data == definition
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_split_selection_static_tf_and_renamed_topics(tmp_path, sequence):
    out = tmp_path / "bag"
    topics = TopicNames.from_assignments(["image=/cam/image", "pose=/cam/pose"])
    write_bag(sequence.root, out, splits=["test", "train"], topics=topics, static_parent="world")
    wanted = [f for f in sequence.frames if f.split in ("train", "test")]
    messages = _by_topic(out)
    assert [t for t, _ in messages["/cam/image"]] == [f.stamp_ns for f in wanted]
    assert "/arm_camera/image_raw" not in messages and len(messages["/cam/pose"]) == len(wanted)
    ((stamp, static),) = messages["/tf_static"]
    (transform,) = static.transforms
    assert stamp == wanted[0].stamp_ns
    assert (transform.header.frame_id, transform.child_frame_id) == ("world", "gateway")
    assert transform.transform.rotation.w == 1.0
    metadata = yaml.safe_load((out / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    qos = {
        t["topic_metadata"]["name"]: t["topic_metadata"]["offered_qos_profiles"]
        for t in metadata["topics_with_message_count"]
    }
    assert qos["/tf_static"][0]["durability"] == "transient_local"
    assert qos["/cam/image"][0]["durability"] == "volatile"
    assert json.loads(metadata["custom_data"]["allo.topics"])["image"] == "/cam/image"


def test_split_runs_and_topic_names_are_validated():
    splits = ["train"] * 3 + ["test"] * 2 + ["train"]
    assert encode_splits(splits) == "train:3,test:2,train:1"
    assert decode_splits(encode_splits(splits)) == splits
    with pytest.raises(ValueError, match="malformed"):
        decode_splits("train:x")
    with pytest.raises(TopicError, match="not a valid ROS 2 topic name"):
        TopicNames(image="/bad name")
    with pytest.raises(TopicError, match="share the name"):
        TopicNames(mask="/arm_camera/image_raw")
    with pytest.raises(TopicError, match="unknown topic role"):
        TopicNames.from_assignments(["imgae=/x"])


def _corrupt_copy(sequence, tmp_path: Path, how: str) -> tuple[Path, str]:
    """A copy of the sequence with one defect; returns the root and the text the error must
    contain."""
    root = tmp_path / "corrupt"
    _write_sequence(root)
    frames = read_sequence(root).frames
    if how == "missing image":
        frames[3].image.unlink()
        return root, frames[3].image.name
    if how == "truncated png":
        data = frames[4].image.read_bytes()
        frames[4].image.write_bytes(data[: len(data) // 2])
        return root, frames[4].image.name
    if how == "malformed row":
        text = (root / FRAMES_FILE).read_text()
        rows = list(csv.reader(io.StringIO(text)))
        rows[3][rows[0].index("tx")] = "abc"
        buffer = io.StringIO()
        csv.writer(buffer, lineterminator="\n").writerows(rows)
        (root / FRAMES_FILE).write_text(buffer.getvalue())
        return root, "row 3"
    raise AssertionError(how)


@pytest.mark.parametrize("how", ["missing image", "truncated png", "malformed row"])
def test_corrupt_input_names_the_defect_and_leaves_no_bag(tmp_path, sequence, how, capsys):
    root, named = _corrupt_copy(sequence, tmp_path, how)
    out = tmp_path / "out" / "bag"
    out.parent.mkdir()
    with pytest.raises(BagWriteError, match=named):
        write_bag(root, out)
    assert not out.exists() and not list(out.parent.iterdir())
    # Through the CLI: exit status 1 and the defect on stderr.
    assert main(["write", str(root), str(out), "--quiet"]) == 1
    assert named in capsys.readouterr().err
    assert not out.exists() and not list(out.parent.iterdir())


def test_existing_bag_is_kept_unless_overwritten_and_survives_a_failed_overwrite(
    tmp_path, sequence
):
    out = tmp_path / "bag"
    write_bag(sequence.root, out, splits=["test"])
    before = sorted(p.name for p in out.iterdir())
    with pytest.raises(TargetError, match="already holds a bag; use --overwrite"):
        write_bag(sequence.root, out)
    root, named = _corrupt_copy(sequence, tmp_path, "truncated png")
    with pytest.raises(BagWriteError, match=named):
        write_bag(root, out, overwrite=True)
    assert sorted(p.name for p in out.iterdir()) == before
    assert bag_info(out).topics[0].count == 2
    write_bag(sequence.root, out, overwrite=True)
    assert {t.name: t.count for t in bag_info(out).topics}[T.image] == FRAMES
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []


def test_info_lists_topics_counts_duration_and_image_sizes(tmp_path, sequence, capsys):
    out = tmp_path / "bag"
    assert main(["write", str(sequence.root), str(out), "--storage", "sqlite3", "--quiet"]) == 0
    info = bag_info(out)
    counts = {t.name: (t.msgtype, t.count, t.image) for t in info.topics}
    assert counts[T.image] == ("sensor_msgs/msg/Image", FRAMES, "32x24 rgb8")
    assert counts[T.mask] == ("sensor_msgs/msg/Image", FRAMES - 1, "32x24 mono8")
    assert counts[T.tf] == ("tf2_msgs/msg/TFMessage", FRAMES, "")
    assert info.duration_s == pytest.approx((FRAMES - 1) / 20.0)
    assert info.message_count == 9 * FRAMES - 1 and info.storage == "sqlite3"
    text = format_info(info)
    assert "sqlite3" in text and "train 2, val 2, test 2" in text and "32x24 rgb8" in text
    capsys.readouterr()
    assert main(["info", str(out), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["duration_s"] == pytest.approx(0.25)
    assert main(["info", str(tmp_path / "nothing")]) == 1
    assert "not found" in capsys.readouterr().err


def test_rosbag2_folder_named_dot_bag_and_damaged_storage(tmp_path, sequence):
    out = tmp_path / "run.bag"  # a common name for a rosbag2 folder, not a ROS 1 bag
    write_bag(sequence.root, out)
    assert {t.name: t.count for t in bag_info(out).topics}[T.image] == FRAMES
    (storage,) = out.glob("*.mcap")
    data = storage.read_bytes()
    storage.write_bytes(data[: len(data) // 3])
    with pytest.raises(InfoError, match=r"run\.bag"):
        bag_info(out)


def subscribe_once_published(node, wanted, qos, alive, limit_s: float = 60.0) -> None:
    """Subscribe ``node`` to each ``(type, topic, list)`` of ``wanted`` only once the player's
    publishers are in its graph, so each subscription matches the publisher as it is made.

    Discovery is two-sided: a player that sees our subscription (``--wait-for``) and
    publishes at once can send before our side has matched its publisher, and the first
    samples are lost, reliable or not. Subscribing after our side knows the publisher
    leaves no such window, on any machine.
    """
    deadline = time.monotonic() + limit_s
    while any(node.count_publishers(topic) == 0 for _, topic, _ in wanted):
        assert alive(), "the player ended before it published"
        assert time.monotonic() < deadline, "the player's publishers never appeared"
        time.sleep(0.01)
    for kind, topic, into in wanted:
        node.create_subscription(kind, topic, into.append, qos)


@pytest.mark.timeout(120)
def test_play_publishes_the_bag_into_an_rclpy_subscriber(tmp_path, sequence):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from sensor_msgs.msg import Image
    from std_msgs.msg import String
    from visualization_msgs.msg import MarkerArray

    out = tmp_path / "bag"
    write_bag(sequence.root, out, static_parent="world")
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("allo_bag_test_listener", context=context)
    images, labels, bodies = [], [], []
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    env = dict(
        os.environ, PYTHONPATH=os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])
    )
    player = subprocess.Popen(
        [
            *(sys.executable, "-m", "rosbag_tools", "play", str(out), "--rate", "4"),
            *("--delay", "0", "--wait-for", T.image, T.label, T.bodies, "--wait-timeout", "90"),
        ],
        cwd=REPO,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        qos = QoSProfile(depth=50)
        subscribe_once_published(
            node,
            [(Image, T.image, images), (String, T.label, labels), (MarkerArray, T.bodies, bodies)],
            qos,
            alive=lambda: player.poll() is None,
        )
        deadline = time.monotonic() + 60
        finished = None
        while time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
            if player.poll() is None:
                continue
            finished = finished or time.monotonic()
            complete = min(len(images), len(labels), len(bodies)) >= FRAMES
            # Once the player is gone, late samples get a few seconds to arrive.
            if complete or time.monotonic() - finished > 3:
                break
        stdout, stderr = player.communicate(timeout=30)
    finally:
        if player.poll() is None:
            player.kill()
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    assert player.returncode == 0, stderr
    # tf2_msgs has no PyPI wheel: /tf and /tf_static are skipped, one warning each.
    assert (
        stderr.count("skipping topic /tf:") == 1 and stderr.count("skipping topic /tf_static:") == 1
    )
    assert "published" in stdout
    frames = sequence.frames
    assert [_stamp(m.header) for m in images] == [f.stamp_ns for f in frames]
    for frame, message in zip(frames, images, strict=True):
        assert (message.encoding, message.header.frame_id) == ("rgb8", "arm_cam_optical")
        pixels = np.frombuffer(bytes(message.data), np.uint8).reshape(24, 32, 3)
        np.testing.assert_array_equal(pixels, sequence.load_image(frame))
    assert [m.data for m in labels] == ["normal", "drill"] * 3
    assert [sorted(m.ns for m in b.markers if m.action == MARKER_ADD) for b in bodies] == [
        sorted(n for n, v in (("earth", f.earth), ("moon", f.moon)) if v is not None)
        for f in frames
    ]


@pytest.mark.timeout(120)
def test_play_loops_filters_topics_and_publishes_the_clock(tmp_path, sequence):
    rclpy = pytest.importorskip("rclpy")
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String

    from rosbag_tools.play import PlayError, play_bag

    out = tmp_path / "bag"
    write_bag(sequence.root, out)
    with pytest.raises(PlayError, match="rate must be positive"):
        play_bag(out, rate=0.0)
    with pytest.raises(PlayError, match="no topic"):
        play_bag(out, topics=["/nope"], delay=0)
    context = rclpy.Context()
    rclpy.init(context=context)
    node = rclpy.create_node("allo_bag_loop_listener", context=context)
    labels, clocks = [], []
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    result = {}

    def player() -> None:
        result["summary"] = play_bag(
            out,
            rate=10.0,
            loop=True,
            passes=2,
            topics=[T.label],
            clock=True,
            delay=0,  # our subscriptions have matched the player when it sees them
            wait_for=[T.label, "/clock"],
            wait_timeout=90.0,
            node_name="allo_bag_loop_player",
        )

    thread = threading.Thread(target=player)
    thread.start()
    try:
        subscribe_once_published(
            node,
            [(String, T.label, labels), (Clock, "/clock", clocks)],
            QoSProfile(depth=50),
            alive=thread.is_alive,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and (thread.is_alive() or len(labels) < 2 * FRAMES):
            executor.spin_once(timeout_sec=0.05)
            if not thread.is_alive() and time.monotonic() > deadline - 50:
                break
    finally:
        thread.join(timeout=30)
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
    summary = result["summary"]
    assert summary.passes == 2 and summary.published == {T.label: 2 * FRAMES}
    assert [m.data for m in labels] == ["normal", "drill"] * 6
    stamps = [c.clock.sec * 10**9 + c.clock.nanosec for c in clocks]
    assert stamps[:FRAMES] == [f.stamp_ns for f in sequence.frames]
