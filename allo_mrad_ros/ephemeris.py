"""Sun, Earth and Moon as seen from a Gateway-like station in lunar orbit, scaled for rendering.

Two sources give the same :class:`Sky` (all in the station frame, metres):

* :class:`StationEphemeris` computes it from JPL DE421 (``skyfield`` + ``skyfield-data``,
  offline) for a station on a Keplerian lunar orbit (:class:`LunarOrbit`);
* :mod:`allo_mrad_ros.allo_ephemeris` reads ALLO's own 2030 table, shipped with
  the package.

Scaling, as in ALLO
    Each body sits at a fixed scaled distance along its true direction with its apparent
    size kept (see :mod:`allo_mrad_ros.sky`). The default distances are ALLO's (Moon 500 m,
    Earth 2 km, Sun 4 km, read off its table): they keep the true depth order, so the Moon
    can hide the Earth, and stay inside a 10 km far clip plane.

The orbit
    A two-body ellipse around the Moon (Moon GM only: no Earth or Sun perturbation), perilune
    altitude 3,000 km and apolune altitude 70,000 km, period about 7.8 days (Gateway's
    real NRHO, shaped by the Earth's pull, takes 6.6). Its orientation is fixed in the J2000
    ecliptic frame: inclination 90 deg (polar; the lunar equator is within 1.5 deg of the
    ecliptic), ascending node on the vernal equinox direction, argument of perilune 90 deg,
    so perilune lies over the north pole and apolune over the south pole as for Gateway's
    southern L2 NRHO. Perilune passage at 2030-01-01T00:00Z.

The station frame
    The station holds an inertially fixed attitude tied to its orbit: +z points from the
    Moon's centre to perilune (at closest approach the Moon is straight "below", along -z),
    +y is the direction of flight at perilune and +x = y cross z is opposite to the orbit's
    angular momentum. The Moon therefore always lies in the station's y-z plane, as in ALLO's
    table, whose Moon x is 0 on every row.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone
from functools import cache

import numpy as np
from scipy.spatial.transform import Rotation

from allo_mrad_ros.errors import InvalidInput
from allo_mrad_ros.sky import (
    EARTH_DISTANCE_M,
    EARTH_RADIUS_KM,
    MOON_DISTANCE_M,
    MOON_RADIUS_KM,
    SUN_DISTANCE_M,
    SUN_RADIUS_KM,
    Sky,
    scaled_to_distance,
)

EPOCH_2030 = datetime(2030, 1, 1, tzinfo=timezone.utc)
"""2030-01-01T00:00:00Z, day 1.0 of :meth:`StationEphemeris.sky_on_day`."""

# Lunar GM of DE421.
MOON_GM_KM3_S2 = 4_902.800066
# IAU 1976 mean obliquity of the ecliptic at J2000 (84381.448 arcsec).
OBLIQUITY_J2000_DEG = 23.439291111


class EphemerisError(InvalidInput):
    """Invalid orbit parameters, times or ephemeris table contents."""


def _check_aware(when: object, name: str) -> None:
    if not isinstance(when, datetime):
        raise EphemerisError(f"{name} must be a datetime, got {type(when).__name__}")
    if when.tzinfo is None or when.utcoffset() is None:
        raise EphemerisError(f"{name} must be timezone-aware (e.g. UTC), got {when!r}")


@dataclass(frozen=True)
class LunarOrbit:
    """A Keplerian orbit around the Moon, oriented in the J2000 ecliptic frame.

    Parameters
    ----------
    perilune_altitude_km, apolune_altitude_km : float
        Altitudes above the mean lunar radius; ``0 < perilune <= apolune``.
    inclination_deg : float
        Inclination to the J2000 ecliptic.
    raan_deg : float
        Ecliptic longitude of the ascending node.
    arg_perilune_deg : float
        Argument of perilune, measured from the ascending node in the direction of motion.
    mean_anomaly_deg : float
        Mean anomaly at ``epoch`` (0: perilune passage).
    epoch : datetime.datetime
        Timezone-aware reference time.
    """

    perilune_altitude_km: float = 3_000.0
    apolune_altitude_km: float = 70_000.0
    inclination_deg: float = 90.0
    raan_deg: float = 0.0
    arg_perilune_deg: float = 90.0
    mean_anomaly_deg: float = 0.0
    epoch: datetime = EPOCH_2030

    def __post_init__(self) -> None:
        for name in (
            "perilune_altitude_km",
            "apolune_altitude_km",
            "inclination_deg",
            "raan_deg",
            "arg_perilune_deg",
            "mean_anomaly_deg",
        ):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise EphemerisError(f"{name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise EphemerisError(f"{name} must be finite, got {value!r}")
        if not 0 < self.perilune_altitude_km <= self.apolune_altitude_km:
            raise EphemerisError(
                "need 0 < perilune_altitude_km <= apolune_altitude_km, got "
                f"{self.perilune_altitude_km} and {self.apolune_altitude_km}"
            )
        _check_aware(self.epoch, "epoch")

    @property
    def perilune_radius_km(self) -> float:
        """Distance from the Moon's centre at perilune."""
        return MOON_RADIUS_KM + self.perilune_altitude_km

    @property
    def apolune_radius_km(self) -> float:
        """Distance from the Moon's centre at apolune."""
        return MOON_RADIUS_KM + self.apolune_altitude_km

    @property
    def semi_major_axis_km(self) -> float:
        """Semi-major axis."""
        return 0.5 * (self.perilune_radius_km + self.apolune_radius_km)

    @property
    def eccentricity(self) -> float:
        """Eccentricity."""
        rp, ra = self.perilune_radius_km, self.apolune_radius_km
        return (ra - rp) / (ra + rp)

    @property
    def period_s(self) -> float:
        """Orbital period in seconds."""
        return 2.0 * math.pi * math.sqrt(self.semi_major_axis_km**3 / MOON_GM_KM3_S2)

    def perifocal_basis(self) -> np.ndarray:
        """Return the 3x3 matrix whose columns are P (to perilune), Q (flight direction at
        perilune) and W (angular momentum), in J2000 ecliptic axes."""
        angles = np.radians([self.raan_deg, self.inclination_deg, self.arg_perilune_deg])
        return Rotation.from_euler("ZXZ", angles).as_matrix()

    def position_km(self, seconds_since_epoch: object) -> np.ndarray:
        """Station position relative to the Moon's centre, J2000 ecliptic axes, km.

        Parameters
        ----------
        seconds_since_epoch : array_like
            Times (TT seconds after ``epoch``), any shape.

        Returns
        -------
        numpy.ndarray
            Shape ``(..., 3)``.
        """
        t = np.asarray(seconds_since_epoch, dtype=np.float64)
        a, e = self.semi_major_axis_km, self.eccentricity
        mean_motion = 2.0 * math.pi / self.period_s
        mean = np.remainder(math.radians(self.mean_anomaly_deg) + mean_motion * t, 2 * math.pi)
        # Newton on Kepler's equation; starting at pi converges for every e < 1.
        eccentric = np.full_like(mean, math.pi) if e > 0.8 else mean + e * np.sin(mean)
        for _ in range(50):
            step = (eccentric - e * np.sin(eccentric) - mean) / (1.0 - e * np.cos(eccentric))
            eccentric = eccentric - step
            if np.all(np.abs(step) < 1e-13):
                break
        p_coord = a * (np.cos(eccentric) - e)
        q_coord = a * math.sqrt(1.0 - e * e) * np.sin(eccentric)
        basis = self.perifocal_basis()
        return p_coord[..., None] * basis[:, 0] + q_coord[..., None] * basis[:, 1]

    def station_axes(self) -> np.ndarray:
        """Return the 3x3 matrix whose columns are the station frame's x, y, z axes in J2000
        ecliptic axes: ``x = -W``, ``y = Q``, ``z = P`` (see the module notes)."""
        basis = self.perifocal_basis()
        return np.column_stack([-basis[:, 2], basis[:, 1], basis[:, 0]])


