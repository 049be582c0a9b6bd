"""The node's deployment cases of the sweep: start-up refusals (mesh, params files, empty
values, QoS overrides, TF without tf2), encodings a camera driver sends, camera_info binning,
ROI, stamps and frame ids. Kept apart from ``sweep_node_cases`` (the older cases)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from sensor_msgs.msg import Image
from sweep_node import IMAGE, INTRINSICS, POSE, Live, RunCase, StartCase
from sweep_node_cases import _image, _publish_pose, image, pixels

from allo_mrad_ros.ros.messages import fill_camera_info


def deploy_start_cases(work: Path) -> list[StartCase]:
    """Start-up input the node refuses in one line (exit 2) or warns about."""
    empty = work / "empty.glb"
    empty.write_bytes(b"")
    garbage = work / "garbage.glb"
    garbage.write_bytes(b"glTF\x02\x00\x00\x00 this is not a model")
    flat = work / "flat.yaml"
    flat.write_text("/**:\n  pose_source: topic\n")
    other = work / "other_node.yaml"
    other.write_text("other_node:\n  ros__parameters:\n    mrad:\n      grid: 4\n")
    p = "-p"
    return [
        StartCase("zero-byte mesh", (p, f"mesh:={empty}"), "not a usable model", quick=True),
        StartCase("garbage mesh", (p, f"mesh:={garbage}"), "not a usable model"),
        StartCase(
            "params file without ros__parameters",
            ("--params-file", str(flat)),
            "has no ros__parameters",
        ),
        StartCase("empty -p mesh:=", (p, "mesh:="), "mesh:= has no value", quick=True),
        StartCase("-p without :=", (p, "mesh"), "expected name:=value"),
        StartCase(
            "QoS override of a misspelt policy",
            (p, "qos_overrides./mrad_detector/mask.publisher.durabilty:=transient_local"),
            "match no publisher or subscription",
        ),
        StartCase(
            "QoS override of a topic the node lacks",
            (p, "qos_overrides./no/such/topic.publisher.depth:=1"),
            "match no publisher or subscription",
        ),
        StartCase("pose_source tf without tf2", (p, "pose_source:=tf"), "tf2_ros_py"),
        StartCase(
            "params file for another node",
            ("--params-file", str(other)),
            "not for this node",
            starts=True,
        ),
    ]


def _info_then_image(live: Live, stamp: int, info, msg: Image) -> None:
    feed = live.feed
    info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp, 10**9)
    msg.header.stamp = info.header.stamp
    _publish_pose(live, stamp, POSE)
    feed.pub_info.publish(info)
    feed.spin(0.2)
    feed.pub_image.publish(msg)


def binned(live: Live, stamp: int) -> None:
    """camera_info of the full 320x180 camera binned 2x2, with its 160x90 image."""
    info = fill_camera_info(live.feed.camera_info(), INTRINSICS, live.feed.frame_id)
    info.binning_x = info.binning_y = 2
    small = np.ascontiguousarray(IMAGE[::2, ::2])
    msg = _image(live, stamp, data=small.tobytes(), width=160, height=90, step=160 * 3)
    _info_then_image(live, stamp, info, msg)


def roi(x: int, y: int, width: int, height: int):
    def send(live: Live, stamp: int) -> None:
        info = live.feed.camera_info()
        info.roi.x_offset, info.roi.y_offset = x, y
        info.roi.width, info.roi.height = width, height
        crop = np.ascontiguousarray(IMAGE[: max(height, 1), : max(width, 1)])
        h, w = crop.shape[:2]
        msg = _image(live, stamp, data=crop.tobytes(), width=w, height=h, step=w * 3)
        _info_then_image(live, stamp, info, msg)

    return send


def info_frame(frame_id: str):
    def send(live: Live, stamp: int) -> None:
        info = live.feed.camera_info()
        info.header.frame_id = frame_id
        _info_then_image(live, stamp, info, _image(live, stamp))

    return send


def info_stamped_apart(live: Live, stamp: int) -> None:
    info = live.feed.camera_info()
    info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp + 10**9, 10**9)
    live.feed.pub_info.publish(info)  # one second after the image: not its camera_info
    live.feed.spin(0.2)
    msg = _image(live, stamp)
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    _publish_pose(live, stamp, POSE)
    live.feed.pub_image.publish(msg)


def deploy_run_cases() -> list[RunCase]:
    """Camera-driver input to the running node."""
    rgb16 = IMAGE.astype(np.uint16) * 256
    return [
        RunCase(
            "bgr16 image", pixels(rgb16[..., ::-1].astype(">u2"), "bgr16", 2, 1), accepted=True
        ),
        RunCase(
            "rgba16 little-endian",
            pixels(np.dstack([rgb16, rgb16[..., :1]]).astype("<u2"), "rgba16", 2, 0),
            accepted=True,
        ),
        RunCase(
            "bayer_rggb8 names the debayering node",
            image(encoding="bayer_rggb8"),
            "errors_encoding",
            "image_proc",
            quick=True,
        ),
        RunCase(
            "yuv422_yuy2 names image_proc",
            image(encoding="yuv422_yuy2"),
            "errors_encoding",
            "image_proc",
        ),
        RunCase("camera_info binned 2x2 with its 160x90 image", binned, accepted=True),
        RunCase("camera_info ROI with its cropped image", roi(40, 20, 200, 100), accepted=True),
        RunCase(
            "camera_info ROI outside the image",
            roi(300, 0, 100, 100),
            "errors_camera_info",
            "outside",
        ),
        RunCase(
            "camera_info frame_id differs from the image's",
            info_frame("other_camera_optical_frame"),
            "camera_info_frame_mismatches",
            "differs from the image",
            quick=True,
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info stamped 1 s after the image",
            info_stamped_apart,
            "errors_camera_info",
            "no valid camera_info",
        ),
    ]
