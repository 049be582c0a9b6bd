"""ROS message conversions without DDS: message objects are plain namespaces with the fields."""

from __future__ import annotations

import array
from types import SimpleNamespace as Msg

import numpy as np
import pytest

from allo_mrad_ros import interface
from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import pose_matrix
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.messages import MessageError


def _image(pixels: np.ndarray, encoding: str, step_pad: int = 0, bigendian: bool = False):
    height, width = pixels.shape[:2]
    rows = pixels.reshape(height, -1).view(np.uint8)
    padded = np.zeros((height, rows.shape[1] + step_pad), np.uint8)
    padded[:, : rows.shape[1]] = rows
    return Msg(
        encoding=encoding,
        width=width,
        height=height,
        step=padded.shape[1],
        is_bigendian=bigendian,
        data=padded.tobytes(),
    )


RNG = np.random.default_rng(3)
RGB = RNG.integers(0, 256, (5, 7, 3), dtype=np.uint8)


@pytest.mark.parametrize(
    ("encoding", "pixels", "expected"),
    [
        ("rgb8", RGB, RGB),
        ("bgr8", RGB[..., ::-1].copy(), RGB),
        ("rgba8", np.dstack([RGB, np.full((5, 7), 9, np.uint8)]), RGB),
        ("bgra8", np.dstack([RGB[..., ::-1], np.full((5, 7), 9, np.uint8)]), RGB),
        ("mono8", RGB[..., :1].copy(), np.repeat(RGB[..., :1], 3, axis=2)),
    ],
)
def test_colour_encodings_decode_to_rgb_with_row_padding(encoding, pixels, expected):
    decoded = messages.image_to_rgb(_image(pixels, encoding, step_pad=3), (7, 5))
    np.testing.assert_array_equal(decoded, expected)
    assert decoded.flags.c_contiguous


def test_sixteen_bit_images_honour_the_byte_order():
    values = RNG.integers(0, 65536, (4, 6, 3)).astype(np.uint16)
    big = _image(values.astype(">u2"), "rgb16", bigendian=True)
    little = _image(values.astype("<u2"), "rgb16", bigendian=False)
    for msg in (big, little):
        decoded = messages.image_to_rgb(msg)
        np.testing.assert_array_equal(decoded, values)
        assert decoded.dtype.byteorder in ("=", "|")


def test_image_to_array_keeps_mono_two_dimensional():
    mask = RNG.integers(0, 3, (5, 7), dtype=np.uint8)
    np.testing.assert_array_equal(messages.image_to_array(_image(mask[..., None], "mono8")), mask)
    assert messages.image_to_array(_image(RGB, "rgb8")).shape == (5, 7, 3)


@pytest.mark.parametrize(
    ("change", "cause"),
    [
        ({"encoding": "yuv422"}, "encoding"),
        ({"width": 0}, "size"),
        ({"step": 3}, "step"),
        ({"data": b"\x00" * 10}, "data"),
    ],
)
def test_malformed_images_name_the_field(change, cause):
    msg = _image(RGB, "rgb8")
    for key, value in change.items():
        setattr(msg, key, value)
    with pytest.raises(MessageError) as error:
        messages.image_to_rgb(msg)
    assert error.value.cause == cause


def test_size_other_than_camera_info_is_refused():
    with pytest.raises(MessageError, match="differs from camera_info 8x5"):
        messages.image_to_rgb(_image(RGB, "rgb8"), (8, 5))


def test_fill_image_round_trips_and_keeps_the_header():
    header = Msg(frame_id="cam")
    msg = messages.fill_image(Msg(), header, RGB, interface.RGB8)
    assert msg.header is header and msg.step == 21 and isinstance(msg.data, array.array)
    np.testing.assert_array_equal(messages.image_to_rgb(msg), RGB)
    score = RNG.random((3, 4)).astype(np.float32)
    filled = messages.fill_image(Msg(), None, score, interface.SCORE_ENCODING)
    restored = np.frombuffer(filled.data, np.float32).reshape(3, 4)
    np.testing.assert_array_equal(restored, score)


