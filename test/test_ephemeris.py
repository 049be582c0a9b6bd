"""Sun, Earth and Moon seen from the lunar-orbit station; ALLO's ephemeris table."""

from __future__ import annotations

import math
import warnings
from datetime import datetime, timedelta, timezone
from pathlib import Path

import numpy as np
import pytest

from allo_mrad_ros.allo_ephemeris import allo_sky, parse_allo_ephemeris, read_allo_ephemeris
from allo_mrad_ros.ephemeris import (
    EARTH_DISTANCE_M,
    EARTH_RADIUS_KM,
    EPOCH_2030,
    MOON_DISTANCE_M,
    MOON_RADIUS_KM,
    SUN_DISTANCE_M,
    SUN_RADIUS_KM,
    EphemerisError,
    LunarOrbit,
    Sky,
    StationEphemeris,
    day_to_datetime,
)
from allo_mrad_ros.sky import SkyError

SHARED_ALLO = Path(__file__).resolve().parents[1].parent / "shared" / "allo"
PACKAGE_DATA = Path(__file__).resolve().parents[1] / "allo_mrad_ros" / "data"

DAYS = [day_to_datetime(d + 0.37) for d in range(1, 366, 3)]


@pytest.fixture(scope="module")
def ephemeris() -> StationEphemeris:
    return StationEphemeris()


@pytest.fixture(scope="module")
def skies(ephemeris: StationEphemeris) -> list[Sky]:
    return ephemeris.skies(DAYS)


def _true_vectors_km(ephemeris: StationEphemeris) -> dict[str, np.ndarray]:
    """Body vectors from the station, km, station axes, straight from skyfield."""
    from skyfield.api import Loader
    from skyfield_data import get_skyfield_data_path

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # skyfield-data's expired EOP file
        loader = Loader(get_skyfield_data_path(), expire=False, verbose=False)
    timescale, kernel = loader.timescale(builtin=True), loader("de421.bsp")
    times = timescale.from_datetimes(DAYS)
    station = ephemeris.station_positions_km(DAYS)
    vectors = {"moon": -station}
    try:
        for body in ("sun", "earth"):
            icrf = np.asarray((kernel[body] - kernel["moon"]).at(times).position.km).T
            vectors[body] = icrf @ ephemeris.station_from_icrf.T - station
    finally:
        kernel.close()
    return vectors


def test_sun_direction_is_unit(skies: list[Sky]) -> None:
    for sky in skies:
        assert np.linalg.norm(sky.sun_direction) == pytest.approx(1.0, abs=1e-12)
        np.testing.assert_allclose(sky.sun[:3] / SUN_DISTANCE_M, sky.sun_direction, atol=1e-12)


def test_bodies_at_scaled_distances(skies: list[Sky]) -> None:
    names = [body.name for body in skies[0].bodies()]
    assert names == ["sun", "earth", "moon"]
    assert skies[0].bodies()[1].radius == skies[0].earth[3]
    for sky in skies:
        for body, distance in (
            ("sun", SUN_DISTANCE_M),
            ("earth", EARTH_DISTANCE_M),
            ("moon", MOON_DISTANCE_M),
        ):
            assert np.linalg.norm(getattr(sky, body)[:3]) == pytest.approx(distance)


def test_apparent_sizes_match_true_ones(ephemeris: StationEphemeris, skies: list[Sky]) -> None:
    true = _true_vectors_km(ephemeris)
    radii = {"sun": SUN_RADIUS_KM, "earth": EARTH_RADIUS_KM, "moon": MOON_RADIUS_KM}
    for i, sky in enumerate(skies):
        for body, vectors in true.items():
            distance = np.linalg.norm(vectors[i])
            expected = math.asin(radii[body] / distance)
            assert sky.angular_radius(body) == pytest.approx(expected, rel=0.01), body
            # And the direction is the true one.
            direction = getattr(sky, body)[:3] / np.linalg.norm(getattr(sky, body)[:3])
            np.testing.assert_allclose(direction, vectors[i] / distance, atol=1e-9)


def test_apparent_sizes_are_physically_plausible(skies: list[Sky]) -> None:
    sun = np.array([s.angular_radius("sun") for s in skies])
    earth = np.array([s.angular_radius("earth") for s in skies])
    moon = np.array([s.angular_radius("moon") for s in skies])
    # The Sun subtends 31.5'-32.5' in diameter over the year.
    assert np.degrees(2 * sun).min() * 60 == pytest.approx(31.5, abs=0.2)
    assert np.degrees(2 * sun).max() * 60 == pytest.approx(32.5, abs=0.2)
    # Earth from near the Moon: 6371 km at 0.28-0.48 million km.
    assert np.all((earth > 6371 / 480_000) & (earth < 6371 / 280_000))
    # Moon from 4,737-71,737 km.
    assert np.all((moon >= math.asin(1737.4 / 71_738)) & (moon <= math.asin(1737.4 / 4_737)))


