"""The supersampled reference: rendered at a multiple of its size and area-averaged down, so
a bar thinner than a reference pixel stays one line instead of breaking into dashes."""

import cv2
import numpy as np
import pytest
import trimesh

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.geometry import look_at
from allo_mrad_ros.render import ReferenceRenderer
from allo_mrad_ros.render.provider import ReferenceProvider
from allo_mrad_ros.render.reuse import ReuseBounds
from allo_mrad_ros.render.settings import RenderSettings, RenderSettingsError
from allo_mrad_ros.view import View

CAMERA = CameraIntrinsics(width=320, height=180, fx=300.0, fy=300.0, cx=160.0, cy=90.0)
SUN = np.array([0.2, -0.3, 0.93])
EYE = np.array([0.0, -30.0, 0.0])
POSE = look_at(EYE, [0.0, 0.0, 0.0])


def thin_bar() -> trimesh.Trimesh:
    """A bar 0.14 m thick and 16 m long at 30 m, tilted 30 degrees in the image: 1.4 camera
    pixels across, 0.7 at the reference's half scale."""
    bar = trimesh.creation.box((0.14, 0.14, 16.0))
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.radians(30), [0, 1, 0]))
    bar.visual.face_colors = (200, 200, 200, 255)
    return bar


def rows_with_bar(image: np.ndarray) -> np.ndarray:
    """Per image row along the bar's middle, whether any pixel of it is lit."""
    lit = image.max(axis=2) > 0
    return lit[20:-20].any(axis=1)


@pytest.mark.parametrize("supersampling", [1, 2, 3])
def test_the_reference_is_the_area_average_of_a_larger_render(supersampling):
    settings = RenderSettings(0.5, supersampling=supersampling, shadows=False)
    provider = ReferenceProvider(thin_bar(), CAMERA, settings)
    try:
        reference, depth = provider.render_with_depth(View(POSE, SUN))
    finally:
        provider.close()
    size = provider.reference_camera
    assert reference.shape == (size.height, size.width, 3) and depth.shape == reference.shape[:2]
    with ReferenceRenderer(thin_bar(), size, scale=supersampling, shadows=False) as large:
        full = large.render(POSE, SUN, depth=True)
    np.testing.assert_array_equal(
        reference, cv2.resize(full.rgb, (size.width, size.height), interpolation=cv2.INTER_AREA)
    )
    # The depth is one sample's, never a blend of the bar's and space's (0).
    np.testing.assert_array_equal(
        depth,
        cv2.resize(full.depth, (size.width, size.height), interpolation=cv2.INTER_NEAREST),
    )


def test_a_bar_thinner_than_a_reference_pixel_is_one_line_only_when_supersampled():
    lines = {}
    for supersampling in (1, 2):
        settings = RenderSettings(0.5, supersampling=supersampling, shadows=False)
        provider = ReferenceProvider(thin_bar(), CAMERA, settings)
        try:
            lines[supersampling] = rows_with_bar(provider.render(View(POSE, SUN)))
        finally:
            provider.close()
    assert not lines[1].all()  # dashes: rows where no pixel centre falls on the bar
    assert lines[2].all()


def test_with_reuse_the_keyframe_is_supersampled_too():
    bounds = ReuseBounds(max_error_px=2.0)
    references = []
    for supersampling in (1, 2):
        settings = RenderSettings(0.5, supersampling=supersampling, shadows=False, reuse=bounds)
        provider = ReferenceProvider(thin_bar(), CAMERA, settings)
        try:
            references.append(provider.render(View(POSE, SUN), time_s=0.0))
        finally:
            provider.close()
    assert references[0].shape == references[1].shape
    assert not rows_with_bar(references[0]).all() and rows_with_bar(references[1]).all()


@pytest.mark.parametrize("value", [0, 5, 1.5, True, "2"])
def test_a_bad_supersampling_is_refused(value):
    with pytest.raises(RenderSettingsError, match="supersampling"):
        RenderSettings(supersampling=value)


def test_the_settings_made_by_position_keep_their_meaning():
    settings = RenderSettings(0.5, False, False, "", None)
    assert (settings.shadows, settings.cull_bodies, settings.supersampling) == (False, False, 1)