def test_camera_info_round_trip_and_bad_intrinsics():
    camera = CameraIntrinsics(640, 480, 500.0, 510.0, 319.5, 239.5)
    msg = messages.fill_camera_info(Msg(header=Msg()), camera, "cam")
    assert messages.intrinsics_from_camera_info(msg) == camera and msg.header.frame_id == "cam"
    msg.k = [0.0] * 9
    with pytest.raises(MessageError, match="camera_info") as error:
        messages.intrinsics_from_camera_info(msg)
    assert error.value.cause == "camera_info"


def _xyz(x, y, z):
    return Msg(x=x, y=y, z=z)


def test_poses_and_transforms_give_the_same_matrix():
    position, quaternion = (1.0, -2.0, 3.0), (0.1, 0.2, 0.3, 0.9)
    expected = pose_matrix(position, quaternion)
    q = Msg(x=quaternion[0], y=quaternion[1], z=quaternion[2], w=quaternion[3])
    pose = Msg(position=_xyz(*position), orientation=q)
    transform = Msg(translation=_xyz(*position), rotation=q)
    np.testing.assert_allclose(messages.pose_to_matrix(pose), expected)
    np.testing.assert_allclose(messages.transform_to_matrix(transform), expected)
    bad = Msg(position=_xyz(*position), orientation=Msg(x=0.0, y=0.0, z=0.0, w=0.0))
    with pytest.raises(MessageError, match="pose is invalid") as error:
        messages.pose_to_matrix(bad)
    assert error.value.cause == "pose"


def test_sun_vector_is_normalised_and_zero_is_refused():
    np.testing.assert_allclose(messages.vector_to_direction(_xyz(0.0, 3.0, 4.0)), [0, 0.6, 0.8])
    for vector in (_xyz(0.0, 0.0, 0.0), _xyz(float("nan"), 1.0, 0.0)):
        with pytest.raises(MessageError, match="sun direction"):
            messages.vector_to_direction(vector)


def _marker(ns, kind=interface.MARKER_SPHERE, action=interface.MARKER_ADD, diameter=2.0):
    return Msg(
        ns=ns,
        type=kind,
        action=action,
        pose=Msg(position=_xyz(1.0, 2.0, 3.0)),
        scale=_xyz(diameter, diameter, diameter),
    )


def test_sphere_markers_become_bodies_and_others_are_ignored():
    markers = [
        _marker("earth"),
        _marker("moon", action=interface.MARKER_DELETE),
        _marker("cube", kind=1),
        _marker("sun", action=interface.MARKER_MODIFY, diameter=4.0),
    ]
    bodies = messages.markers_to_bodies(markers)
    assert [(b.name, b.centre, b.radius) for b in bodies] == [
        ("earth", (1.0, 2.0, 3.0), 1.0),
        ("sun", (1.0, 2.0, 3.0), 2.0),
    ]
    with pytest.raises(MessageError, match="'moon'") as error:
        messages.markers_to_bodies([_marker("moon", diameter=-1.0)])
    assert error.value.cause == "bodies"


def test_stamp_to_ns():
    assert messages.stamp_to_ns(Msg(sec=3, nanosec=7)) == 3_000_000_007


def _compressed(pixels: np.ndarray, extension: str, format_text: str):
    import cv2

    bgr = pixels[..., ::-1] if pixels.ndim == 3 else pixels
    ok, data = cv2.imencode(extension, np.ascontiguousarray(bgr))
    assert ok
    return Msg(format=format_text, data=data.tobytes())


