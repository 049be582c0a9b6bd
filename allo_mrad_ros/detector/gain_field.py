"""Stage 0': a smooth multiplicative gain field between the query and its reference.

Another light model than the reference's (a lamp's other fall-off, bounce light, a Sun of
finite size) shades a module smoothly in a way the reference does not draw: after the
colour transfer (one table per frame, blind to where a pixel is) the query stays brighter
at one end of a module than the reference predicts. Each frame, the log ratio of the query's
luma to the reference's luma is fitted by a low-order 2-D polynomial in the pixel's
position:

* only station pixels enter the fit: the reference is not space (a channel above
  :data:`SPACE_LEVEL`), neither image is clipped or black, and the pixel is at least
  :data:`EDGE_MARGIN` pixels from a reference edge (a pose error moves edges);
* the fit is robust: iteratively reweighted least squares with Tukey's biweight on the
  residuals, scaled by their median absolute deviation, so an object (a ratio far off the
  smooth field) gets weight 0 and does not bend the field;
* the query is divided by ``exp(field)``, so the scoring stages see it in the reference's
  shading; what departs from the smooth field (an object) keeps its departure.

Degree 0 is off (nothing is fitted); degree 1..3 has 3, 6 or 10 coefficients.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from allo_mrad_ros.detector.images import (
    SPACE_LEVEL,
    area_downscale,
    brightest_channel,
    eight_bit,
    nearest_resize,
    station_surface,
)
from allo_mrad_ros.errors import InvalidInput

__all__ = [
    "SPACE_LEVEL",
    "GainField",
    "GainFieldError",
    "apply_gain_field",
    "design_matrix",
    "fit_gain_field",
]

MAX_DEGREE = 3
CLIPPED_LEVEL = 250.0
"""A query or reference pixel with a channel at or above this level is clipped."""
DARK_LEVEL = 4.0
"""Luma at or below this (either image) carries no ratio."""
EDGE_LEVELS = 48.0
"""A reference pixel is at an edge where its neighbourhood spans more than this many 8-bit
levels in some channel (as the colour transfer's edge rule)."""
EDGE_MARGIN = 2
"""Pixels around reference edges left out of the fit."""
MAX_SAMPLES = 4096
"""At most this many pixels enter the fit (every k-th kept pixel): a low-order field needs
no more, and the fit's cost follows the count."""
MIN_SAMPLES = 64
"""Below this many usable pixels no field is fitted (gain 1)."""
MAX_LOG_GAIN = float(np.log(2.0))
"""The field is clipped to gains in [1/2, 2]: beyond that the difference is not shading."""
TUKEY_C = 4.685
ITERATIONS = 8
# 1.4826 MAD estimates a normal distribution's standard deviation.
_MAD_SCALE = 1.4826
# Scale floor: log-ratio noise below about 1 % is not resolved by 8-bit luma anyway.
_MIN_SCALE = 0.01
# Rec. 601 luma weights (R, G, B).
_LUMA = np.array([0.299, 0.587, 0.114])


class GainFieldError(InvalidInput):
    """The gain field cannot be fitted with these inputs or parameters."""


@dataclass(frozen=True)
class GainField:
    """A fitted log-gain polynomial.

    Attributes
    ----------
    coefficients : numpy.ndarray
        (k,) float64 coefficients of :func:`design_matrix`'s columns; empty when no field
        was fitted (too few usable pixels).
    degree : int
        The polynomial's total degree.
    inliers : numpy.ndarray
        (n,) bool, the fit's samples that ended with non-zero weight.
    samples : int
        Pixels the fit used.
    bounds : tuple of float
        The lowest and highest fitted log gain at the inliers: the field is clipped to them,
        so a polynomial does not run away where it has no samples (space, a frame's corner).
    """

    coefficients: np.ndarray
    degree: int
    inliers: np.ndarray
    samples: int
    bounds: tuple[float, float] = (-MAX_LOG_GAIN, MAX_LOG_GAIN)

    def log_gain(self, shape: tuple[int, int]) -> np.ndarray:
        """The field's log gain (H x W float32) over an image of ``shape``, clipped to
        :attr:`bounds` and +-:data:`MAX_LOG_GAIN`; zero when nothing was fitted."""
        height, width = shape
        if self.coefficients.size == 0:
            return np.zeros(shape, np.float32)
        # Separable: sum c_ij x**i y**j = Y @ C @ X.T, Y and X the powers of each row's y
        # and each column's x, C[j, i] = c_ij: one small matrix product.
        powers = np.arange(self.degree + 1)
        ys = _normalised(np.arange(height), height)[:, None] ** powers
        xs = _normalised(np.arange(width), width)[:, None] ** powers
        table = np.zeros((self.degree + 1, self.degree + 1))
        for column, (i, j) in enumerate(_powers(self.degree)):
            table[j, i] = self.coefficients[column]
        field = ys @ table @ xs.T
        low = max(self.bounds[0], -MAX_LOG_GAIN)
        high = min(self.bounds[1], MAX_LOG_GAIN)
        return np.clip(field, low, high).astype(np.float32)


def _powers(degree: int) -> list[tuple[int, int]]:
    # (power of x, power of y) of each column, by total degree then x power descending.
    return [(total - j, j) for total in range(degree + 1) for j in range(total + 1)]


def _normalised(index: np.ndarray, size: int) -> np.ndarray:
    # Pixel centres to [-1, 1]: keeps the design matrix well conditioned at every size.
    return (2.0 * (index.astype(np.float64) + 0.5) / size) - 1.0


def design_matrix(
    rows: np.ndarray, cols: np.ndarray, shape: tuple[int, int], degree: int
) -> np.ndarray:
    """(n, k) float64 monomials ``x**i * y**j`` (``i + j <= degree``) of pixel positions,
    ``x`` and ``y`` the column and row mapped to [-1, 1] over an image of ``shape``."""
    x = _normalised(cols, shape[1])
    y = _normalised(rows, shape[0])
    return np.stack([x**i * y**j for i, j in _powers(degree)], axis=1)


def _check_degree(degree: object) -> int:
    if isinstance(degree, bool) or not isinstance(degree, int | np.integer):
        raise GainFieldError(f"gain_field_degree must be an integer, got {degree!r}")
    if not 0 <= degree <= MAX_DEGREE:
        raise GainFieldError(f"gain_field_degree must be in [0, {MAX_DEGREE}], got {degree}")
    return int(degree)


def _luma(image: np.ndarray) -> np.ndarray:
    return image.astype(np.float32) @ _LUMA.astype(np.float32)


def usable_pixels(query: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """H x W bool: the pixels a fit may use (uint8 images of one size): reference station
    surface, neither image clipped or dark, away from reference edges."""
    size = 3 + 2 * EDGE_MARGIN
    kernel = np.ones((size, size), np.uint8)
    spread = cv2.subtract(cv2.dilate(reference, kernel), cv2.erode(reference, kernel))
    edge = brightest_channel(spread) > EDGE_LEVELS
    station = station_surface(reference)
    clipped = (brightest_channel(query) >= CLIPPED_LEVEL) | (
        brightest_channel(reference) >= CLIPPED_LEVEL
    )
    dark = (_luma(query) <= DARK_LEVEL) | (_luma(reference) <= DARK_LEVEL)
    return station & ~edge & ~clipped & ~dark


def fit_gain_field(query: np.ndarray, reference: np.ndarray, degree: int) -> GainField:
    """Fit ``log(luma(query) / luma(reference))`` by a degree-``degree`` polynomial.

    Parameters
    ----------
    query, reference : numpy.ndarray
        uint8 H x W x 3 images of one size (the reference resized to the query's).
    degree : int
        Total degree, 0..3 (0 fits the frame's robust mean log gain).

    Returns
    -------
    GainField
        Empty coefficients when fewer than :data:`MIN_SAMPLES` pixels are usable.

    Raises
    ------
    GainFieldError
        For a degree out of range or images of different shapes.
    """
    degree = _check_degree(degree)
    if query.shape != reference.shape or query.ndim != 3:
        raise GainFieldError(
            f"query {query.shape} and reference {reference.shape} must be H x W x 3 of one size"
        )
    usable = np.flatnonzero(usable_pixels(query, reference))
    usable = usable[:: max(1, -(-usable.size // MAX_SAMPLES))]
    if usable.size < MIN_SAMPLES:
        return GainField(np.zeros(0), degree, np.zeros(0, bool), int(usable.size))
    q = _luma(query.reshape(-1, 3)[usable]).astype(np.float64)
    r = _luma(reference.reshape(-1, 3)[usable]).astype(np.float64)
    target = np.log(q) - np.log(r)
    rows, cols = np.divmod(usable, query.shape[1])
    design = design_matrix(rows, cols, query.shape[:2], degree)
    coefficients, weights = robust_fit(design, target)
    inliers = weights > 0.0
    fitted = design[inliers] @ coefficients
    bounds = (float(fitted.min()), float(fitted.max())) if fitted.size else (0.0, 0.0)
    return GainField(coefficients, degree, inliers, int(usable.size), bounds)


def robust_fit(design: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Iteratively reweighted least squares with Tukey's biweight.

    Starts from the least-squares fit of the samples whose target lies within the middle
    half (a fit an object covering under a quarter of them does not move far), then
    :data:`ITERATIONS` reweightings with the residuals' MAD as scale.

    Returns
    -------
    coefficients : numpy.ndarray
        (k,) float64.
    weights : numpy.ndarray
        (n,) float64 final weights in [0, 1].
    """
    low, high = np.quantile(target, [0.25, 0.75])
    weights = ((target >= low) & (target <= high)).astype(np.float64)
    coefficients = _weighted_lstsq(design, target, weights)
    for _ in range(ITERATIONS):
        residual = target - design @ coefficients
        scale = max(_MAD_SCALE * float(np.median(np.abs(residual))), _MIN_SCALE)
        u = residual / (TUKEY_C * scale)
        weights = np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)
        coefficients = _weighted_lstsq(design, target, weights)
    return coefficients, weights


def _weighted_lstsq(design: np.ndarray, target: np.ndarray, weights: np.ndarray) -> np.ndarray:
    # The normal equations: at most 10 columns of monomials of coordinates in [-1, 1] are
    # well conditioned, and a k x k solve is far cheaper than an SVD of n x k (lstsq).
    weighted = design.T * weights
    normal = weighted @ design
    try:
        return np.linalg.solve(normal, weighted @ target)
    except np.linalg.LinAlgError:
        # Samples on a line (a thin strip of station) leave a direction undetermined.
        solution, *_ = np.linalg.lstsq(normal, weighted @ target, rcond=None)
        return solution


def apply_gain_field(query: np.ndarray, reference: np.ndarray, degree: int) -> np.ndarray:
    """The query divided by the frame's fitted gain field (uint8, the query's size).

    Parameters
    ----------
    query : numpy.ndarray
        uint8 H x W x 3, the processed query (after any colour transfer).
    reference : numpy.ndarray
        uint8 h x w x 3 reference of the same view (any size with the query's aspect): the
        fit runs at the smaller of the two sizes, the field is evaluated at the query's.
    degree : int
        0 returns ``query`` unchanged; 1..3 the polynomial's degree.
    """
    degree = _check_degree(degree)
    if degree == 0:
        return query
    query, reference = eight_bit(query), eight_bit(reference)
    height, width = query.shape[:2]
    hr, wr = reference.shape[:2]
    if hr * wr < height * width:
        small_query = area_downscale(query, (wr, hr))
        small_reference = reference
    else:
        small_query = query
        small_reference = nearest_resize(reference, (height, width))
    field = fit_gain_field(small_query, small_reference, degree)
    if field.coefficients.size == 0:
        return query
    inverse = np.exp(-field.log_gain((height, width)))
    out = query.astype(np.float32) * inverse[..., None]
    return cv2.convertScaleAbs(np.maximum(out, 0.0))
