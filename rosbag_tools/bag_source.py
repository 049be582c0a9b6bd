"""Bags as an evaluation source: frames of a bag written by ``allo-bag write``.

A bag carries no station mesh and no splits by itself; ``allo-bag write`` records both in
the bag's ``custom_data`` (see :mod:`rosbag_tools.writer`), and ``mesh`` overrides the
recorded model. Frames are assembled from the messages sharing one bag time (the writer
stamps every message of a frame with the frame's stamp), streaming, so a bag of any length
needs memory for one frame only. Messages are decoded by :mod:`allo_mrad_ros.ros.messages`,
as the node decodes them.
"""

from __future__ import annotations

from collections.abc import Iterator
from os import PathLike
from pathlib import Path
from typing import Any

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.evaluation.sources import (
    EvalFrame,
    FrameHeader,
    FrameSource,
    FrameSourceError,
    open_sequence,
)
from allo_mrad_ros.ros.messages import (
    MessageError,
    image_to_array,
    intrinsics_from_camera_info,
    markers_to_bodies,
    pose_to_matrix,
)
from allo_mrad_ros.sequence import (
    MASK_ANOMALY,
    META_FILE,
    GroundTruthObject,
    SequenceError,
    parse_objects,
)
from allo_mrad_ros.sequence.png import bad_mask_values
from allo_mrad_ros.view import View
from rosbag_tools.bag_meta import (
    KEY_MESH,
    KEY_MESH_SHA256,
    KEY_NAME,
    KEY_OBJECTS,
    KEY_SPLITS,
    decode_splits,
    file_sha256,
)
from rosbag_tools.bagio import BagReadError, bag_topics, custom_data, is_bag, open_bag


class BagSource(FrameSource):
    """Frames of a bag written by ``allo-bag write`` (see :func:`open_source`)."""

    def __init__(
        self,
        path: Path,
        name: str,
        camera: CameraIntrinsics,
        mesh: Path | None,
        headers: tuple[FrameHeader, ...],
        objects: tuple[GroundTruthObject, ...] = (),
    ) -> None:
        super().__init__(path, "bag", name, camera, mesh, headers, objects)
        self.topics = bag_topics(path)

    def frames(self, indices: list[int]) -> Iterator[EvalFrame]:
        """Yield the frames of ``indices`` in order, streaming through the bag."""
        wanted = set(indices)
        last = max(indices)
        for index, group in enumerate(_frame_groups(self.path, self.topics)):
            if index > last:
                return
            if index in wanted:
                frame = _frame_from_group(index, self.headers[index].split, group, self.topics)
                if self.objects and frame.instances is not None:
                    _check_instances(frame, self.objects, self.topics.instances)
                yield frame


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
        topics.instances,
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


def _decoded(topic: str, index: int, decode: Any, message: Any) -> Any:
    try:
        return decode(message)
    except MessageError as error:
        raise FrameSourceError(f"topic {topic}: frame {index}: {error}") from None