GATEWAY_LIKE_ORBIT = LunarOrbit()
"""The default orbit: 3,000 x 70,000 km altitude, polar, apolune over the south pole."""


def day_to_datetime(day: float, year: int = 2030) -> datetime:
    """Return the UTC time of a 1-based, possibly fractional day of ``year``.

    Day 1.0 is January 1st at 00:00 UTC and day 1.5 is noon that day, which matches ALLO's
    day numbering (its table's row ``d`` is January 1st plus ``d - 1`` days).
    """
    if isinstance(day, bool) or not isinstance(day, (int, float)) or not math.isfinite(day):
        raise EphemerisError(f"day must be a finite number, got {day!r}")
    start = datetime(year, 1, 1, tzinfo=timezone.utc)
    days_in_year = (datetime(year + 1, 1, 1, tzinfo=timezone.utc) - start).days
    if not 1 <= day < days_in_year + 1:
        raise EphemerisError(f"day must be in [1, {days_in_year + 1}) for {year}, got {day}")
    return start + timedelta(days=day - 1)


@cache
def _de421() -> tuple[object, object]:
    # Imported lazily: loading skyfield and the 17 MB kernel takes about a second.
    from skyfield.api import Loader
    from skyfield_data import get_skyfield_data_path

    with warnings.catch_warnings():
        # skyfield-data warns about its Earth-orientation file (finals2000A.all), which
        # these geometric positions do not use.
        warnings.filterwarnings("ignore", message=".*has expired.*", category=RuntimeWarning)
        loader = Loader(get_skyfield_data_path(), expire=False, verbose=False)
    return loader.timescale(builtin=True), loader("de421.bsp")


