"""The node's cases of the sweep: start-up parameters, bad messages, parameter changes."""

from __future__ import annotations

import array
from pathlib import Path

import numpy as np
from geometry_msgs.msg import PoseStamped, Vector3Stamped
from rcl_interfaces.msg import ParameterType, ParameterValue
from sensor_msgs.msg import Image
from std_msgs.msg import Float32
from sweep_node import IMAGE, INTRINSICS, POSE, Live, ParamCase, ProcessCase, RunCase, StartCase
from sweep_verdicts import SILENT
from visualization_msgs.msg import Marker, MarkerArray

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import matrix_to_quaternion
from allo_mrad_ros.ros.messages import fill_camera_info


def start_cases(work: Path) -> list[StartCase | ProcessCase]:
    """Invalid start-up parameters: one line naming the parameter, exit 2."""
    garbage = work / "garbage.yaml"
    garbage.write_text("/**:\n  ros__parameters: [unclosed\n")
    typed = work / "typed.yaml"
    typed.write_text("/**:\n  ros__parameters:\n    mrad:\n      grid: abc\n")
    p = "-p"
    cases = [
        StartCase("mrad.grid 0", (p, "mrad.grid:=0"), r"mrad\.grid .*got 0", quick=True),
        StartCase("reference_scale 0.0", (p, "reference_scale:=0.0"), "reference_scale"),
        StartCase("mrad.tolerance nan", (p, "mrad.tolerance:=.nan"), "mrad.tolerance .*nan"),
        StartCase(
            "diagnostics_period_s 0", (p, "diagnostics_period_s:=0.0"), "diagnostics_period_s"
        ),
        StartCase("mrad.grid abc", (p, "mrad.grid:=abc"), "mrad.grid .*abc", quick=True),
        StartCase("mrad.kernel_fraction 0", (p, "mrad.kernel_fraction:=0.0"), "kernel_fraction"),
        StartCase("sun_direction nan", (p, "sun_direction:=[1e300,1e300,.nan]"), "sun_direction"),
        StartCase("sun_direction zero", (p, "sun_direction:=[0.0,0.0,0.0]"), "sun_direction"),
        StartCase("sun_direction of 2", (p, "sun_direction:=[1.0,2.0]"), "sun_direction"),
        StartCase("pose_source gps", (p, "pose_source:=gps"), "pose_source .*gps"),
        StartCase("image_transport theora", (p, "image_transport:=theora"), "image_transport"),
        StartCase("render_backend vulkan", (p, "render_backend:=vulkan"), "render_backend"),
        StartCase("reference_scale 2", (p, "reference_scale:=2.0"), "reference_scale"),
        StartCase("pose_tolerance_s -1", (p, "pose_tolerance_s:=-1.0"), "pose_tolerance_s"),
        StartCase("tf_timeout_s 100", (p, "tf_timeout_s:=100.0"), "tf_timeout_s"),
        StartCase("sun_strength -1", (p, "sun_strength:=-1.0"), "sun_strength"),
        StartCase("input_timeout_s 0", (p, "input_timeout_s:=0.0"), "input_timeout_s"),
        StartCase("shadows maybe", (p, "shadows:=maybe"), "shadows"),
        StartCase("mrad.grid 1e9", (p, "mrad.grid:=1000000000"), "mrad.grid"),
        StartCase("mrad.grid 4.5", (p, "mrad.grid:=4.5"), "mrad.grid"),
        StartCase("mrad.tolerance inf", (p, "mrad.tolerance:=.inf"), "mrad.tolerance"),
        StartCase("reference_scale abc", (p, "reference_scale:=abc"), "reference_scale"),
        StartCase("missing mesh file", (p, "mesh:=/nonexistent/station.glb"), "mesh"),
        StartCase("params file missing", ("--params-file", str(work / "none.yaml")), "none.yaml"),
        StartCase("params file garbage", ("--params-file", str(garbage)), "garbage.yaml"),
        StartCase("params file grid abc", ("--params-file", str(typed)), "mrad.grid .*abc"),
        StartCase("unknown parameter name", (p, "mrad.gird:=4"), "mrad.gird", starts=True),
    ]
    return cases + process_cases()


