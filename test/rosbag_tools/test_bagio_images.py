"""Bags and the node decode images with one decoder: every encoding the node takes reads here."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from rosbag_tools.bagio import BagReadError, image_array

TYPES = get_typestore(Stores.ROS2_HUMBLE)
Header = TYPES.types["std_msgs/msg/Header"]
Time = TYPES.types["builtin_interfaces/msg/Time"]
Image = TYPES.types["sensor_msgs/msg/Image"]
CompressedImage = TYPES.types["sensor_msgs/msg/CompressedImage"]
TOPIC = "/arm_camera/image_raw"


def bag_image(pixels: np.ndarray, encoding: str) -> Image:
    """A rosbags Image (the type bag reading gives), little-endian, no row padding."""
    height, width = pixels.shape[:2]
    data = np.ascontiguousarray(pixels).reshape(height, -1).view(np.uint8)
    return Image(
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id="cam"),
        height=height,
        width=width,
        encoding=encoding,
        is_bigendian=0,
        step=data.shape[1],
        data=data.reshape(-1),
    )


RNG = np.random.default_rng(5)
RGB = RNG.integers(0, 256, (6, 9, 3), dtype=np.uint8)
MONO16 = RNG.integers(0, 65536, (6, 9), dtype=np.uint16)


@pytest.mark.parametrize(
    ("pixels", "encoding", "expected"),
    [
        (RGB, "rgb8", RGB),
        (RGB[..., ::-1], "bgr8", RGB),
        (np.dstack([RGB, np.full((6, 9), 255, np.uint8)]), "rgba8", RGB),
        (np.dstack([RGB[..., ::-1], np.zeros((6, 9), np.uint8)]), "bgra8", RGB),
        (RGB[..., 0], "mono8", RGB[..., 0]),
        (MONO16, "mono16", MONO16),
        (RGB.astype(np.uint16) * 257, "rgb16", RGB.astype(np.uint16) * 257),
    ],
)
def test_every_encoding_the_node_accepts_reads_from_a_bag(pixels, encoding, expected):
    np.testing.assert_array_equal(image_array(bag_image(pixels, encoding), TOPIC), expected)


def test_compressed_bag_images_read_as_the_node_reads_them():
    ok, data = cv2.imencode(".png", np.ascontiguousarray(RGB[..., ::-1]))
    assert ok
    message = CompressedImage(
        header=Header(stamp=Time(sec=1, nanosec=0), frame_id="cam"),
        format="rgb8; png compressed bgr8",
        data=data.reshape(-1),
    )
    np.testing.assert_array_equal(image_array(message, TOPIC), RGB)


def test_refused_image_names_the_topic_and_the_encoding():
    with pytest.raises(BagReadError, match=r"topic /arm_camera/image_raw: .*'yuv422'"):
        image_array(bag_image(RGB, "yuv422"), TOPIC)