def test_sun_size_matches_allo_table_day_for_day(ephemeris: StationEphemeris) -> None:
    # ALLO's row d is 2030-01-01 plus d - 1 days: the Sun's apparent size, which hardly
    # depends on where around the Moon the station is, agrees within 0.2 %.
    table = read_allo_ephemeris()
    days = list(range(1, 365, 7))
    ours = ephemeris.skies([day_to_datetime(d) for d in days])
    for day, sky in zip(days, ours, strict=True):
        assert sky.angular_radius("sun") == pytest.approx(
            table[day].angular_radius("sun"), rel=0.002
        )


def test_station_stays_between_perilune_and_apolune(ephemeris: StationEphemeris) -> None:
    orbit = ephemeris.orbit
    times = [EPOCH_2030 + timedelta(hours=h) for h in range(0, 24 * 365, 2)]
    distance = np.linalg.norm(ephemeris.station_positions_km(times), axis=1)
    assert orbit.perilune_radius_km == pytest.approx(MOON_RADIUS_KM + 3_000)
    assert orbit.apolune_radius_km == pytest.approx(MOON_RADIUS_KM + 70_000)
    assert np.all(distance >= orbit.perilune_radius_km - 1e-6)
    assert np.all(distance <= orbit.apolune_radius_km + 1e-6)
    # Two-hour sampling comes within 1 % of both ends.
    assert distance.min() < orbit.perilune_radius_km * 1.01
    assert distance.max() > orbit.apolune_radius_km * 0.99
    # The Moon's apparent size follows: the station's distance sets it.
    sky = ephemeris.sky(times[0])
    assert sky.angular_radius("moon") == pytest.approx(math.asin(MOON_RADIUS_KM / distance[0]))


def test_orbit_is_periodic_and_keplerian() -> None:
    orbit = LunarOrbit()
    assert 7.0 < orbit.period_s / 86_400 < 8.5
    start = orbit.position_km(0.0)
    np.testing.assert_allclose(orbit.position_km(orbit.period_s), start, atol=1e-6)
    # Vis-viva from finite differences: v^2 = GM (2/r - 1/a).
    for t in (1_000.0, 150_000.0, 330_000.0):
        dt = 1.0
        v = (orbit.position_km(t + dt) - orbit.position_km(t - dt)) / (2 * dt)
        r = np.linalg.norm(orbit.position_km(t))
        expected = 4_902.800066 * (2 / r - 1 / orbit.semi_major_axis_km)
        assert float(v @ v) == pytest.approx(expected, rel=1e-5)


def test_station_frame_convention(ephemeris: StationEphemeris) -> None:
    rotation = ephemeris.station_from_icrf
    np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rotation) == pytest.approx(1.0)
    # At perilune (the epoch) the Moon is straight below the station.
    sky = ephemeris.sky(EPOCH_2030)
    np.testing.assert_allclose(sky.moon[:3], [0, 0, -MOON_DISTANCE_M], atol=1e-6)
    # The Moon always lies in the station's y-z plane, as in ALLO's table.
    moons = np.array([s.moon[:3] for s in ephemeris.skies(DAYS)])
    assert np.abs(moons[:, 0]).max() < 1e-6
    # Shortly after perilune the station has moved along +y: the Moon appears towards -y.
    later = ephemeris.sky(EPOCH_2030 + timedelta(hours=1))
    assert later.moon[1] < 0


def test_polar_orbit_reaches_over_both_poles(ephemeris: StationEphemeris) -> None:
    # Perilune over the ecliptic north, apolune over the south (Gateway's southern NRHO).
    epsilon = math.radians(23.439291111)
    ecliptic_north_icrf = np.array([0.0, -math.sin(epsilon), math.cos(epsilon)])
    np.testing.assert_allclose(
        ephemeris.station_from_icrf @ ecliptic_north_icrf, [0, 0, 1], atol=1e-12
    )


def test_times_must_be_aware_and_days_in_range(ephemeris: StationEphemeris) -> None:
    with pytest.raises(EphemerisError, match="timezone-aware"):
        ephemeris.sky(datetime(2030, 1, 1))
    assert day_to_datetime(1) == EPOCH_2030
    assert day_to_datetime(32.5) == datetime(2030, 2, 1, 12, tzinfo=timezone.utc)
    for day in (0, 366, math.nan):
        with pytest.raises(EphemerisError, match="day"):
            day_to_datetime(day)
    assert ephemeris.skies([]) == []
    sky = ephemeris.sky_on_day(100.25)
    np.testing.assert_array_equal(sky.sun, ephemeris.sky(day_to_datetime(100.25)).sun)