def process_cases() -> list[ProcessCase]:
    """Node processes of their own: shutdowns under a 1080p feed, a second signal, and what
    the shipped DDS profile delivers."""
    shutdowns = ("sweep_node_shutdown.py", "shutdowns", "--runs", "10", "--signal")
    return [
        ProcessCase("SIGTERM x10 under a 1080p30 feed", (*shutdowns, "SIGTERM")),
        ProcessCase("SIGINT x10 under a 1080p30 feed", (*shutdowns, "SIGINT")),
        ProcessCase(
            "second SIGINT while a frame is stuck in publishing",
            ("sweep_node_shutdown.py", "second-signal"),
        ),
        ProcessCase(
            "first image of each new larger size (DDS profile)",
            ("dds_sizes.py", "--runs", "3"),
            failure=SILENT,
        ),
    ]


# --- messages ------------------------------------------------------------------------------


def _image(live: Live, stamp: int, **fields) -> Image:
    msg = Image()
    msg.header.frame_id = interface.CAMERA_FRAME
    msg.height, msg.width = IMAGE.shape[:2]
    msg.encoding, msg.step = "rgb8", IMAGE.shape[1] * 3
    data = fields.pop("data", None)
    msg.data = IMAGE.tobytes() if data is None else data
    for key, value in fields.items():
        setattr(msg, key, value)
    return msg


def image(**fields):
    def send(live: Live, stamp: int) -> None:
        live.feed.publish_frame(stamp, None, POSE, image=_image(live, stamp, **fields))

    return send


def pixels(array_: np.ndarray, encoding: str, bytes_per_value: int = 1, big: int = 0):
    def send(live: Live, stamp: int) -> None:
        height, width = array_.shape[:2]
        channels = array_.shape[2] if array_.ndim == 3 else 1
        msg = _image(
            live,
            stamp,
            data=array_.tobytes(),
            encoding=encoding,
            height=height,
            width=width,
            step=width * channels * bytes_per_value,
            is_bigendian=big,
        )
        live.feed.publish_frame(stamp, None, POSE, image=msg)

    return send


def huge_image(live: Live, stamp: int) -> None:
    side = 8000
    msg = _image(live, stamp, data=bytes(side * side * 3), height=side, width=side, step=side * 3)
    for _ in range(3):
        live.feed.publish_frame(stamp, None, POSE, image=msg)
        live.feed.spin(2.0)


def camera_info(**fields):
    def send(live: Live, stamp: int) -> None:
        feed = live.feed
        info = feed.camera_info()
        for key, value in fields.items():
            setattr(info, key, value)
        info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp, 10**9)
        feed.pub_info.publish(info)
        feed.spin(0.2)
        msg = _image(live, stamp)
        msg.header.stamp = info.header.stamp
        _publish_pose(live, stamp, POSE)
        feed.pub_image.publish(msg)

    return send


def _publish_pose(
    live: Live, stamp: int, pose, position=None, quaternion=None, frame=interface.STATION_FRAME
) -> None:
    msg = PoseStamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
    msg.header.frame_id = frame
    p = position if position is not None else pose[:3, 3].tolist()
    q = quaternion if quaternion is not None else matrix_to_quaternion(pose[:3, :3]).tolist()
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = (float(v) for v in p)
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = (float(v) for v in q)
    live.feed.pub_pose.publish(msg)


def pose(position=None, quaternion=None, frame=interface.STATION_FRAME, offset_s=0.0):
    def send(live: Live, stamp: int) -> None:
        if offset_s:
            stamp = live.stamp = stamp + 60 * 10**9  # far from every pose published so far
        _publish_pose(live, stamp + int(offset_s * 1e9), POSE, position, quaternion, frame)
        live.feed.spin(0.1)
        live.feed.publish_frame(stamp, IMAGE, None)

    return send


def sun(vector, frame=interface.STATION_FRAME):
    def send(live: Live, stamp: int) -> None:
        msg = Vector3Stamped()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 10**9)
        msg.header.frame_id = frame
        msg.vector.x, msg.vector.y, msg.vector.z = (float(v) for v in vector)
        live.feed.pub_sun.publish(msg)
        live.feed.spin(0.1)
        live.feed.publish_frame(stamp, IMAGE, POSE, sun=tuple(float(v) for v in vector))

    return send


def sun_strength(value):
    def send(live: Live, stamp: int) -> None:
        publisher = getattr(live, "_strength", None) or live.feed.node.create_publisher(
            Float32, "/" + interface.SUN_STRENGTH_INPUT, 10
        )
        live._strength = publisher
        publisher.publish(Float32(data=float(value)))
        live.feed.spin(0.3)
        live.feed.publish_frame(stamp, IMAGE, POSE)

    return send


