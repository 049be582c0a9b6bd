"""The smooth gain field: a float64 oracle, recovery of a known field past an object, and the
object kept out of the field.

The oracle selects the usable pixels pixel by pixel (station, unclipped, not dark, away from
reference edges) and runs Tukey-weighted IRLS through the normal equations in float64; the
module's fit must match it, and on the final inlier set its coefficients must equal
``numpy.linalg.lstsq`` weighted by the same weights.
"""

import numpy as np
import pytest

from allo_mrad_ros.detector import MradParams, detect
from allo_mrad_ros.detector.gain_field import (
    CLIPPED_LEVEL,
    DARK_LEVEL,
    EDGE_LEVELS,
    EDGE_MARGIN,
    ITERATIONS,
    SPACE_LEVEL,
    TUKEY_C,
    GainFieldError,
    apply_gain_field,
    fit_gain_field,
    usable_pixels,
)
from allo_mrad_ros.detector.params import ParamsError

HEIGHT, WIDTH = 60, 80
OBJECT = (slice(20, 38), slice(50, 72))


def scene() -> np.ndarray:
    """Space on the left, two station panels with an edge between them."""
    image = np.zeros((HEIGHT, WIDTH, 3))
    image[:, :13] = (3, 3, 5)
    image[:, 13:40] = (100, 140, 90)
    image[:, 40:] = (120, 118, 125)
    return image


def true_log_gain(degree: int) -> np.ndarray:
    rows, cols = np.mgrid[0:HEIGHT, 0:WIDTH]
    x = 2.0 * (cols + 0.5) / WIDTH - 1.0
    y = 2.0 * (rows + 0.5) / HEIGHT - 1.0
    field = 0.05 + 0.2 * x - 0.1 * y
    if degree >= 2:
        field += 0.15 * x * y - 0.1 * x * x
    if degree >= 3:
        field += 0.05 * x**3
    return field


def shaded_query(degree: int, *, with_object: bool, seed: int = 0) -> tuple[np.ndarray, ...]:
    reference = np.clip(np.rint(scene()), 0, 255).astype(np.uint8)
    query = scene() * np.exp(true_log_gain(degree))[..., None]
    query += np.random.default_rng(seed).normal(0.0, 1.0, query.shape)
    if with_object:
        query[OBJECT] = (30.0, 28.0, 26.0)  # a dark object, well off the field
    return reference, np.clip(np.rint(query), 0, 255).astype(np.uint8)


