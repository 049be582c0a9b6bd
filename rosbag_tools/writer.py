"""``allo-bag write``: an ALLO sequence folder becomes a rosbag2 bag.

The bag is built in a hidden sibling folder (``.<name>.partial-<pid>/<name>``) and renamed
to its final name only once it is complete, so a crash or a corrupt input never leaves a
half-written bag under the name the user asked for. The whole sequence is validated
(``frames.csv``, ``sequence.yaml``, every PNG header) before the first message is written;
corrupt pixel data (a truncated PNG) is found when the frame is decoded and aborts the write.

Besides the messages (see :mod:`rosbag_tools.topics`) the bag's ``custom_data`` records what
a bag cannot otherwise say about the sequence, so that ``allo-bag evaluate`` can work from the
bag alone: the split of every frame, the topic names, the station mesh (a path relative to
the bag folder plus its SHA-256) and the sequence name; for a sequence of format version 2,
also its objects table (``allo.objects``, the text of ``objects.csv``), and its instance
masks and object boxes go on topics of their own.
"""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterable
from dataclasses import dataclass, field
from os import PathLike
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability
from rosbags.interfaces import QosTime as _QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from tqdm import tqdm

from allo_mrad_ros.errors import BackendError
from allo_mrad_ros.sequence import (
    SPLITS,
    Frame,
    Sequence,
    SequenceError,
    read_sequence,
    write_objects_text,
)
from allo_mrad_ros.staging import (
    StagingError,
    hold_point,
    interrupts_held,
    prepare_staging,
    put_in_place,
    staging_path,
)
from allo_mrad_ros.targets import BAG, check_target
from rosbag_tools.bag_meta import (
    BAG_FORMAT,
    KEY_FORMAT,
    KEY_MESH,
    KEY_MESH_SHA256,
    KEY_NAME,
    KEY_OBJECTS,
    KEY_RATE,
    KEY_SPLITS,
    KEY_TOPICS,
    add_file_digests,
    encode_splits,
    file_sha256,
    set_metadata_version,
)
from rosbag_tools.integrity import KEY_MESSAGE_CRC32, MessageDigests, add_chunk_crcs
from rosbag_tools.message_factory import MessageFactory
from rosbag_tools.topics import (
    CAMERA_INFO,
    DEFAULT_DISTRO,
    DEFAULT_TOPICS,
    DISTROS,
    FLOAT32,
    IMAGE,
    MARKER_ARRAY,
    POSE_STAMPED,
    RECORDER_VERSIONS,
    STRING,
    TF_MESSAGE,
    VECTOR3_STAMPED,
    TopicError,
    TopicNames,
    typestore_for,
)

STORAGES = {"mcap": StoragePlugin.MCAP, "sqlite3": StoragePlugin.SQLITE3}
DEFAULT_STORAGE = "mcap"


_FRAME_ID = re.compile(r"^[A-Za-z0-9_./-]+$")
_UNSPECIFIED = _QosTime(0, 0)


class BagWriteError(BackendError):
    """A bag cannot be written: invalid input sequence, option or output path."""


def _qos(durability: QosDurability, depth: int) -> Qos:
    return Qos(
        history=QosHistory.KEEP_LAST,
        depth=depth,
        reliability=QosReliability.RELIABLE,
        durability=durability,
        deadline=_UNSPECIFIED,
        lifespan=_UNSPECIFIED,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_UNSPECIFIED,
        avoid_ros_namespace_conventions=False,
    )


# What a default rclpy publisher offers (reliable, volatile, depth 10); /tf_static latches.
DATA_QOS = _qos(QosDurability.VOLATILE, 10)
STATIC_QOS = _qos(QosDurability.TRANSIENT_LOCAL, 1)


@dataclass(frozen=True)
class BagSummary:
    """What :func:`write_bag` wrote: the bag folder, its storage plugin and message-definition
    distribution, the frames written, the message count per topic, the first and last frame
    stamps."""

    path: Path
    storage: str
    distro: str
    frames: int
    messages: dict[str, int] = field(default_factory=dict)
    start_ns: int = 0
    end_ns: int = 0


def _check_options(storage: str, distro: str, static_parent: str | None) -> None:
    if storage not in STORAGES:
        raise BagWriteError(f"unknown storage {storage!r}; choose from {sorted(STORAGES)}")
    if distro not in DISTROS:
        raise BagWriteError(f"unsupported ROS distribution {distro!r}; choose {sorted(DISTROS)}")
    if static_parent is not None and not _FRAME_ID.match(static_parent):
        raise BagWriteError(f"static parent frame {static_parent!r} is not a valid TF frame name")


def _select(sequence: Sequence, splits: Iterable[str] | None) -> list[Frame]:
    if splits is None:
        frames = list(sequence.frames)
    else:
        wanted = set(splits)
        unknown = sorted(wanted - set(SPLITS))
        if unknown:
            raise BagWriteError(f"unknown split(s) {unknown}; choose from {list(SPLITS)}")
        frames = [f for f in sequence.frames if f.split in wanted]
    if not frames:
        raise BagWriteError(f"{sequence.root}: no frames to write (splits {sorted(splits or [])})")
    return frames


