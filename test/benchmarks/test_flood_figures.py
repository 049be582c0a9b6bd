"""The flood's memory figure: growth of the per-minute peak, not of two single samples."""

import pytest

pytest.importorskip("rclpy")  # the flood benchmark drives a node (skipped on the distro route)

from benchmarks.flood import peak_growth


def sawtooth(minutes: float, base_mb: float, rise_mb_per_minute: float = 0.0) -> list:
    """Samples every second: frames in flight add 0 to 50 MB on top of a base that may rise."""
    return [
        (float(t), base_mb + rise_mb_per_minute * t / 60.0 + 50.0 * ((t * 7) % 11) / 10.0)
        for t in range(int(60 * minutes) + 1)
    ]


def test_a_flat_sawtooth_shows_no_growth_wherever_single_samples_fall():
    samples = sawtooth(10, 450.0)
    figures = peak_growth(samples, 600.0)
    assert figures["growth_percent"] == pytest.approx(0.0)
    assert figures["second_minute"]["peak"] == pytest.approx(500.0)
    single = {mb for t, mb in samples if t in (60.0, 600.0)}
    assert len(single) == 2  # the two single samples differ: that is the noise the peak avoids


def test_a_leak_shows_as_growth_of_the_peak():
    figures = peak_growth(sawtooth(10, 450.0, rise_mb_per_minute=5.0), 600.0)
    # peak of minute 2 about 450 + 10 + 50, of minute 10 about 450 + 50 + 50
    assert figures["growth_percent"] == pytest.approx(100.0 * (550.0 / 510.0 - 1), rel=0.02)


def test_a_flood_shorter_than_two_minutes_has_no_figure():
    assert peak_growth(sawtooth(1.5, 450.0), 90.0)["growth_percent"] is not None
    assert peak_growth(sawtooth(0.9, 450.0), 54.0)["growth_percent"] is None
