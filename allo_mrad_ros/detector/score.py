"""Stage 1b: the cross RXD score (and the plain RX score) per grid cell.

The per-cell Gaussians are built here (plain, or through the ``cell_affine`` photometric
fit) and their quadratic forms (:mod:`.quadratic`) evaluated at every pixel on the chosen
array backend (:mod:`.backends`).

:func:`cross_scores` scores one query under several photometric models at once: the cell
statistics and the photometric fit are computed once and every model's per-pixel work is
done while a cell's pixels are in cache.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from allo_mrad_ros.detector.backends import PixelBackend, resolve_backend
from allo_mrad_ros.detector.photometric import fit_cell_affine, saturation_variance
from allo_mrad_ros.detector.quadratic import CellModels, pixel_quadratic
from allo_mrad_ros.detector.reference_cache import ReferenceCache, derived
from allo_mrad_ros.detector.statistics import CellStatistics, regularised_precision

PHOTOMETRIC_MODELS = ("none", "cell_affine")
# From this absolute floor on a precision's eigenvalues are at most max_gain**2 / floor
# (<= 1e7), so every score is far inside float32's range and the final finiteness check
# over the whole map can be skipped; below it (property tests run unregularised) it runs.
_BOUNDED_FLOOR = 1e-3


def cross_score(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    abs_floor: float,
    rel_floor: float,
    photometric: str = "none",
    max_gain: float = 2.0,
    backend: PixelBackend | str | None = None,
    cache: ReferenceCache | None = None,
) -> np.ndarray:
    """Return the cross RXD score of every query pixel against its reference cell.

    The one-model form of :func:`cross_scores` (same parameters, ``photometric`` one of
    its models): ``cell_affine`` first maps each reference cell's statistics through the
    gain and offset fitted by :func:`~allo_mrad_ros.detector.photometric.fit_cell_affine`.

    Returns
    -------
    numpy.ndarray
        H x W float32 raw score of the query, finite.
    """
    return cross_scores(
        query, reference, grid, abs_floor, rel_floor, (photometric,), max_gain, backend, cache
    )[0]


def cross_scores(
    query: np.ndarray,
    reference: np.ndarray,
    grid: int,
    abs_floor: float,
    rel_floor: float,
    photometrics: Sequence[str],
    max_gain: float = 2.0,
    backend: PixelBackend | str | None = None,
    cache: ReferenceCache | None = None,
) -> list[np.ndarray]:
    """Return :func:`cross_score` under each photometric model, sharing the statistics.

    Parameters
    ----------
    query, reference : numpy.ndarray
        Validated H x W x 3 images with the same aspect ratio (any resolutions).
    grid : int
        Cells per side.
    abs_floor, rel_floor : float
        Covariance regularisation (see :func:`regularised_precision`).
    photometrics : sequence of {"none", "cell_affine"}
        One score map is returned per entry, in order.
    max_gain : float
        Gain limit of the ``cell_affine`` fit.
    backend : PixelBackend or str, optional
        Where the per-pixel work runs (see :func:`~.backends.select_backend`); NumPy when
        omitted.
    cache : ReferenceCache, optional
        Where the reference's cell statistics and precisions are kept while it is reused.

    Returns
    -------
    list of numpy.ndarray
        H x W float32 raw scores, finite, each equal to the single-model result.
    """
    for photometric in photometrics:
        if photometric not in PHOTOMETRIC_MODELS:
            raise ValueError(f"photometric must be 'none' or 'cell_affine', got {photometric!r}")
    backend = resolve_backend(backend)
    statistics = backend.cell_statistics
    ref_stats = derived(
        cache, reference, ("cell_statistics", statistics, grid), lambda: statistics(reference, grid)
    )
    query_stats = statistics(query, grid)
    affine = None
    models = []
    for photometric in photometrics:
        if photometric == "none":
            ref_precision = derived(
                cache,
                reference,
                ("precision", statistics, grid, abs_floor, rel_floor),
                lambda: regularised_precision(ref_stats.cov, abs_floor, rel_floor),
            )
            models.append(
                CellModels(
                    ref_mean=ref_stats.mean,
                    ref_precision=ref_precision,
                    query_mean=query_stats.mean,
                    query_precision=regularised_precision(query_stats.cov, abs_floor, rel_floor),
                )
            )
            continue
        if affine is None:
            gain, offset = fit_cell_affine(
                query, reference, grid, max_gain, quantiles=backend.cell_quantiles, cache=cache
            )
            widening = derived(
                cache,
                reference,
                ("saturation_variance", grid, max_gain),
                lambda: saturation_variance(reference, grid, max_gain),
            )
            widened_precision = derived(
                cache,
                reference,
                ("widened_precision", statistics, grid, max_gain, abs_floor, rel_floor),
                lambda widening=widening: regularised_precision(
                    ref_stats.cov + widening, abs_floor, rel_floor
                ),
            )
            affine = (gain, offset, widening, widened_precision)
        models.append(_affine_models(ref_stats, query_stats, *affine, abs_floor, rel_floor))
    quadratics = [pixel_quadratic(model) for model in models]
    check_finite = abs_floor < _BOUNDED_FLOOR
    return backend.evaluate(query, grid, quadratics, check_finite)


def _affine_models(
    ref_stats: CellStatistics,
    query_stats: CellStatistics,
    gain: np.ndarray,
    offset: np.ndarray,
    widening: np.ndarray,
    widened_ref_precision: np.ndarray,
    abs_floor: float,
    rel_floor: float,
) -> CellModels:
    # Score in the reference's photometric units (x_ref = (x - offset) / gain), so the
    # regularisation floors mean the same whatever the query's exposure: a darker query
    # does not hide its anomalies under a floor sized for the render. Both models are
    # widened where the reference is saturated, so identical images still cancel exactly.
    # widened_ref_precision is regularised_precision(ref_stats.cov + widening, ...).
    inverse = 1.0 / gain
    in_ref_units = query_stats.cov * inverse[:, :, None] * inverse[:, None, :]
    return CellModels(
        ref_mean=gain * ref_stats.mean + offset,
        ref_precision=_to_query_units(widened_ref_precision, inverse),
        query_mean=query_stats.mean,
        query_precision=_to_query_units(
            regularised_precision(in_ref_units + widening, abs_floor, rel_floor), inverse
        ),
    )


def _to_query_units(precision: np.ndarray, inverse_gain: np.ndarray) -> np.ndarray:
    # A precision P on x_ref = (x - o) / g is D^-1 P D^-1 on x, D = diag(g).
    return precision * inverse_gain[:, :, None] * inverse_gain[:, None, :]


def rx_score(
    image: np.ndarray,
    abs_floor: float,
    rel_floor: float,
    backend: PixelBackend | str | None = None,
) -> np.ndarray:
    """Return the global RX score: squared Mahalanobis distance to the image's own model."""
    backend = resolve_backend(backend)
    stats = backend.cell_statistics(image, 1)
    precision = regularised_precision(stats.cov, abs_floor, rel_floor)
    model = CellModels(stats.mean, precision, stats.mean, np.zeros_like(precision))
    quadratic = pixel_quadratic(model)
    check_finite = abs_floor < _BOUNDED_FLOOR
    return backend.evaluate(image, 1, [quadratic], check_finite)[0]