# ---------------------------------------------------------------- oracle
def oracle_usable(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    q = query.astype(np.float64)
    r = reference.astype(np.float64)
    luma = np.array([0.299, 0.587, 0.114])
    half = 1 + EDGE_MARGIN
    keep = np.zeros(q.shape[:2], bool)
    for y in range(q.shape[0]):
        for x in range(q.shape[1]):
            window = r[max(0, y - half) : y + half + 1, max(0, x - half) : x + half + 1]
            spread = (window.max(axis=(0, 1)) - window.min(axis=(0, 1))).max()
            keep[y, x] = (
                spread <= EDGE_LEVELS
                and r[y, x].max() > SPACE_LEVEL
                and q[y, x].max() < CLIPPED_LEVEL
                and r[y, x].max() < CLIPPED_LEVEL
                and q[y, x] @ luma > DARK_LEVEL
                and r[y, x] @ luma > DARK_LEVEL
            )
    return keep


def oracle_fit(query, reference, degree):
    """Float64 IRLS by the normal equations over every usable pixel (no subsampling)."""
    keep = oracle_usable(query, reference)
    rows, cols = np.nonzero(keep)
    luma = np.array([0.299, 0.587, 0.114])
    target = np.log(query[rows, cols].astype(np.float64) @ luma) - np.log(
        reference[rows, cols].astype(np.float64) @ luma
    )
    x = 2.0 * (cols + 0.5) / query.shape[1] - 1.0
    y = 2.0 * (rows + 0.5) / query.shape[0] - 1.0
    terms = [(t - j, j) for t in range(degree + 1) for j in range(t + 1)]
    design = np.stack([x**i * y**j for i, j in terms], axis=1)
    low, high = np.quantile(target, [0.25, 0.75])
    weights = ((target >= low) & (target <= high)).astype(np.float64)
    for step in range(ITERATIONS + 1):
        normal = design.T @ (weights[:, None] * design)
        coefficients = np.linalg.solve(normal, design.T @ (weights * target))
        if step == ITERATIONS:
            break
        residual = target - design @ coefficients
        scale = max(1.4826 * np.median(np.abs(residual)), 0.01)
        u = residual / (TUKEY_C * scale)
        weights = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
    return keep, coefficients, weights, design, target


@pytest.mark.slow
@pytest.mark.parametrize("degree", [1, 2, 3])
@pytest.mark.parametrize("with_object", [False, True])
def test_fit_matches_the_float64_oracle_and_lstsq_on_its_inliers(degree, with_object):
    reference, query = shaded_query(degree, with_object=with_object)
    keep, expected, weights, design, target = oracle_fit(query, reference, degree)
    np.testing.assert_array_equal(usable_pixels(query, reference), keep)
    assert keep.sum() <= 4096  # the module subsamples above that; here it takes every pixel
    fitted = fit_gain_field(query, reference, degree)
    assert fitted.samples == keep.sum()
    np.testing.assert_allclose(fitted.coefficients, expected, rtol=0, atol=1e-6)
    np.testing.assert_array_equal(fitted.inliers, weights > 0.0)
    # numpy.linalg.lstsq on the inlier set, weighted by the final weights (the module takes
    # luma in float32: agreement to 1e-6 in log gain).
    inliers = weights > 0.0
    root = np.sqrt(weights[inliers])
    check, *_ = np.linalg.lstsq(design[inliers] * root[:, None], target[inliers] * root, rcond=None)
    np.testing.assert_allclose(fitted.coefficients, check, rtol=0, atol=1e-6)


# ---------------------------------------------------------------- recovery
@pytest.mark.parametrize("degree", [1, 2, 3])
def test_a_known_polynomial_gain_is_recovered_past_an_object(degree):
    reference, query = shaded_query(degree, with_object=True)
    fitted = fit_gain_field(query, reference, degree)
    # Where the fit had samples (the field is clipped to its fitted range beyond them).
    usable = usable_pixels(query, reference)
    usable[OBJECT] = False
    error = np.abs(fitted.log_gain((HEIGHT, WIDTH)) - true_log_gain(degree))[usable]
    assert error.max() < 0.02, error.max()


def test_a_pasted_object_is_not_absorbed_by_the_field():
    reference, query = shaded_query(2, with_object=True)
    fitted = fit_gain_field(query, reference, 2)
    rows, cols = np.nonzero(usable_pixels(query, reference))
    index = rows * WIDTH + cols
    index = index[:: max(1, -(-index.size // 4096))]
    on_object = np.zeros((HEIGHT, WIDTH), bool)
    on_object[OBJECT] = True
    # Every sample on the object ends with weight 0.
    assert not fitted.inliers[on_object.reshape(-1)[index]].any()
    # After the division the station is back at the reference's colours and the object
    # keeps its departure from them.
    flat = apply_gain_field(query, reference, 2).astype(np.float64)
    background = ~on_object & (reference.max(axis=2) > SPACE_LEVEL)
    drift = np.abs(flat - reference)[background]
    assert np.median(drift) <= 1.5 and np.quantile(drift, 0.99) <= 6.0
    departure = (reference.astype(np.float64) - flat)[OBJECT].mean()
    assert departure > 60.0, departure


def test_the_field_flattens_shading_the_detector_would_flag_and_keeps_the_object():
    # A strong smooth fall-off across the grey panel, with and without the field.
    reference, shaded = shaded_query(2, with_object=False)
    _, with_object = shaded_query(2, with_object=True)
    # Twice the field: steeper than the cells' photometric model follows.
    gain = np.exp(true_log_gain(2))[..., None]
    shaded = np.clip(np.rint(shaded * gain), 0, 255).astype(np.uint8)
    with_object = np.clip(np.rint(with_object * gain), 0, 255).astype(np.uint8)
    on = MradParams(gain_field_degree=2, process_scale=1.0, grid=4)
    off = on.replace(gain_field_degree=0)
    assert detect(shaded, reference, off).area > 0
    assert detect(shaded, reference, on).area == 0
    found = detect(with_object, reference, on)
    truth = np.zeros((HEIGHT, WIDTH), bool)
    truth[OBJECT] = True
    assert found.anomalous
    assert np.count_nonzero(found.mask[truth]) >= 0.8 * truth.sum()


# ---------------------------------------------------------------- parameters
def test_degree_zero_returns_the_query_itself():
    reference, query = shaded_query(1, with_object=False)
    assert apply_gain_field(query, reference, 0) is query


def test_too_few_usable_pixels_leave_the_query_unchanged():
    reference = np.zeros((HEIGHT, WIDTH, 3), np.uint8)  # all space
    query = np.full((HEIGHT, WIDTH, 3), 50, np.uint8)
    assert fit_gain_field(query, reference, 2).coefficients.size == 0
    np.testing.assert_array_equal(apply_gain_field(query, reference, 2), query)


def test_a_smaller_reference_is_fitted_at_its_size():
    reference, query = shaded_query(1, with_object=False)
    small = reference[::3, ::3]
    flat = apply_gain_field(query, small, 1).astype(np.float64)
    station = (reference.max(axis=2) > SPACE_LEVEL)[..., None]
    station = np.broadcast_to(station, flat.shape)
    assert np.median(np.abs(flat - reference)[station]) <= 2.0


@pytest.mark.parametrize("degree", [-1, 4, 1.0, True, "2"])
def test_invalid_degrees_are_refused_by_name(degree):
    reference, query = shaded_query(1, with_object=False)
    with pytest.raises(GainFieldError, match="gain_field_degree"):
        apply_gain_field(query, reference, degree)
    with pytest.raises(ParamsError, match="gain_field_degree"):
        MradParams(gain_field_degree=degree)
