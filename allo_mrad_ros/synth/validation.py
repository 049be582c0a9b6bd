"""The generator's error type and the checks its settings share."""

from __future__ import annotations

import math

from allo_mrad_ros.errors import InvalidInput


class SynthError(InvalidInput):
    """An invalid generator setting, or a scene in which the rules cannot be met."""


def finite_number(
    value: object, name: str, low: float | None = None, high: float | None = None
) -> float:
    """``value`` as a finite float in ``[low, high]`` (either end optional)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SynthError(f"{name} must be a number, got {value!r}")
    number = float(value)
    if not math.isfinite(number):
        raise SynthError(f"{name} must be finite, got {value!r}")
    if low is not None and number < low:
        raise SynthError(f"{name} must be >= {low}, got {value!r}")
    if high is not None and number > high:
        raise SynthError(f"{name} must be <= {high}, got {value!r}")
    return number


def integer_at_least(value: object, name: str, low: int = 0) -> int:
    """``value``, an int of at least ``low`` (a bool is refused)."""
    if isinstance(value, bool) or not isinstance(value, int) or value < low:
        raise SynthError(f"{name} must be an integer >= {low}, got {value!r}")
    return value


def number_pair(value: object, name: str, low: float) -> tuple[float, float]:
    """``value``, a ``(min, max)`` pair of finite numbers of at least ``low``."""
    if not isinstance(value, (tuple, list)) or len(value) != 2:
        raise SynthError(f"{name} must be a (min, max) pair, got {value!r}")
    a, b = (finite_number(v, name, low) for v in value)
    if a > b:
        raise SynthError(f"{name} must have min <= max, got {value!r}")
    return a, b
