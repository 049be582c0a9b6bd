"""Lazy outputs: each output is built and published only for a subscriber; stamped results."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest
import rclpy
from sensor_msgs.msg import CameraInfo
from std_msgs.msg import Header

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.pipeline import DetectionResult
from allo_mrad_ros.detector.regions import extract_regions
from allo_mrad_ros.pipeline import ProcessedFrame
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros import outputs as outputs_module
from allo_mrad_ros.ros.outputs import (
    OVERLAY_COLOUR,
    Outputs,
    region_marker,
)
from allo_mrad_ros.ros.parameters import NodeConfig, default_config
from allo_mrad_ros.visualise import outline

pytestmark = pytest.mark.ros

DEFAULTS = default_config()


def settings(**changes: object) -> NodeConfig:
    """The node's default settings with ``changes``."""
    return dataclasses.replace(DEFAULTS, **changes)


NAMES = (
    "score",
    "score_info",
    "mask",
    "anomaly",
    "result",
    "regions",
    "reference",
    "reference_info",
    "overlay",
    "mask_info",
    "overlay_info",
)


class FakePublisher:
    def __init__(self, subscribers: int) -> None:
        self.subscribers = subscribers
        self.sent: list = []

    def get_subscription_count(self) -> int:
        return self.subscribers

    def publish(self, msg) -> None:
        self.sent.append(msg)


@pytest.fixture
def outputs():
    rclpy.init()
    node = rclpy.create_node("outputs_test")
    built = Outputs(node)
    yield built
    node.destroy_node()
    rclpy.shutdown()


def subscribe(outputs: Outputs, *names: str) -> dict[str, FakePublisher]:
    fakes = {name: FakePublisher(1 if name in names else 0) for name in NAMES}
    for name, fake in fakes.items():
        setattr(outputs, name, fake)
    return fakes


# The camera of the 160x90 image; the detector's map is 80x45 (process_scale 0.5).
IMAGE_CAMERA = CameraIntrinsics(160, 90, 100.0, 100.0, 80.0, 45.0)


def frame() -> ProcessedFrame:
    work_mask = np.zeros((45, 80), np.uint8)
    work_mask[5:10, 15:25] = 255
    work_mask[30, 50] = 255
    mask = cv2.resize(work_mask, (160, 90), interpolation=cv2.INTER_NEAREST)
    work_score = np.zeros((45, 80), np.float32)
    work_score[6, 20] = 90.0  # inside the first region (rows 10-19, columns 30-49)
    result = DetectionResult(
        work_score=work_score,
        raw_score=np.zeros((45, 80), np.float32),
        mask=mask,
        area=int(np.count_nonzero(mask)),
        anomalous=True,
        image_score=40.0,
        regions=extract_regions(work_mask, work_score, (90, 160), 8),
        anomaly_score=0.75,
    )
    return ProcessedFrame(reference=np.zeros((45, 80, 3), np.uint8), results={"MRAD": result})


def publish(
    outputs: Outputs,
    reference: bool = True,
    overlay: bool = True,
    processed: ProcessedFrame | None = None,
    full_resolution: bool = False,
    overlay_full_resolution: bool = False,
    image: np.ndarray | None = None,
) -> None:
    header = Header(frame_id="cam")
    header.stamp.sec = 7
    camera = CameraIntrinsics(80, 45, 50.0, 50.0, 40.0, 22.5)
    info = messages.fill_camera_info(CameraInfo(), IMAGE_CAMERA, "cam")
    outputs.publish(
        header,
        np.zeros((90, 160, 3), np.uint8) if image is None else image,
        processed or frame(),
        config=settings(
            publish_reference=reference,
            publish_overlay=overlay,
            score_full_resolution=full_resolution,
            overlay_full_resolution=overlay_full_resolution,
        ),
        reference_camera=camera,
        camera_info=info,
    )


