"""Celestial bodies (Sun disc, Earth, Moon) as spheres, and the view-frustum test for them."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from allo_mrad_ros.camera import CameraIntrinsics
from allo_mrad_ros.errors import InvalidInput

# Linear base colours used when a body gives none, keyed by lower-case name.
DEFAULT_COLOURS: dict[str, tuple[float, float, float]] = {
    "sun": (1.0, 0.98, 0.92),
    "earth": (0.16, 0.3, 0.62),
    "moon": (0.42, 0.41, 0.39),
}
_FALLBACK_COLOUR = (0.5, 0.5, 0.5)
# Bodies are pulled inside the far plane on a log scale that saturates at this distance
# (about 70 astronomical units).
FARTHEST_BODY_M = 1.0e13


@dataclass(frozen=True)
class CelestialBody:
    """A sphere far from the station, e.g. the Sun disc, the Earth or the Moon.

    Parameters
    ----------
    name : str
        Body name; ``"sun"``, ``"earth"`` and ``"moon"`` pick default colours, and ``"sun"``
        is emissive (self-lit) unless ``emissive`` says otherwise.
    centre : sequence of 3 floats
        Centre in the station frame, metres (ALLO's scaled-down ephemeris keeps apparent
        sizes; bodies further than the far clipping plane are pulled in the same way).
    radius : float
        Radius in metres, positive.
    colour : sequence of 3 floats or None
        Linear RGB base colour in [0, 1]; None for the default of ``name``.
    emissive : bool or None
        Self-lit (not shaded by the Sun light); None means ``name == "sun"``.
    """

    name: str
    centre: tuple[float, float, float]
    radius: float
    colour: tuple[float, float, float] | None = None
    emissive: bool | None = None
    _centre: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        centre = np.asarray(self.centre, dtype=np.float64)
        if centre.shape != (3,) or not np.all(np.isfinite(centre)):
            raise InvalidInput(f"body {self.name!r}: centre must be 3 finite numbers")
        if not math.isfinite(self.radius) or self.radius <= 0:
            raise InvalidInput(f"body {self.name!r}: radius must be positive, got {self.radius!r}")
        colour = self.resolved_colour
        if len(colour) != 3 or not all(0.0 <= c <= 1.0 for c in colour):
            raise InvalidInput(f"body {self.name!r}: colour must be 3 values in [0, 1]")
        object.__setattr__(self, "_centre", centre)

    @property
    def resolved_colour(self) -> tuple[float, float, float]:
        """The colour to draw: the given one or the default of the body's name."""
        if self.colour is not None:
            return tuple(float(c) for c in self.colour)
        return DEFAULT_COLOURS.get(self.name.lower(), _FALLBACK_COLOUR)

    @property
    def is_emissive(self) -> bool:
        """Whether the body glows instead of being lit by the Sun light."""
        return self.name.lower() == "sun" if self.emissive is None else bool(self.emissive)

    @property
    def centre_array(self) -> np.ndarray:
        """The centre as a float64 array."""
        return self._centre


def frustum_planes(intrinsics: CameraIntrinsics) -> np.ndarray:
    """Return the four side planes of the pinhole view frustum in the optical frame.

    Parameters
    ----------
    intrinsics : CameraIntrinsics
        The camera. The image spans pixel edges -0.5 .. width - 0.5 (and height).

    Returns
    -------
    numpy.ndarray
        (4, 3) unit inward normals ``n``; a point ``p`` is inside when ``n @ p >= 0`` for all.
    """
    k = intrinsics
    left = (-0.5 - k.cx) / k.fx
    right = (k.width - 0.5 - k.cx) / k.fx
    top = (-0.5 - k.cy) / k.fy
    bottom = (k.height - 0.5 - k.cy) / k.fy
    planes = np.array(
        [[1.0, 0.0, -left], [-1.0, 0.0, right], [0.0, 1.0, -top], [0.0, -1.0, bottom]]
    )
    return planes / np.linalg.norm(planes, axis=1, keepdims=True)


def sphere_in_view(
    centre_optical: np.ndarray, radius: float, planes: np.ndarray, znear: float, zfar: float
) -> bool:
    """Conservative sphere/frustum test in the optical frame (z forward).

    Returns False only when the sphere lies entirely outside one plane (behind the near plane,
    beyond the far plane or outside an image edge).
    """
    z = float(centre_optical[2])
    if z + radius < znear or z - radius > zfar:
        return False
    return bool(np.all(planes @ centre_optical >= -radius))


def pull_within(
    centre: np.ndarray, radius: float, eye: np.ndarray, limit: float
) -> tuple[np.ndarray, float]:
    """Move a sphere towards ``eye`` so it sits within ``limit``, keeping its apparent size.

    Distances beyond ``limit / 2`` are compressed logarithmically into ``[limit / 2, 0.95
    limit)`` (saturating at :data:`FARTHEST_BODY_M`), so the depth order of bodies as far
    apart as the Moon and the Sun is kept, with room between them.

    Returns
    -------
    tuple
        The new centre and radius (unchanged if the sphere already fits).
    """
    offset = centre - eye
    distance = float(np.linalg.norm(offset))
    if distance + radius <= limit or distance == 0.0:
        return centre, radius
    half = limit / 2.0
    fraction = math.log(max(distance, half) / half) / math.log(FARTHEST_BODY_M / half)
    target = half + 0.9 * half * min(fraction, 1.0)
    scale = min(target / distance, 0.99 * limit / (distance + radius))
    return eye + offset * scale, radius * scale


def bodies_in_view(
    T_station_camera: np.ndarray,
    bodies: Sequence[CelestialBody | Sequence],
    planes: np.ndarray,
    znear: float,
    zfar: float,
    cull: bool = True,
) -> list[tuple[CelestialBody, np.ndarray, float]]:
    """The bodies that intersect a view frustum, each moved within the far plane.

    Parameters
    ----------
    T_station_camera : numpy.ndarray
        (4, 4) optical-frame camera pose in the station frame (validated by the caller).
    bodies : sequence of CelestialBody or (name, centre, radius[, colour]) tuples
        Candidate bodies.
    planes : numpy.ndarray
        The frustum's side planes (:func:`frustum_planes`).
    znear, zfar : float
        Clipping distances.
    cull : bool
        False keeps every body (pulled within the far plane all the same).

    Returns
    -------
    list of tuple
        ``(body, centre, radius)`` for each body in view, with the drawn centre and radius.
    """
    eye = T_station_camera[:3, 3]
    world_to_camera = T_station_camera[:3, :3].T
    result = []
    for body in as_bodies(bodies):
        centre, radius = pull_within(body.centre_array, body.radius, eye, zfar)
        optical = world_to_camera @ (centre - eye)
        if not cull or sphere_in_view(optical, radius, planes, znear, zfar):
            result.append((body, centre, radius))
    return result


def as_bodies(bodies: Sequence[CelestialBody | Sequence]) -> list[CelestialBody]:
    """Accept :class:`CelestialBody` objects or ``(name, centre, radius[, colour])`` tuples."""
    result = []
    for body in bodies:
        if isinstance(body, CelestialBody):
            result.append(body)
        elif isinstance(body, (tuple, list)) and 3 <= len(body) <= 5:
            result.append(CelestialBody(*body))
        else:
            raise InvalidInput(f"not a celestial body: {body!r}")
    return result
