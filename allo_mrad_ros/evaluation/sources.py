"""Frames for evaluation, from a sequence folder or from a bag written by ``allo-bag write``.

Both sources yield the same :class:`EvalFrame`: the camera image, its ground-truth mask, the
pose, the lighting and the celestial bodies, i.e. everything
:meth:`allo_mrad_ros.processing.FrameProcessor.process` and the metrics need. A bag carries
no station mesh and no splits by itself; ``allo-bag write`` records both in the bag's
``custom_data`` (see :mod:`rosbag_tools.writer`), and ``mesh`` overrides the recorded model.

Bag frames are assembled from the messages sharing one bag time (the writer stamps every
message of a frame with the frame's stamp), streaming, so a bag of any length needs memory
for one frame only.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.processing import earth_and_moon
from allo_mrad_ros.render import CelestialBody
from allo_mrad_ros.sequence import (
    MASK_ANOMALY,
    META_FILE,
    SPLITS,
    Sequence,
    SequenceError,
    read_sequence,
)
from rosbag_tools.bagio import (
    BagReadError,
    bag_topics,
    custom_data,
    image_array,
    is_bag,
    open_bag,
)
from rosbag_tools.topics import MARKER_ADD, MARKER_SPHERE
from rosbag_tools.writer import (
    KEY_MESH,
    KEY_MESH_SHA256,
    KEY_NAME,
    KEY_SPLITS,
    decode_splits,
    file_sha256,
)


class FrameSourceError(RuntimeError):
    """An input cannot be evaluated: unreadable, incomplete frames, missing mesh or mask."""


@dataclass(frozen=True)
class EvalFrame:
    """One frame to evaluate (plain arrays, so it pickles to worker processes).

    Attributes
    ----------
    index : int
        Position of the frame in the input (0-based, all splits counted).
    name : str
        The sequence's image name, or ``frame<index>`` for bags.
    stamp_ns : int
        Frame time.
    split : str
        ``train``, ``val`` or ``test``.
    anomaly : str
        Anomaly type, empty for normal frames.
    image : numpy.ndarray
        RGB uint8 (H, W, 3).
    mask : numpy.ndarray
        Ground truth uint8 (H, W), classes 0, 1, 2.
    T_station_camera : numpy.ndarray
        4x4 camera pose in the station frame.
    sun_direction : numpy.ndarray
        Unit vector towards the Sun, station frame.
    sun_strength : float
        Relative Sun intensity.
    bodies : tuple of CelestialBody
        Earth and Moon where the frame has them.
    reference : numpy.ndarray or None
        Pre-rendered reference, when asked for and available.
    """

    index: int
    name: str
    stamp_ns: int
    split: str
    anomaly: str
    image: np.ndarray
    mask: np.ndarray
    T_station_camera: np.ndarray
    sun_direction: np.ndarray
    sun_strength: float
    bodies: tuple[CelestialBody, ...] = ()
    reference: np.ndarray | None = None

    @property
    def is_anomalous(self) -> bool:
        """True when the mask has anomaly pixels."""
        return bool(np.any(self.mask == MASK_ANOMALY))


@dataclass(frozen=True)
class FrameHeader:
    """What is known of a frame before its pixels are read: index, split."""

    index: int
    split: str


class FrameSource:
    """Frames of a sequence or a bag, with the camera and the station model.

    Build it with :func:`open_source`.

    Attributes
    ----------
    path : pathlib.Path
        The input.
    kind : str
        ``"sequence"`` or ``"bag"``.
    name : str
        Sequence name (from the bag's custom data for bags).
    camera : CameraIntrinsics
        Full-resolution intrinsics.
    mesh : pathlib.Path or None
        The station model to render references with (None: the package's model).
    headers : tuple of FrameHeader
        Index and split of every frame, in order.
    """

    def __init__(
        self,
        path: Path,
        kind: str,
        name: str,
        camera: CameraIntrinsics,
        mesh: Path | None,
        headers: tuple[FrameHeader, ...],
    ) -> None:
        self.path = path
        self.kind = kind
        self.name = name
        self.camera = camera
        self.mesh = mesh
        self.headers = headers

    @property
    def splits(self) -> tuple[str, ...]:
        """Splits present, in order of first appearance."""
        return tuple(dict.fromkeys(h.split for h in self.headers))

    def default_split(self) -> str | None:
        """``test`` if present, else None (all frames)."""
        return "test" if "test" in self.splits else None

    def select(self, split: str | None, limit: int | None = None) -> list[int]:
        """Indices of the frames of ``split`` (None: all), at most ``limit`` of them.

        A limit keeps frames evenly spread over the split (see :func:`spread`), so a quick
        run still sees every part of a sequence whatever its order (cameras, anomaly types).

        Raises
        ------
        FrameSourceError
            For an unknown or absent split, or a limit below 1.
        """
        if split is not None and split not in SPLITS:
            raise FrameSourceError(f"unknown split {split!r}; choose from {list(SPLITS)}")
        if limit is not None and limit < 1:
            raise FrameSourceError(f"limit must be at least 1, got {limit}")
        indices = [h.index for h in self.headers if split is None or h.split == split]
        if not indices:
            raise FrameSourceError(
                f"{self.path}: no frames in split {split!r} (splits present: {list(self.splits)})"
            )
        return spread(indices, limit) if limit is not None else indices

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` (ascending) in order."""
        raise NotImplementedError


def spread(indices: list[int], limit: int) -> list[int]:
    """At most ``limit`` items of ``indices``, evenly spaced, first and last included."""
    if limit >= len(indices):
        return list(indices)
    if limit == 1:
        return [indices[0]]
    positions = np.floor(np.linspace(0, len(indices) - 1, limit) + 0.5).astype(int)
    return [indices[i] for i in positions]


class SequenceSource(FrameSource):
    """Frames of a sequence folder (see :func:`open_source`)."""

    def __init__(self, sequence: Sequence, use_references: bool, mesh: Path | None) -> None:
        headers = tuple(FrameHeader(f.index, f.split) for f in sequence.frames)
        super().__init__(
            sequence.root,
            "sequence",
            sequence.meta.name,
            sequence.meta.camera,
            mesh if mesh is not None else sequence.meta.mesh,
            headers,
        )
        self.sequence = sequence
        self.use_references = use_references

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` in order, decoding their PNGs."""
        sequence = self.sequence
        for index in indices:
            frame = sequence.frames[index]
            try:
                image = sequence.load_image(frame)
                mask = sequence.load_mask(frame)
                reference = sequence.load_reference(frame) if self.use_references else None
            except SequenceError as error:
                raise FrameSourceError(str(error)) from None
            if mask is None:
                raise FrameSourceError(
                    f"{sequence.root}: frame {frame.name} (row {index + 1}) has no mask; "
                    "evaluation needs ground truth"
                )
            if self.use_references and reference is None:
                raise FrameSourceError(
                    f"{sequence.root}: frame {frame.name} (row {index + 1}) has no reference; "
                    "drop --use-sequence-references to render one"
                )
            yield EvalFrame(
                index=index,
                name=frame.name,
                stamp_ns=frame.stamp_ns,
                split=frame.split,
                anomaly=frame.anomaly,
                image=image,
                mask=mask,
                T_station_camera=frame.T_station_camera,
                sun_direction=np.array(frame.sun_direction),
                sun_strength=float(frame.sun_strength),
                bodies=earth_and_moon(frame.earth, frame.moon),
                reference=reference,
            )


class BagSource(FrameSource):
    """Frames of a bag written by ``allo-bag write`` (see :func:`open_source`)."""

    def __init__(
        self,
        path: Path,
        name: str,
        camera: CameraIntrinsics,
        mesh: Path | None,
        headers: tuple[FrameHeader, ...],
    ) -> None:
        super().__init__(path, "bag", name, camera, mesh, headers)
        self.topics = bag_topics(path)

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` in order, streaming through the bag."""
        wanted = set(indices)
        last = max(indices)
        for index, group in enumerate(_frame_groups(self.path, self.topics)):
            if index > last:
                return
            if index in wanted:
                yield _frame_from_group(index, self.headers[index].split, group, self.topics)


def _frame_groups(path: Path, topics: Any) -> Iterator[dict[str, tuple[int, Any]]]:
    """Yield {topic: (bag time, message)} per frame, a frame ending with its image."""
    needed = {
        topics.image,
        topics.mask,
        topics.pose,
        topics.sun_direction,
        topics.sun_strength,
        topics.bodies,
        topics.label,
    }
    with open_bag(path) as reader:
        connections = [c for c in reader.connections if c.topic in needed]
        present = {c.topic for c in connections}
        for topic in (topics.image, topics.pose, topics.sun_direction, topics.mask):
            if topic not in present:
                raise FrameSourceError(f"{path}: topic {topic} is missing; evaluate needs it")
        group: dict[str, tuple[int, Any]] = {}
        group_time = None
        for connection, timestamp, raw in reader.messages(connections=connections):
            if group_time is not None and timestamp != group_time and topics.image in group:
                yield group
                group = {}
            group_time = timestamp
            if connection.topic in group:
                raise FrameSourceError(
                    f"{path}: two messages on {connection.topic} at {timestamp} ns "
                    "without an image between them"
                )
            group[connection.topic] = (timestamp, reader.deserialize(raw, connection.msgtype))
        if group:
            if topics.image not in group:
                raise FrameSourceError(f"{path}: the last frame at {group_time} ns has no image")
            yield group


def _frame_from_group(
    index: int, split: str, group: dict[str, tuple[int, Any]], topics: Any
) -> EvalFrame:
    stamp, image_msg = group[topics.image]
    for topic in (topics.mask, topics.pose, topics.sun_direction):
        if topic not in group:
            raise FrameSourceError(f"frame {index} at {stamp} ns: no message on {topic}")
    image = image_array(image_msg, topics.image)
    if image.ndim != 3:
        raise FrameSourceError(f"topic {topics.image}: frame {index} is not a colour image")
    mask = image_array(group[topics.mask][1], topics.mask)
    if mask.shape != image.shape[:2]:
        raise FrameSourceError(f"topic {topics.mask}: frame {index} mask size differs from image")
    pose = group[topics.pose][1].pose
    position = (pose.position.x, pose.position.y, pose.position.z)
    orientation = (pose.orientation.x, pose.orientation.y, pose.orientation.z, pose.orientation.w)
    vector = group[topics.sun_direction][1].vector
    sun_strength = 1.0
    if topics.sun_strength in group:
        sun_strength = float(group[topics.sun_strength][1].data)
    label = str(group[topics.label][1].data) if topics.label in group else ""
    is_anomalous = bool(np.any(mask == MASK_ANOMALY))
    anomaly = label if is_anomalous and label != "normal" else ""
    if is_anomalous and not anomaly:
        anomaly = "unknown"
    bodies = []
    if topics.bodies in group:
        for marker in group[topics.bodies][1].markers:
            if marker.action == MARKER_ADD and marker.type == MARKER_SPHERE:
                centre = (marker.pose.position.x, marker.pose.position.y, marker.pose.position.z)
                bodies.append(CelestialBody(marker.ns, centre, marker.scale.x / 2.0))
    return EvalFrame(
        index=index,
        name=f"frame{index:06d}",
        stamp_ns=stamp,
        split=split,
        anomaly=anomaly,
        image=image,
        mask=mask,
        T_station_camera=pose_matrix(position, orientation),
        sun_direction=np.array([vector.x, vector.y, vector.z]),
        sun_strength=sun_strength,
        bodies=tuple(bodies),
    )


def _bag_mesh(path: Path, data: dict[str, str], mesh: Path | None) -> Path | None:
    if mesh is not None:
        if not mesh.is_file():
            raise FrameSourceError(f"{mesh}: station mesh not found")
        return mesh
    recorded = data.get(KEY_MESH, "")
    if not recorded:
        # Written from a sequence without a mesh: the package's station model.
        return None
    base = path if path.is_dir() else path.parent
    candidate = base / recorded
    if not candidate.is_file():
        raise FrameSourceError(
            f"{path}: the station mesh recorded in the bag ({recorded}, relative to the bag) "
            "is not there; pass --mesh with the sequence's station model"
        )
    expected = data.get(KEY_MESH_SHA256, "")
    if expected and file_sha256(candidate) != expected:
        raise FrameSourceError(
            f"{candidate}: differs from the station mesh the bag was written with "
            "(SHA-256 mismatch); pass --mesh with the right model"
        )
    return candidate


def _bag_camera(path: Path) -> tuple[CameraIntrinsics, int]:
    """Intrinsics from the first CameraInfo and the number of image frames."""
    topics = bag_topics(path)
    with open_bag(path) as reader:
        info = reader.topics.get(topics.camera_info)
        images = reader.topics.get(topics.image)
        if images is None or not images.msgcount:
            raise FrameSourceError(f"{path}: no messages on {topics.image}")
        if info is None or not info.msgcount:
            raise FrameSourceError(f"{path}: no messages on {topics.camera_info}")
        _, _, raw = next(reader.messages(connections=info.connections))
        msg = reader.deserialize(raw, info.msgtype)
        k = [float(v) for v in msg.k]
        try:
            camera = CameraIntrinsics(int(msg.width), int(msg.height), k[0], k[4], k[2], k[5])
        except ValueError as error:
            raise FrameSourceError(f"topic {topics.camera_info}: {error}") from None
        return camera, int(images.msgcount)


def open_source(
    path: str | PathLike[str],
    *,
    mesh: str | PathLike[str] | None = None,
    use_references: bool = False,
) -> FrameSource:
    """Open a sequence folder or a bag for evaluation.

    Parameters
    ----------
    path : path-like
        Sequence folder (with ``sequence.yaml``) or rosbag2 bag.
    mesh : path-like, optional
        Station model to render references with, instead of the sequence's or the bag's.
    use_references : bool
        Use the sequence's pre-rendered references (sequences only).

    Returns
    -------
    FrameSource

    Raises
    ------
    FrameSourceError
        If the input is neither, cannot be read, or lacks what evaluation needs.
    """
    path = Path(path)
    mesh_path = Path(mesh) if mesh is not None else None
    if mesh_path is not None and not mesh_path.is_file():
        raise FrameSourceError(f"{mesh_path}: station mesh not found")
    if path.is_dir() and (path / META_FILE).is_file():
        try:
            sequence = read_sequence(path, check_images=True)
        except SequenceError as error:
            raise FrameSourceError(str(error)) from None
        return SequenceSource(sequence, use_references, mesh_path)
    if not path.exists():
        raise FrameSourceError(f"{path}: input not found")
    if not is_bag(path):
        raise FrameSourceError(f"{path}: neither a sequence folder ({META_FILE}) nor a rosbag2 bag")
    if use_references:
        raise FrameSourceError(
            f"{path}: --use-sequence-references needs a sequence folder; bags carry no references"
        )
    try:
        data = custom_data(path)
        camera, count = _bag_camera(path)
    except BagReadError as error:
        raise FrameSourceError(str(error)) from None
    splits_text = data.get(KEY_SPLITS)
    if splits_text:
        try:
            splits = decode_splits(splits_text)
        except ValueError as error:
            raise FrameSourceError(f"{path}: {error}") from None
        if len(splits) != count:
            raise FrameSourceError(
                f"{path}: custom_data lists {len(splits)} frames but the bag has {count} images"
            )
    else:
        # Not written by allo-bag: no split information, every frame is evaluated.
        splits = ["test"] * count
    headers = tuple(FrameHeader(i, s) for i, s in enumerate(splits))
    return BagSource(
        path, data.get(KEY_NAME, path.name), camera, _bag_mesh(path, data, mesh_path), headers
    )