def test_png_compressed_images_decode_exactly_to_rgb():
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (12, 20, 3), dtype=np.uint8)
    msg = _compressed(rgb, ".png", "rgb8; png compressed bgr8")
    np.testing.assert_array_equal(messages.image_to_rgb(msg, (20, 12)), rgb)
    mono = rng.integers(0, 256, (12, 20), dtype=np.uint8)
    decoded = messages.image_to_rgb(_compressed(mono, ".png", "mono8; png compressed mono8"))
    np.testing.assert_array_equal(decoded, np.repeat(mono[..., None], 3, axis=2))
    deep = rng.integers(0, 65536, (12, 20, 3), dtype=np.uint16)
    decoded = messages.image_to_rgb(_compressed(deep, ".png", "rgb16; png compressed bgr16"))
    assert decoded.dtype == np.uint16
    np.testing.assert_array_equal(decoded, deep)


def test_jpeg_compressed_images_decode_close_to_rgb_in_channel_order():
    rgb = np.zeros((32, 48, 3), np.uint8)
    rgb[..., 0] = 200  # red: a swapped channel order would give blue
    rgb[:, 24:, 1] = 120
    decoded = messages.image_to_rgb(_compressed(rgb, ".jpg", "bgr8; jpeg compressed bgr8"))
    assert decoded.shape == rgb.shape
    assert np.abs(decoded.astype(int) - rgb).mean() < 3  # lossy, ringing at the edge


@pytest.mark.parametrize(
    ("msg", "cause", "text"),
    [
        (Msg(format="16UC1; compressedDepth png", data=b"\x00"), "encoding", "compressedDepth"),
        (Msg(format="tiff", data=b"\x00"), "encoding", "use jpeg or png"),
        (Msg(format="png", data=b"not a png"), "data", "cannot be decoded"),
    ],
)
def test_unsupported_or_corrupt_compressed_images_are_refused(msg, cause, text):
    with pytest.raises(MessageError, match=text) as caught:
        messages.image_to_rgb(msg)
    assert caught.value.cause == cause


def test_compressed_image_of_another_size_than_camera_info_is_refused():
    msg = _compressed(np.zeros((10, 10, 3), np.uint8), ".png", "png")
    with pytest.raises(MessageError, match="10x10 differs from camera_info 20x10"):
        messages.image_to_rgb(msg, (20, 10))


