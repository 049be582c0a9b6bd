"""MRAD composed from its stages, the image decision, and the RXD/PAD baselines.

Every method takes ``(query, reference, params)`` and returns a :class:`DetectionResult`,
so the node, the evaluator and the benchmarks treat them alike.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from allo_mrad_ros.detector.backends import PixelBackend, resolve_backend
from allo_mrad_ros.detector.bodies import Disc, take_reference_at_limbs
from allo_mrad_ros.detector.colour_transfer import (
    apply_to_query,
    apply_to_reference,
    clip_glare,
    fit_colour_transfer,
)
from allo_mrad_ros.detector.decision import frame_decision, image_score
from allo_mrad_ros.detector.gain_field import apply_gain_field
from allo_mrad_ros.detector.highlights import sun_reach, tolerate_highlights
from allo_mrad_ros.detector.images import (
    area_downscale,
    check_aspect,
    check_image,
    eight_bit,
    nearest_upscale,
    reference_at,
)
from allo_mrad_ros.detector.local import colour_evidence, combine, dark_evidence
from allo_mrad_ros.detector.params import MradParams
from allo_mrad_ros.detector.photometric import fit_cell_affine
from allo_mrad_ros.detector.postprocess import (
    blur_scores,
    continuous_scores,
    remove_noise,
    scale_scores,
    threshold_scores,
)
from allo_mrad_ros.detector.reference_cache import ReferenceCache
from allo_mrad_ros.detector.regions import (
    Region,
    extract_regions,
    find_seeds,
    grow_hysteresis,
    grow_regions,
    seed_window,
)
from allo_mrad_ros.detector.score import cross_score, cross_scores, rx_score
from allo_mrad_ros.detector.structure import structure_score


@dataclass(frozen=True)
class DetectionResult:
    """What a detector found in one query image.

    Attributes
    ----------
    work_score : numpy.ndarray
        h x w float32 in 0..255: the pixel anomaly score at the processing resolution
        (``process_scale`` of the query; the query's own size for the baselines).
    raw_score : numpy.ndarray
        h x w float32 raw score before scaling (at the processing resolution).
    mask : numpy.ndarray
        H x W uint8, 0 or 255, at the query's resolution.
    area : int
        Number of anomalous pixels in ``mask``.
    anomalous : bool
        The frame decision (:attr:`MradParams.frame_rule`): by default, the top of the
        ranking map stands out from the frame's own background level by more than
        ``frame_contrast``; with ``frame_rule="area"``, ``area`` exceeds the area threshold.
    image_score : float
        The frame's anomaly score that image-level metrics rank (see
        :attr:`MradParams.image_score`).
    regions : tuple of Region
        The connected regions of the mask (``connectivity`` of the parameters), in the
        raster order of their first pixel: boxes in the image's and the processing
        resolution's pixels, area, centroid, peak and mean evidence and a score in [0, 1]
        (see :class:`~allo_mrad_ros.detector.regions.Region`).
    timings_ms : dict
        Milliseconds per stage, in pipeline order, plus ``total``.
    masked_score : bool
        The score is zero outside the mask (``pixel_score="regions"``): :attr:`score` is
        masked again after its upscaling.
    work_query : numpy.ndarray or None
        The query at the processing resolution, as the detector saw it before the colour
        transfer (area-averaged); None when not kept.
    work_mask : numpy.ndarray or None
        ``mask`` at the processing resolution, before its upscaling; None when not kept.
    anomaly_score : float
        In [0, 1], the frame decision's score: above 0.5 exactly when ``anomalous`` (see
        :func:`~allo_mrad_ros.detector.decision.frame_decision`).
    """

    work_score: np.ndarray
    raw_score: np.ndarray
    mask: np.ndarray
    area: int
    anomalous: bool
    image_score: float
    regions: tuple[Region, ...]
    timings_ms: dict[str, float] = field(default_factory=dict)
    masked_score: bool = False
    work_query: np.ndarray | None = None
    work_mask: np.ndarray | None = None
    anomaly_score: float = 0.0

    @cached_property
    def score(self) -> np.ndarray:
        """H x W float32 in 0..255: the pixel anomaly score that pixel metrics rank, at the
        query's resolution.

        Made from :attr:`work_score` on first use (a 1080p float32 resize), not by the
        detector: a consumer of the mask or of the processing-resolution map never pays for
        it. Computed once per result; the same values as the detector used to return.
        """
        return _restore_score(self.work_score, self.mask, self.masked_score)


Detector = Callable[..., DetectionResult]
"""``(query, reference, params, *, backend=None, cache=None) -> DetectionResult``."""


class _StageTimer:
    def __init__(self) -> None:
        self.timings: dict[str, float] = {}
        self._start = time.perf_counter()

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.timings[name] = self.timings.get(name, 0.0) + 1e3 * (time.perf_counter() - start)

    def finish(self) -> dict[str, float]:
        self.timings["total"] = 1e3 * (time.perf_counter() - self._start)
        return self.timings


def detect(
    query: np.ndarray,
    reference: np.ndarray | None,
    params: MradParams | None = None,
    *,
    backend: PixelBackend | str | None = None,
    cache: ReferenceCache | None = None,
    sun_pixel: tuple[float, float] | None = None,
    body_discs: Sequence[Disc] = (),
) -> DetectionResult:
    """Run MRAD on a query image against the rendered reference of the same view.

    Parameters
    ----------
    query : numpy.ndarray
        H x W x 3 camera image (uint8, uint16, or float on the 0..1 scale).
    reference : numpy.ndarray
        Rendered reference, same aspect ratio, any resolution.
    params : MradParams, optional
        Detector parameters (defaults if omitted).
    backend : PixelBackend or str, optional
        Array backend of the cross score's per-pixel work (see
        :func:`~allo_mrad_ros.detector.backends.select_backend`); NumPy when omitted.
    cache : ReferenceCache, optional
        Keeps what is derived from a read-only ``reference`` alone (cell statistics,
        quantiles, colour bins) for the next call with the same array object; the result is
        the same as without it.
    sun_pixel : tuple of float, optional
        The Sun's centre ``(x, y)`` in ``query``'s continuous pixel coordinates
        (:meth:`~allo_mrad_ros.view.View.sun_pixel`), None when it is not in front of the
        camera; read only with ``params.sun_glare`` > 0.
    body_discs : sequence of (x, y, radius)
        The Earth's and the Moon's discs in ``query``'s pixels
        (:meth:`~allo_mrad_ros.view.View.body_discs`); read only with ``params.body_margin``
        > 0.

    Returns
    -------
    DetectionResult

    Raises
    ------
    ValueError
        For a malformed image (shape, dtype, NaN/Inf, empty), an aspect mismatch or an
        image smaller than the grid.
    """
    params = params or MradParams()
    timer = _StageTimer()
    query, reference = _checked_pair(query, reference, params, cache, "MRAD")
    full_shape = query.shape[:2]
    work = _resize_query(query, params.process_scale)
    if params.process_scale < 1.0 and min(work.shape[:2]) < params.grid:
        fix = (
            "use a larger image or process_scale=1"
            if min(full_shape) >= params.grid
            else f"use process_scale=1 and a grid of at most {min(full_shape)}"
        )
        raise ValueError(
            f"grid={params.grid} is too fine for the {full_shape[1]}x{full_shape[0]} query "
            f"processed at process_scale={params.process_scale} "
            f"({work.shape[1]}x{work.shape[0]}); {fix}"
        )
    if min(work.shape[:2]) >= params.grid > min(reference.shape[:2]):
        # A narrow camera's reference (700x3 at reference_scale 0.125: 233x1).
        raise ValueError(
            f"grid={params.grid} is too fine for the {reference.shape[1]}x{reference.shape[0]} "
            f"reference of the {full_shape[1]}x{full_shape[0]} query: render it larger "
            f"(reference_scale) or use a grid of at most {min(reference.shape[:2])}"
        )
    seen = work
    if params.colour_transfer != "none":
        with timer.stage("colour_transfer"):
            work, reference = transfer_colours(work, reference, params, cache, backend)
    if params.gain_field_degree > 0:
        with timer.stage("gain_field"):
            work = apply_gain_field(work, reference, params.gain_field_degree)
    sun_in_work = None
    if sun_pixel is not None and params.sun_glare > 0.0:
        sun_in_work = _sun_near_image(sun_pixel, full_shape, work.shape[:2])
    if params.specular_tolerance > 0.0 or params.glare_halo > 0.0 or sun_in_work is not None:
        with timer.stage("highlights"):
            work = tolerate_highlights(
                seen,
                work,
                reference,
                specular_tolerance=params.specular_tolerance,
                glare_halo_factor=params.glare_halo,
                sun_glare_factor=params.sun_glare,
                sun_pixel=sun_in_work,
                cache=cache,
            )
    if body_discs and params.body_margin > 0.0:
        with timer.stage("bodies"):
            work = _limbs_tolerated(
                work, reference, body_discs, params.body_margin, full_shape, cache
            )
    # The ranking map may use another photometric model than the mask; both come from
    # one pass that shares the cell statistics.
    models = [params.photometric]
    if params.pixel_score == "continuous" and params.map_photometric != params.photometric:
        models.append(params.map_photometric)
    with timer.stage("cross_score"):
        raw, *map_raw = cross_scores(
            work,
            reference,
            params.grid,
            params.abs_floor,
            params.rel_floor,
            models,
            params.max_gain,
            backend,
            cache,
        )
    if params.structure_weight > 0.0:
        with timer.stage("structure"):
            # In raw-score units, so it passes through the same scaling, mask and map.
            cue = structure_score(work, reference, params.grid)
            cue *= np.float32(params.structure_weight * params.score_ref)
            raw, map_raw = raw + cue, [m + cue for m in map_raw]
    # The frame decision reads the cell statistics alone: its operating point is calibrated
    # on them, and the local cues' evidence (chosen for the ranking map and the regions)
    # would move it. With a cue on, the decision gets a mask of its own.
    verdict = None
    if params.local_weight > 0.0 or params.dark_weight > 0.0:
        with timer.stage("decision_mask"):
            verdict = _verdict_inputs(raw, map_raw, params, full_shape)
        with timer.stage("local"):
            evidence = local_evidence(work, reference, params, cache)
            raw, map_raw = combine(raw, evidence), [combine(m, evidence) for m in map_raw]
    blurred, mask = _grown_mask(raw, params, timer)
    with timer.stage("regions"):
        regions = extract_regions(mask, blurred, full_shape, params.connectivity)
    with timer.stage("pixel_score"):
        score = _pixel_score(map_raw[0] if map_raw else raw, blurred, mask, params)
    return _decided(
        timer,
        params,
        score,
        raw,
        mask,
        regions,
        full_shape=full_shape,
        work_query=seen,
        masked_score=params.pixel_score == "regions",
        verdict=verdict,
    )


def _limbs_tolerated(
    work: np.ndarray,
    reference: np.ndarray,
    discs: Sequence[Disc],
    margin: float,
    full_shape: tuple[int, int],
    cache: ReferenceCache | None,
) -> np.ndarray:
    """``work`` with the reference's colour within ``margin`` reference pixels of the
    bodies' limbs (``discs`` in the pixels of the query, of ``full_shape``)."""
    height, width = work.shape[:2]
    scaled = [
        (*_at_work_scale((x, y), full_shape, work.shape[:2]), radius * width / full_shape[1])
        for x, y, radius in discs
    ]
    # A reference pixel in processing pixels (the aspect ratios agree: check_aspect).
    margin_px = margin * width / reference.shape[1]
    near = reference_at(reference, (height, width), cache)
    return take_reference_at_limbs(eight_bit(work), near, scaled, margin_px)


