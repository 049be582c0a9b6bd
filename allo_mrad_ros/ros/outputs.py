"""The node's outputs, built and published only for topics someone subscribes to.

``~/mask`` (mono8) and ``~/anomaly`` (Bool, kept for compatibility) are cheap; ``~/score``
(32FC1), ``~/overlay`` and ``~/reference`` are built only when subscribed. ``~/score`` is the
map at the detector's processing resolution (``mrad.process_scale``: 480x270, 0.5 MB, for a
1080p camera), described by ``~/score/camera_info`` (the image's camera_info scaled as
image_proc's resize node scales it); with ``score_full_resolution`` it is upscaled to the
image's size (8.3 MB at 1080p) and ``~/score/camera_info`` is the image's camera_info.
``~/result`` (DiagnosticArray) and ``~/regions`` (ImageMarker boxes) carry the image's header,
so a flag can be matched to its image; ``~/reference/camera_info`` describes the 1/8-size
reference. ``~/mask/camera_info`` and ``~/overlay/camera_info`` describe the mask (the image's
resolution) and the overlay (the image's or the processing resolution), so a
CameraSubscriber on either gets its pair; each camera_info is published only while
subscribed. Every publisher accepts QoS overrides (``qos_overrides.<topic>.publisher.*``).

``~/result``, ``~/regions`` and ``~/detections`` format the detector's regions
(``DetectionResult.regions``, grown and labelled with ``mrad.connectivity``); nothing here
labels the mask again. ``~/detections`` (vision_msgs/Detection2DArray: one detection per
region, its box and an ``anomaly`` hypothesis scored with the region's score in [0, 1])
exists where vision_msgs is installed (every ROS distro; no pip wheel).
:func:`detection_array` builds it from any module of classes with vision_msgs' fields; the
tests create the publisher with types generated from vision_msgs' own ``.msg`` files.

``~/objects`` (vision_msgs/Detection3DArray, where vision_msgs is installed) and
``~/objects/markers`` (visualization_msgs/MarkerArray) publish the object tracker's result
in the station frame (:mod:`.object_messages`), for frames the worker tracked; the markers of
every object once a second (:data:`MARKERS_REFRESH_S`), in between those that changed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, ColorRGBA, Header
from visualization_msgs.msg import ImageMarker, MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector.regions import Region
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.object_messages import anomaly_hypothesis, object_array, object_markers
from allo_mrad_ros.ros.object_tracking import ObjectsUpdate
from allo_mrad_ros.ros.parameters import NodeConfig
from allo_mrad_ros.visualise import outline

OVERLAY_COLOUR = (255, 40, 40)
REGION_COLOUR = ColorRGBA(r=1.0, g=0.16, b=0.16, a=1.0)
REGION_LINE_WIDTH = 2.0
# ~/objects/markers sends every object's markers at most this often (a viewer that joins
# sees them all within it), and in the frames between only the objects that changed:
# building a Marker costs about 0.1 ms, and a hundred tentative objects are not rare.
MARKERS_REFRESH_S = 1.0


def vision_msgs_module() -> Any | None:
    """``vision_msgs.msg`` where installed (a ROS distro), else None."""
    try:
        from vision_msgs import msg
    except ImportError:
        return None
    return msg


def detection_array(msg: Any, header: object, regions: Sequence[Region]) -> Any:
    """A vision_msgs/Detection2DArray of the detector's ``regions``: per region a Detection2D
    with the image header, the box (centre and size in the image's pixels) and one
    ObjectHypothesisWithPose (class ``anomaly``, the region's score in [0, 1], see
    :attr:`Region.score`). ``msg`` is the module of the message classes."""
    detections = []
    for index, region in enumerate(regions):
        x, y, w, h = region.box
        detection = msg.Detection2D()
        detection.header = header
        detection.id = str(index)
        detection.bbox.center.position.x = x + w / 2.0
        detection.bbox.center.position.y = y + h / 2.0
        detection.bbox.center.theta = 0.0
        detection.bbox.size_x = float(w)
        detection.bbox.size_y = float(h)
        detection.results = [anomaly_hypothesis(msg, region.score)]
        detections.append(detection)
    return msg.Detection2DArray(header=header, detections=detections)


def region_marker(header: object, regions: Sequence[Region]) -> ImageMarker:
    """One ``LINE_LIST`` ImageMarker outlining each region's box in the image's pixels."""
    marker = ImageMarker(header=header, ns="mrad_regions", id=0)
    marker.type = ImageMarker.LINE_LIST
    marker.action = ImageMarker.ADD
    marker.scale = REGION_LINE_WIDTH
    marker.outline_color = REGION_COLOUR
    points = []
    for region in regions:
        x, y, w, h = region.box
        corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)]
        for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1], strict=True):
            points += [Point(x=float(x0), y=float(y0)), Point(x=float(x1), y=float(y1))]
    marker.points = points
    return marker


def result_status(
    node_name: str,
    anomalous: bool,
    area: int,
    pixels: int,
    regions: Sequence[Region],
    image_score: float,
    hardware_id: str = "",
    *,
    anomaly_score: float | None = None,
) -> DiagnosticStatus:
    """The frame's result as a status: WARN when anomalous; area, image score, the frame
    decision's anomaly score in [0, 1] (when given) and the regions' boxes (image pixels) as
    values. ``hardware_id`` empty: the package's default."""
    status = DiagnosticStatus(
        name=f"{node_name}: result",
        hardware_id=hardware_id or interface.HARDWARE_ID,
        level=DiagnosticStatus.WARN if anomalous else DiagnosticStatus.OK,
        message="anomalous" if anomalous else "clean",
    )
    values = {
        "anomalous": str(bool(anomalous)).lower(),
        "area_px": str(int(area)),
        "area_fraction": f"{area / max(pixels, 1):.6f}",
        "image_score": f"{image_score:.3f}",
        **({} if anomaly_score is None else {"anomaly_score": f"{anomaly_score:.4f}"}),
        "regions": str(len(regions)),
        "boxes_xywh": ";".join("{},{},{},{}".format(*region.box) for region in regions),
    }
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return status


class Outputs:
    """The node's output publishers; each builds its message only for a subscriber."""

    def __init__(
        self,
        node: Node,
        *,
        overriding: Callable[[], QoSOverridingOptions] = QoSOverridingOptions.with_default_policies,
        event_callbacks: Any | None = None,
        station_mesh: str = "",
    ) -> None:
        """``event_callbacks``: rclpy's ``PublisherEventCallbacks`` given to every publisher
        (the node's matched event, which subscribes its inputs), or None. ``station_mesh``:
        the URI of the station model drawn with ``~/objects/markers`` (empty: none)."""
        self._node = node
        self._station_mesh = station_mesh
        self._markers_refreshed: float | None = None  # monotonic s of the last full set

        def publisher(kind: type, topic: str, depth: int):
            return node.create_publisher(
                kind,
                topic,
                depth,
                qos_overriding_options=overriding(),
                event_callbacks=event_callbacks,
            )

        self.score = publisher(Image, interface.SCORE_OUTPUT, 5)
        self.score_info = publisher(CameraInfo, interface.SCORE_INFO_OUTPUT, 5)
        self.mask = publisher(Image, interface.MASK_OUTPUT, 5)
        self.mask_info = publisher(CameraInfo, interface.MASK_INFO_OUTPUT, 5)
        self.anomaly = publisher(Bool, interface.ANOMALY_OUTPUT, 10)
        self.result = publisher(DiagnosticArray, interface.RESULT_OUTPUT, 10)
        self.regions = publisher(ImageMarker, interface.REGIONS_OUTPUT, 10)
        self.reference = publisher(Image, interface.REFERENCE_OUTPUT, 5)
        self.reference_info = publisher(CameraInfo, interface.REFERENCE_INFO_OUTPUT, 5)
        self.overlay = publisher(Image, interface.OVERLAY_OUTPUT, 5)
        self.overlay_info = publisher(CameraInfo, interface.OVERLAY_INFO_OUTPUT, 5)
        self._vision = vision_msgs_module()
        self.detections = (
            None
            if self._vision is None
            else publisher(self._vision.Detection2DArray, interface.DETECTIONS_OUTPUT, 10)
        )
        self.objects = (
            None
            if self._vision is None
            else publisher(self._vision.Detection3DArray, interface.OBJECTS_OUTPUT, 10)
        )
        self.object_markers = publisher(MarkerArray, interface.OBJECT_MARKERS_OUTPUT, 10)

    def objects_wanted(self) -> bool:
        """Whether ``~/objects`` or ``~/objects/markers`` has a subscriber."""
        return bool(
            self.object_markers.get_subscription_count()
            or (self.objects is not None and self.objects.get_subscription_count())
        )

    def wanted(self, config: NodeConfig) -> bool:
        """Whether any output has a subscriber (if not, a frame need not be processed);
        ``~/reference`` and ``~/overlay`` count only where ``config`` publishes them."""
        always = [
            self.mask,
            self.mask_info,
            self.score,
            self.score_info,
            self.anomaly,
            self.result,
            self.regions,
        ]
        if self.detections is not None:
            always.append(self.detections)
        if self.objects_wanted():
            return True
        if any(p.get_subscription_count() for p in always):
            return True
        if config.publish_reference and (
            self.reference.get_subscription_count() or self.reference_info.get_subscription_count()
        ):
            return True
        return bool(
            config.publish_overlay
            and (
                self.overlay.get_subscription_count() or self.overlay_info.get_subscription_count()
            )
        )

    def publish(
        self,
        header: object,
        image: np.ndarray,
        frame: ProcessedFrame,
        *,
        config: NodeConfig,
        reference_camera: CameraIntrinsics | None = None,
        camera_info: Any | None = None,
        score_map: bool = True,
        objects: ObjectsUpdate | None = None,
    ) -> None:
        """Build and publish every subscribed output with the input image's ``header``.

        ``config``: the node's settings for this frame (``publish_reference``,
        ``publish_overlay``, ``score_full_resolution``: ``~/score`` at the image's resolution,
        upscaled, instead of the detector's processing resolution; ``overlay_full_resolution``
        likewise for ``~/overlay``; ``hardware_id``, empty: each result names the image's
        frame_id, as /diagnostics does). ``reference_camera``: the camera the reference was
        rendered for (None: no ``~/reference/camera_info``). ``camera_info``: the image's
        ``sensor_msgs/CameraInfo`` (None: unknown, so no ``~/score/camera_info``).
        ``score_map`` False: the frame's score is not the ranking map (no one subscribed
        when it was detected), so ``~/score`` is left out for this frame. ``objects``: the
        object tracker's result for this frame (None: not tracked), published on
        ``~/objects`` and ``~/objects/markers`` in ``config.station_frame``; with
        ``decision: objects`` it is what ``~/anomaly`` says (an untracked frame has no flag).
        """
        result = frame.primary
        fill = messages.fill_image
        # The mask and the flag first: they are what a consumer acts on, and the 8 MB score
        # would otherwise delay them by its serialisation.
        if self.mask.get_subscription_count():
            self.mask.publish(fill(Image(), header, result.mask, interface.MONO8))
        self._publish_info(self.mask_info, header, camera_info, image.shape, result.mask.shape)
        if config.decision == "objects":
            if objects is not None:
                self.anomaly.publish(Bool(data=objects.anomalous))
        else:
            self.anomaly.publish(Bool(data=bool(result.anomalous)))
        if objects is not None:
            self._publish_objects(header, objects, config.station_frame)
        # The map as the detector made it: upscaling it is a 1080p float32 resize and 16 times
        # the bytes to send, worth it only to a consumer that asked for it.
        score = result.score if config.score_full_resolution else result.work_score
        if score_map and self.score.get_subscription_count():
            self.score.publish(fill(Image(), header, score, interface.SCORE_ENCODING))
        self._publish_info(self.score_info, header, camera_info, image.shape, score.shape)
        # The detector's own regions (its connectivity), formatted: no second labelling.
        if self.detections is not None and self.detections.get_subscription_count():
            self.detections.publish(detection_array(self._vision, header, result.regions))
        if self.regions.get_subscription_count():
            self.regions.publish(region_marker(header, result.regions))
        if self.result.get_subscription_count():
            status = result_status(
                self._node.get_fully_qualified_name().lstrip("/"),
                result.anomalous,
                result.area,
                result.mask.size,
                result.regions,
                result.image_score,
                config.hardware_id or getattr(header, "frame_id", ""),
                anomaly_score=result.anomaly_score,
            )
            self.result.publish(DiagnosticArray(header=header, status=[status]))
        if config.publish_reference:
            if self.reference.get_subscription_count():
                self.reference.publish(fill(Image(), header, frame.reference, interface.RGB8))
            if reference_camera is not None and self.reference_info.get_subscription_count():
                info = messages.fill_camera_info(CameraInfo(), reference_camera)
                info.header = header
                self.reference_info.publish(info)
        if config.publish_overlay:
            if self.overlay.get_subscription_count():
                overlay = _overlay(image, result, config.overlay_full_resolution)
                self.overlay.publish(fill(Image(), header, overlay, interface.RGB8))
            shape = _overlay_shape(image, result, config.overlay_full_resolution)
            self._publish_info(self.overlay_info, header, camera_info, image.shape, shape)

    def _publish_objects(self, header: Any, objects: ObjectsUpdate, station_frame: str) -> None:
        """``~/objects`` and ``~/objects/markers``, to subscribers, in the station frame with
        the image's stamp."""
        wanted = self.objects is not None and self.objects.get_subscription_count()
        markers = self.object_markers.get_subscription_count()
        if not (wanted or markers):
            return
        station = Header(stamp=header.stamp, frame_id=station_frame)
        if wanted:
            self.objects.publish(object_array(self._vision, station, objects.objects))
        if markers:
            now = time.monotonic()
            full = self._markers_refreshed is None or now - self._markers_refreshed >= (
                MARKERS_REFRESH_S
            )
            if full:
                self._markers_refreshed = now
            array = object_markers(
                station,
                objects.objects,
                station_mesh=self._station_mesh if full else "",
                changed_only=not full,
            )
            if array.markers:
                self.object_markers.publish(array)

    @staticmethod
    def _publish_info(
        publisher: Any,
        header: object,
        camera_info: Any | None,
        image_shape: tuple[int, ...],
        shape: tuple[int, ...],
    ) -> None:
        """Publish, to a subscriber, the image's ``camera_info`` scaled to an output of
        ``shape`` (rows, columns) made from the image of ``image_shape``, with the image's
        header (as image_proc's resize node scales it; the image's own for the same size)."""
        if camera_info is None or not publisher.get_subscription_count():
            return
        info = messages.scaled_camera_info(
            CameraInfo(), camera_info, (image_shape[1], image_shape[0]), (shape[1], shape[0])
        )
        info.header = header
        publisher.publish(info)


def _overlay_shape(image: np.ndarray, result: Any, full_resolution: bool) -> tuple[int, int]:
    """The (rows, columns) :func:`_overlay` gives, without drawing it."""
    if full_resolution:
        return image.shape[:2]
    return result.work_score.shape[:2]


def _overlay(image: np.ndarray, result: Any, full_resolution: bool) -> np.ndarray:
    """The image with the mask outlined, at the image's or the processing resolution."""
    height, width = result.work_score.shape[:2]
    if full_resolution or (height, width) == image.shape[:2]:
        return outline(_as_uint8(image), result.mask, OVERLAY_COLOUR)
    # A display's copy: what the detector saw, at a sixteenth of the bytes of a full one.
    # The detector's own downscaled query and mask when it kept them (no second resize).
    small, mask = result.work_query, result.work_mask
    if small is None or small.shape[:2] != (height, width):
        small = cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)
    if mask is None or mask.shape[:2] != (height, width):
        mask = cv2.resize(result.mask, (width, height), interpolation=cv2.INTER_NEAREST)
    return outline(_as_uint8(small), mask, OVERLAY_COLOUR)


def _as_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    return (image / 257).astype(np.uint8)
