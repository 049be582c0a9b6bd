"""MRAD parameters: one validated dataclass, named profiles.

Defaults keep the paper's kernel (20 % of the cell), blur SD 5 and tolerance 50 (used by
tolerance growth only). Grid 8x8, processing at a quarter of the query's size
(``process_scale`` 0.25), the per-cell noise rule, hysteresis growth, the continuous ranking
map and the photometric models were chosen on the validation split by the
speed-against-error benchmark (``make bench``), the colour transfer of the query into the
reference's colours on the multi-station bench, the Sun's glare on the frames of the
validation sequences with the Sun in view; the values the paper leaves open were
decided by measurement. docs/method.md states the method and the rule by which a default
is chosen; docs/detector.md ("How the defaults were chosen") gives the measurements.
"""

from __future__ import annotations

import argparse
import math
import numbers
import textwrap
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field, fields, replace
from typing import Any, Literal, get_args, get_origin, get_type_hints

import numpy as np

from allo_mrad_ros.errors import InvalidInput

SCORE_RANGE = 255.0


class ParamsError(InvalidInput):
    """A detector parameter of the wrong type or out of range, or an unknown name or profile."""


def parameter(
    default: Any,
    description: str,
    low: float | None = None,
    high: float | None = None,
    *,
    low_open: bool = False,
    high_open: bool = False,
) -> Any:
    """One field of :class:`MradParams`: its default, description and range, the row of the
    parameter table the node's declarations, the docs and ``config/mrad.yaml`` come from.

    The type, and the choices of a ``Literal`` or ``bool`` field, come from the field's
    annotation (:data:`PARAMETER_SPECS` gathers them).
    """
    return field(
        default=default,
        metadata={
            "description": description,
            "low": low,
            "high": high,
            "low_open": low_open,
            "high_open": high_open,
        },
    )


