"""Property-based bad input over image headers, camera_info, poses, Sun vectors and sequence
rows: each case is handled cleanly (accepted with a valid result, or refused with the
package's error naming the problem), never a stray exception or a silently wrong result.

Verdicts: ``accepted`` / ``refused`` (both clean), ``traceback`` (another exception type),
``silent wrong`` (accepted, but the result breaks an invariant).
"""

from __future__ import annotations

import csv
import math
import types
from pathlib import Path

import numpy as np
import pytest
from fuzz_verdicts import VERDICTS
from hypothesis import example, given
from hypothesis import strategies as st

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.ros import messages
from allo_mrad_ros.ros.parameters import node_parameters, validate
from allo_mrad_ros.sequence import FRAMES_FILE, SequenceMeta, SequenceWriter, read_sequence

pytestmark = pytest.mark.fuzz

FLOATS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, -0.0, 1e-320, 1e300, -1e300, 1.0, 0.5]),
)
SIZES = st.one_of(st.integers(0, 64), st.sampled_from([2**31 - 1, 2**32 - 1, 16385]))


def verdict(target: str, call, valid) -> str:
    """Run ``call``; classify its outcome; record and return the verdict."""
    try:
        result = call()
    except InvalidInput as error:
        outcome = "refused" if str(error) else "silent wrong"  # an error must say something
    except Exception as error:
        outcome = f"traceback:{type(error).__name__}"
    else:
        outcome = "accepted" if valid(result) else "silent wrong"
    VERDICTS[(target, outcome.split(":")[0])] += 1
    return outcome


def clean(outcome: str) -> bool:
    return outcome in ("accepted", "refused")


@given(
    encoding=st.sampled_from(
        [
            "rgb8",
            "bgr8",
            "mono8",
            "rgba8",
            "16UC1",
            "rgb16",
            "bgra16",
            "mono16",
            "32FC1",
            "yuv422",
            "",
            "RGB8",
            "bayer_rggb8",
        ]
    ),
    width=SIZES,
    height=SIZES,
    step_delta=st.integers(-8, 8),
    data_delta=st.integers(-20, 20),
    bigendian=st.integers(0, 2),
)
def test_image_headers(encoding, width, height, step_delta, data_delta, bigendian):
    channels = {"rgb8": 3, "bgr8": 3, "mono8": 1, "rgba8": 4}.get(encoding, 2)
    step = max(0, min(width, 64) * channels + step_delta)
    size = max(0, step * min(height, 64) + data_delta)
    msg = types.SimpleNamespace(
        encoding=encoding,
        width=width,
        height=height,
        step=step,
        is_bigendian=bigendian,
        data=bytes(size),
    )
    expected = (min(width, 64), min(height, 64))

    def valid(image):
        return (
            image.shape[:2] == (height, width)
            and image.ndim == 3
            and image.shape[2] == 3
            and (width, height) == expected
        )

    outcome = verdict("image header", lambda: messages.image_to_rgb(msg, expected), valid)
    assert clean(outcome), (outcome, msg)


@given(width=SIZES, height=SIZES, k=st.lists(FLOATS, min_size=0, max_size=10))
def test_camera_info(width, height, k):
    msg = types.SimpleNamespace(width=width, height=height, k=k)

    def convert():
        return messages.check_camera_size(messages.intrinsics_from_camera_info(msg))

    def valid(intrinsics: CameraIntrinsics):
        values = (intrinsics.fx, intrinsics.fy, intrinsics.cx, intrinsics.cy)
        return (
            0 < intrinsics.width <= messages.MAX_IMAGE_SIDE
            and 0 < intrinsics.height <= messages.MAX_IMAGE_SIDE
            and all(math.isfinite(v) for v in values)
            and intrinsics.fx > 0
            and intrinsics.fy > 0
        )

    outcome = verdict("camera_info", convert, valid)
    assert clean(outcome), (outcome, msg)


def _xyz(values):
    return types.SimpleNamespace(x=values[0], y=values[1], z=values[2])