def test_only_the_subscribed_mask_is_built_and_nothing_heavy(outputs, monkeypatch):
    fakes = subscribe(outputs, "mask")
    outlined = []
    monkeypatch.setattr(outputs_module, "outline", lambda *a: outlined.append(a))
    processed = frame()
    publish(outputs, processed=processed)
    assert len(fakes["mask"].sent) == 1 and fakes["mask"].sent[0].header.stamp.sec == 7
    for name in NAMES:
        if name not in ("mask", "anomaly"):
            assert fakes[name].sent == [], name
    assert outlined == []
    # The full-resolution score (a cached property) was never made.
    assert "score" not in vars(processed.primary)


@pytest.mark.parametrize("full_resolution", [False, True], ids=["processing", "full"])
def test_the_score_and_its_camera_info_at_either_resolution(outputs, full_resolution):
    fakes = subscribe(outputs, "score", "score_info")
    processed = frame()
    publish(outputs, processed=processed, full_resolution=full_resolution)
    score, info = fakes["score"].sent[0], fakes["score_info"].sent[0]
    width, height = (160, 90) if full_resolution else (80, 45)
    assert (score.width, score.height, score.encoding) == (width, height, "32FC1")
    assert (info.width, info.height) == (width, height)
    assert score.header.stamp.sec == info.header.stamp.sec == 7
    assert score.header.frame_id == info.header.frame_id == "cam"
    values = np.frombuffer(score.data, np.float32).reshape(height, width)
    expected = processed.primary.score if full_resolution else processed.primary.work_score
    np.testing.assert_array_equal(values, expected)
    assert ("score" in vars(processed.primary)) == full_resolution
    # The map's camera: half the focal lengths; pixel centres kept, (80 + 0.5) / 2 - 0.5.
    fx, cx, fy, cy = info.k[0], info.k[2], info.k[4], info.k[5]
    assert (fx, cx, fy, cy) == (
        (100.0, 80.0, 100.0, 45.0) if full_resolution else (50, 39.75, 50, 22.25)
    )