class _FrameEncoder:
    """Turns sequence frames into (topic, msgtype, CDR bytes) in write order."""

    def __init__(self, sequence: Sequence, topics: TopicNames, factory: MessageFactory) -> None:
        self.sequence = sequence
        self.topics = topics
        self.factory = factory
        self._shown: list[str] = []

    def encode(self, frame: Frame) -> list[tuple[str, str, bytes]]:
        meta = self.sequence.meta
        build, t = self.factory, self.topics
        stamp = frame.stamp_ns
        station, camera = meta.station_frame, meta.camera_frame
        # Decode first: a corrupt PNG must abort the bag before anything of this frame is
        # written (the whole bag is discarded anyway, but errors come out in row order).
        image = self.sequence.load_image(frame)
        mask = self.sequence.load_mask(frame)
        instances = self.sequence.load_instances(frame, mask)
        bodies = [
            (name, value[:3], float(value[3]))
            for name, value in (("earth", frame.earth), ("moon", frame.moon))
            if value is not None
        ]
        present = [name for name, _, _ in bodies]
        deleted = [name for name in self._shown if name not in present]
        self._shown = present
        messages = [
            (t.camera_info, CAMERA_INFO, build.camera_info(stamp, camera, meta.camera)),
            (
                t.tf,
                TF_MESSAGE,
                build.tf_message(stamp, station, camera, frame.position, frame.quaternion),
            ),
            (
                t.pose,
                POSE_STAMPED,
                build.pose_stamped(stamp, station, (frame.position, frame.quaternion)),
            ),
            (
                t.sun_direction,
                VECTOR3_STAMPED,
                build.vector3_stamped(stamp, station, frame.sun_direction),
            ),
            (t.sun_strength, FLOAT32, build.float32(frame.sun_strength)),
            (t.bodies, MARKER_ARRAY, build.body_markers(stamp, station, bodies, deleted)),
            (t.label, STRING, build.string(frame.anomaly if frame.is_anomalous else "normal")),
        ]
        if mask is not None:
            messages.append((t.mask, IMAGE, build.image(stamp, camera, mask)))
        if self.sequence.has_objects:
            objects = build.object_markers(stamp, station, self.sequence.objects)
            messages.append((t.objects, MARKER_ARRAY, objects))
        if instances is not None:
            messages.append((t.instances, IMAGE, build.image(stamp, camera, instances)))
        # The image last: a live consumer that acts on the image has the rest of the frame.
        messages.append((t.image, IMAGE, build.image(stamp, camera, image)))
        return [(topic, kind, build.serialize(msg, kind)) for topic, kind, msg in messages]


def _custom_data(sequence: Sequence, frames: list[Frame], topics: TopicNames, out: Path) -> dict:
    meta = sequence.meta
    data = {
        KEY_FORMAT: BAG_FORMAT,
        KEY_NAME: meta.name,
        KEY_SPLITS: encode_splits(f.split for f in frames),
        KEY_TOPICS: json.dumps(topics.as_dict(), sort_keys=True),
        KEY_RATE: repr(meta.rate_hz),
        KEY_MESH: "",
        KEY_MESH_SHA256: "",
    }
    if meta.mesh is not None:
        relative = os.path.relpath(meta.mesh.resolve(), out.resolve())
        data[KEY_MESH] = Path(relative).as_posix()
        data[KEY_MESH_SHA256] = file_sha256(meta.mesh)
    if sequence.has_objects:
        data[KEY_OBJECTS] = write_objects_text(sequence.objects)
    return data