def body(position=(1500.0, -800.0, 400.0), diameter=70.0):
    def send(live: Live, stamp: int) -> None:
        publisher = getattr(live, "_bodies", None) or live.feed.node.create_publisher(
            MarkerArray, "/" + interface.BODIES_INPUT, 10
        )
        live._bodies = publisher
        marker = Marker(type=Marker.SPHERE, action=Marker.ADD, ns="earth")
        marker.header.frame_id = interface.STATION_FRAME
        marker.pose.position.x, marker.pose.position.y, marker.pose.position.z = position
        marker.pose.orientation.w = 1.0
        marker.scale.x = marker.scale.y = marker.scale.z = float(diameter)
        publisher.publish(MarkerArray(markers=[marker]))
        live.feed.spin(0.3)
        live.feed.publish_frame(stamp, IMAGE, POSE)

    return send


def run_cases() -> list[RunCase]:
    """Bad messages to the running node."""
    nan, inf = float("nan"), float("inf")
    rgb16 = (IMAGE.astype(np.uint16) * 256).astype(">u2")
    return [
        RunCase(
            "encoding yuv422", image(encoding="yuv422"), "errors_encoding", "yuv422", quick=True
        ),
        RunCase("empty encoding", image(encoding=""), "errors_encoding", "encoding ''"),
        RunCase("encoding bayer_rggb8", image(encoding="bayer_rggb8"), "errors_encoding", "bayer"),
        RunCase("encoding 16UC1", image(encoding="16UC1"), "errors_encoding", "16UC1"),
        RunCase("width 0", image(width=0), "errors_size", "empty"),
        RunCase("height 0", image(height=0), "errors_size", "empty"),
        RunCase(
            "size differs from camera_info",
            pixels(IMAGE[:90, :160], "rgb8"),
            "errors_size",
            "differs from camera_info",
        ),
        RunCase("step too small", image(step=100), "errors_step", "step", quick=True),
        RunCase("data too short", image(data=IMAGE.tobytes()[:-7]), "errors_data", "bytes"),
        RunCase("data too long", image(data=IMAGE.tobytes() + b"extra"), "errors_data", "bytes"),
        RunCase(
            "width 2^31-1 header", image(width=2**31 - 1), "errors_size", "differs from camera_info"
        ),
        RunCase("8000x8000 rgb8 (beyond the segment)", huge_image, rss_bound=True),
        RunCase(
            "4000x4000 rgb8, camera_info 320x180",
            pixels(np.zeros((4000, 4000, 3), np.uint8), "rgb8"),
            "errors_size",
            "differs from camera_info",
        ),
        RunCase("mono8 image", pixels(IMAGE[..., 0], "mono8"), accepted=True),
        RunCase("bgr8 image", pixels(IMAGE, "bgr8"), accepted=True),
        RunCase("rgba8 image", pixels(np.dstack([IMAGE, IMAGE[..., :1]]), "rgba8"), accepted=True),
        RunCase("rgb16 big-endian", pixels(rgb16, "rgb16", 2, 1), accepted=True),
        RunCase("empty frame_id", image(header=_header("")), accepted=True),
        RunCase("frame_id with a slash", image(header=_header("/arm_camera")), accepted=True),
        RunCase("stamp 0 (no pose near)", stamp_zero, "pose_lookup_failures", "no camera pose"),
        RunCase(
            "camera_info width 0",
            camera_info(width=0),
            "errors_camera_info",
            "camera_info",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info width 2^32-1",
            camera_info(width=2**32 - 1),
            "errors_camera_info",
            "4294967295",
            quick=True,
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info K zero",
            camera_info(k=[0.0] * 9),
            "errors_camera_info",
            "camera_info",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info K NaN",
            camera_info(k=[nan] * 9),
            "errors_camera_info",
            "camera_info",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info fx negative",
            camera_info(k=[-222.2, 0.0, 160.0, 0.0, 222.2, 90.0, 0.0, 0.0, 1.0]),
            "errors_camera_info",
            "camera_info",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info cx 1e9",
            camera_info(k=[222.2, 0.0, 1e9, 0.0, 222.2, 90.0, 0.0, 0.0, 1.0]),
            "errors_camera_info|errors_renderer",
            "camera_info|cx",
            either=True,
        ),
        RunCase(
            "camera_info distortion",
            camera_info(d=[0.1, 0.0, 0.0, 0.0, 0.0]),
            "errors_distortion",
            "distortion",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info D NaN",
            camera_info(d=[nan] * 5),
            "errors_distortion",
            "distortion",
            frame_is_bad=False,
        ),
        RunCase(
            "camera_info 640x360 (image 320x180)",
            camera_info(
                width=640, height=360, k=[444.4, 0.0, 320.0, 0.0, 444.4, 180.0, 0.0, 0.0, 1.0]
            ),
            "errors_size",
            "differs from camera_info",
            frame_is_bad=False,
        ),
        RunCase(
            "pose NaN position",
            pose(position=[nan, 0.0, 0.0]),
            "errors_pose|pose_lookup_failures",
            "pose",
            quick=True,
            frame_is_bad=False,
        ),
        RunCase(
            "pose inf position",
            pose(position=[inf, 0.0, 0.0]),
            "errors_pose|pose_lookup_failures",
            "pose",
            frame_is_bad=False,
        ),
        RunCase(
            "pose zero quaternion",
            pose(quaternion=[0.0, 0.0, 0.0, 0.0]),
            "errors_pose|pose_lookup_failures",
            "quaternion",
            frame_is_bad=False,
        ),
        RunCase(
            "pose NaN quaternion",
            pose(quaternion=[nan, 0.0, 0.0, 1.0]),
            "errors_pose|pose_lookup_failures",
            "quaternion",
            frame_is_bad=False,
        ),
        RunCase("pose quaternion of norm 2", pose(quaternion=[0.0, 0.0, 0.0, 2.0]), accepted=True),
        RunCase(
            "pose 1e300 m away",
            pose(position=[1e300, 0.0, 0.0]),
            "errors_.*|pose_lookup_failures",
            "pose|position",
            either=True,
        ),
        RunCase(
            "pose in frame 'map'",
            pose(frame="map"),
            "errors_pose.*|pose_lookup_failures",
            "map",
            frame_is_bad=False,
        ),
        RunCase(
            "pose 1 s off the image", pose(offset_s=1.0), "pose_lookup_failures", "no camera pose"
        ),
        RunCase("sun NaN", sun([nan, 0.0, 1.0]), "errors_sun", "sun direction", frame_is_bad=False),
        RunCase(
            "sun zero vector",
            sun([0.0, 0.0, 0.0]),
            "errors_sun",
            "sun direction",
            quick=True,
            frame_is_bad=False,
        ),
        RunCase("sun inf", sun([inf, 0.0, 0.0]), "errors_sun", "sun direction", frame_is_bad=False),
        RunCase("sun 1e300", sun([1e300, -1e300, 1e300]), accepted=True),
        RunCase(
            "sun in frame 'map'",
            sun([0.0, 0.0, 1.0], frame="map"),
            "errors_sun.*",
            "map",
            frame_is_bad=False,
        ),
        RunCase(
            "sun strength NaN", sun_strength(nan), "errors_sun", "strength", frame_is_bad=False
        ),
        RunCase(
            "sun strength -1", sun_strength(-1.0), "errors_sun", "strength", frame_is_bad=False
        ),
        RunCase(
            "sun strength inf", sun_strength(inf), "errors_sun", "strength", frame_is_bad=False
        ),
        RunCase(
            "body NaN centre",
            body(position=(nan, 0.0, 0.0)),
            "errors_bodies",
            "earth",
            frame_is_bad=False,
        ),
        RunCase(
            "body negative diameter",
            body(diameter=-5.0),
            "errors_bodies",
            "earth",
            frame_is_bad=False,
        ),
        RunCase(
            "body zero diameter", body(diameter=0.0), "errors_bodies", "earth", frame_is_bad=False
        ),
        RunCase("body in frame 'map'", body_in_map, "errors_bodies.*", "map", frame_is_bad=False),
        RunCase(
            "camera 700x3 (grid too fine, not its reference)",
            narrow_camera(700, 3),
            "errors_processing",
            "grid=8 is too fine for the",
        ),
        RunCase(
            "camera 3x700 (grid too fine, not its reference)",
            narrow_camera(3, 700),
            "errors_processing",
            # Logged once per kind: the 700x3 case's line stands for this one.
            "grid=8 is too fine for the",
        ),
        RunCase("camera_info alternating every frame", alternating_camera, rebuilds=400),
    ]