@dataclass(frozen=True)
class MradParams:
    """Parameters of :func:`allo_mrad_ros.detector.detect`.

    All score-valued parameters are on the 0..255 scale of the scaled score map; colour
    values are on the 0..255 scale of an 8-bit image whatever the input dtype. Each field
    below is one row of the parameter table: default, description and valid range
    (:data:`PARAMETER_SPECS`); the Parameters section of this docstring is written from it.
    """

    grid: int = parameter(8, "cells per side of the statistics grid (1 = no grid)", 1, 64)
    tolerance: float = parameter(
        50.0,
        "region-growing range around a seed's blurred score (growth tolerance only)",
        0,
        SCORE_RANGE,
    )
    kernel_fraction: float = parameter(
        0.20,
        "side of the local-std window as a fraction of the cell's height and width",
        0,
        1,
        low_open=True,
    )
    blur_sigma: float = parameter(
        5.0, "Gaussian blur SD in pixels at full query resolution (0 = no blur)", 0, 100
    )
    score_scaling: Literal["fixed", "per_image"] = parameter(
        "fixed",
        "fixed: the raw score score_ref maps to 255 in every frame; per_image: the frame's "
        "maximum does (the paper's reading)",
    )
    score_ref: float = parameter(
        1000.0, "raw cross score mapped to 255 by fixed scaling", 0, 1e12, low_open=True
    )
    min_score: float = parameter(
        25.0,
        "scaled scores below this are zeroed; also the lowest seed and grown value",
        0,
        SCORE_RANGE,
    )
    noise_removal: Literal["local_std", "cell_spread", "none"] = parameter(
        "cell_spread",
        "local_std: zero pixels whose local standard deviation is below std_thresh (the "
        "paper's text); cell_spread: zero a whole cell whose local standard deviations spread "
        "less than std_thresh (the paper's pseudo-code); none",
    )
    std_thresh: float = parameter(
        10.0, "flatness threshold of the noise removal (0..255 scale)", 0, SCORE_RANGE
    )
    large_anomaly_fraction: float = parameter(
        0.90,
        "a cell with more than this fraction of its scores above min_score is kept whole and "
        "skips noise removal",
        0,
        1,
        low_open=True,
    )
    abs_floor: float = parameter(
        16.0,
        "absolute covariance regularisation, 8-bit intensity units squared (16: noise SD 4)",
        0,
        1e6,
        low_open=True,
    )
    rel_floor: float = parameter(
        1e-3, "covariance regularisation relative to the mean variance trace(S)/3", 0, 1
    )
    connectivity: Literal[4, 8] = parameter(
        8, "region-growing neighbourhood: 8 (the 3x3 square) or 4"
    )
    area_threshold: float = parameter(
        0.001,
        "with frame_rule area, fraction of the image the mask must exceed for the frame to "
        "be anomalous (0.001: ALLO's smallest anomaly)",
        0,
        1,
        high_open=True,
    )
    process_scale: float = parameter(
        0.25,
        "linear scale at which the query is processed; outputs are at the query's resolution",
        0,
        1,
        low_open=True,
    )
    pixel_score: Literal["continuous", "regions", "blurred"] = parameter(
        "continuous",
        "what the score map holds (the mask is the same): continuous, the raw score softly "
        "saturated onto 0..255, a pixel ranking; regions, the paper's sparse map (the blurred "
        "map inside the grown regions); blurred, the whole blurred map",
    )
    score_sigma: float = parameter(
        1.0, "Gaussian smoothing SD of the continuous map in pixels at full resolution", 0, 100
    )
    growth: Literal["tolerance", "hysteresis"] = parameter(
        "hysteresis",
        "tolerance: mean-shift seeds grown within tolerance of their score (the paper); "
        "hysteresis: every connected region of the blurred map at or above min_score that "
        "reaches seed_score (keeps small, thin objects whose peak the blur lowered)",
    )
    seed_score: float = parameter(
        30.0, "score a hysteresis region must reach somewhere (0..255 scale)", 0, SCORE_RANGE
    )
    photometric: Literal["none", "cell_affine"] = parameter(
        "cell_affine",
        "photometric model of the score the mask and the decision come from: cell_affine fits "
        "each cell's reference colours to the query's by a robust per-channel gain and "
        "offset, so exposure, tone curve, white balance and light fall-off do not flag a "
        "normal frame; none",
    )
    map_photometric: Literal["none", "cell_affine"] = parameter(
        "none",
        "photometric model of the score behind the continuous ranking map (chosen apart: on "
        "the validation split the model cost ranking accuracy)",
    )
    max_gain: float = parameter(
        2.0, "largest per-channel gain (and smallest, its inverse) cell_affine may apply", 1, 100
    )
    bit_depth: int = parameter(
        16, "significant bits of uint16 input (12 for a 12-bit camera)", 9, 16
    )
    image_score: Literal["area", "map_top"] = parameter(
        "map_top",
        "the frame's anomaly score, what image metrics rank: map_top, the mean of the top "
        "image_top_fraction of the score map; area, the mask's area (the paper's); the "
        "anomalous flag comes from frame_rule",
    )
    image_top_fraction: float = parameter(
        1e-3,
        "fraction of the processed pixels the map_top image score averages",
        0,
        1,
        low_open=True,
    )
    colour_transfer: Literal["none", "reference", "query"] = parameter(
        "query",
        "per-frame colour table before the statistics: query maps the query into the "
        "reference's colours, reference the reference into the query's; none skips it",
    )
    transfer_bin: Literal[4, 8, 16, 32, 64] = parameter(
        16, "finest colour-bin width of the colour transfer, 8-bit levels"
    )
    transfer_min_count: int = parameter(
        16,
        "pixel pairs a colour bin needs for an offset of its own (else the coarser bin's)",
        1,
        1_000_000,
    )
    transfer_edge_margin: int = parameter(
        0, "pixels around reference edges left out of the colour-transfer fit", 0, 16
    )
    transfer_gain: bool = parameter(
        True,
        "with colour_transfer query, divide departures from the transferred colours by each "
        "cell's contrast gain (capped at 1)",
    )
    glare_level: float = parameter(
        250.0,
        "with a colour transfer, a query pixel whose every channel reaches this level over "
        "station surface is glare and takes the reference's colour; 256 = off",
        128,
        256,
    )
    gain_field_degree: int = parameter(
        0,
        "degree of the smooth multiplicative gain field (log luma ratio of query to reference, "
        "a 2-D polynomial fitted per frame by robust least squares over station pixels away "
        "from reference edges) the query is divided by after the colour transfer; 0 = off",
        0,
        3,
    )
    specular_tolerance: float = parameter(
        0.0,
        "8-bit levels of colourless brightening of the query over its transferred reference "
        "tolerated where the reference predicts a highlight for this view (a top-hat of its "
        "darkest channel), in proportion to that prediction; 0 = off",
        0,
        SCORE_RANGE,
    )
    glare_halo: float = parameter(
        0.0,
        "radius, per square root of its area (pixels at the processing resolution), of the "
        "halo round each clipped query region within which any colourless brightening over "
        "the reference is tolerated; 0 = off (measured: it did not pay)",
        0,
        16,
    )
    body_margin: float = parameter(
        1.0,
        "reference pixels either side of the Earth's and the Moon's projected limb within which "
        "the query takes the reference's colour (the reference places a limb to within a "
        "pixel and draws a small body as a blocky disc; needs the view: Pipeline and the node "
        "pass it); 0 = off",
        0,
        16,
    )
    sun_glare: float = parameter(
        8.0,
        "radius, per square root of its area (pixels at the processing resolution), of the "
        "Sun's glare round the clipped query region at the Sun's position in the image, "
        "within which any colourless brightening over the reference is tolerated (needs the "
        "view: Pipeline and the node pass it); 0 = off",
        0,
        16,
    )
    structure_weight: float = parameter(
        0.0,
        "weight of the structure cue (edges the query has and its reference cell lacks, "
        "luminance-normalised) added to the cross score, in score_ref units; 0 = off "
        "(measured: it did not pay)",
        0,
        100,
    )
    local_weight: float = parameter(
        0.0,
        "weight of the local colour cue (each pixel's departure, in robust noise scales of its "
        "cell, beyond the colours the reference shows within local_radius pixels; squared, "
        "in cross-score units), which replaces the cross score where it is larger (the frame "
        "decision reads the cross score alone); 0 = off",
        0,
        100,
    )
    dark_weight: float = parameter(
        0.0,
        "weight of the local dark cue (the share of the darkest lit reference luma within "
        "local_radius that the query lacks, beyond its cell's median; none where the "
        "reference shows space), in score_ref units, which replaces the cross score where it "
        "is larger; 0 = off (measured: it did not pay)",
        0,
        100,
    )
    local_radius: int = parameter(
        3,
        "half side, in pixels at the processing resolution, of the reference neighbourhood the "
        "local cues compare each query pixel with (tolerates reference edges moved by a pose "
        "error)",
        0,
        4,
    )
    frame_rule: Literal["contrast", "area"] = parameter(
        "contrast",
        "the frame decision: contrast, the mean of the top frame_top_fraction of a score map "
        "(frame_map) over the frame's background level must exceed frame_contrast; area, the "
        "mask's area must exceed area_threshold (the paper's)",
    )
    frame_map: Literal["mask", "ranking"] = parameter(
        "mask",
        "the map the contrast rule reads: mask, the score of the mask's photometric model on "
        "the ranking map's 0..255 scale; ranking, the pixel ranking map",
    )
    frame_top_fraction: float = parameter(
        3e-3,
        "fraction of the processed pixels the contrast rule's evidence averages (the top of "
        "its map)",
        0,
        1,
        low_open=True,
    )
    frame_background: float = parameter(
        0.995,
        "quantile of the contrast rule's map over the station pixels outside the mask that is "
        "the frame's background level",
        0,
        1,
    )
    frame_floor: float = parameter(
        5.0,
        "lowest background level of the contrast rule (0..255 scale): a clean frame's "
        "evidence is compared with this",
        0,
        SCORE_RANGE,
        low_open=True,
    )
    frame_contrast: float = parameter(
        3.9,
        "evidence over background level above which the contrast rule calls a frame "
        "anomalous (its anomaly score is then above 0.5)",
        0,
        1e6,
        low_open=True,
    )

    def __post_init__(self) -> None:
        # Stored as plain int, float, bool and str, so a numpy scalar given here does not
        # reach the stages (nor a JSON report) as one.
        for name, spec in PARAMETER_SPECS.items():
            object.__setattr__(self, name, spec.validated(name, getattr(self, name)))

    def replace(self, **changes: Any) -> MradParams:
        """Return a copy with ``changes`` applied (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ParamsError(f"unknown MRAD parameter(s): {sorted(unknown)}")
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        """Return the parameters as a plain dictionary."""
        return asdict(self)


@dataclass(frozen=True)
class ParameterSpec:
    """Type, valid values and description of one parameter (also used by the ROS node).

    Numbers must lie in ``[low, high]`` (ends excluded where ``low_open``/``high_open``);
    ``choices``, when given, lists the only valid values.
    """

    kind: type
    description: str
    low: float | None = None
    high: float | None = None
    low_open: bool = False
    high_open: bool = False
    choices: tuple[Any, ...] = ()

    def check(self, name: str, value: object) -> None:
        """Raise :class:`ParamsError` naming ``name`` and ``value`` if the value is invalid."""
        self.validated(name, value)

    def validated(self, name: str, value: object) -> Any:
        """``value`` checked and as the parameter's own Python type (``int``, ``float``,
        ``bool`` or ``str``).

        Any integer type (``numpy.int64`` too) is accepted where an integer is meant, any
        real type (an integer too) where a real is meant; a bool is neither. A bool parameter
        takes only ``True`` or ``False`` (``numpy.bool_`` too), a choice only a value of its
        own type (``connectivity=8.0`` and ``transfer_gain=1`` are refused).

        Raises
        ------
        ParamsError
            Naming ``name``, the value and what is allowed.
        """
        if self.kind is bool:
            if not isinstance(value, bool | np.bool_):
                raise ParamsError(f"{name} must be true or false, got {value!r}")
            return bool(value)
        if self.kind is str:
            if not isinstance(value, str):
                allowed = f"one of {list(self.choices)}" if self.choices else "a string"
                raise ParamsError(f"{name} must be {allowed}, got {value!r}")
            value = str(value)
        elif self.kind is int:
            # bool is an Integral too, but True for a grid size is a mistake.
            if isinstance(value, bool) or not isinstance(value, numbers.Integral):
                what = f"one of {list(self.choices)}" if self.choices else f"in {self.interval()}"
                raise ParamsError(f"{name} must be an integer {what}, got {value!r}")
            value = int(value)
        elif self.kind is float:
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise ParamsError(f"{name} must be a number, got {value!r}")
            value = float(value)
        if self.choices:
            # The type matched above, so this compares like with like (8 is not 8.0 here).
            if value not in self.choices:
                raise ParamsError(f"{name} must be one of {list(self.choices)}, got {value!r}")
            return value
        if self.kind not in (int, float):
            return value  # free text, or a kind the caller checks (the node's vectors)
        if not math.isfinite(value):
            raise ParamsError(f"{name} must be finite, got {value!r}")
        too_low = value <= self.low if self.low_open else value < self.low
        too_high = value >= self.high if self.high_open else value > self.high
        if too_low or too_high:
            what = "an integer in" if self.kind is int else "in"
            raise ParamsError(f"{name} must be {what} {self.interval()}, got {value!r}")
        return value

    def interval(self) -> str:
        """The valid range in interval notation, e.g. ``(0, 1]``."""
        lo, hi = ("(" if self.low_open else "["), (")" if self.high_open else "]")
        return f"{lo}{self.low:g}, {self.high:g}{hi}"


def _specs() -> dict[str, ParameterSpec]:
    """Each :class:`MradParams` field's spec: kind and choices from its annotation (a
    ``Literal`` lists the choices, ``bool`` has two), description and range from its
    :func:`parameter` row."""
    hints = get_type_hints(MradParams)
    specs = {}
    for item in fields(MradParams):
        hint = hints[item.name]
        choices: tuple[Any, ...] = get_args(hint) if get_origin(hint) is Literal else ()
        if hint is bool:
            choices = (True, False)
        kind = type(choices[0]) if choices else hint
        specs[item.name] = ParameterSpec(kind, choices=choices, **item.metadata)
    return specs


# Name to spec of every MradParams field, in field order: what validates each value, and what
# the node declares as ``mrad.<name>``.
PARAMETER_SPECS: dict[str, ParameterSpec] = _specs()


def _numpydoc(specs: Mapping[str, ParameterSpec]) -> str:
    """The Parameters section of :class:`MradParams`' docstring, from the table."""
    defaults = {item.name: item.default for item in fields(MradParams)}
    lines = ["", "    Parameters", "    ----------"]
    for name, spec in specs.items():
        if spec.kind is bool:
            kind = "bool"
        elif spec.choices:
            kind = "{" + ", ".join(repr(c) for c in spec.choices) + "}"
        else:
            kind = spec.kind.__name__
        where = "" if spec.choices else f" Range {spec.interval()}."
        lines.append(f"    {name} : {kind}, default {defaults[name]!r}")
        text = f"{spec.description[0].upper()}{spec.description[1:]}.{where}"
        lines += textwrap.wrap(text, 92, initial_indent=" " * 8, subsequent_indent=" " * 8)
    return "\n".join(lines) + "\n"