@pytest.mark.parametrize("full_resolution", [False, True], ids=["processing", "full"])
def test_the_overlay_at_either_resolution_outlines_the_mask_on_the_image(outputs, full_resolution):
    fakes = subscribe(outputs, "overlay")
    image = np.zeros((90, 160, 3), np.uint8)
    image[:, 80:] = 120  # right half grey
    publish(outputs, image=image, overlay_full_resolution=full_resolution)
    sent = fakes["overlay"].sent[0]
    width, height = (160, 90) if full_resolution else (80, 45)
    assert (sent.width, sent.height, sent.encoding) == (width, height, "rgb8")
    overlay = np.frombuffer(sent.data, np.uint8).reshape(height, width, 3)
    red = np.all(overlay == OVERLAY_COLOUR, axis=2)
    # Every outline pixel lies around one of the two regions, and the first is outlined.
    scale = width / 160
    near = np.zeros((height, width), bool)
    for top, bottom, left, right in ((10, 20, 30, 50), (60, 62, 100, 102)):
        near[
            max(0, int(top * scale) - 3) : int(bottom * scale) + 3,
            max(0, int(left * scale) - 3) : int(right * scale) + 3,
        ] = True
    assert red.any() and not (red & ~near).any()
    assert red[int(10 * scale) - 3 : int(20 * scale) + 3, int(30 * scale) - 3 :][:, :30].any()
    # Elsewhere it is the image, area-averaged when smaller.
    assert overlay[height // 2, width - 1].tolist() == [120, 120, 120]
    assert overlay[height - 1, 0].tolist() == [0, 0, 0]


def test_the_small_overlay_draws_on_what_the_detector_saw(outputs):
    # The detector's downscaled query and mask, not a second resize of the image: an image
    # the overlay would resample to another colour shows that it was not resampled.
    fakes = subscribe(outputs, "overlay")
    seen = np.full((45, 80, 3), 77, np.uint8)
    work_mask = np.zeros((45, 80), np.uint8)
    work_mask[20:30, 10:20] = 255
    result = dataclasses.replace(frame().primary, work_query=seen, work_mask=work_mask)
    processed = ProcessedFrame(reference=np.zeros((45, 80, 3), np.uint8), results={"MRAD": result})
    publish(outputs, processed=processed, image=np.full((90, 160, 3), 200, np.uint8))
    overlay = np.frombuffer(fakes["overlay"].sent[0].data, np.uint8).reshape(45, 80, 3)
    np.testing.assert_array_equal(overlay, outline(seen, work_mask, OVERLAY_COLOUR))
    assert np.all(overlay == OVERLAY_COLOUR, axis=2)[20:30, 10:20].any()


def test_every_subscribed_output_is_published_with_the_image_header(outputs):
    fakes = subscribe(outputs, *NAMES)
    publish(outputs)
    for name in NAMES:
        assert len(fakes[name].sent) == 1, name
        if name != "anomaly":
            assert fakes[name].sent[0].header.frame_id == "cam", name
    info = fakes["reference_info"].sent[0]
    assert (info.width, info.height, info.k[0]) == (80, 45, 50.0)
    status = fakes["result"].sent[0].status[0]
    values = {kv.key: kv.value for kv in status.values}
    assert values == {
        "anomalous": "true",
        "area_px": "204",
        "area_fraction": f"{204 / (90 * 160):.6f}",
        "image_score": "40.000",
        "anomaly_score": "0.7500",
        "regions": "2",
        "boxes_xywh": "30,10,20,10;100,60,2,2",
    }


def test_a_frame_detected_without_the_score_map_leaves_the_score_out(outputs):
    fakes = subscribe(outputs, *NAMES)
    header = Header(frame_id="cam")
    image = np.zeros((90, 160, 3), np.uint8)
    config = settings(publish_reference=True, publish_overlay=True)
    outputs.publish(header, image, frame(), config=config, score_map=False)
    assert fakes["score"].sent == []
    assert fakes["score_info"].sent == []  # no camera_info was given
    assert all(len(fakes[name].sent) == 1 for name in ("mask", "overlay", "result"))


def test_switched_off_outputs_stay_off_even_when_subscribed(outputs):
    fakes = subscribe(outputs, *NAMES)
    publish(outputs, reference=False, overlay=False)
    assert fakes["reference"].sent == fakes["reference_info"].sent == fakes["overlay"].sent == []


def test_wanted_only_with_a_subscriber_to_an_enabled_output(outputs):
    def wanted(reference: bool, overlay: bool) -> bool:
        return outputs.wanted(settings(publish_reference=reference, publish_overlay=overlay))

    subscribe(outputs)
    assert not wanted(True, True)
    subscribe(outputs, "overlay")
    assert wanted(True, True) and not wanted(True, False)
    subscribe(outputs, "reference_info")
    assert wanted(True, False) and not wanted(False, True)
    for name in ("mask", "mask_info", "score", "score_info", "anomaly", "result", "regions"):
        subscribe(outputs, name)
        assert wanted(False, False), name
    subscribe(outputs, "overlay_info")
    assert wanted(False, True) and not wanted(True, False)


def test_the_outline_marker_draws_each_region_box():
    regions = extract_regions(
        np.pad(np.full((3, 6), 255, np.uint8), ((2, 0), (3, 0))),
        np.zeros((5, 9), np.float32),
        (5, 9),
        8,
    )
    marker = region_marker(Header(frame_id="cam"), regions)
    segments = [
        ((a.x, a.y), (b.x, b.y))
        for a, b in zip(marker.points[::2], marker.points[1::2], strict=True)
    ]
    assert segments == [((3, 2), (9, 2)), ((9, 2), (9, 5)), ((9, 5), (3, 5)), ((3, 5), (3, 2))]


# Two squares touching at one corner: one region for 8-connectivity, two for 4.
DIAGONAL = np.zeros((24, 32), np.uint8)
DIAGONAL[4:10, 4:10] = 255
DIAGONAL[10:16, 10:16] = 255


def diagonal_result(connectivity: int) -> DetectionResult:
    """A real detection of the two corner-touching squares (a pasted object in each)."""
    reference = np.full((24, 32, 3), 90, np.uint8)
    query = reference.copy()
    query[DIAGONAL > 0] = (250, 20, 20)
    params = MradParams(
        grid=1,
        process_scale=1.0,
        blur_sigma=0.0,
        noise_removal="none",
        colour_transfer="none",
        photometric="none",
        connectivity=connectivity,
    )
    return detect(query, reference, params)


@pytest.mark.parametrize("connectivity", [4, 8])
def test_published_boxes_are_the_detectors_regions_with_its_connectivity(outputs, connectivity):
    result = diagonal_result(connectivity)
    np.testing.assert_array_equal(result.mask, DIAGONAL)
    boxes = [region.box for region in result.regions]
    # 8-connected, the squares are one region; 4-connected, two (a second, 8-connected
    # labelling of the mask would merge them).
    eight = [(4, 4, 12, 12)]
    assert boxes == ([(4, 4, 6, 6), (10, 10, 6, 6)] if connectivity == 4 else eight)
    assert (boxes != eight) == (connectivity == 4)
    fakes = subscribe(outputs, *NAMES)
    processed = ProcessedFrame(reference=np.zeros((3, 4, 3), np.uint8), results={"MRAD": result})
    header = Header(frame_id="cam")
    config = settings(publish_reference=False, publish_overlay=False)
    outputs.publish(header, np.zeros((24, 32, 3), np.uint8), processed, config=config)
    status = {kv.key: kv.value for kv in fakes["result"].sent[0].status[0].values}
    assert status["boxes_xywh"] == ";".join("{},{},{},{}".format(*box) for box in boxes)
    assert status["regions"] == str(len(boxes))
    points = [(p.x, p.y) for p in fakes["regions"].sent[0].points]
    assert len(points) == 8 * len(boxes)
    assert {(x, y) for x, y, _, _ in boxes} <= set(points)
    assert {(x + w, y + h) for x, y, w, h in boxes} <= set(points)


@pytest.mark.parametrize("full_resolution", [False, True], ids=["processing", "full"])
def test_the_mask_and_the_overlay_have_camera_infos_of_their_own_resolution(
    outputs, full_resolution
):
    fakes = subscribe(outputs, "mask", "mask_info", "overlay", "overlay_info")
    publish(outputs, overlay_full_resolution=full_resolution)
    for image_name in ("mask", "overlay"):
        image, info = fakes[image_name].sent[0], fakes[f"{image_name}_info"].sent[0]
        assert (info.width, info.height) == (image.width, image.height), image_name
        assert info.header.stamp.sec == image.header.stamp.sec == 7
        assert info.header.frame_id == image.header.frame_id == "cam"
    # The mask is at the image's resolution: the image's camera_info itself.
    mask_info = fakes["mask_info"].sent[0]
    assert list(mask_info.k) == [100.0, 0.0, 80.0, 0.0, 100.0, 45.0, 0.0, 0.0, 1.0]
    overlay_info = fakes["overlay_info"].sent[0]
    assert overlay_info.k[0] == (100.0 if full_resolution else 50.0)


def test_the_mask_and_overlay_camera_infos_only_when_subscribed_and_enabled(outputs):
    fakes = subscribe(outputs, "mask", "overlay")
    publish(outputs)
    assert fakes["mask_info"].sent == fakes["overlay_info"].sent == []
    fakes = subscribe(outputs, "mask_info", "overlay_info")
    publish(outputs, overlay=False)
    assert len(fakes["mask_info"].sent) == 1 and fakes["overlay_info"].sent == []
    assert fakes["mask"].sent == fakes["overlay"].sent == []  # the images are not made