def _at_work_scale(
    point: tuple[float, float], full_shape: tuple[int, int], work_shape: tuple[int, int]
) -> tuple[float, float]:
    """A point in the query's continuous pixel coordinates at the processing resolution
    (continuous coordinates scale with the image's size along each axis)."""
    return (point[0] * work_shape[1] / full_shape[1], point[1] * work_shape[0] / full_shape[0])


def _sun_near_image(
    sun_pixel: tuple[float, float], full_shape: tuple[int, int], work_shape: tuple[int, int]
) -> tuple[float, float] | None:
    """The Sun's pixel at the processing resolution, None when it lies farther outside the
    image than a clipped component may lie from it (:func:`sun_reach`): then there is no
    glare to place, and the highlights stage is skipped."""
    x, y = _at_work_scale(sun_pixel, full_shape, work_shape)
    reach = sun_reach(work_shape)
    inside = -reach <= x < work_shape[1] + reach and -reach <= y < work_shape[0] + reach
    return (x, y) if inside else None


@dataclass(frozen=True)
class _VerdictInputs:
    """What the frame decision reads when it is made apart from the published mask (see
    :func:`detect`): the mask at both resolutions, the ranking map and the mask's raw score."""

    full_mask: np.ndarray
    score: np.ndarray
    raw: np.ndarray
    mask: np.ndarray


