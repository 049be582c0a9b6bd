"""Conversions between ROS messages and the arrays and poses the detector uses.

Functions here take and return message *objects* duck-typed on their fields, so they work
with rclpy messages and with ``rosbags`` messages alike, and are testable without DDS.
"""

from __future__ import annotations

import array
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.geometry import PoseError, pose_matrix, unit_vector
from allo_mrad_ros.render import CelestialBody

# Encodings the node accepts for the camera image: name -> (channels, dtype, OpenCV
# conversion to RGB or None). cv2.cvtColor converts in one pass, where a NumPy channel
# index would gather into a temporary and copy again.
_COLOUR_ENCODINGS: dict[str, tuple[int, np.dtype, int | None]] = {
    "rgb8": (3, np.dtype(np.uint8), None),
    "bgr8": (3, np.dtype(np.uint8), cv2.COLOR_BGR2RGB),
    "rgba8": (4, np.dtype(np.uint8), cv2.COLOR_RGBA2RGB),
    "bgra8": (4, np.dtype(np.uint8), cv2.COLOR_BGRA2RGB),
    "mono8": (1, np.dtype(np.uint8), None),
    "rgb16": (3, np.dtype(">u2"), None),
    "bgr16": (3, np.dtype(">u2"), cv2.COLOR_BGR2RGB),
    "rgba16": (4, np.dtype(">u2"), cv2.COLOR_RGBA2RGB),
    "bgra16": (4, np.dtype(">u2"), cv2.COLOR_BGRA2RGB),
    "mono16": (1, np.dtype(">u2"), None),
}
# Raw sensor encodings a camera driver may send that need a debayering or colour
# conversion node in front (image_proc's debayer node, as in ``image_proc`` launch files).
_NEEDS_IMAGE_PROC = {"yuv422", "yuv422_yuy2", "uyvy", "yuyv", "nv21", "nv24"}


class MessageError(InvalidInput):
    """A message cannot be converted; ``cause`` groups errors for once-per-cause logging."""

    def __init__(self, cause: str, message: str) -> None:
        super().__init__(message)
        self.cause = cause


def _decode(msg: Any, expected_size: tuple[int, int] | None) -> np.ndarray:
    """H x W x C pixels of a ``sensor_msgs/Image`` in RGB order, native byte order."""
    encoding = str(msg.encoding).lower()
    if encoding.startswith("bayer_") or encoding in _NEEDS_IMAGE_PROC:
        raise MessageError(
            "encoding",
            f"image encoding {msg.encoding!r} is a raw sensor format: put image_proc's debayer "
            "node (image_proc::DebayerNode, output image_color) in front and feed its "
            "image_color",
        )
    if encoding not in _COLOUR_ENCODINGS:
        raise MessageError(
            "encoding",
            f"image encoding {msg.encoding!r} is not supported; "
            f"use one of {sorted(_COLOUR_ENCODINGS)}",
        )
    channels, dtype, conversion = _COLOUR_ENCODINGS[encoding]
    width, height = int(msg.width), int(msg.height)
    if width <= 0 or height <= 0:
        raise MessageError("size", f"image size {width}x{height} is empty")
    check_size(width, height, expected_size)
    row_bytes = width * channels * dtype.itemsize
    step = int(msg.step)
    if step < row_bytes:
        raise MessageError(
            "step", f"image step {step} is smaller than width x pixel size = {row_bytes} bytes"
        )
    data = np.frombuffer(msg.data, dtype=np.uint8)
    if data.size != step * height:
        raise MessageError(
            "data", f"image data has {data.size} bytes, expected step x height = {step * height}"
        )
    if dtype.itemsize == 2 and not msg.is_bigendian:
        dtype = dtype.newbyteorder("<")
    rows = data.reshape(height, step)[:, :row_bytes]
    if conversion is not None and dtype.itemsize == 1:
        # OpenCV reads the padded rows in place and writes one new image.
        return cv2.cvtColor(rows.reshape(height, width, channels), conversion)
    pixels = np.ascontiguousarray(rows).view(dtype).reshape(height, width, channels)
    if pixels.dtype.byteorder not in ("=", "|"):
        pixels = pixels.astype(pixels.dtype.newbyteorder("="))
    if conversion is not None:
        return cv2.cvtColor(pixels, conversion)
    return pixels