def _plumb_bob(d):
    k = CameraIntrinsics(640, 480, 500.0, 502.0, 320.5, 240.5)
    info = messages.fill_camera_info(Msg(header=Msg()), k)
    info.d = list(d)
    # The rectified camera of image_proc: another focal length and principal point.
    info.p = [480.0, 0.0, 318.0, 0.0, 0.0, 481.0, 242.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    return info


def test_plumb_bob_camera_with_distortion_is_refused_for_raw_images():
    info = _plumb_bob([-0.28, 0.07, 0.0002, -0.0001, 0.0])
    with pytest.raises(MessageError, match=r"image_rect.*rectified_input:=true") as caught:
        messages.camera_intrinsics(info, rectified=False)
    assert caught.value.cause == "distortion"
    assert "plumb_bob" in str(caught.value)


def test_plumb_bob_camera_rectified_uses_p_and_zero_distortion_uses_k():
    rectified = messages.camera_intrinsics(_plumb_bob([-0.28, 0.07, 0.0, 0.0, 0.0]), rectified=True)
    assert (rectified.fx, rectified.fy, rectified.cx, rectified.cy) == (480.0, 481.0, 318.0, 242.0)
    raw = messages.camera_intrinsics(_plumb_bob([0.0] * 5), rectified=False)
    assert (raw.fx, raw.fy, raw.cx, raw.cy) == (500.0, 502.0, 320.5, 240.5)


def _info(width, height, k, p=None, binning=(0, 0), roi=(0, 0, 0, 0), d=(0.0,) * 5):
    """A CameraInfo stand-in with every field scaled_camera_info reads."""
    x, y, w, h = roi
    return Msg(
        header=Msg(),
        width=width,
        height=height,
        distortion_model="plumb_bob",
        d=list(d),
        k=list(k),
        r=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
        p=list(p if p is not None else [k[0], 0.0, k[2], 0.0, 0.0, k[4], k[5], 0.0, 0, 0, 1, 0]),
        binning_x=binning[0],
        binning_y=binning[1],
        roi=Msg(x_offset=x, y_offset=y, width=w, height=h, do_rectify=False),
    )


def _target():
    return Msg(header=Msg(), roi=Msg())


def test_scaled_camera_info_of_a_quarter_size_map():
    k = [1333.0, 0.0, 959.5, 0.0, 1340.0, 539.5, 0.0, 0.0, 1.0]
    p = [1300.0, 0.0, 950.0, -130.0, 0.0, 1310.0, 540.0, 2.0, 0.0, 0.0, 1.0, 0.0]
    source = _info(1920, 1080, k, p)
    info = messages.scaled_camera_info(_target(), source, (1920, 1080), (480, 270))
    assert (info.width, info.height) == (480, 270)
    # Written out by hand: f / 4; pixel centres kept, c' = (c + 0.5) / 4 - 0.5; Tx, Ty / 4.
    assert info.k == [333.25, 0.0, 239.5, 0.0, 335.0, 134.5, 0.0, 0.0, 1.0]
    assert info.p == [325.0, 0.0, 237.125, -32.5, 0.0, 327.5, 134.625, 0.5, 0.0, 0.0, 1.0, 0.0]
    assert info.d == source.d and info.r == source.r and info.distortion_model == "plumb_bob"
    assert (info.binning_x, info.binning_y) == (0, 0)
    assert (info.roi.x_offset, info.roi.y_offset, info.roi.width, info.roi.height) == (0, 0, 0, 0)


def test_scaled_camera_info_to_the_same_size_is_a_copy():
    k = [500.0, 0.0, 100.0, 0.0, 500.0, 80.0, 0.0, 0.0, 1.0]
    source = _info(400, 300, k, binning=(2, 2), roi=(10, 20, 200, 120))
    info = messages.scaled_camera_info(_target(), source, (100, 60), (100, 60))
    assert (info.width, info.height, info.k, info.p) == (400, 300, source.k, source.p)
    assert (info.binning_x, info.roi.x_offset, info.roi.width) == (2, 10, 200)


@pytest.mark.parametrize("rectified", [False, True])
@pytest.mark.parametrize(
    ("binning", "roi"),
    [
        ((0, 0), (0, 0, 0, 0)),
        ((2, 2), (0, 0, 0, 0)),
        ((1, 1), (40, 24, 640, 360)),
        ((2, 1), (40, 24, 640, 360)),
    ],
    ids=["plain", "binned", "roi", "binned_roi"],
)
def test_scaled_camera_info_describes_the_resampled_image(binning, roi, rectified):
    # image_geometry's model of the scaled camera_info (crop to the ROI, then bin) is the
    # camera of the image resampled to the map's size, computed here from the image's camera.
    k = [1000.0, 0.0, 700.3, 0.0, 990.0, 401.7, 0.0, 0.0, 1.0]
    p = [980.0, 0.0, 690.0, 0.0, 0.0, 985.0, 405.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    source = _info(1280, 800, k, p, binning, roi)
    image = messages.camera_intrinsics(source, rectified)
    size = (round(image.width * 0.25), round(image.height * 0.25))
    info = messages.scaled_camera_info(_target(), source, (image.width, image.height), size)
    scaled = messages.camera_intrinsics(info, rectified)
    sx, sy = size[0] / image.width, size[1] / image.height
    assert (scaled.width, scaled.height) == size
    assert scaled.fx == pytest.approx(image.fx * sx) and scaled.fy == pytest.approx(image.fy * sy)
    assert scaled.cx == pytest.approx((image.cx + 0.5) * sx - 0.5)
    assert scaled.cy == pytest.approx((image.cy + 0.5) * sy - 0.5)
    assert (info.binning_x, info.binning_y) == binning
