"""A reference keeps its camera's aspect ratio at any size, so a narrow camera (700x3) is
processed, or refused for a reason of its own (its grid), never for its own reference."""

from __future__ import annotations

import numpy as np
import pytest

from allo_mrad_ros.camera import ALLO_INTRINSICS, CameraIntrinsics
from allo_mrad_ros.detector import MradParams
from allo_mrad_ros.detector.images import check_aspect
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.pipeline import Pipeline, PipelineConfig
from allo_mrad_ros.render import (
    ReferenceRenderer,
    RenderSettings,
    scaled_keeping_aspect,
)
from allo_mrad_ros.view import View

SCALES = (0.05, 0.1, 0.125, 0.25, 0.5, 1.0)
VIEW = View(look_at([-30.0, -12.0, 6.0], [0.0, 0.0, 0.0]), np.array([0.3, -0.5, 0.8]))


def camera(width: int, height: int) -> CameraIntrinsics:
    focal = 0.8 * max(width, height)
    return CameraIntrinsics(width, height, focal, focal, width / 2 - 0.5, height / 2 - 0.5)


def _passes_aspect_check(full: CameraIntrinsics, reference: CameraIntrinsics) -> bool:
    try:
        check_aspect(
            np.empty((full.height, full.width, 0)), np.empty((reference.height, reference.width, 0))
        )
    except ValueError:
        return False
    return True


def test_every_size_scaled_keeps_the_aspect_the_detector_checks():
    sizes = [(w, h) for w in range(1, 41) for h in range(1, 41)]
    sizes += [(700, 3), (3, 700), (1000, 300), (700, 12), (2448, 2048), (1920, 1200)]
    for width, height in sizes:
        full = camera(width, height)
        for scale in SCALES:
            reference = scaled_keeping_aspect(full, scale)
            assert _passes_aspect_check(full, reference), (width, height, scale, reference)
            # The same camera: the field of view is kept on both axes.
            assert reference.fx / reference.width == pytest.approx(full.fx / full.width)
            assert reference.fy / reference.height == pytest.approx(full.fy / full.height)


@pytest.mark.parametrize("scale", SCALES)
def test_a_camera_whose_shorter_side_scales_to_whole_pixels_scales_as_before(scale):
    assert scaled_keeping_aspect(ALLO_INTRINSICS, scale) == ALLO_INTRINSICS.scaled(scale)


def test_narrow_cameras_rendered_before_had_a_reference_the_detector_refused():
    # What the renderer made before: each side rounded alone.
    assert not _passes_aspect_check(camera(700, 3), camera(700, 3).scaled(0.125))
    assert not _passes_aspect_check(camera(1000, 300), camera(1000, 300).scaled(0.125))


@pytest.mark.parametrize(("width", "height"), [(700, 3), (3, 700)])
def test_the_renderer_draws_a_narrow_camera_at_its_own_aspect(width, height):
    with ReferenceRenderer(None, camera(width, height), scale=0.125, shadows=False) as renderer:
        rgb = renderer.render(VIEW.T_station_camera, VIEW.sun_direction).rgb
    assert rgb.shape[:2] == ((1, 233) if width > height else (233, 1))


def _detect(width: int, height: int, settings: RenderSettings, params: MradParams) -> object:
    config = PipelineConfig(render=settings, params=params)
    with Pipeline.open(camera(width, height), config=config) as pipeline:
        image = np.full((height, width, 3), 40, np.uint8)
        return pipeline.process(image, VIEW)


@pytest.mark.parametrize(("width", "height"), [(700, 3), (3, 700)])
def test_a_narrow_camera_is_refused_for_its_grid_with_the_fix(width, height):
    with pytest.raises(ValueError) as refused:
        _detect(width, height, RenderSettings(shadows=False), MradParams())
    message = str(refused.value)
    assert "aspect" not in message
    assert f"grid=8 is too fine for the {width}x{height} query" in message
    assert "process_scale=1 and a grid of at most 3" in message


@pytest.mark.parametrize(("width", "height"), [(700, 3), (3, 700)])
def test_a_narrow_reference_is_named_as_the_reference(width, height):
    with pytest.raises(ValueError, match=r"too fine for the (233x1|1x233) reference of the"):
        _detect(width, height, RenderSettings(shadows=False), MradParams(grid=3, process_scale=1))


@pytest.mark.parametrize(("width", "height"), [(700, 3), (3, 700)])
def test_a_narrow_camera_with_a_grid_it_can_hold_is_processed(width, height):
    settings = RenderSettings(reference_scale=1.0, shadows=False)
    results = _detect(width, height, settings, MradParams(grid=3, process_scale=1)).results
    assert results["MRAD"].mask.shape == (height, width)