# ICRF (J2000 equatorial) to J2000 ecliptic axes.
_ECLIPTIC_FROM_ICRF = Rotation.from_euler("x", -math.radians(OBLIQUITY_J2000_DEG)).as_matrix()


class StationEphemeris:
    """Sun, Earth and Moon seen from a station on a lunar orbit, from DE421.

    Parameters
    ----------
    orbit : LunarOrbit
        The station's orbit; also fixes the station frame (see the module notes).
    moon_distance_m, earth_distance_m, sun_distance_m : float
        Scaled distances at which the bodies are placed, positive.

    Attributes
    ----------
    orbit : LunarOrbit
        As given.
    distances_m : dict of str to float
        Scaled distance per body (``sun``, ``earth``, ``moon``).
    station_from_icrf : numpy.ndarray
        3x3 rotation taking ICRF vectors into the station frame (fixed in time).

    Notes
    -----
    Positions are geometric (no light-time or aberration): the difference is below
    30 arcsec, under a quarter of one of ALLO's 1920x1080 camera pixels (0.037 deg).
    """

    def __init__(
        self,
        orbit: LunarOrbit = GATEWAY_LIKE_ORBIT,
        *,
        moon_distance_m: float = MOON_DISTANCE_M,
        earth_distance_m: float = EARTH_DISTANCE_M,
        sun_distance_m: float = SUN_DISTANCE_M,
    ) -> None:
        if not isinstance(orbit, LunarOrbit):
            raise EphemerisError(f"orbit must be a LunarOrbit, got {type(orbit).__name__}")
        for name, value in (
            ("moon_distance_m", moon_distance_m),
            ("earth_distance_m", earth_distance_m),
            ("sun_distance_m", sun_distance_m),
        ):
            if not math.isfinite(value) or value <= 0:
                raise EphemerisError(f"{name} must be positive and finite, got {value!r}")
        self.orbit = orbit
        self.distances_m = {
            "moon": float(moon_distance_m),
            "earth": float(earth_distance_m),
            "sun": float(sun_distance_m),
        }
        # Rows are the station axes in ICRF: maps ICRF vectors into the station frame.
        self.station_from_icrf = orbit.station_axes().T @ _ECLIPTIC_FROM_ICRF

    def _times(self, whens: list[datetime]) -> tuple[object, np.ndarray]:
        for when in whens:
            _check_aware(when, "time")
        timescale, _ = _de421()
        times = timescale.from_datetimes(whens)
        epoch = timescale.from_datetime(self.orbit.epoch)
        return times, (np.asarray(times.tt) - epoch.tt) * 86_400.0

    def station_positions_km(self, whens: Iterable[datetime]) -> np.ndarray:
        """Station positions relative to the Moon's centre, station axes, km, shape (N, 3)."""
        whens = list(whens)
        if not whens:
            return np.zeros((0, 3))
        _, seconds = self._times(whens)
        ecliptic = self.orbit.position_km(seconds)
        return ecliptic @ self.orbit.station_axes()

    def skies(self, whens: Iterable[datetime]) -> list[Sky]:
        """Return the :class:`Sky` at each of several timezone-aware times (vectorised)."""
        whens = list(whens)
        if not whens:
            return []
        times, seconds = self._times(whens)
        _, kernel = _de421()
        moon = kernel["moon"]
        station = self.orbit.position_km(seconds) @ self.orbit.station_axes()
        relative = {"moon": -station}
        for body in ("sun", "earth"):
            from_moon = np.asarray((kernel[body] - moon).at(times).position.km).reshape(3, -1)
            relative[body] = from_moon.T @ self.station_from_icrf.T - station
        radii = {"sun": SUN_RADIUS_KM, "earth": EARTH_RADIUS_KM, "moon": MOON_RADIUS_KM}
        scaled = {
            body: scaled_to_distance(vectors, radii[body], self.distances_m[body])
            for body, vectors in relative.items()
        }
        sun_direction = scaled["sun"][:, :3] / self.distances_m["sun"]
        sun_direction /= np.linalg.norm(sun_direction, axis=1, keepdims=True)
        return [
            Sky(
                sun_direction=sun_direction[i],
                sun=scaled["sun"][i],
                earth=scaled["earth"][i],
                moon=scaled["moon"][i],
            )
            for i in range(len(whens))
        ]

    def sky(self, when: datetime) -> Sky:
        """Return the :class:`Sky` at one timezone-aware time."""
        return self.skies([when])[0]

    def sky_on_day(self, day: float, year: int = 2030) -> Sky:
        """Return the :class:`Sky` on a 1-based, possibly fractional day (see
        :func:`day_to_datetime`)."""
        return self.sky(day_to_datetime(day, year))