@given(
    position=st.lists(FLOATS, min_size=3, max_size=3),
    orientation=st.lists(FLOATS, min_size=4, max_size=4),
)
def test_poses(position, orientation):
    quaternion = types.SimpleNamespace(
        x=orientation[0], y=orientation[1], z=orientation[2], w=orientation[3]
    )
    pose = types.SimpleNamespace(position=_xyz(position), orientation=quaternion)

    def valid(matrix):
        rotation = matrix[:3, :3]
        return (
            matrix.shape == (4, 4)
            and np.isfinite(matrix).all()
            and np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6)
        )

    outcome = verdict("pose", lambda: messages.pose_to_matrix(pose), valid)
    assert clean(outcome), (outcome, position, orientation)


@given(vector=st.lists(FLOATS, min_size=3, max_size=3))
def test_sun_vectors(vector):
    def unit(direction):
        direction = np.asarray(direction, dtype=float)
        return np.isfinite(direction).all() and abs(np.linalg.norm(direction) - 1) < 1e-9

    topic = verdict("sun topic", lambda: messages.vector_to_direction(_xyz(vector)), unit)
    parameter = node_parameters(False)["sun_direction"]
    param = verdict("sun parameter", lambda: validate("sun_direction", parameter, vector), unit)
    assert clean(topic) and clean(param), (topic, param, vector)


@pytest.fixture(scope="module")
def sequence_template(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("template") / "seq"
    camera = CameraIntrinsics(16, 12, 16.0, 16.0, 8.0, 6.0)
    with SequenceWriter(root, SequenceMeta(name="fuzz", camera=camera, rate_hz=10.0)) as writer:
        for index in range(2):
            mask = np.ones((12, 16), np.uint8)
            writer.add_frame(
                split="test",
                camera=0,
                image=np.full((12, 16, 3), 50 * index, np.uint8),
                mask=mask,
                position=[1.0, 2.0, 3.0],
                quaternion=[0.0, 0.0, 0.0, 1.0],
                sun_direction=[1.0, 0.0, 0.0],
            )
    return root


NUL_STAND_IN = "\ue000"
CELLS = st.one_of(
    st.sampled_from(
        [
            "",
            "nan",
            "inf",
            "-1",
            "1e400",
            "0",
            "train",
            "drill",
            "x",
            "1,2",
            "frame9999.png",
            "../etc/passwd",
            "\u00e9",
            " 1",
            "2",
            "-0",
            "1\x002",
        ]
    ),
    st.text(max_size=6).filter(lambda text: NUL_STAND_IN not in text),
)


@given(row=st.integers(0, 1), column=st.integers(0, 40), value=CELLS)
@example(row=0, column=0, value="\x00")
@example(row=1, column=3, value="1\x002")
def test_sequence_rows(sequence_template, tmp_path_factory, row, column, value):
    import shutil

    root = tmp_path_factory.mktemp("case") / "seq"
    shutil.copytree(sequence_template, root)
    table = root / FRAMES_FILE
    with table.open(newline="") as stream:
        rows = list(csv.reader(stream))
    header, body = rows[0], rows[1:]
    column %= len(header)
    # The csv module cannot write a NUL byte on every Python: the cell is written with a
    # stand-in character and the NUL put back, so the reader still meets it.
    body[row][column] = value.replace("\x00", NUL_STAND_IN)
    with table.open("w", newline="") as stream:
        csv.writer(stream).writerows([header, *body])
    table.write_bytes(table.read_bytes().replace(NUL_STAND_IN.encode(), b"\x00"))

    def read():
        sequence = read_sequence(root, check_images=True)
        for frame in sequence.frames:
            sequence.load_image(frame)
            sequence.load_mask(frame)
        return sequence

    def valid(sequence):
        return all(
            np.isfinite(frame.position).all()
            and np.isfinite(frame.quaternion).all()
            and np.isfinite(frame.sun_direction).all()
            for frame in sequence.frames
        )

    outcome = verdict("sequence row", read, valid)
    assert clean(outcome), (outcome, header[column], value)
