"""The node's outputs, built and published only for topics someone subscribes to.

``~/mask`` (mono8) and ``~/anomaly`` (Bool, kept for compatibility) are cheap; ``~/score``
(32FC1, 8.3 MB at 1080p), ``~/overlay`` and ``~/reference`` are built only when subscribed.
``~/result`` (DiagnosticArray) and ``~/regions`` (ImageMarker boxes) carry the image's header,
so a flag can be matched to its image; ``~/reference/camera_info`` describes the 1/8-size
reference. Every publisher accepts QoS overrides (``qos_overrides.<topic>.publisher.*``).
"""

from __future__ import annotations

import cv2
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image
from std_msgs.msg import Bool, ColorRGBA
from visualization_msgs.msg import ImageMarker

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages
from allo_mrad_ros.visualise import outline

OVERLAY_COLOUR = (255, 40, 40)
REGION_COLOUR = ColorRGBA(r=1.0, g=0.16, b=0.16, a=1.0)
REGION_LINE_WIDTH = 2.0


def connected_boxes(mask: np.ndarray) -> list[tuple[int, int, int, int]]:
    """``(x, y, width, height)`` of each 8-connected region of a mask, in pixels."""
    if mask.dtype != np.uint8:  # OpenCV takes any non-zero uint8 as foreground: no copy
        mask = (mask > 0).astype(np.uint8)
    count, _, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    return [tuple(int(v) for v in stats[i, :4]) for i in range(1, count)]


def region_marker(header: object, boxes: list[tuple[int, int, int, int]]) -> ImageMarker:
    """One ``LINE_LIST`` ImageMarker outlining each ``(x, y, width, height)`` box in pixels."""
    marker = ImageMarker(header=header, ns="mrad_regions", id=0)
    marker.type = ImageMarker.LINE_LIST
    marker.action = ImageMarker.ADD
    marker.scale = REGION_LINE_WIDTH
    marker.outline_color = REGION_COLOUR
    points = []
    for x, y, w, h in boxes:
        corners = [(x, y), (x + w, y), (x + w, y + h), (x, y + h)]
        for (x0, y0), (x1, y1) in zip(corners, corners[1:] + corners[:1], strict=True):
            points += [Point(x=float(x0), y=float(y0)), Point(x=float(x1), y=float(y1))]
    marker.points = points
    return marker


def result_status(
    node_name: str, anomalous: bool, area: int, pixels: int, boxes: list, image_score: float
) -> DiagnosticStatus:
    """The frame's result as a status: WARN when anomalous; area, image score and boxes as
    values."""
    status = DiagnosticStatus(
        name=f"{node_name}: result",
        hardware_id=interface.HARDWARE_ID,
        level=DiagnosticStatus.WARN if anomalous else DiagnosticStatus.OK,
        message="anomalous" if anomalous else "clean",
    )
    values = {
        "anomalous": str(bool(anomalous)).lower(),
        "area_px": str(int(area)),
        "area_fraction": f"{area / max(pixels, 1):.6f}",
        "image_score": f"{image_score:.3f}",
        "regions": str(len(boxes)),
        "boxes_xywh": ";".join(f"{x},{y},{w},{h}" for x, y, w, h in boxes),
    }
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return status


class Outputs:
    """The node's output publishers; each builds its message only for a subscriber."""

    def __init__(self, node: Node) -> None:
        self._node = node
        overrides = QoSOverridingOptions.with_default_policies()

        def publisher(kind: type, topic: str, depth: int):
            return node.create_publisher(kind, topic, depth, qos_overriding_options=overrides)

        self.score = publisher(Image, interface.SCORE_OUTPUT, 5)
        self.mask = publisher(Image, interface.MASK_OUTPUT, 5)
        self.anomaly = publisher(Bool, interface.ANOMALY_OUTPUT, 10)
        self.result = publisher(DiagnosticArray, interface.RESULT_OUTPUT, 10)
        self.regions = publisher(ImageMarker, interface.REGIONS_OUTPUT, 10)
        self.reference = publisher(Image, interface.REFERENCE_OUTPUT, 5)
        self.reference_info = publisher(CameraInfo, interface.REFERENCE_INFO_OUTPUT, 5)
        self.overlay = publisher(Image, interface.OVERLAY_OUTPUT, 5)

    def wanted(self, publish_reference: bool, publish_overlay: bool) -> bool:
        """Whether any output has a subscriber (if not, a frame need not be processed)."""
        always = (self.mask, self.score, self.anomaly, self.result, self.regions)
        if any(p.get_subscription_count() for p in always):
            return True
        if publish_reference and (
            self.reference.get_subscription_count() or self.reference_info.get_subscription_count()
        ):
            return True
        return bool(publish_overlay and self.overlay.get_subscription_count())

    def publish(
        self,
        header: object,
        image: np.ndarray,
        frame: ProcessedFrame,
        reference_camera: CameraIntrinsics | None,
        publish_reference: bool,
        publish_overlay: bool,
        score_map: bool = True,
    ) -> None:
        """Build and publish every subscribed output with the input image's ``header``.

        ``score_map`` False: the frame's score is not the ranking map (no one subscribed
        when it was detected), so ``~/score`` is left out for this frame.
        """
        result = frame.primary
        fill = messages.fill_image
        # The mask and the flag first: they are what a consumer acts on, and the 8 MB score
        # would otherwise delay them by its serialisation.
        if self.mask.get_subscription_count():
            self.mask.publish(fill(Image(), header, result.mask, interface.MONO8))
        self.anomaly.publish(Bool(data=bool(result.anomalous)))
        if score_map and self.score.get_subscription_count():
            self.score.publish(fill(Image(), header, result.score, interface.SCORE_ENCODING))
        if self.result.get_subscription_count() or self.regions.get_subscription_count():
            boxes = connected_boxes(result.mask)
            if self.regions.get_subscription_count():
                self.regions.publish(region_marker(header, boxes))
            if self.result.get_subscription_count():
                status = result_status(
                    self._node.get_fully_qualified_name().lstrip("/"),
                    result.anomalous,
                    result.area,
                    result.mask.size,
                    boxes,
                    result.image_score,
                )
                self.result.publish(DiagnosticArray(header=header, status=[status]))
        if publish_reference:
            if self.reference.get_subscription_count():
                self.reference.publish(fill(Image(), header, frame.reference, interface.RGB8))
            if reference_camera is not None and self.reference_info.get_subscription_count():
                info = messages.fill_camera_info(CameraInfo(), reference_camera)
                info.header = header
                self.reference_info.publish(info)
        if publish_overlay and self.overlay.get_subscription_count():
            overlay = outline(_as_uint8(image), result.mask, OVERLAY_COLOUR)
            self.overlay.publish(fill(Image(), header, overlay, interface.RGB8))


def _as_uint8(image: np.ndarray) -> np.ndarray:
    if image.dtype == np.uint8:
        return image
    return (image / 257).astype(np.uint8)
