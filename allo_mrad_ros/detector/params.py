"""MRAD parameters: one validated dataclass, named profiles.

Defaults keep the paper's kernel (20 % of the cell), blur SD 5 and tolerance 50 (used by
tolerance growth only). Grid 8x8, processing at a quarter of the query's size
(``process_scale`` 0.25), the per-cell noise rule, hysteresis growth, the continuous ranking
map and the photometric models were chosen on the validation split by the
speed-against-error benchmark (``make bench``), the colour transfer of the query into the
reference's colours on the multi-station bench; the values the paper leaves open were
decided by measurement. docs/method.md states the method and the rule by which a default
is chosen; docs/detector.md ("How the defaults were chosen") gives the measurements.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Literal

from allo_mrad_ros.detector.colour_transfer import DIRECTIONS as TRANSFER_DIRECTIONS

ScoreScaling = Literal["fixed", "per_image"]
NoiseRemoval = Literal["local_std", "cell_spread", "none"]
PixelScore = Literal["continuous", "regions", "blurred"]
Growth = Literal["tolerance", "hysteresis"]
Photometric = Literal["none", "cell_affine"]
ImageScore = Literal["area", "map_top"]
ColourTransferDirection = Literal["none", "reference", "query"]

SCORE_RANGE = 255.0


@dataclass(frozen=True)
class MradParams:
    """Parameters of :func:`allo_mrad_ros.detector.detect`.

    All score-valued parameters are on the 0..255 scale of the scaled score map; colour
    values are on the 0..255 scale of an 8-bit image whatever the input dtype.

    Parameters
    ----------
    grid : int
        Cells per side of the statistics grid (1 = no grid), 1..64.
    tolerance : float
        Region-growing range around a seed's blurred score, 0..255.
    kernel_fraction : float
        Side of the local-std window as a fraction of the cell's height and width, (0, 1].
    blur_sigma : float
        Standard deviation of the Gaussian blur in pixels at full query resolution, >= 0
        (0 disables the blur).
    score_scaling : {"fixed", "per_image"}
        ``fixed`` maps raw score ``score_ref`` to 255 in every frame; ``per_image``
        divides by the frame's maximum (the paper's reading).
    score_ref : float
        Raw cross score mapped to 255 by ``fixed`` scaling, > 0.
    min_score : float
        Scaled scores below this are zeroed; also the lowest seed and grown value, 0..255.
    noise_removal : {"local_std", "cell_spread", "none"}
        ``local_std`` zeroes pixels whose local standard deviation is below ``std_thresh``
        (the paper's text); ``cell_spread`` zeroes a whole cell when the spread of its local
        standard deviations is below ``std_thresh`` (the paper's pseudo-code).
    std_thresh : float
        Flatness threshold of noise removal on the 0..255 scale, 0..255.
    large_anomaly_fraction : float
        A cell with more than this fraction of scores above ``min_score`` is kept whole and
        skips noise removal, (0, 1].
    abs_floor : float
        Absolute covariance regularisation (8-bit intensity units squared), > 0.
    rel_floor : float
        Covariance regularisation relative to the mean variance ``trace(S) / 3``, >= 0.
    connectivity : {4, 8}
        Region-growing neighbourhood (8 = the 3x3 square footprint).
    area_threshold : float
        Fraction of the image the mask must exceed for the frame to be anomalous, [0, 1).
    process_scale : float
        Linear scale at which the query is processed, (0, 1]; outputs are returned at the
        query's resolution.
    pixel_score : {"continuous", "regions", "blurred"}
        What ``DetectionResult.score`` holds (the mask is the same either way):
        ``continuous`` is the positive raw score softly saturated onto 0..255 (no minimum
        cut, no zeroing outside the regions), smoothed by ``score_sigma``; it ranks pixels.
        ``regions`` (the paper's sparse map) keeps the blurred map inside the grown regions
        only; ``blurred`` keeps the whole blurred map.
    score_sigma : float
        Gaussian smoothing of the ``continuous`` map in pixels at full resolution, >= 0.
    growth : {"tolerance", "hysteresis"}
        ``tolerance``: mean-shift seeds grown within ``tolerance`` of their score (the
        paper). ``hysteresis``: every connected region of the blurred map at or above
        ``min_score`` that reaches ``seed_score`` somewhere (keeps small and thin objects
        whose peak the blur lowered).
    seed_score : float
        Score a hysteresis region must reach, 0..255.
    photometric : {"none", "cell_affine"}
        Photometric model of the score the mask and the decision come from:
        ``cell_affine`` fits each cell's reference colours to the query's by a robust
        per-channel gain and offset (quantiles) before scoring, so exposure, tone curve,
        white balance and light fall-off do not flag a normal frame.
    map_photometric : {"none", "cell_affine"}
        Photometric model of the score behind the ``continuous`` ranking map (chosen
        separately: on the bench validation split the model cost ranking accuracy).
    max_gain : float
        Largest per-channel gain (and smallest, its inverse) ``cell_affine`` may apply, >= 1.
    bit_depth : int
        Significant bits of uint16 input (e.g. 12 for a 12-bit camera), 9..16.
    image_score : {"area", "map_top"}
        The frame's anomaly score, what image-level metrics (I.AUROC) rank: ``area`` is the
        mask's area (the paper's); ``map_top`` the mean of the top ``image_top_fraction``
        of the pixel score map (anomalib ranks frames by the map's maximum; a top fraction
        does not hang on one pixel). The anomalous flag always comes from the mask's area.
    image_top_fraction : float
        Fraction of the processed pixels ``map_top`` averages, (0, 1].
    colour_transfer : {"none", "reference", "query"}
        Per-frame colour transfer before the cell statistics (a 3-D table from reference
        colour to query colour, medians per colour bin, fitted away from reference edges):
        ``query`` maps the query into the reference's colours (the reference's statistics
        stay its own), ``reference`` maps the reference into the query's; ``none`` skips it.
    transfer_bin : int
        Width of the finest colour bins of the transfer, 8-bit levels: 4, 8, 16, 32 or 64.
    transfer_min_count : int
        Pixel pairs a colour bin needs for an offset of its own (else the enclosing coarser
        bin's), 1..1e6.
    transfer_edge_margin : int
        Pixels around reference edges left out of the transfer's fit, 0..16.
    transfer_gain : bool
        With ``colour_transfer="query"``, divide what departs from the transferred colours by
        each cell's contrast gain (the ``cell_affine`` fit, capped at 1), so an object keeps
        its contrast in the reference's units under a darker or flatter query.
    glare_level : float
        With a colour transfer, a query pixel whose every channel reaches this level over
        station surface is glare (it says "brighter than white", not which colour) and
        takes the reference's colour; 256 disables it, 128..256.
    structure_weight : float
        Weight of the structure cue (:mod:`~allo_mrad_ros.detector.structure`: edges the
        query has and its reference cell does not, luminance-normalised) added to the raw
        cross score, in units of ``score_ref`` per unit of excess log-contrast; 0 (the
        default, as measured: it did not pay) leaves it out, 0..100.
    """

    grid: int = 8
    tolerance: float = 50.0
    kernel_fraction: float = 0.20
    blur_sigma: float = 5.0
    score_scaling: ScoreScaling = "fixed"
    score_ref: float = 1000.0
    min_score: float = 25.0
    noise_removal: NoiseRemoval = "cell_spread"
    std_thresh: float = 10.0
    large_anomaly_fraction: float = 0.90
    abs_floor: float = 16.0
    rel_floor: float = 1e-3
    connectivity: int = 8
    area_threshold: float = 0.001
    process_scale: float = 0.25
    pixel_score: PixelScore = "continuous"
    score_sigma: float = 1.0
    growth: Growth = "hysteresis"
    seed_score: float = 30.0
    photometric: Photometric = "cell_affine"
    map_photometric: Photometric = "none"
    max_gain: float = 2.0
    bit_depth: int = 16
    image_score: ImageScore = "map_top"
    image_top_fraction: float = 1e-3
    colour_transfer: ColourTransferDirection = "query"
    transfer_bin: int = 16
    transfer_min_count: int = 16
    transfer_edge_margin: int = 0
    transfer_gain: bool = True
    glare_level: float = 250.0
    structure_weight: float = 0.0

    def __post_init__(self) -> None:
        for name, spec in PARAMETER_SPECS.items():
            spec.check(name, getattr(self, name))

    def replace(self, **changes: Any) -> MradParams:
        """Return a copy with ``changes`` applied (validated)."""
        unknown = set(changes) - {f.name for f in fields(self)}
        if unknown:
            raise ValueError(f"unknown MRAD parameter(s): {sorted(unknown)}")
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
        """Raise ValueError naming ``name`` and ``value`` if the value is invalid."""
        if self.choices:
            if value not in self.choices:
                raise ValueError(f"{name} must be one of {list(self.choices)}, got {value!r}")
            return
        if self.kind is int:
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"{name} must be an integer in {self.interval()}, got {value!r}")
        elif isinstance(value, bool) or not isinstance(value, int | float):
            raise ValueError(f"{name} must be a number, got {value!r}")
        if not math.isfinite(value):
            raise ValueError(f"{name} must be finite, got {value!r}")
        too_low = value <= self.low if self.low_open else value < self.low
        too_high = value >= self.high if self.high_open else value > self.high
        if too_low or too_high:
            what = "an integer in" if self.kind is int else "in"
            raise ValueError(f"{name} must be {what} {self.interval()}, got {value!r}")

    def interval(self) -> str:
        """The valid range in interval notation, e.g. ``(0, 1]``."""
        lo, hi = ("(" if self.low_open else "["), (")" if self.high_open else "]")
        return f"{lo}{self.low:g}, {self.high:g}{hi}"


PARAMETER_SPECS: dict[str, ParameterSpec] = {
    "grid": ParameterSpec(int, "cells per side of the statistics grid (1 = no grid)", 1, 64),
    "tolerance": ParameterSpec(
        float, "region-growing range around a seed's blurred score (0..255 scale)", 0, SCORE_RANGE
    ),
    "kernel_fraction": ParameterSpec(
        float, "local-std window as a fraction of the cell's height and width", 0, 1, low_open=True
    ),
    "blur_sigma": ParameterSpec(
        float, "Gaussian blur SD in pixels at full resolution (0 = no blur)", 0, 100
    ),
    "score_scaling": ParameterSpec(
        str,
        "fixed: score_ref maps to 255; per_image: the frame maximum maps to 255",
        choices=("fixed", "per_image"),
    ),
    "score_ref": ParameterSpec(
        float, "raw cross score mapped to 255 by fixed scaling", 0, 1e12, low_open=True
    ),
    "min_score": ParameterSpec(
        float, "scaled scores below this are zeroed; lowest seed and grown value", 0, SCORE_RANGE
    ),
    "noise_removal": ParameterSpec(
        str,
        "local_std: per-region flatness rule; cell_spread: per-cell rule; none",
        choices=("local_std", "cell_spread", "none"),
    ),
    "std_thresh": ParameterSpec(
        float, "local standard deviation below which scores are flat noise (0..255)", 0, SCORE_RANGE
    ),
    "large_anomaly_fraction": ParameterSpec(
        float, "a cell with more of its scores above min_score is kept whole", 0, 1, low_open=True
    ),
    "abs_floor": ParameterSpec(
        float, "absolute covariance regularisation (8-bit units squared)", 0, 1e6, low_open=True
    ),
    "rel_floor": ParameterSpec(float, "covariance regularisation relative to trace(S)/3", 0, 1),
    "connectivity": ParameterSpec(
        int, "region-growing neighbourhood: 8 (3x3 square) or 4", choices=(4, 8)
    ),
    "area_threshold": ParameterSpec(
        float,
        "mask fraction of the image above which the frame is anomalous",
        0,
        1,
        high_open=True,
    ),
    "process_scale": ParameterSpec(
        float, "linear scale at which the query is processed", 0, 1, low_open=True
    ),
    "pixel_score": ParameterSpec(
        str,
        "score output: continuous (ranking map), regions (paper's sparse map) or blurred",
        choices=("continuous", "regions", "blurred"),
    ),
    "score_sigma": ParameterSpec(
        float, "Gaussian smoothing SD of the continuous score map (px, full resolution)", 0, 100
    ),
    "growth": ParameterSpec(
        str,
        "tolerance: seeds grown within tolerance (paper); hysteresis: min_score/seed_score",
        choices=("tolerance", "hysteresis"),
    ),
    "seed_score": ParameterSpec(
        float, "score a hysteresis region must reach somewhere (0..255)", 0, SCORE_RANGE
    ),
    "photometric": ParameterSpec(
        str,
        "none, or cell_affine: robust per-cell gain/offset fit of the reference to the query",
        choices=("none", "cell_affine"),
    ),
    "map_photometric": ParameterSpec(
        str,
        "photometric model of the continuous ranking map: none or cell_affine",
        choices=("none", "cell_affine"),
    ),
    "max_gain": ParameterSpec(float, "largest per-channel gain of cell_affine", 1, 100),
    "bit_depth": ParameterSpec(int, "significant bits of uint16 input images", 9, 16),
    "image_score": ParameterSpec(
        str,
        "frame score that image metrics rank: area (of the mask) or map_top (top of the map)",
        choices=("area", "map_top"),
    ),
    "image_top_fraction": ParameterSpec(
        float,
        "fraction of the processed pixels the map_top image score averages",
        0,
        1,
        low_open=True,
    ),
    "colour_transfer": ParameterSpec(
        str,
        "per-frame colour table before the statistics: query (map the query), reference, none",
        choices=("none", *TRANSFER_DIRECTIONS),
    ),
    "transfer_bin": ParameterSpec(
        int,
        "finest colour-bin width of the colour transfer (8-bit levels)",
        choices=(4, 8, 16, 32, 64),
    ),
    "transfer_min_count": ParameterSpec(
        int, "pixel pairs a colour bin needs for its own offset", 1, 1_000_000
    ),
    "transfer_edge_margin": ParameterSpec(
        int, "pixels around reference edges left out of the colour-transfer fit", 0, 16
    ),
    "transfer_gain": ParameterSpec(
        bool,
        "divide departures from the transferred colours by the cell's contrast gain",
        choices=(True, False),
    ),
    "glare_level": ParameterSpec(
        float, "query level (every channel) above which station pixels are glare; 256 off", 128, 256
    ),
    "structure_weight": ParameterSpec(
        float,
        "weight of the structure cue (edges absent from the reference cell); 0 off",
        0,
        100,
    ),
}


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
)

PROFILES: dict[str, MradParams] = {
    # Chosen on the validation split by `make bench` (docs/evaluation.md, "Speed against error").
    "default": MradParams(),
    # The paper read literally: its optimum with per-image score scaling, full resolution.
    "paper": _PAPER_OPTIMUM.replace(score_scaling="per_image", pixel_score="regions"),
    # The paper's optimum with fixed scaling and the continuous ranking map.
    "baseline": _PAPER_OPTIMUM,
    # The most accurate mrad.md setting of the sweep on validation, at full resolution.
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
        raise ValueError(f"unknown MRAD profile {name!r}; choose one of {sorted(PROFILES)}")
    return PROFILES[name].replace(**overrides) if overrides else PROFILES[name]
