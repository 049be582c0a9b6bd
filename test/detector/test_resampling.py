"""The query's downscale and the mask's restore against OpenCV's one-step resamplers."""

import cv2
import numpy as np
import pytest

from allo_mrad_ros.detector.images import area_downscale, nearest_upscale


@pytest.mark.parametrize(
    ("shape", "target"),
    [
        ((270, 480), (1080, 1920)),  # x4, the default at 1080p
        ((135, 240), (1080, 1920)),  # x8
        ((540, 960), (1080, 1920)),  # x2
        ((180, 320), (540, 960)),  # x3: no wide-integer trick
        ((7, 5), (7, 5)),  # x1
        ((6, 4), (13, 9)),  # not an integer factor
    ],
)
def test_nearest_upscale_equals_opencv_nearest(shape, target):
    rng = np.random.default_rng(shape[0])
    mask = rng.integers(0, 256, size=shape, dtype=np.uint8)
    expected = cv2.resize(mask, (target[1], target[0]), interpolation=cv2.INTER_NEAREST)
    got = nearest_upscale(mask, target)
    assert got.shape == target and got.flags.c_contiguous
    np.testing.assert_array_equal(got, expected)


@pytest.mark.parametrize(
    ("shape", "size"),
    [
        ((1080, 1920), (480, 270)),  # two exact halvings
        ((720, 1280), (320, 180)),
        ((1080, 1920), (240, 135)),  # three halvings
        ((1080, 1920), (640, 360)),  # x3: one general area resize
        ((1440, 2560), (640, 360)),  # x4
        ((2160, 3840), (640, 360)),  # x6: one halving, then a x3 box
        ((1081, 1921), (480, 270)),  # not an integer factor: one general area resize
    ],
)
def test_area_downscale_is_the_box_average_up_to_rounding(shape, size):
    rng = np.random.default_rng(shape[1])
    image = rng.integers(0, 256, size=(*shape, 3), dtype=np.uint8)
    got = area_downscale(image, size)
    one_step = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
    exact = cv2.resize(image.astype(np.float64), size, interpolation=cv2.INTER_AREA)
    assert got.shape == one_step.shape and got.dtype == np.uint8
    # Each halving rounds once: the error against the exact float average stays below
    # half a level per rounding step.
    steps = max(1, int(np.log2(shape[1] / size[0])))
    assert np.abs(got - exact).max() <= 0.5 * steps + 1e-9
    assert np.abs(got.astype(int) - one_step).max() <= steps


def test_area_downscale_of_float_images_equals_one_step():
    rng = np.random.default_rng(9)
    image = rng.random((1080, 1920, 3)).astype(np.float32)
    got = area_downscale(image, (480, 270))
    one_step = cv2.resize(image, (480, 270), interpolation=cv2.INTER_AREA)
    np.testing.assert_allclose(got, one_step, rtol=0, atol=1e-6)