def _grown_mask(
    raw: np.ndarray, params: MradParams, timer: _StageTimer | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Stages 2-4 on a raw score map: scaling and threshold, noise removal, blur and region
    growth; the blurred scores and the mask (uint8, 0/1), at the processing resolution."""
    timer = timer or _StageTimer()
    with timer.stage("scale_threshold"):
        scaled = threshold_scores(
            scale_scores(raw, params.score_scaling, params.score_ref), params.min_score
        )
    with timer.stage("noise_removal"):
        cleaned = remove_noise(
            scaled,
            params.grid,
            min_score=params.min_score,
            kernel_fraction=params.kernel_fraction,
            std_thresh=params.std_thresh,
            large_anomaly_fraction=params.large_anomaly_fraction,
            noise_removal=params.noise_removal,
        )
    sigma = params.blur_sigma * params.process_scale
    with timer.stage("blur"):
        blurred = blur_scores(cleaned, sigma)
    if params.growth == "hysteresis":
        with timer.stage("region_growing"):
            mask = grow_hysteresis(
                blurred, params.min_score, params.seed_score, params.connectivity
            )
    else:
        with timer.stage("seeds"):
            seeds = find_seeds(blurred, params.min_score, seed_window(sigma))
        with timer.stage("region_growing"):
            mask = grow_regions(
                blurred, seeds, params.tolerance, params.min_score, params.connectivity
            )
    return blurred, mask


def _verdict_inputs(
    raw: np.ndarray, map_raw: list[np.ndarray], params: MradParams, full_shape: tuple[int, int]
) -> _VerdictInputs:
    """The decision's inputs from the cell statistics' scores alone (``raw`` for the mask,
    ``map_raw`` for the ranking map where it has a model of its own)."""
    blurred, mask = _grown_mask(raw, params)
    score = blurred
    if params.frame_map == "ranking":
        score = _pixel_score(map_raw[0] if map_raw else raw, blurred, mask, params)
    return _VerdictInputs(_restore_resolution(mask, full_shape), score, raw, mask)


def transfer_colours(
    query: np.ndarray,
    reference: np.ndarray,
    params: MradParams,
    cache: ReferenceCache | None = None,
    backend: PixelBackend | str | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Stage 0: bring query and reference to one set of colours (``params.colour_transfer``).

    ``cache`` keeps the reference's share of the work while it is reused and ``backend``
    computes the contrast gain's cell quantiles (see :func:`detect`).

    Returns
    -------
    query, reference : numpy.ndarray
        The pair with one of them mapped (uint8); both unchanged for ``none``.
    """
    if params.colour_transfer == "none":
        return query, reference
    transfer = fit_colour_transfer(
        query,
        reference,
        params.transfer_bin,
        params.transfer_min_count,
        params.transfer_edge_margin,
        cache,
    )
    if params.colour_transfer == "query":
        gain = None
        if params.transfer_gain:
            # Only a flatter query's contrast is restored: a steeper one (a gain a black
            # shadow or a tone curve's toe inflated) would shrink an object's departure.
            quantiles = resolve_backend(backend).cell_quantiles
            gain, _ = fit_cell_affine(
                query, reference, params.grid, params.max_gain, quantiles, cache
            )
            gain = np.minimum(gain, 1.0)
        mapped = apply_to_query(query, reference, transfer, params.glare_level, gain, cache)
        return mapped, reference
    reference = apply_to_reference(reference, transfer)
    if params.glare_level < 256.0:
        query = clip_glare(query, reference, params.glare_level)
    return query, reference


def local_evidence(
    query: np.ndarray,
    reference: np.ndarray,
    params: MradParams,
    cache: ReferenceCache | None = None,
) -> np.ndarray:
    """The local cues of ``params`` (``local_weight``, ``dark_weight``) in raw-score units,
    the larger where both are on and ``-inf`` where neither has evidence: what
    :func:`~allo_mrad_ros.detector.local.combine` merges with the cross score. ``query`` is
    the processed query after the colour transfer.
    """
    weighted = (
        (colour_evidence, params.local_weight),
        (dark_evidence, params.dark_weight * params.score_ref),
    )
    cues = [
        evidence(
            query,
            reference,
            params.grid,
            params.local_radius,
            params.abs_floor,
            cache,
            weight=weight,
            empty=-np.inf,
        )
        for evidence, weight in weighted
        if weight > 0.0
    ]
    return cues[0] if len(cues) == 1 else cv2.max(cues[0], cues[1])


def _pixel_score(
    raw: np.ndarray, blurred: np.ndarray, mask: np.ndarray, params: MradParams
) -> np.ndarray:
    # The map the pixel metrics rank. The regions decide the mask; zeroing the map outside
    # them ("regions", the paper's sparse map) ties most anomaly pixels at 0.
    if params.pixel_score == "regions":
        return _masked(blurred, mask)
    if params.pixel_score == "blurred":
        return blurred
    ranked = continuous_scores(raw, params.score_scaling, params.score_ref)
    return blur_scores(ranked, params.score_sigma * params.process_scale)


def detect_pad(
    query: np.ndarray,
    reference: np.ndarray | None,
    params: MradParams | None = None,
    *,
    backend: PixelBackend | str | None = None,
    cache: ReferenceCache | None = None,
    sun_pixel: tuple[float, float] | None = None,
    body_discs: Sequence[Disc] = (),
) -> DetectionResult:
    """PAD baseline: the cross score with one cell and only a threshold after scaling.

    The result's ``score`` is the scaled cross score; ``mask`` is where it reaches
    ``params.min_score``. ``cache`` as for :func:`detect`; ``sun_pixel`` and ``body_discs``
    are accepted for a uniform interface and ignored (the baseline models neither).
    """
    params = params or MradParams()
    query, reference = _checked_pair(query, reference, params, cache, "PAD")
    timer = _StageTimer()
    with timer.stage("cross_score"):
        raw = cross_score(
            query, reference, 1, params.abs_floor, params.rel_floor, backend=backend, cache=cache
        )
    return _threshold_only(query, raw, params, timer)


def detect_rxd(
    query: np.ndarray,
    reference: np.ndarray | None = None,
    params: MradParams | None = None,
    *,
    backend: PixelBackend | str | None = None,
    cache: ReferenceCache | None = None,
    sun_pixel: tuple[float, float] | None = None,
    body_discs: Sequence[Disc] = (),
) -> DetectionResult:
    """RXD baseline: each pixel against the whole query's mean and covariance.

    ``reference``, ``cache``, ``sun_pixel`` and ``body_discs`` are accepted for a uniform
    interface and ignored. Scores and mask as in :func:`detect_pad`.
    """
    params = params or MradParams()
    query = check_image(query, "query", params.bit_depth)
    timer = _StageTimer()
    with timer.stage("rx_score"):
        raw = rx_score(query, params.abs_floor, params.rel_floor, backend)
    return _threshold_only(query, raw, params, timer)


def _threshold_only(
    query: np.ndarray, raw: np.ndarray, params: MradParams, timer: _StageTimer
) -> DetectionResult:
    # The baselines rank pixels by their scaled score; the threshold only makes the mask.
    with timer.stage("scale_threshold"):
        score = scale_scores(raw, params.score_scaling, params.score_ref)
        mask = cv2.compare(threshold_scores(score.copy(), params.min_score), 0.0, cv2.CMP_GT)
    with timer.stage("regions"):
        regions = extract_regions(mask, score, mask.shape, params.connectivity)
    return _decided(
        timer, params, score, raw, mask, regions, full_shape=mask.shape, work_query=query
    )


def _decided(
    timer: _StageTimer,
    params: MradParams,
    score: np.ndarray,
    raw: np.ndarray,
    mask: np.ndarray,
    regions: tuple[Region, ...],
    *,
    full_shape: tuple[int, int],
    work_query: np.ndarray,
    masked_score: bool = False,
    verdict: _VerdictInputs | None = None,
) -> DetectionResult:
    """The last stage of every method: the mask (at the processing resolution) back at the
    query's ``full_shape``, the image decision on it (on ``verdict`` where the decision is
    made apart), and the result."""
    with timer.stage("decision"):
        # The full-resolution score is made only when read (DetectionResult.score).
        full_mask = _restore_resolution(mask, full_shape)
        decided = verdict or _VerdictInputs(full_mask, score, raw, mask)
        decision = frame_decision(
            decided.full_mask, decided.score, decided.raw, decided.mask, work_query, params
        )
        area = decision.area if verdict is None else int(cv2.countNonZero(full_mask))
        frame_score = image_score(score, area, params)
    return DetectionResult(
        work_score=score,
        raw_score=raw,
        mask=full_mask,
        area=area,
        anomalous=decision.anomalous,
        image_score=frame_score,
        regions=regions,
        timings_ms=timer.finish(),
        masked_score=masked_score,
        work_query=work_query,
        work_mask=mask,
        anomaly_score=decision.anomaly_score,
    )


def _checked_pair(
    query: np.ndarray,
    reference: np.ndarray | None,
    params: MradParams,
    cache: ReferenceCache | None,
    method: str,
) -> tuple[np.ndarray, np.ndarray]:
    """The validated query and reference of a ``method`` that compares them, with ``cache``
    told which reference is in use."""
    if reference is None:
        raise ValueError(f"reference is required for {method} (got None)")
    query = check_image(query, "query", params.bit_depth)
    reference = check_image(reference, "reference", params.bit_depth)
    check_aspect(query, reference)
    if cache is not None:
        cache.use(reference)
    return query, reference


def _resize_query(query: np.ndarray, scale: float) -> np.ndarray:
    if scale == 1.0:
        return query
    height, width = query.shape[:2]
    return area_downscale(query, (max(1, round(width * scale)), max(1, round(height * scale))))


def _restore_resolution(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The mask at the query's resolution (``shape``)."""
    return mask if mask.shape == shape else nearest_upscale(mask, shape)


def _restore_score(score: np.ndarray, mask: np.ndarray, masked: bool) -> np.ndarray:
    """The score map at the mask's (the query's) resolution: bilinear, and zero outside the
    mask again when ``masked`` (the ``regions`` map), whose upscaling would blur it out."""
    shape = mask.shape[:2]
    if score.shape == shape:
        return score
    score = cv2.resize(score, (shape[1], shape[0]), interpolation=cv2.INTER_LINEAR)
    return _masked(score, mask) if masked else score


def _masked(values: np.ndarray, mask: np.ndarray) -> np.ndarray:
    out = np.zeros_like(values)
    cv2.copyTo(values, mask, out)
    return out


METHODS: dict[str, Detector] = {"MRAD": detect, "PAD": detect_pad, "RXD": detect_rxd}
