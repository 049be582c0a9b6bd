"""The Sun, the Earth and the Moon as the reference renderer draws them.

One place for the sky: the true radii, ALLO's scaled distances, the scaling that keeps each
body's apparent size, the :class:`Sky` of one moment, and the rules that turn a frame's
inputs (a Sun direction, an Earth and a Moon as ``(x, y, z, r)``) into the
:class:`~allo_mrad_ros.render.CelestialBody` list the renderer takes. The node, the offline
evaluation, the benchmarks and the generator all build their bodies here.

Scaling, as in ALLO
    A renderer cannot draw the Sun 150 million km away, so each body is placed at a fixed
    scaled distance along its true direction with its radius scaled by the same factor:
    ``r' = R * d' / D``. The ratio radius/distance, hence the apparent angular radius
    ``asin(r'/d')``, is exactly the true one.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.render.bodies import CelestialBody, as_bodies

# IAU 2015 nominal solar radius; mean Earth and Moon radii.
SUN_RADIUS_KM = 695_700.0
EARTH_RADIUS_KM = 6_371.0
MOON_RADIUS_KM = 1_737.4
ASTRONOMICAL_UNIT_KM = 149_597_870.7

# ALLO's scaled distances (ephemeris_2030.csv: every row at exactly these distances).
MOON_DISTANCE_M = 500.0
EARTH_DISTANCE_M = 2_000.0
SUN_DISTANCE_M = 4_000.0

# Mean apparent radius of the Sun from the Earth-Moon system (1 au): 0.2665 degrees.
SUN_ANGULAR_RADIUS_RAD = math.asin(SUN_RADIUS_KM / ASTRONOMICAL_UNIT_KM)

BODY_NAMES = ("sun", "earth", "moon")


class SkyError(InvalidInput):
    """Invalid sky: a non-unit Sun direction, a body inside its own radius, non-finite values."""


def _frozen(values: object, length: int, name: str) -> np.ndarray:
    array = np.array(values, dtype=np.float64)
    if array.shape != (length,) or not np.all(np.isfinite(array)):
        raise SkyError(f"{name} must be {length} finite numbers, got {values!r}")
    array.setflags(write=False)
    return array


def scaled_to_distance(vectors_km: np.ndarray, radius_km: float, distance_m: float) -> np.ndarray:
    """(N, 3) true vectors -> (N, 4) ``(x, y, z, r)`` at ``distance_m``, same angular size."""
    true_distance = np.linalg.norm(vectors_km, axis=1, keepdims=True)
    scale = distance_m / true_distance
    return np.hstack([vectors_km * scale, radius_km * scale])


@dataclass(frozen=True, eq=False)
class Sky:
    """Sun, Earth and Moon in the station frame at one time, scaled for rendering.

    Attributes
    ----------
    sun_direction : numpy.ndarray
        Unit vector from the station origin towards the Sun, shape (3,).
    sun, earth, moon : numpy.ndarray
        ``(x, y, z, r)``: scaled-down centre and radius in metres, apparent size kept.
    """

    sun_direction: np.ndarray
    sun: np.ndarray
    earth: np.ndarray
    moon: np.ndarray

    def __post_init__(self) -> None:
        direction = _frozen(self.sun_direction, 3, "sun_direction")
        if abs(np.linalg.norm(direction) - 1.0) > 1e-9:
            raise SkyError(f"sun_direction must be a unit vector, got {direction}")
        object.__setattr__(self, "sun_direction", direction)
        for body in BODY_NAMES:
            value = _frozen(getattr(self, body), 4, body)
            distance = float(np.linalg.norm(value[:3]))
            if not 0 < value[3] < distance:
                raise SkyError(
                    f"{body} radius must be positive and below its distance, "
                    f"got r={value[3]} at {distance}"
                )
            object.__setattr__(self, body, value)

    def bodies(self) -> tuple[CelestialBody, ...]:
        """The Sun, the Earth and the Moon, in that order, for the renderer."""
        return tuple(body_from_xyzr(name, getattr(self, name)) for name in BODY_NAMES)

    def angular_radius(self, body: str) -> float:
        """Apparent angular radius of ``sun``, ``earth`` or ``moon`` in radians."""
        if body not in BODY_NAMES:
            raise SkyError(f"body must be sun, earth or moon, got {body!r}")
        value = getattr(self, body)
        return math.asin(value[3] / float(np.linalg.norm(value[:3])))


def body_from_xyzr(name: str, xyzr: Sequence[float]) -> CelestialBody:
    """A body from a sequence row's or a table's ``(x, y, z, r)``."""
    return CelestialBody(name, tuple(float(v) for v in xyzr[:3]), float(xyzr[3]))


def earth_and_moon(
    earth: Sequence[float] | None, moon: Sequence[float] | None
) -> tuple[CelestialBody, ...]:
    """Celestial bodies from a sequence frame's ``(x, y, z, r)`` Earth and Moon, where given."""
    return tuple(
        body_from_xyzr(name, value)
        for name, value in (("earth", earth), ("moon", moon))
        if value is not None
    )


def sun_disc(sun_direction: Sequence[float]) -> CelestialBody | None:
    """The Sun's disc along ``sun_direction`` with its true apparent size.

    None for a zero or non-finite direction (the renderer reports that direction itself).
    """
    direction = np.asarray(sun_direction, dtype=np.float64)
    norm = float(np.linalg.norm(direction))
    if not np.isfinite(norm) or norm == 0.0:
        return None
    centre = tuple(SUN_DISTANCE_M * direction / norm)
    return CelestialBody("sun", centre, SUN_DISTANCE_M * math.tan(SUN_ANGULAR_RADIUS_RAD))


def with_sun(
    bodies: Sequence[CelestialBody | Sequence], sun_direction: Sequence[float]
) -> tuple[CelestialBody, ...]:
    """``bodies`` plus the Sun's disc along ``sun_direction``, unless a ``sun`` is there.

    The Sun's disc is in the camera image whenever the Sun is in view, so every reference
    carries it (the renderer culls it when out of view, at no cost).
    """
    complete = tuple(as_bodies(bodies))
    if any(body.name == "sun" for body in complete):
        return complete
    disc = sun_disc(sun_direction)
    return complete if disc is None else (*complete, disc)