MradParams.__doc__ = (MradParams.__doc__ or "").rstrip() + "\n" + _numpydoc(PARAMETER_SPECS)


# The paper's optimum (grid 4x4, tolerance 50, kernel 20 % of the cell, blur SD 5) with this
# project's fixed scaling: the defaults before the speed-against-error benchmark.
_PAPER_OPTIMUM = MradParams(
    grid=4,
    noise_removal="local_std",
    process_scale=1.0,
    photometric="none",
    map_photometric="none",
    growth="tolerance",
    image_score="area",
    colour_transfer="none",
    specular_tolerance=0.0,
    sun_glare=0.0,
    body_margin=0.0,
    local_weight=0.0,
    frame_rule="area",
)

PROFILES: dict[str, MradParams] = {
    # Chosen on the validation split by `make bench` (docs/evaluation.md, "Speed against error").
    "default": MradParams(),
    # The paper read literally: its optimum with per-image score scaling, full resolution.
    "paper": _PAPER_OPTIMUM.replace(score_scaling="per_image", pixel_score="regions"),
    # The paper's optimum with fixed scaling and the continuous ranking map.
    "baseline": _PAPER_OPTIMUM,
    # The most accurate setting of the sweep that docs/method.md admits on validation, at
    # full resolution.
    "accurate": MradParams(process_scale=1.0),
    # A simpler configuration (grid 6, per-cell noise rule, half resolution, no photometric
    # model, tolerance growth, the sparse map, area image score), kept to compare against.
    "previous": _PAPER_OPTIMUM.replace(
        grid=6,
        noise_removal="cell_spread",
        process_scale=0.5,
        pixel_score="regions",
        score_sigma=0.0,
    ),
}


