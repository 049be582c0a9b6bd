"""The sky module and the View: one place for the Sun's disc, the Earth and the Moon."""

from __future__ import annotations

import math

import numpy as np
import pytest

from allo_mrad_ros.errors import AlloError, BackendError, InvalidInput
from allo_mrad_ros.render import CelestialBody, RendererError
from allo_mrad_ros.sky import (
    SUN_ANGULAR_RADIUS_RAD,
    SUN_DISTANCE_M,
    SkyError,
    earth_and_moon,
    scaled_to_distance,
    sun_disc,
    with_sun,
)
from allo_mrad_ros.view import View


def test_sun_disc_has_the_true_apparent_size_along_the_direction():
    disc = sun_disc((0.0, 3.0, 4.0))
    centre = np.array(disc.centre)
    np.testing.assert_allclose(centre / np.linalg.norm(centre), [0.0, 0.6, 0.8])
    assert np.linalg.norm(centre) == pytest.approx(SUN_DISTANCE_M)
    # 0.2665 degrees: the Sun seen from 1 au.
    assert math.degrees(math.atan(disc.radius / SUN_DISTANCE_M)) == pytest.approx(0.2665, 1e-3)
    assert math.atan(disc.radius / SUN_DISTANCE_M) == pytest.approx(SUN_ANGULAR_RADIUS_RAD)
    assert sun_disc((0.0, 0.0, 0.0)) is None and sun_disc((math.nan, 1.0, 0.0)) is None


def test_scaling_keeps_the_angular_size():
    vectors = np.array([[3.0e5, 4.0e5, 0.0]])
    scaled = scaled_to_distance(vectors, 1737.4, 500.0)
    assert np.linalg.norm(scaled[0, :3]) == pytest.approx(500.0)
    assert scaled[0, 3] / 500.0 == pytest.approx(1737.4 / 5.0e5)


def test_view_bodies_are_the_frame_bodies_plus_the_sun_once():
    view = View.from_row(np.eye(4), (1.0, 0.0, 0.0), 2.0, (0.0, 2000.0, 0.0, 20.0), None)
    assert [b.name for b in view.bodies] == ["earth"]
    assert [b.name for b in view.sky_bodies] == ["earth", "sun"]
    assert view.sun_strength == 2.0
    given = (CelestialBody("sun", (0.0, 0.0, 100.0), 1.0),)
    assert with_sun(given, (1.0, 0.0, 0.0)) == given
    assert earth_and_moon(None, None) == ()


def test_one_exception_base_with_two_kinds():
    assert issubclass(SkyError, InvalidInput) and issubclass(InvalidInput, ValueError)
    assert issubclass(RendererError, BackendError) and issubclass(BackendError, RuntimeError)
    assert issubclass(SkyError, AlloError) and issubclass(RendererError, AlloError)
    with pytest.raises(InvalidInput, match="radius"):
        CelestialBody("moon", (0.0, 0.0, 10.0), -1.0)