def narrow_camera(width: int, height: int):
    """camera_info and an image of a legal but narrow camera (700x3)."""

    def send(live: Live, stamp: int) -> None:
        focal = 0.8 * max(width, height)
        camera = CameraIntrinsics(width, height, focal, focal, width / 2 - 0.5, height / 2 - 0.5)
        info = fill_camera_info(live.feed.camera_info(), camera, live.feed.frame_id)
        info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp, 10**9)
        pixels = np.full((height, width, 3), 40, np.uint8)
        msg = _image(live, stamp, data=pixels.tobytes(), width=width, height=height)
        msg.step = width * 3
        msg.header.stamp = info.header.stamp
        _publish_pose(live, stamp, POSE)
        live.feed.pub_info.publish(info)
        live.feed.spin(0.2)
        live.feed.pub_image.publish(msg)

    return send


def alternating_camera(live: Live, stamp: int) -> None:
    """camera_info whose focal length alternates every frame: a renderer rebuild each."""
    fx = INTRINSICS.fx + 0.1 * ((stamp // 10**7) % 2)
    camera = CameraIntrinsics(INTRINSICS.width, INTRINSICS.height, fx, fx, 160.0, 90.0)
    feed = live.feed
    info = fill_camera_info(feed.camera_info(), camera, feed.frame_id)
    info.header.stamp.sec, info.header.stamp.nanosec = divmod(stamp, 10**9)
    msg = _image(live, stamp)
    msg.header.stamp = info.header.stamp
    _publish_pose(live, stamp, POSE)
    feed.pub_info.publish(info)
    feed.pub_image.publish(msg)


def _header(frame_id: str):
    from std_msgs.msg import Header

    return Header(frame_id=frame_id)


def stamp_zero(live: Live, stamp: int) -> None:
    live.feed.pub_info.publish(live.feed.camera_info())  # paired by stamp: its own, 0
    live.feed.spin(0.1)
    msg = _image(live, 0)
    live.feed.pub_image.publish(msg)  # stamp 0: no pose was published near it


def body_in_map(live: Live, stamp: int) -> None:
    publisher = getattr(live, "_bodies", None) or live.feed.node.create_publisher(
        MarkerArray, "/" + interface.BODIES_INPUT, 10
    )
    live._bodies = publisher
    marker = Marker(type=Marker.SPHERE, action=Marker.ADD, ns="moon")
    marker.header.frame_id = "map"
    marker.pose.orientation.w = 1.0
    marker.pose.position.x = 300.0
    marker.scale.x = 20.0
    publisher.publish(MarkerArray(markers=[marker]))
    live.feed.spin(0.3)
    live.feed.publish_frame(stamp, IMAGE, POSE)


def _value(kind: str, value) -> ParameterValue:
    types = {
        "int": (ParameterType.PARAMETER_INTEGER, "integer_value"),
        "double": (ParameterType.PARAMETER_DOUBLE, "double_value"),
        "string": (ParameterType.PARAMETER_STRING, "string_value"),
        "doubles": (ParameterType.PARAMETER_DOUBLE_ARRAY, "double_array_value"),
    }
    code, field_name = types[kind]
    return ParameterValue(type=code, **{field_name: value})


def param_cases() -> list[ParamCase]:
    """Parameter changes while running."""
    nan = float("nan")
    return [
        ParamCase("mrad.grid 0", "mrad.grid", _value("int", 0), "mrad.grid", quick=True),
        ParamCase("mrad.grid as a string", "mrad.grid", _value("string", "abc"), "mrad.grid|type"),
        ParamCase("mrad.tolerance nan", "mrad.tolerance", _value("double", nan), "mrad.tolerance"),
        ParamCase(
            "mrad.kernel_fraction 0",
            "mrad.kernel_fraction",
            _value("double", 0.0),
            "kernel_fraction",
        ),
        ParamCase(
            "read-only reference_scale",
            "reference_scale",
            _value("double", 0.5),
            "read-only|read only",
        ),
        ParamCase(
            "read-only pose_source", "pose_source", _value("string", "tf"), "read-only|read only"
        ),
        ParamCase(
            "sun_direction zero", "sun_direction", _value("doubles", [0.0, 0.0, 0.0]), "zero"
        ),
        ParamCase(
            "sun_direction NaN", "sun_direction", _value("doubles", [nan, 1.0, 0.0]), "finite"
        ),
        ParamCase("sun_direction of 2", "sun_direction", _value("doubles", [1.0, 0.0]), "3"),
        ParamCase("sun_strength -1", "sun_strength", _value("double", -1.0), "sun_strength"),
        ParamCase(
            "undeclared parameter", "mrad.gird", _value("int", 4), "gird|not declared|undeclared"
        ),
        ParamCase(
            "sun_direction [0, 2, 0]",
            "sun_direction",
            _value("doubles", array.array("d", [0.0, 2.0, 0.0])),
            accepted=True,
        ),
        ParamCase(
            "sun_direction 1e300",
            "sun_direction",
            _value("doubles", [1e300, 1e300, 0.0]),
            accepted=True,
        ),
    ]