def profile(name: str, **overrides: Any) -> MradParams:
    """Return a named parameter profile, optionally with overrides.

    :class:`MradParams` itself is the way to make parameters; a profile is another starting
    point than the defaults: ``profile(name, **f) == PROFILES[name].replace(**f)``, and
    ``profile("default", **f) == MradParams(**f)``.

    Parameters
    ----------
    name : str
        One of :data:`PROFILES`.
    **overrides
        Fields to change, validated like the constructor's arguments.

    Returns
    -------
    MradParams
    """
    if name not in PROFILES:
        raise ParamsError(f"unknown MRAD profile {name!r}; choose one of {sorted(PROFILES)}")
    return PROFILES[name].replace(**overrides) if overrides else PROFILES[name]


# --- parameters from text: command lines, YAML and ROS parameters -------------------------


def coerce_value(name: str, spec: ParameterSpec, value: Any) -> Any:
    """``value`` as ``spec``'s type, from text (command lines) or a number (YAML, ROS).

    Text is parsed as the parameter's type (``"8"``, ``"0.5"``, ``"true"``); a number is
    taken as :meth:`ParameterSpec.validated` takes it.

    Raises
    ------
    ParamsError
        Naming the parameter and the value.
    """
    if isinstance(value, str) and spec.kind in (int, float):
        try:
            value = spec.kind(value.strip())
        except ValueError:
            raise ParamsError(f"{name}: {value!r} is not a valid {spec.kind.__name__}") from None
    if isinstance(value, str) and spec.kind is bool:
        text = value.strip().lower()
        if text not in ("true", "false"):
            raise ParamsError(f"{name}: {value!r} is not true or false")
        value = text == "true"
    return spec.validated(name, value)