def check_size(width: int, height: int, expected_size: tuple[int, int] | None) -> None:
    """Refuse an image whose size differs from its camera_info's (``expected_size``, width
    and height; None: nothing to compare with)."""
    if expected_size is not None and (width, height) != tuple(expected_size):
        raise MessageError(
            "size",
            f"image size {width}x{height} differs from camera_info "
            f"{expected_size[0]}x{expected_size[1]}",
        )


def _decode_compressed(msg: Any, expected_size: tuple[int, int] | None) -> np.ndarray:
    """H x W x C pixels (RGB order) of a ``sensor_msgs/CompressedImage``, jpeg or png.

    ``format`` follows image_transport: ``"rgb8; jpeg compressed bgr8"``, or just ``"png"``.
    The compressed file holds the standard channel order whatever the original encoding.
    """
    text = str(msg.format).lower()
    if "compresseddepth" in text or not ("jpeg" in text or "jpg" in text or "png" in text):
        raise MessageError(
            "encoding",
            f"compressed image format {msg.format!r} is not supported; use jpeg or png "
            "(image_transport 'compressed')",
        )
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    pixels = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if pixels is None:
        raise MessageError(
            "data", f"compressed image ({msg.format!r}, {data.size} bytes) cannot be decoded"
        )
    check_size(pixels.shape[1], pixels.shape[0], expected_size)
    if pixels.ndim == 2:
        return pixels[..., None]
    return cv2.cvtColor(pixels, cv2.COLOR_BGRA2RGB if pixels.shape[2] == 4 else cv2.COLOR_BGR2RGB)


def is_compressed(msg: Any) -> bool:
    """Whether ``msg`` is a ``sensor_msgs/CompressedImage`` (it has ``format``, no ``encoding``)."""
    return hasattr(msg, "format") and not hasattr(msg, "encoding")


def image_to_rgb(msg: Any, expected_size: tuple[int, int] | None = None) -> np.ndarray:
    """Decode a ``sensor_msgs/Image`` or ``CompressedImage`` into H x W x 3 RGB (uint8/uint16).

    Parameters
    ----------
    msg : sensor_msgs/Image or sensor_msgs/CompressedImage
        The camera image; compressed ones jpeg or png (image_transport ``compressed``).
    expected_size : (width, height), optional
        The size announced by ``camera_info``; a different size is an error.

    Raises
    ------
    MessageError
        With ``cause`` ``encoding``, ``size``, ``step`` or ``data`` and a message that
        names the field and the values.
    """
    pixels = (
        _decode_compressed(msg, expected_size)
        if is_compressed(msg)
        else _decode(msg, expected_size)
    )
    if pixels.shape[2] == 1:
        return cv2.cvtColor(pixels, cv2.COLOR_GRAY2RGB)
    return np.ascontiguousarray(pixels)


def image_to_array(msg: Any) -> np.ndarray:
    """Decode a ``sensor_msgs/Image`` keeping its channels: H x W for mono, else H x W x 3 RGB.

    Raises
    ------
    MessageError
        As :func:`image_to_rgb`.
    """
    pixels = _decode_compressed(msg, None) if is_compressed(msg) else _decode(msg, None)
    if pixels.shape[2] == 1:
        return np.ascontiguousarray(pixels[..., 0])
    return np.ascontiguousarray(pixels)


def fill_image(msg: Any, header: Any, pixels: np.ndarray, encoding: str) -> Any:
    """Fill a ``sensor_msgs/Image`` with an array (uint8 mono/rgb, or float32 32FC1).

    ``header`` is copied into the message unless it is None.
    """
    pixels = np.ascontiguousarray(pixels)
    if header is not None:
        msg.header = header
    msg.height, msg.width = int(pixels.shape[0]), int(pixels.shape[1])
    msg.encoding = encoding
    msg.is_bigendian = 0
    msg.step = int(pixels.strides[0])
    buffer = array.array("B")
    # frombytes on a memoryview is a memcpy; assigning bytes makes rclpy convert per element.
    buffer.frombytes(memoryview(pixels).cast("B"))
    msg.data = buffer
    return msg


