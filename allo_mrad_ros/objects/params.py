"""The tracker's parameters: one validated dataclass (:class:`ObjectParams`) and the module's
one exception type (:class:`ObjectsError`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Any

from allo_mrad_ros.errors import InvalidInput


class ObjectsError(InvalidInput):
    """An invalid tracker parameter or per-frame input (pose, depth, regions, stamp)."""


def parameter(
    default: float | int,
    description: str,
    low: float,
    high: float,
    *,
    low_open: bool = False,
) -> Any:
    """A field of :class:`ObjectParams` with its description and valid range."""
    return field(
        default=default,
        metadata={"description": description, "low": low, "high": high, "low_open": low_open},
    )


@dataclass(frozen=True)
class ObjectParams:
    """Parameters of :class:`~allo_mrad_ros.objects.tracker.ObjectTracker`.

    Distances are in metres, times in seconds of the frames' stamps, pixels in the camera's
    full-resolution pixels. Each field carries its description and range (``docs/objects.md``
    lists them); construction refuses a value of the wrong type or outside its range with
    an :class:`ObjectsError` naming the field.
    """

    pixel_sigma: float = parameter(
        4.0, "standard deviation of a region's centroid, pixels", 0.0, 1000.0, low_open=True
    )
    extent_sigma_fraction: float = parameter(
        0.1,
        "more centroid noise for large regions: this fraction of the region's extent (the "
        "largest side of its box), added in quadrature",
        0.0,
        1.0,
    )
    edge_sigma_fraction: float = parameter(
        2.0,
        "more centroid noise for a region touching the image's edge (the object may extend "
        "beyond it): this fraction of the region's side across that edge, added in quadrature",
        0.0,
        10.0,
    )
    position_sigma: float = parameter(
        0.04,
        "standard deviation of the camera position the pose reports, m (per axis): its rays "
        "count with that much more variance across them",
        0.0,
        100.0,
    )
    min_range: float = parameter(
        0.3, "nearest an object may be to the camera", 0.0, 1e4, low_open=True
    )
    max_range: float = parameter(
        50.0,
        "farthest an object seen against space may be; an object whose range parallax cannot "
        "place within it is not confirmed",
        0.0,
        1e6,
        low_open=True,
    )
    surface_quantile: float = parameter(
        0.1,
        "the quantile of the surface ranges behind a region's pixels that bounds its range (0: "
        "the nearest; a little above 0 ignores a few pixels spilling onto nearer structure)",
        0.0,
        1.0,
    )
    occlusion_margin: float = parameter(
        0.3,
        "an object is hidden when it lies this far (plus 3 of its depth's standard deviations) "
        "behind the station surface at its pixel",
        0.0,
        1e3,
    )
    gate_sigma: float = parameter(
        3.0,
        "association gate: largest Mahalanobis distance of a region's centroid from an "
        "object's projection",
        0.0,
        100.0,
        low_open=True,
    )
    size_ratio_max: float = parameter(
        2.0,
        "association gate: largest ratio between a region's extent and an object's projected "
        "extent (either way)",
        1.0,
        1e3,
    )
    drift_speed: float = parameter(
        0.05,
        "how fast an object may drift (process noise): a ray t seconds old counts with "
        "(drift_speed t)^2 more variance",
        0.0,
        10.0,
    )
    confirm_hits: int = parameter(
        3, "N: hits needed in the last confirm_window in-view frames to confirm", 1, 1000
    )
    confirm_window: int = parameter(
        5, "M: the in-view frames the confirmation counts hits over", 1, 1000
    )
    end_misses: int = parameter(5, "K: consecutive in-view misses that end an object", 1, 100000)
    parallax_sigma: float = parameter(
        4.0,
        "an object is confirmed only when parallax places it nearer than max_range by this "
        "many standard deviations (of its inverse range); 0 drops the requirement",
        0.0,
        100.0,
    )
    residual_quantile: float = parameter(
        0.999,
        "an object is confirmed only when the squared residuals of its newest rays (at most "
        "confirm_window) about its estimate, each over its variance, lie within this quantile "
        "of the chi-square distribution (2 per ray); 1 drops the test",
        0.0,
        1.0,
        low_open=True,
    )
    steady_size_ratio: float = parameter(
        1.25,
        "an object is confirmed only while the sizes of its newest regions (at most "
        "confirm_window; each region's extent times its range) lie within this ratio of each "
        "other: a region still growing or shrinking (a part of the thing becoming more of it, "
        "glare blooming) moves its centroid on the thing, and the parallax that drift feigns "
        "would confirm it off its place; 1e6 drops the test",
        1.0,
        1e6,
    )
    partial_size_ratio: float = parameter(
        2.0,
        "a region smaller than its object's largest by more than this ratio (each region's "
        "extent times its range) shows a part of the thing: its ray is left out of the "
        "object's position (its centroid moves across the thing as the detection grows, "
        "the same way frame after frame, and would pass for parallax); 1e6 keeps every ray",
        1.0,
        1e6,
    )
    duplicate_quantile: float = parameter(
        0.999,
        "an object is not confirmed while its extent meets a confirmed object's in the image "
        "and in range: each gap (less half their summed sizes) at most zero or within this "
        "two-sided normal quantile of its noise (the regions' centroid noise; the ranges' "
        "uncertainty): a second track of one thing, as a detection split into regions "
        "gives; 0 drops the test",
        0.0,
        0.999999,
    )
    max_rays: int = parameter(32, "the newest rays kept per object for its triangulation", 2, 4096)
    history_s: float = parameter(30.0, "rays older than this are dropped", 0.0, 1e6, low_open=True)
    tentative_timeout_s: float = parameter(
        2.0, "a tentative object not hit for this long ends", 0.0, 1e6, low_open=True
    )
    reacquire_s: float = parameter(
        5.0,
        "a confirmed object that ended this recently keeps its id for an object confirmed "
        "where it was (the same test as duplicate_quantile's, against its last estimate); "
        "0 = never",
        0.0,
        1e6,
    )
    min_region_score: float = parameter(
        0.5, "regions scoring below this are ignored (Region.score, 0..1)", 0.0, 1.0
    )
    hit_region_score: float = parameter(
        0.5,
        "a region scoring below min_region_score but at least this continues an object its "
        "gate takes (a hit) and starts none (Region.score, 0..1; at or above "
        "min_region_score: no such regions)",
        0.0,
        1.0,
    )
    max_objects: int = parameter(
        256, "most objects kept; beyond, the stalest tentative objects end", 1, 100000
    )

    def __post_init__(self) -> None:
        for spec in fields(self):
            value = getattr(self, spec.name)
            meta = spec.metadata
            integer = spec.type in ("int", int)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ObjectsError(f"{spec.name} must be a number, got {value!r}")
            if integer and int(value) != value:
                raise ObjectsError(f"{spec.name} must be an integer, got {value!r}")
            low, high = meta["low"], meta["high"]
            inside = (value > low if meta["low_open"] else value >= low) and value <= high
            if not (math.isfinite(value) and inside):
                interval = f"{'(' if meta['low_open'] else '['}{low:g}, {high:g}]"
                raise ObjectsError(f"{spec.name} must be in {interval}, got {value!r}")
            object.__setattr__(self, spec.name, int(value) if integer else float(value))
        if self.confirm_hits > self.confirm_window:
            raise ObjectsError(
                f"confirm_hits ({self.confirm_hits}) must not exceed confirm_window "
                f"({self.confirm_window})"
            )
        if self.max_range <= self.min_range:
            raise ObjectsError(
                f"max_range ({self.max_range}) must exceed min_range ({self.min_range})"
            )

    def replace(self, **changes: Any) -> ObjectParams:
        """A validated copy with ``changes``; an unknown name raises :class:`ObjectsError`."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ObjectsError(f"unknown object tracker parameter(s): {sorted(unknown)}")
        return replace(self, **changes)


def params_from(assignments: Sequence[str]) -> ObjectParams:
    """:class:`ObjectParams` with ``NAME=VALUE`` texts (numbers; a whole number as an int)
    over the defaults, for command lines.

    Raises
    ------
    ObjectsError
        For a text that is not ``NAME=VALUE``, a value that is not a number, an unknown
        name or a value out of range.
    """
    changes: dict[str, float | int] = {}
    for text in assignments:
        name, sep, value = text.partition("=")
        if not sep or not name.strip():
            raise ObjectsError(f"expected NAME=VALUE, got {text!r}")
        try:
            number = float(value)
        except ValueError:
            raise ObjectsError(f"{name.strip()}: not a number: {value!r}") from None
        changes[name.strip()] = int(number) if number.is_integer() else number
    return ObjectParams().replace(**changes)


def parameter_table() -> list[tuple[str, object, str, str]]:
    """``(name, default, range, description)`` of every parameter, in field order."""
    rows = []
    for spec in fields(ObjectParams):
        meta = spec.metadata
        interval = f"{'(' if meta['low_open'] else '['}{meta['low']:g}, {meta['high']:g}]"
        rows.append((spec.name, spec.default, interval, meta["description"]))
    return rows