def params_from(profile_name: str, changes: Mapping[str, Any] | Sequence[str] = ()) -> MradParams:
    """:func:`profile` for command lines: the changes as ``KEY=VALUE`` texts (or a mapping
    of texts or numbers), each value read as its parameter's type by :func:`coerce_value`.

    ``params_from("paper", ["grid=6"]) == profile("paper", grid=6)``.

    Raises
    ------
    ParamsError
        For an unknown profile or key, a text that is not ``KEY=VALUE``, or a value of the
        wrong type or range.
    """
    if not isinstance(changes, Mapping):
        pairs = {}
        for text in changes:
            key, sep, value = text.partition("=")
            if not sep or key.strip() not in PARAMETER_SPECS:
                raise ParamsError(
                    f"expected KEY=VALUE with KEY one of {sorted(PARAMETER_SPECS)}; got {text!r}"
                )
            pairs[key.strip()] = value.strip()
        changes = pairs
    unknown = sorted(set(changes) - set(PARAMETER_SPECS))
    if unknown:
        raise ParamsError(f"unknown MRAD parameter(s) {unknown}")
    return profile(
        profile_name, **{k: coerce_value(k, PARAMETER_SPECS[k], v) for k, v in changes.items()}
    )


def add_params_options(parser: argparse.ArgumentParser) -> None:
    """Add ``--profile NAME`` and repeatable ``--set KEY=VALUE`` to a command line, read back
    with ``params_from(args.profile, args.set)``."""
    parser.add_argument("--profile", default="default", help=f"one of {sorted(PROFILES)}")
    parser.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="an MRAD parameter over the profile (repeatable)",
    )