def intrinsics_from_camera_info(msg: Any) -> CameraIntrinsics:
    """The pinhole intrinsics of a ``sensor_msgs/CameraInfo`` (``k``; distortion ignored).

    Raises
    ------
    MessageError
        With cause ``camera_info`` for a zero size or a non-positive focal length.
    """
    return _pinhole(msg, "k", 3)


def _pinhole(msg: Any, matrix: str, columns: int) -> CameraIntrinsics:
    """Intrinsics from the row-major ``K`` (3 columns) or ``P`` (4 columns) of a CameraInfo."""
    m = np.asarray(getattr(msg, matrix), dtype=np.float64)
    try:
        return CameraIntrinsics(
            width=int(msg.width),
            height=int(msg.height),
            fx=float(m[0]),
            fy=float(m[columns + 1]),
            cx=float(m[2]),
            cy=float(m[columns + 2]),
        )
    except (ValueError, IndexError) as error:
        raise MessageError(
            "camera_info", f"camera_info {matrix.upper()} is unusable: {error}"
        ) from error


def camera_intrinsics(msg: Any, rectified: bool) -> CameraIntrinsics:
    """The pinhole camera the reference is rendered for, from a ``sensor_msgs/CameraInfo``.

    The reference is a distortion-free render. ``rectified`` (the image is ``image_rect``):
    the rectified camera ``P``. Otherwise ``K``, and only if ``D`` is all zero: a distorted
    ``image_raw`` would be compared with an undistorted reference.

    Raises
    ------
    MessageError
        Cause ``distortion`` for non-zero ``D`` on a raw image, ``camera_info`` for an
        unusable one.
    """
    d = np.asarray(msg.d, dtype=np.float64)
    distorted = bool(d.size and (not np.isfinite(d).all() or np.any(d != 0.0)))
    if rectified:
        return _binned(msg, _pinhole(msg, "p", 4), distorted)
    if distorted:
        raise MessageError(
            "distortion",
            f"camera_info has distortion ({msg.distortion_model}, D={d.tolist()}) but the "
            "reference is an undistorted render: feed the rectified image (image_proc's "
            "image_rect, e.g. image_topic:=image_rect) and set rectified_input:=true",
        )
    return _binned(msg, intrinsics_from_camera_info(msg), False)


def _binned(msg: Any, full: CameraIntrinsics, distorted_rectified: bool) -> CameraIntrinsics:
    """The camera of the image actually sent: ``full`` (the calibrated full resolution)
    cropped to ``roi`` and divided by ``binning_x/y``, as image_geometry's
    PinholeCameraModel does (binning 0 means 1; an all-zero ROI is the full image).

    Raises
    ------
    MessageError
        Cause ``camera_info`` for an ROI outside the image, and for an ROI on a rectified
        image of a distorted camera (its rectified ROI is not the raw one: not supported).
    """
    binning_x = int(getattr(msg, "binning_x", 0) or 1)
    binning_y = int(getattr(msg, "binning_y", 0) or 1)
    roi = getattr(msg, "roi", None)
    x, y, width, height = (
        (0, 0, 0, 0)
        if roi is None
        else (int(roi.x_offset), int(roi.y_offset), int(roi.width), int(roi.height))
    )
    has_roi = (x, y, width, height) != (0, 0, 0, 0)
    if not has_roi and binning_x == binning_y == 1:
        return full
    if has_roi and distorted_rectified:
        raise MessageError(
            "camera_info",
            "camera_info has an ROI and distortion with rectified_input: the rectified ROI "
            "differs from the raw one and is not supported; send the full image",
        )
    if not has_roi:
        width, height = full.width, full.height
    if width <= 0 or height <= 0 or x + width > full.width or y + height > full.height:
        raise MessageError(
            "camera_info",
            f"camera_info ROI {width}x{height}+{x}+{y} lies outside the "
            f"{full.width}x{full.height} image",
        )
    try:
        return CameraIntrinsics(
            width=width // binning_x,
            height=height // binning_y,
            fx=full.fx / binning_x,
            fy=full.fy / binning_y,
            cx=(full.cx - x) / binning_x,
            cy=(full.cy - y) / binning_y,
        )
    except ValueError as error:
        raise MessageError("camera_info", f"camera_info binning/ROI is unusable: {error}") from None