def _frame_from_group(
    index: int, split: str, group: dict[str, tuple[int, Any]], topics: Any
) -> EvalFrame:
    stamp, image_msg = group[topics.image]
    for topic in (topics.mask, topics.pose, topics.sun_direction):
        if topic not in group:
            raise FrameSourceError(f"frame {index} at {stamp} ns: no message on {topic}")
    image = _decoded(topics.image, index, image_to_array, image_msg)
    if image.ndim != 3:
        raise FrameSourceError(f"topic {topics.image}: frame {index} is not a colour image")
    mask_stamp, mask_msg = group[topics.mask]
    mask = _decoded(topics.mask, index, image_to_array, mask_msg)
    where = f"topic {topics.mask}: frame {index} at {mask_stamp} ns"
    if mask.ndim != 2 or mask.dtype != np.uint8 or mask.shape != image.shape[:2]:
        raise FrameSourceError(
            f"{where}: mask {mask.dtype} {mask.shape} does not match the image "
            f"{image.shape[1]}x{image.shape[0]} (mono8 expected)"
        )
    bad = bad_mask_values(mask)
    if bad:
        raise FrameSourceError(f"{where}: mask values must be 0, 1 or 2; found {bad[:10]}")
    pose = _decoded(topics.pose, index, pose_to_matrix, group[topics.pose][1].pose)
    vector = group[topics.sun_direction][1].vector
    sun_strength = 1.0
    if topics.sun_strength in group:
        sun_strength = float(group[topics.sun_strength][1].data)
    label = str(group[topics.label][1].data) if topics.label in group else ""
    is_anomalous = bool(np.any(mask == MASK_ANOMALY))
    anomaly = label if is_anomalous and label != "normal" else ""
    if is_anomalous and not anomaly:
        anomaly = "unknown"
    instances = None
    if topics.instances in group:
        instances_stamp, instances_msg = group[topics.instances]
        instances = _decoded(topics.instances, index, image_to_array, instances_msg)
        if instances.dtype != np.uint16 or instances.shape != mask.shape:
            raise FrameSourceError(
                f"topic {topics.instances}: frame {index} at {instances_stamp} ns: instance "
                f"mask {instances.dtype} {instances.shape} does not match the image "
                f"{image.shape[1]}x{image.shape[0]} (mono16 expected)"
            )
        differ = int(np.count_nonzero((instances > 0) != (mask == MASK_ANOMALY)))
        if differ:
            raise FrameSourceError(
                f"topic {topics.instances}: frame {index} at {instances_stamp} ns: {differ} "
                "pixels differ from the mask's anomaly pixels"
            )
    bodies: tuple = ()
    if topics.bodies in group:
        markers = group[topics.bodies][1].markers
        bodies = tuple(_decoded(topics.bodies, index, markers_to_bodies, markers))
    return EvalFrame(
        index=index,
        name=f"frame{index:06d}",
        stamp_ns=stamp,
        split=split,
        anomaly=anomaly,
        image=image,
        mask=mask,
        view=View(pose, np.array([vector.x, vector.y, vector.z]), sun_strength, bodies),
        instances=instances,
    )


def _check_instances(frame: EvalFrame, objects: tuple[GroundTruthObject, ...], topic: str) -> None:
    known = {item.id for item in objects}
    unknown = sorted(int(v) for v in np.unique(frame.instances) if v and int(v) not in known)
    if unknown:
        raise FrameSourceError(
            f"topic {topic}: frame {frame.index} at {frame.stamp_ns} ns: ids {unknown[:10]} "
            f"are not in the bag's objects table ({KEY_OBJECTS})"
        )


def _bag_objects(path: Path, data: dict[str, str]) -> tuple[GroundTruthObject, ...]:
    """The objects table recorded in the bag's custom data, empty if none."""
    text = data.get(KEY_OBJECTS)
    if not text:
        return ()
    try:
        return parse_objects(text, f"{path} custom_data {KEY_OBJECTS}")
    except SequenceError as error:
        raise FrameSourceError(str(error)) from None


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
        try:
            camera = intrinsics_from_camera_info(msg)
        except MessageError as error:
            raise FrameSourceError(f"topic {topics.camera_info}: {error}") from None
        return camera, int(images.msgcount)


def open_source(
    path: str | PathLike[str],
    *,
    mesh: str | PathLike[str] | None = None,
    use_references: bool = False,
) -> FrameSource:
    """Open a sequence folder (as :func:`~allo_mrad_ros.evaluation.sources.open_sequence`) or
    a bag (``mesh`` then overrides the model the bag records; it has no references).

    Raises
    ------
    FrameSourceError
        If the input is neither, cannot be read, or lacks what evaluation needs.
    """
    path = Path(path)
    mesh_path = Path(mesh) if mesh is not None else None
    if path.is_dir() and (path / META_FILE).is_file():
        return open_sequence(path, mesh=mesh_path, use_references=use_references)
    if mesh_path is not None and not mesh_path.is_file():
        raise FrameSourceError(f"{mesh_path}: station mesh not found")
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
        path,
        data.get(KEY_NAME, path.name),
        camera,
        _bag_mesh(path, data, mesh_path),
        headers,
        _bag_objects(path, data),
    )