def write_bag(
    sequence: str | PathLike[str] | Sequence,
    out: str | PathLike[str],
    *,
    storage: str = DEFAULT_STORAGE,
    distro: str = DEFAULT_DISTRO,
    topics: TopicNames = DEFAULT_TOPICS,
    splits: Iterable[str] | None = None,
    static_parent: str | None = None,
    overwrite: bool = False,
    progress: bool = False,
) -> BagSummary:
    """Write a sequence as a rosbag2 bag.

    Parameters
    ----------
    sequence : path-like or Sequence
        The sequence folder (read and validated here) or an already read sequence.
    out : path-like
        The bag folder to create.
    storage : {"mcap", "sqlite3"}
        rosbag2 storage plugin.
    distro : {"humble", "jazzy", "kilted"}
        Distribution whose message definitions the bag embeds.
    topics : TopicNames
        Topic names.
    splits : iterable of str, optional
        Write only the frames of these splits (default: all frames).
    static_parent : str, optional
        Also write ``/tf_static`` with an identity transform from this frame to the station
        frame, once at the first stamp.
    overwrite : bool
        Replace an existing bag at ``out`` (only after the new bag is complete).
    progress : bool
        Show a progress bar on stderr.

    Returns
    -------
    BagSummary

    Raises
    ------
    BagWriteError
        For an invalid option or an invalid sequence (the message names the file, row and
        column); no bag is left under ``out`` then.
    TargetError
        For an output the rule of :mod:`allo_mrad_ros.targets` refuses: an existing bag
        without ``overwrite``, a folder of other files, a file, the working folder, ...
    """
    _check_options(storage, distro, static_parent)
    root = sequence.root if isinstance(sequence, Sequence) else sequence
    check_target(out, BAG, overwrite=overwrite, inputs=(root,))
    out = Path(out)
    try:
        if not isinstance(sequence, Sequence):
            sequence = read_sequence(sequence, check_images=True)
        frames = _select(sequence, splits)
        factory = MessageFactory(typestore_for(distro))
    except (SequenceError, TopicError) as error:
        raise BagWriteError(str(error)) from error
    # Named before it exists, so a signal between its creation and the try below cannot
    # leave it behind: the finally removes it whatever point was reached.
    staging = staging_path(out)
    counts: dict[str, int] = {}
    try:
        try:
            prepare_staging(out)
        except StagingError as error:
            raise BagWriteError(str(error)) from None
        _write(
            sequence,
            frames,
            staging / out.name,
            storage=storage,
            distro=distro,
            topics=topics,
            factory=factory,
            static_parent=static_parent,
            counts=counts,
            progress=progress,
            final=out,
        )
        if RECORDER_VERSIONS[distro] < DISTROS[distro][1]:
            set_metadata_version(staging / out.name, RECORDER_VERSIONS[distro])
        for storage_file in (staging / out.name).glob("*.mcap"):
            add_chunk_crcs(storage_file)
        add_file_digests(staging / out.name)
        put_in_place(staging / out.name, out)
    except (SequenceError, TopicError, StagingError) as error:
        raise BagWriteError(str(error)) from error
    except (OSError, WriterError) as error:
        # Disk full, permissions, or rosbags refusing: name the bag, not a temporary path.
        raise BagWriteError(f"{out}: cannot write the bag: {error}") from error
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return BagSummary(
        path=out,
        storage=storage,
        distro=distro,
        frames=len(frames),
        messages=counts,
        start_ns=frames[0].stamp_ns,
        end_ns=frames[-1].stamp_ns,
    )


def _write(
    sequence: Sequence,
    frames: list[Frame],
    path: Path,
    *,
    storage: str,
    distro: str,
    topics: TopicNames,
    factory: MessageFactory,
    static_parent: str | None,
    counts: dict[str, int],
    progress: bool,
    final: Path,
) -> None:
    writer = Writer(path, version=DISTROS[distro][1], storage_plugin=STORAGES[storage])
    for key, value in _custom_data(sequence, frames, topics, final).items():
        writer.set_custom_data(key, value)
    digests = MessageDigests()
    with writer:
        typestore = factory.typestore
        plan = [
            (topics.camera_info, CAMERA_INFO),
            (topics.tf, TF_MESSAGE),
            (topics.pose, POSE_STAMPED),
            (topics.sun_direction, VECTOR3_STAMPED),
            (topics.sun_strength, FLOAT32),
            (topics.bodies, MARKER_ARRAY),
            (topics.label, STRING),
            (topics.mask, IMAGE),
        ]
        if sequence.has_objects:
            plan += [(topics.objects, MARKER_ARRAY), (topics.instances, IMAGE)]
        plan.append((topics.image, IMAGE))
        connections = {
            topic: writer.add_connection(
                topic, kind, typestore=typestore, offered_qos_profiles=[DATA_QOS]
            )
            for topic, kind in plan
        }
        if static_parent is not None:
            static = writer.add_connection(
                topics.tf_static, TF_MESSAGE, typestore=typestore, offered_qos_profiles=[STATIC_QOS]
            )
            first = frames[0].stamp_ns
            message = factory.tf_message(
                first, static_parent, sequence.meta.station_frame, (0, 0, 0), (0, 0, 0, 1)
            )
            data = factory.serialize(message, TF_MESSAGE)
            writer.write(static, first, data)
            digests.add(topics.tf_static, data)
            counts[topics.tf_static] = 1
        encoder = _FrameEncoder(sequence, topics, factory)
        bar = None
        try:
            with interrupts_held():  # a held signal is raised on leaving, with the bar built
                bar = tqdm(frames, desc="write", unit="frame", disable=not progress)
            for frame in bar:
                for topic, _, data in encoder.encode(frame):
                    writer.write(connections[topic], frame.stamp_ns, data)
                    digests.add(topic, data)
                    counts[topic] = counts.get(topic, 0) + 1
                hold_point("bag-frame")
        finally:
            # Now, not when the interrupted frame is freed: that can be after the command's
            # last line, and the bar would then be drawn below it.
            if bar is not None:
                bar.close()
        writer.set_custom_data(KEY_MESSAGE_CRC32, digests.custom_data())