def fill_camera_info(msg: Any, intrinsics: CameraIntrinsics, frame_id: str = "") -> Any:
    """Fill a ``sensor_msgs/CameraInfo`` for a distortion-free pinhole camera."""
    k = intrinsics
    msg.width, msg.height = k.width, k.height
    msg.distortion_model = "plumb_bob"
    msg.d = [0.0] * 5
    msg.k = [k.fx, 0.0, k.cx, 0.0, k.fy, k.cy, 0.0, 0.0, 1.0]
    msg.r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    msg.p = [k.fx, 0.0, k.cx, 0.0, 0.0, k.fy, k.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    msg.header.frame_id = frame_id
    return msg


def scaled_camera_info(
    msg: Any, source: Any, image_size: tuple[int, int], size: tuple[int, int]
) -> Any:
    """Fill ``msg`` with the ``sensor_msgs/CameraInfo`` ``source`` describing a ``size``
    (width, height) resampling of its ``image_size`` image, as image_proc's resize node
    publishes a scaled image's camera_info.

    Like image_proc: ``K`` and ``P`` are scaled per axis by the ratio of the actual sizes
    (``Tx``, ``Ty`` with them), the ROI's offsets scaled, binning, ``D``, ``R`` and the
    distortion model kept. Unlike image_proc, which multiplies ``cx``, ``cy`` by the ratio,
    the principal point keeps the pixel-centre convention of OpenCV's resampling (as
    :meth:`~allo_mrad_ros.camera.CameraIntrinsics.scaled` does for the reference): a 4x
    smaller map moves it by 0.375 pixel. The ROI's size is the new image's times the
    binning, and the principal point is set so that image_geometry's model of ``msg``
    (ROI crop, then binning) is the camera of the resampled image exactly. The same
    ``size`` as ``image_size`` copies ``source`` unchanged. ``msg.header`` is left alone.
    """
    width, height = (int(v) for v in image_size)
    new_width, new_height = (int(v) for v in size)
    if width <= 0 or height <= 0 or new_width <= 0 or new_height <= 0:
        raise ValueError(f"image sizes must be positive, got {image_size} and {size}")
    msg.distortion_model = source.distortion_model
    msg.d = list(source.d)
    msg.r = list(source.r)
    msg.binning_x, msg.binning_y = int(source.binning_x), int(source.binning_y)
    msg.roi.do_rectify = bool(source.roi.do_rectify)
    k, p = [float(v) for v in source.k], [float(v) for v in source.p]
    if (new_width, new_height) == (width, height):
        msg.width, msg.height = int(source.width), int(source.height)
        msg.k, msg.p = k, p
        roi = source.roi
        msg.roi.x_offset, msg.roi.y_offset = int(roi.x_offset), int(roi.y_offset)
        msg.roi.width, msg.roi.height = int(roi.width), int(roi.height)
        return msg
    binning = (int(source.binning_x) or 1, int(source.binning_y) or 1)
    roi = source.roi
    offsets = (int(roi.x_offset), int(roi.y_offset))
    has_roi = (*offsets, int(roi.width), int(roi.height)) != (0, 0, 0, 0)
    ratios = (new_width / width, new_height / height)
    new_offsets = tuple(round(o * r) for o, r in zip(offsets, ratios, strict=True))
    new_sizes = (new_width, new_height)
    calibrated = (int(source.width), int(source.height))
    for axis, (f_index, c_index) in enumerate(((0, 2), (4, 5))):
        b, r, o, o_new = binning[axis], ratios[axis], offsets[axis], new_offsets[axis]
        for matrix, (f, c, t) in (
            (k, (f_index, c_index, None)),
            (p, (f_index + axis, c_index + axis, 3 + 4 * axis)),
        ):
            matrix[f] *= r
            # The image's principal point (image_geometry: crop, then bin), moved to the
            # resampled image's pixel centres, then back into the calibrated frame.
            matrix[c] = b * (((matrix[c] - o) / b + 0.5) * r - 0.5) + o_new
            if t is not None:
                matrix[t] *= r
    msg.k, msg.p = k, p
    if has_roi:
        msg.roi.x_offset, msg.roi.y_offset = new_offsets
        msg.roi.width, msg.roi.height = new_width * binning[0], new_height * binning[1]
        msg.width = max(round(calibrated[0] * ratios[0]), new_offsets[0] + msg.roi.width)
        msg.height = max(round(calibrated[1] * ratios[1]), new_offsets[1] + msg.roi.height)
    else:
        msg.roi.x_offset = msg.roi.y_offset = msg.roi.width = msg.roi.height = 0
        msg.width, msg.height = (n * b for n, b in zip(new_sizes, binning, strict=True))
    return msg


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds of a ``builtin_interfaces/Time``."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def _matrix(position: Any, rotation: Any, what: str) -> np.ndarray:
    try:
        return pose_matrix(
            [position.x, position.y, position.z], [rotation.x, rotation.y, rotation.z, rotation.w]
        )
    except PoseError as error:
        raise MessageError("pose", f"{what} is invalid: {error}") from error


def pose_to_matrix(pose: Any) -> np.ndarray:
    """The 4x4 transform of a ``geometry_msgs/Pose`` (raises MessageError ``pose``)."""
    return _matrix(pose.position, pose.orientation, "pose")


def transform_to_matrix(transform: Any) -> np.ndarray:
    """The 4x4 transform of a ``geometry_msgs/Transform``."""
    return _matrix(transform.translation, transform.rotation, "transform")


def vector_to_direction(vector: Any) -> np.ndarray:
    """A unit vector from a ``geometry_msgs/Vector3`` (raises MessageError ``sun``)."""
    v = np.array([vector.x, vector.y, vector.z], dtype=np.float64)
    try:
        return unit_vector(v, "sun direction")
    except PoseError:
        raise MessageError(
            "sun", f"sun direction {v.tolist()} is not a finite non-zero vector"
        ) from None


def markers_to_bodies(markers: Sequence[Any]) -> list[CelestialBody]:
    """Celestial bodies from SPHERE markers (``ns`` = body name, scale.x = diameter).

    Markers of other types, or with action DELETE, are ignored.
    """
    bodies = []
    for marker in markers:
        if int(marker.type) != interface.MARKER_SPHERE or int(marker.action) not in (
            interface.MARKER_ADD,
            interface.MARKER_MODIFY,
        ):
            continue
        p = marker.pose.position
        try:
            bodies.append(
                CelestialBody(
                    name=str(marker.ns), centre=(p.x, p.y, p.z), radius=marker.scale.x / 2
                )
            )
        except ValueError as error:
            raise MessageError("bodies", f"celestial body {marker.ns!r}: {error}") from error
    return bodies


# Largest image side the node accepts: OpenGL implementations (OSMesa, EGL) render at most
# 16384 pixels per side, and an image this size is already 800 MB of rgb8.
MAX_IMAGE_SIDE = 16384


def check_camera_size(intrinsics: CameraIntrinsics) -> CameraIntrinsics:
    """``intrinsics`` unchanged if a camera of this size can be rendered and received.

    Raises
    ------
    MessageError
        With cause ``camera_info``, naming the size and the limit.
    """
    if max(intrinsics.width, intrinsics.height) > MAX_IMAGE_SIDE:
        raise MessageError(
            "camera_info",
            f"camera_info size {intrinsics.width}x{intrinsics.height} is impossible: at most "
            f"{MAX_IMAGE_SIDE} pixels per side",
        )
    return intrinsics