def test_parameters_are_validated() -> None:
    with pytest.raises(EphemerisError, match="perilune"):
        LunarOrbit(perilune_altitude_km=80_000.0)
    with pytest.raises(EphemerisError, match="finite"):
        LunarOrbit(inclination_deg=math.inf)
    with pytest.raises(EphemerisError, match="timezone-aware"):
        LunarOrbit(epoch=datetime(2030, 1, 1))
    with pytest.raises(EphemerisError, match="sun_distance_m"):
        StationEphemeris(sun_distance_m=0.0)
    with pytest.raises(SkyError, match="radius"):
        Sky(sun_direction=[1, 0, 0], sun=[1, 0, 0, 2], earth=[0, 1, 0, 0.1], moon=[0, 0, 1, 0.1])


# --- ALLO's table ------------------------------------------------------------------------


def test_allo_table_skips_garbage_row_zero() -> None:
    table = read_allo_ephemeris()
    assert sorted(table) == list(range(1, 365))
    first = table[1]
    # Values of row 1 of the file (moon r, x, y, z; sun r, x, y, z; earth r, x, y, z).
    np.testing.assert_allclose(
        first.moon, [0.0, -411.4919329468281717, -284.0323733655779961, 212.2815166795452058]
    )
    np.testing.assert_allclose(first.earth[3], 35.28488708199795099)
    for sky in table.values():
        assert np.linalg.norm(sky.sun_direction) == pytest.approx(1.0)
        # ALLO's scaled distances are the defaults here.
        assert np.linalg.norm(sky.moon[:3]) == pytest.approx(MOON_DISTANCE_M)
        assert np.linalg.norm(sky.earth[:3]) == pytest.approx(EARTH_DISTANCE_M)
        assert np.linalg.norm(sky.sun[:3]) == pytest.approx(SUN_DISTANCE_M)
    assert allo_sky(1) is table[1] or np.array_equal(allo_sky(1).moon, first.moon)


def test_allo_sky_day_range() -> None:
    for day in (0, 365, -1, 2.0, True):
        with pytest.raises(EphemerisError, match="ALLO day"):
            allo_sky(day)


GOOD_ROW = "100,0,-400,-300,18.9,700,-3600,-1560,35,1000,1500,700"


def test_allo_parser_ignores_row_zero_values_only() -> None:
    text = f"garbage,nan,inf,1e-310,0,0,0,0,0,0,0,0\n{GOOD_ROW}\n"
    table = parse_allo_ephemeris(text, "t.csv")
    assert list(table) == [1]
    with pytest.raises(EphemerisError, match=r"t\.csv, line 1: expected 12 fields, got 3"):
        parse_allo_ephemeris(f"1,2,3\n{GOOD_ROW}\n", "t.csv")
    with pytest.raises(EphemerisError, match="at least one day"):
        parse_allo_ephemeris(GOOD_ROW + "\n\n", "t.csv")
    with pytest.raises(EphemerisError, match="line 2: expected 12 fields, got 0"):
        parse_allo_ephemeris(f"{GOOD_ROW}\n\n{GOOD_ROW}\n", "t.csv")


@pytest.mark.parametrize(
    ("index", "value", "column", "match"),
    [
        (2, "nan", "moon_y", "not finite"),
        (5, "abc", "sun_x", "not a number"),
        (0, "-1", "moon_r", "radius must be positive"),
        (8, "1e9", "earth_r", "below the distance"),
    ],
)
def test_allo_parser_errors_name_line_and_column(
    index: int, value: str, column: str, match: str
) -> None:
    fields = GOOD_ROW.split(",")
    fields[index] = value
    text = f"{GOOD_ROW}\n{GOOD_ROW}\n{','.join(fields)}\n"
    with pytest.raises(EphemerisError, match=match) as info:
        parse_allo_ephemeris(text, "t.csv")
    assert f"t.csv, line 3, column {column!r}" in str(info.value)


def test_read_allo_ephemeris_from_path(tmp_path: Path) -> None:
    path = tmp_path / "table.csv"
    path.write_text(f"0,0,0,0,0,0,0,0,0,0,0,0\n{GOOD_ROW}\n")
    assert list(read_allo_ephemeris(path)) == [1]
    with pytest.raises(EphemerisError, match="cannot read"):
        read_allo_ephemeris(tmp_path / "missing.csv")


@pytest.mark.skipif(not SHARED_ALLO.is_dir(), reason="shared ALLO facts not present")
@pytest.mark.parametrize("name", ["ephemeris_2030.csv", "camera_base_poses.csv"])
def test_shipped_tables_are_allo_copies(name: str) -> None:
    assert (PACKAGE_DATA / name).read_bytes() == (SHARED_ALLO / name).read_bytes()
