"""Where rays meet: the reprojection error minimised in inverse range, with range
intervals, for many objects at once.

An object seen in views ``i`` lies near each ray ``c_i + r d_i``. The newest ray is the
*anchor*; the object is parameterised from it as ``X = c_a + E^T (alpha, beta, 1) / rho``
(``E`` the anchor's frame, ``rho`` the inverse range along it). Its estimate minimises the
rays' angular residuals,

    sum_i w_i tan^2(angle between d_i and X - c_i),   w_i = 1 / (sigma_i^2 + q_i / r_i^2),

``sigma_i`` the ray's angular noise (pixel noise over the focal length), ``q_i`` a variance
across the ray in metres squared (the camera position's noise, and the ray's age times the
drift speed, squared: a drifting object's old rays count less) and ``r_i`` the range along
it. With ``u_i = rho (X - c_i) = m + rho (c_a - c_i)`` each residual is nearly linear in
``(alpha, beta, rho)`` however weak the parallax, so the estimate is not pulled towards the
cameras as the least squares of the rays' distances from the point is (the noise is then in
the regressor: with a short baseline it attenuated the range by half). Gauss-Newton starts
from that least squares (exact for noise-free rays) and stops once a step moves ``rho`` by
less than half its standard deviation; where the rays keep one direction, ``rho`` is 0 (the
point is at infinity).

Every ray also bounds the range: ``low_i <= d_i . (X - c_i) <= high_i`` (one view's range
evidence, :mod:`.rays`), linear in ``rho`` at the estimate's direction: together an interval
of ``rho``. Along the anchor the object is placed at the mean, with the variance, of the
rays' inverse range (a normal) cut to that interval (uniform in inverse range): a truncated
normal. Where the rays do not fix the range (one view) that is the middle of the interval
in inverse range with the interval's spread, so that an object's projection into a later
view spans the epipolar segment the interval allows; where they do, it is their own
estimate and spread. Where they place the object outside the interval by more than three
standard deviations (glare that keeps its direction over a module), the intervals are
contradicted and the rays' own estimate is kept (the tracker does not confirm it).

:func:`triangulate` works on a batch of objects (rays padded to one count); test/objects
holds a one-object float64 oracle of it (SciPy's least squares on the same cost).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erfcx

from allo_mrad_ros.objects.params import ObjectsError

# An eigenvalue of the rays' information below this fraction of its trace is a direction the
# rays do not determine (parallel rays along it): the solution keeps the anchor's prior there.
_NULL = 1e-12
# The inverse range's information (Schur complement) below this fraction of its own diagonal:
# parallel rays, the inverse range undetermined.
_NULL_RHO = 1e-9
# A bound this many standard deviations from the rays' inverse range leaves its normal's
# moments as they are (its mass beyond is below 1e-15).
_TRUNCATED = 8.0
# Gauss-Newton has converged when a step moves the inverse range by less than this many of
# its standard deviations.
_CONVERGED = 0.5
# Rays whose own inverse range lies this many standard deviations outside the intervals'
# contradict them (see triangulate).
_CONFLICT = 3.0
_SQRT2 = math.sqrt(2.0)
# Beyond this many standard deviations past a bound, the truncated normal's moments are taken
# from its exponential limit.
_FAR_TAIL = 30.0
_SQRT_2_PI = math.sqrt(2.0 / math.pi)
_EYE3 = np.eye(3)


@dataclass(frozen=True)
class RayBatch:
    """The rays of ``B`` objects, padded to ``R`` rays each (float64).

    Attributes
    ----------
    origins, directions : numpy.ndarray
        (B, R, 3) ray origins and unit directions, station frame.
    angular_variance : numpy.ndarray
        (B, R) variance of each ray's direction, rad^2 (per axis across the ray).
    extra_variance : numpy.ndarray
        (B, R) variance added across each ray, m^2 (its age's drift).
    low, high : numpy.ndarray
        (B, R) each ray's range interval, metres, ``0 < low <= high`` (finite).
    valid : numpy.ndarray
        (B, R) bool: padding is False.
    anchor : numpy.ndarray
        (B,) int: the index of each object's anchor (newest) ray, a valid one.
    """

    origins: np.ndarray
    directions: np.ndarray
    angular_variance: np.ndarray
    extra_variance: np.ndarray
    low: np.ndarray
    high: np.ndarray
    valid: np.ndarray
    anchor: np.ndarray

    def __post_init__(self) -> None:
        batch, count = self.valid.shape
        for name in ("origins", "directions"):
            if getattr(self, name).shape != (batch, count, 3):
                raise ObjectsError(f"{name} must have shape {(batch, count, 3)}")
        for name in ("angular_variance", "extra_variance", "low", "high"):
            if getattr(self, name).shape != (batch, count):
                raise ObjectsError(f"{name} must have shape {(batch, count)}")
        if self.anchor.shape != (batch,):
            raise ObjectsError(f"anchor must have shape {(batch,)}")
        if batch and not np.all(self.valid[np.arange(batch), self.anchor]):
            raise ObjectsError("each object's anchor must be one of its valid rays")

    @classmethod
    def unchecked(cls, **arrays: np.ndarray) -> RayBatch:
        """The batch of ``arrays`` (every field, by name) without the checks of its
        constructor: for arrays right by construction (the tracker's own ray tables, every
        frame)."""
        batch = object.__new__(cls)
        batch.__dict__.update(arrays)
        return batch

    @classmethod
    def single(
        cls,
        origins: np.ndarray,
        directions: np.ndarray,
        angular_variance: np.ndarray,
        low: np.ndarray,
        high: np.ndarray,
        extra_variance: np.ndarray | None = None,
    ) -> RayBatch:
        """The batch of one object from its ``n`` rays; the last is the anchor."""
        origins = np.asarray(origins, dtype=np.float64).reshape(1, -1, 3)
        count = origins.shape[1]
        directions = np.asarray(directions, dtype=np.float64).reshape(1, count, 3)
        directions = directions / np.linalg.norm(directions, axis=-1, keepdims=True)

        def row(values: object) -> np.ndarray:
            return np.broadcast_to(np.asarray(values, dtype=np.float64), (count,))[None].copy()

        return cls(
            origins=origins,
            directions=directions,
            angular_variance=row(angular_variance),
            extra_variance=row(0.0 if extra_variance is None else extra_variance),
            low=row(low),
            high=row(high),
            valid=np.ones((1, count), dtype=bool),
            anchor=np.array([count - 1]),
        )


@dataclass(frozen=True)
class Triangulation:
    """The solution for each object of a :class:`RayBatch`.

    Attributes
    ----------
    position : numpy.ndarray
        (B, 3) the position: along the anchor the truncated normal's mean (module text),
        across it the rays' estimate at that inverse range.
    covariance : numpy.ndarray
        (B, 3, 3) its covariance: the rays' information across the anchor, the truncated
        normal's variance along it.
    ranges : numpy.ndarray
        (B, R) the range of ``position`` along each ray (0 for padding).
    free_range : numpy.ndarray
        (B,) range along the anchor ray of the rays-only solution (no bounds, no interval
        information): what parallax alone says, ``1 / inverse_range``; may be negative or
        huge.
    free_range_sigma : numpy.ndarray
        (B,) its standard deviation from the rays alone, linearised (inf for one ray).
    inverse_range : numpy.ndarray
        (B,) the rays-only inverse range along the anchor (0: at infinity, parallel rays).
    inverse_range_sigma : numpy.ndarray
        (B,) its standard deviation (inf where the rays do not determine it: one ray).
    """

    position: np.ndarray
    covariance: np.ndarray
    ranges: np.ndarray
    inverse_range: np.ndarray
    inverse_range_sigma: np.ndarray

    # The free range and its spread follow from the inverse range: computed when read (the
    # tracker reads the inverse range only).
    @property
    def free_range(self) -> np.ndarray:
        """(B,) ``1 / inverse_range`` (inf at 0): see the class text."""
        rho = self.inverse_range
        return np.divide(1.0, rho, out=np.full(len(rho), np.inf), where=rho != 0)

    @property
    def free_range_sigma(self) -> np.ndarray:
        """(B,) the free range's standard deviation (inf where the inverse range's is)."""
        rho, sigma = self.inverse_range, self.inverse_range_sigma
        informed = np.isfinite(sigma)  # where the rays determine the inverse range
        return np.divide(sigma, rho**2, out=np.full(len(rho), np.inf), where=informed & (rho != 0))

    def free_inverse_range(self) -> tuple[np.ndarray, np.ndarray]:
        """(B,) inverse range along the anchor from parallax alone and its standard
        deviation: :attr:`inverse_range` and :attr:`inverse_range_sigma`."""
        return self.inverse_range, self.inverse_range_sigma


def anchor_prior_range(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The middle of ``[low, high]`` in inverse range."""
    return 2.0 / (1.0 / low + 1.0 / high)


def triangulate(rays: RayBatch, *, iterations: int = 4) -> Triangulation:
    """Each object's position from its rays, with the range bounds (see module text).

    Parameters
    ----------
    rays : RayBatch
        ``B`` objects' rays.
    iterations : int
        Most Gauss-Newton steps of the reprojection error from the rays' linear least
        squares, before the last linearisation (fewer once the inverse range moves by less
        than half its standard deviation).

    Returns
    -------
    Triangulation
    """
    batch, count = rays.valid.shape
    if batch == 0:
        empty = np.zeros((0,))
        return Triangulation(
            np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, count)), empty, empty
        )
    index = np.arange(batch)
    c, d, valid = rays.origins, rays.directions, rays.valid
    anchor_d = d[index, rays.anchor]
    anchor_c = c[index, rays.anchor]
    anchor_low, anchor_high = rays.low[index, rays.anchor], rays.high[index, rays.anchor]
    # The anchor's frame: rows e1, e2 across it and its direction; every ray in it.
    basis = _anchor_basis(anchor_d)
    directions = d @ basis.transpose(0, 2, 1)  # (B, R, 3) each ray in the anchor frame
    baseline = (anchor_c[:, None, :] - c) @ basis.transpose(0, 2, 1)  # c_a - c_i, ditto
    middle = anchor_prior_range(anchor_low, anchor_high)
    origin_along = np.einsum("brj,brj->br", d, c)
    # Seed: the rays' linear least squares (exact for noise-free rays), weighted at the
    # interval's middle; only its direction from the anchor and its inverse range are kept.
    prior_point = anchor_c + middle[:, None] * anchor_d
    seed_ranges = np.minimum(np.maximum(_along(prior_point, d, origin_along), rays.low), rays.high)
    weights = np.where(
        valid, 1.0 / (rays.angular_variance * seed_ranges**2 + rays.extra_variance), 0.0
    )
    a_rays, b_rays = _information(weights, c, d, origin_along)
    floor = _NULL * a_rays.trace(axis1=1, axis2=2)
    seed = prior_point + _solve(a_rays, b_rays - _apply(a_rays, prior_point), floor)
    local = np.einsum("bij,bj->bi", basis, seed - anchor_c)
    rho_floor, rho_ceiling = 0.1 / anchor_high, 10.0 / anchor_low
    rho = np.where(local[:, 2] > 0, 1.0 / np.maximum(local[:, 2], 1e-300), 1.0 / middle)
    rho = np.minimum(np.maximum(rho, rho_floor), rho_ceiling)
    ab = np.where(local[:, 2:3] > 0, local[:, :2] * rho[:, None], 0.0)
    geometry = _Geometry.of(directions, baseline, rays)
    for step in range(iterations + 1):
        hessian, gradient = geometry.normal_equations(ab, rho)
        step_ab, slope, mean, inverse_variance, det = _marginal(hessian, gradient, rho)
        # Where the rays leave the inverse range undetermined it stays where it is.
        bounded = np.minimum(np.maximum(mean, rho_floor), rho_ceiling)
        new_rho = np.where(inverse_variance > 0, bounded, rho)
        # Linearised close enough to the optimum (half a standard deviation in inverse
        # range): this linearisation is the last; else step there and linearise again.
        change = (new_rho - rho) ** 2 * inverse_variance
        if step == iterations or not (change > _CONVERGED**2).any():
            break
        ab = ab + step_ab + slope * (new_rho - rho)[:, None]
        rho = new_rho
    informed = inverse_variance > 0
    free_rho = np.where(informed, mean, rho)
    rho_sigma = np.where(informed, 1.0 / np.sqrt(np.where(informed, inverse_variance, 1.0)), np.inf)
    # The interval every ray's range bound leaves the inverse range (at this direction).
    own_low, own_high = 1.0 / anchor_high, 1.0 / anchor_low  # the anchor's own interval
    rho_low, rho_high = _feasible(ab, geometry, rays, own_low, own_high)
    # Only where a bound lies within _TRUNCATED standard deviations does the cut change the
    # normal's moments (to rounding): the rest keep the rays' own.
    rho_mean = free_rho.copy()
    rho_variance = np.where(informed, rho_sigma, 0.0) ** 2
    cut = ~informed | (free_rho - _TRUNCATED * rho_sigma < rho_low)
    cut |= free_rho + _TRUNCATED * rho_sigma > rho_high
    where_cut = cut.nonzero()[0]  # indices: read and written by five arrays each
    if len(where_cut):
        rho_mean[where_cut], rho_variance[where_cut] = truncated_normal_moments(
            np.where(informed[where_cut], free_rho[where_cut], 0.0),
            rho_sigma[where_cut],
            rho_low[where_cut],
            rho_high[where_cut],
        )
    # Rays that meet beyond the intervals (or nearer) by more than _CONFLICT sigma contradict
    # them (glare, the Moon over a module): the rays' own estimate, so that the next region
    # falls where they point; the tracker does not confirm such an object (behind).
    conflict = informed & (
        (free_rho + _CONFLICT * rho_sigma < rho_low) | (free_rho - _CONFLICT * rho_sigma > rho_high)
    )
    # numpy.clip as minimum and maximum, here and below: its dispatch costs more than both.
    kept_rho = np.minimum(np.maximum(free_rho, 1e-3 * own_low), 1e3 * own_high)
    rho_mean = np.where(conflict, kept_rho, rho_mean)
    rho_variance = np.where(conflict, rho_sigma**2, rho_variance)
    ab = ab + step_ab + slope * (rho_mean - rho)[:, None]
    m = np.empty((batch, 3))  # (alpha, beta, 1), written in (numpy.concatenate costs more)
    m[:, :2] = ab
    m[:, 2] = 1.0
    offset = np.einsum("bji,bj->bi", basis, m)  # E^T m
    position = anchor_c + offset / rho_mean[:, None]
    # Covariance: (alpha, beta) given rho from the Gauss-Newton Hessian, rho's variance the
    # truncated normal's; mapped through X = c_a + E^T m / rho.
    # The (alpha, beta) block's inverse, over its determinant (_marginal's).
    a, b, cc = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    cov_ab = np.empty((batch, 2, 2))
    cov_ab[:, 0, 0] = cc / det
    cov_ab[:, 1, 1] = a / det
    cov_ab[:, 0, 1] = cov_ab[:, 1, 0] = -b / det
    theta = np.zeros((batch, 3, 3))
    theta[:, :2, :2] = cov_ab + slope[:, :, None] * slope[:, None, :] * rho_variance[:, None, None]
    theta[:, :2, 2] = theta[:, 2, :2] = slope * rho_variance[:, None]
    theta[:, 2, 2] = rho_variance
    jacobian = np.empty((batch, 3, 3))
    jacobian[:, :, :2] = basis[:, :2].transpose(0, 2, 1) / rho_mean[:, None, None]
    jacobian[:, :, 2] = -offset / rho_mean[:, None] ** 2
    covariance = jacobian @ theta @ jacobian.transpose(0, 2, 1)
    covariance = (covariance + covariance.transpose(0, 2, 1)) / 2.0
    ranges = np.where(valid, _along(position, d, origin_along), 0.0)
    return Triangulation(
        position=position,
        covariance=covariance,
        ranges=ranges,
        inverse_range=free_rho,
        inverse_range_sigma=rho_sigma,
    )


def _anchor_basis(anchor_d: np.ndarray) -> np.ndarray:
    """(B, 3, 3) rows ``e1, e2, d``: an orthonormal frame whose third axis is the anchor."""
    # The world axis least aligned with d makes a well-conditioned first axis.
    axis = _EYE3.take(np.abs(anchor_d).argmin(axis=1), axis=0)
    first = _cross(anchor_d, axis)
    first /= np.sqrt(np.einsum("bi,bi->b", first, first))[:, None]
    # Written row by row into one array (numpy.stack costs more than the three writes).
    basis = np.empty((len(anchor_d), 3, 3))
    basis[:, 0] = first
    basis[:, 1] = _cross(anchor_d, first)
    basis[:, 2] = anchor_d
    return basis


# Component k of a cross product is x[k + 1] y[k + 2] - x[k + 2] y[k + 1] (indices mod 3).
_NEXT = np.array([1, 2, 0])
_AFTER = np.array([2, 0, 1])


def _cross(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Row-wise cross products of (B, 3) arrays, each component as numpy.cross forms it
    (numpy.cross, or a write per component, costs more for small B)."""
    x_next, x_after = x.take(_NEXT, axis=1), x.take(_AFTER, axis=1)
    return x_next * y.take(_AFTER, axis=1) - x_after * y.take(_NEXT, axis=1)


@dataclass  # not frozen: built every frame, and a frozen field costs a call to set
class _Geometry:
    """Per ray, what the Gauss-Newton steps of :func:`triangulate` need, in the anchor's
    frame: the direction ``D``, the baseline ``b = c_a - c_i``, ``C = (D_x, D_y, D . b)``
    and ``A = [[1, 0, b_x], [0, 1, b_y], [b_x, b_y, b . b]]`` (flattened)."""

    directions: np.ndarray  # (B, R, 3)
    baseline: np.ndarray  # (B, R, 3)
    coupling: np.ndarray  # (B, R, 3): C
    outer: np.ndarray  # (B, R, 9): A
    angular_variance: np.ndarray  # (B, R)
    extra_variance: np.ndarray  # (B, R)
    valid: np.ndarray  # (B, R)

    @classmethod
    def of(cls, directions: np.ndarray, baseline: np.ndarray, rays: RayBatch) -> _Geometry:
        batch, count = rays.valid.shape
        coupling = directions.copy()  # then its third column replaced
        coupling[..., 2] = np.einsum("brj,brj->br", directions, baseline)
        outer = np.zeros((batch, count, 9))
        outer[..., 0] = outer[..., 4] = 1.0
        outer[..., 2] = outer[..., 6] = baseline[..., 0]
        outer[..., 5] = outer[..., 7] = baseline[..., 1]
        outer[..., 8] = np.einsum("brj,brj->br", baseline, baseline)
        return cls(
            directions,
            baseline,
            coupling,
            outer,
            rays.angular_variance,
            rays.extra_variance,
            rays.valid,
        )

    def normal_equations(self, ab: np.ndarray, rho: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The Gauss-Newton Hessian and gradient (descent direction) of the weighted angular
        residuals at ``theta = (alpha, beta, rho)``.

        With ``u_i = m + rho b_i`` (``m = (alpha, beta, 1)``, so ``rho (X - c_i) = u_i``),
        ``s_i = D_i . u_i`` and ``v_i = u_i / s_i``, ray ``i``'s residual is ``v_i - D_i``
        (the tangent of its angle to the point, across it). Its Jacobian's columns are
        ``J_k = (a_k - v_i C_k) / s_i`` with ``a = (e_x, e_y, b_i)``; since ``v_i . D_i = 1``
        the products reduce to per-ray scalars: ``J_k . J_l = (A_kl - C_l w_k - C_k w_l +
        C_k C_l |v|^2) / s^2`` and ``J_k . r = (w_k - C_k |v|^2) / s``, ``w = (v_x, v_y,
        b . v)``."""
        batch = len(rho)
        # u = rho b + m, m added whole (an in-place add to two of the three columns costs
        # twice the whole product here).
        m = np.empty((batch, 1, 3))
        m[:, 0, :2] = ab
        m[:, 0, 2] = 1.0
        u = self.baseline * rho[:, None, None] + m
        along = np.einsum("brj,brj->br", self.directions, u)
        valid = self.valid & (along > 1e-9)
        s = np.where(valid, along, 1.0)
        v = u / s[..., None]
        projected = v.copy()  # then its third column replaced (cheaper than two copied)
        projected[..., 2] = np.einsum("brj,brj->br", self.baseline, v)
        vv = np.einsum("brj,brj->br", v, v)
        # The point's range along ray i is s / rho: its drift variance as an angle.
        variance = self.angular_variance + self.extra_variance * (rho[:, None] / s) ** 2
        weight = np.where(valid, 1.0 / variance, 0.0)
        w2 = weight / s**2
        hessian = (w2[:, None, :] @ self.outer)[:, 0].reshape(batch, 3, 3)
        weighted = self.coupling * w2[..., None]
        cross = weighted.transpose(0, 2, 1) @ projected
        hessian += (weighted * vv[..., None]).transpose(0, 2, 1) @ self.coupling
        hessian -= cross + cross.transpose(0, 2, 1)
        rows = projected - self.coupling * vv[..., None]
        gradient = -((weight / s)[:, None, :] @ rows)[:, 0]
        return hessian, gradient


def _marginal(
    hessian: np.ndarray, gradient: np.ndarray, rho: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The Gauss-Newton step split along the inverse range: the step of ``(alpha, beta)``
    at the current ``rho``, its slope in ``rho``, the unconstrained ``rho`` and its
    information (the Schur complement; 0 where the rays do not determine it), and the
    determinant of the ``(alpha, beta)`` block."""
    a, b, cc = hessian[:, 0, 0], hessian[:, 0, 1], hessian[:, 1, 1]
    h0, h1 = hessian[:, 0, 2], hessian[:, 1, 2]
    g0, g1 = gradient[:, 0], gradient[:, 1]
    det = a * cc - b * b
    # The 2x2 inverse of the (alpha, beta) block applied to the gradient and the coupling.
    step_ab = np.empty((len(rho), 2))
    step_ab[:, 0] = (cc * g0 - b * g1) / det
    step_ab[:, 1] = (a * g1 - b * g0) / det
    slope = np.empty((len(rho), 2))
    slope[:, 0] = -(cc * h0 - b * h1) / det
    slope[:, 1] = -(a * h1 - b * h0) / det
    h_ar = hessian[:, :2, 2]
    information = hessian[:, 2, 2] + np.einsum("bi,bi->b", h_ar, slope)
    scale = hessian[:, 2, 2]
    determined = information > _NULL_RHO * np.maximum(scale, 1e-300)
    safe = np.where(determined, information, 1.0)
    mean = rho + (gradient[:, 2] + np.einsum("bi,bi->b", slope, gradient[:, :2])) / safe
    rho_mean = np.where(determined, mean, rho)
    return step_ab, slope, rho_mean, np.where(determined, information, 0.0), det


def _feasible(
    ab: np.ndarray,
    geometry: _Geometry,
    rays: RayBatch,
    own_low: np.ndarray,
    own_high: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """The inverse ranges along the anchor at which every ray's range lies in its interval,
    ``low_i <= (g_i + rho h_i) / rho <= high_i`` (``g_i = d_i . m``, ``h_i = d_i . b_i``):
    linear in ``rho``. Where the rays' intervals exclude each other, the anchor's alone
    (``own_low``, ``own_high``: its interval in inverse range)."""
    directions = geometry.directions
    g = (
        directions[..., 2]
        + directions[..., 0] * ab[:, 0, None]
        + directions[..., 1] * ab[:, 1, None]
    )
    h = geometry.coupling[..., 2]
    # rho * lower <= g and rho * upper >= g; padding's coefficients 0 (it bounds nothing).
    lower = np.where(rays.valid, rays.low - h, 0.0)
    upper = np.where(rays.valid, rays.high - h, 0.0)
    # Each ray bounds rho from above or below by the side its coefficient's sign puts it.
    # Outputs made with numpy.full and numpy.zeros (its *_like forms cost twice as much).
    shape = g.shape
    above = np.divide(g, lower, out=np.full(shape, np.inf), where=lower > 0)
    upper_negative = upper < 0
    if upper_negative.any():  # none in most batches (their bound is inf: changes nothing)
        above = np.minimum(
            above, np.divide(g, upper, out=np.full(shape, np.inf), where=upper_negative)
        )
    below = np.divide(g, upper, out=np.zeros(shape), where=upper > 0)
    below = np.maximum(below, np.divide(g, lower, out=np.zeros(shape), where=lower < 0))
    rho_low = np.maximum(below.max(axis=1), own_low)
    rho_high = np.minimum(above.min(axis=1), own_high)
    clash = ~(rho_low < rho_high)
    return np.where(clash, own_low, rho_low), np.where(clash, own_high, rho_high)


def truncated_normal_moments(
    mean: np.ndarray, sigma: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of ``N(mean, sigma^2)`` restricted to ``[low, high]`` (elementwise);
    an infinite ``sigma`` gives the uniform distribution on the interval.

    In standard units ``a < b`` (mirrored so that ``a + b >= 0``: the bound nearer the mean,
    or the one on its side, is ``a``), every term carries ``exp(-a^2 / 2)``, divided out
    through the scaled complementary error function ``erfcx``: with ``D = exp(-(b^2 - a^2)
    / 2)`` and ``E = erfcx(a / sqrt 2) - D erfcx(b / sqrt 2)``, the mean moves by
    ``sqrt(2 / pi) (1 - D) / E`` and the variance is ``1 + sqrt(2 / pi) (a - b D) / E``
    less that squared (arranged so that nothing cancels far in a tail). Far past a bound
    (``a >> 1``) that stays exact where the tail's mass would round to 0: the mean is the
    bound plus about ``1 / a``, the spread about ``1 / a``. ``a`` below -10 is -10 (the
    mass beyond rounds to nothing).
    """
    width = np.maximum(high - low, 0.0)
    uniform = ~np.isfinite(sigma) | (sigma <= 0)
    any_uniform = bool(uniform.any())  # else the blends below change nothing: skipped
    scale = np.where(uniform, 1.0, sigma) if any_uniform else sigma
    a = (low - mean) / scale
    b = (high - mean) / scale
    mirror = a + b < 0
    a, b = np.where(mirror, -b, a), np.where(mirror, -a, b)
    a = np.maximum(a, -10.0)
    exponent = -0.5 * (b - a) * (b + a)
    decay = np.exp(exponent)
    tail = erfcx(a / _SQRT2) - decay * erfcx(b / _SQRT2)
    tail = np.where(tail > 0, tail, 1.0)
    kept = np.maximum(-np.expm1(exponent), 1e-300)  # 1 - D
    shift = _SQRT_2_PI * kept / tail
    far_term = np.where(np.isinf(b), 0.0, b * decay)
    # 1 + sqrt(2/pi) (a - b D) / E - shift^2, arranged so that far in a tail (shift ~ a,
    # the variance ~ 1 / a^2) nothing cancels: 1 - shift (shift - a / (1 - D)) - ...
    spread = 1.0 - shift * (shift - a / kept) - _SQRT_2_PI * far_term / tail
    # Far in a tail even that loses the spread (shift - a is ~1 / a): the density on [a, b]
    # is then exponential with rate a (relative error ~1 / a^2), its moments exact.
    far = a > _FAR_TAIL
    if far.any():
        rate = np.where(far, a, 1.0)
        length = np.where(far, b - a, 1.0)
        ratio = np.exp(-rate * length) / -np.expm1(-rate * length)  # e^(-aL) / (1 - e^(-aL))
        bounded = np.isfinite(length)
        offset = 1.0 / rate - np.where(bounded, length * ratio, 0.0)
        tail_spread = 1.0 / rate**2 - np.where(bounded, length**2 * ratio * (1.0 + ratio), 0.0)
        shift = np.where(far, a + offset, shift)
        spread = np.where(far, tail_spread, spread)
    out_mean = mean + np.where(mirror, -shift, shift) * scale
    out_variance = scale**2 * np.maximum(spread, 0.0)
    uniform_variance = width**2 / 12.0
    if any_uniform:
        out_mean = np.where(uniform, (low + high) / 2.0, out_mean)
        out_variance = np.where(uniform, uniform_variance, out_variance)
    return np.minimum(np.maximum(out_mean, low), high), np.minimum(out_variance, uniform_variance)


def _information(
    weights: np.ndarray, c: np.ndarray, d: np.ndarray, origin_along: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The rays' normal equations ``A X = b``: ``A = sum w (I - d d^T)`` and
    ``b = sum w (I - d d^T) c`` (matrix products, no per-ray 3x3 projector)."""
    # Batched matrix products over the rays (numpy's einsum and 3-D sums are slower here).
    a = (
        weights.sum(axis=1)[:, None, None] * _EYE3
        - (d.transpose(0, 2, 1) * weights[:, None, :]) @ d
    )
    b = (weights[:, None, :] @ c)[:, 0] - ((weights * origin_along)[:, None, :] @ d)[:, 0]
    return a, b


def _along(position: np.ndarray, d: np.ndarray, origin_along: np.ndarray) -> np.ndarray:
    """(B, R) the range of each object's ``position`` along each of its rays (unclipped)."""
    return (d @ position[:, :, None])[..., 0] - origin_along


def _apply(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    return np.einsum("bij,bj->bi", matrix, vector)


def _well_posed(matrix: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """(B,) whether every eigenvalue of each symmetric positive semi-definite 3x3 ``matrix``
    surely exceeds ``floor``: the least is at least ``4 det / trace^2`` (the other two
    multiply to at most a quarter of the trace squared); twice the floor leaves room for
    the determinant's rounding."""
    trace = matrix.trace(axis1=1, axis2=2)
    return 4.0 * np.linalg.det(matrix) > 2.0 * floor * trace**2


def _solve(matrix: np.ndarray, rhs: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """The least-norm solution of symmetric ``matrix x = rhs`` over the eigen-directions
    whose eigenvalue exceeds ``floor`` (per object): 0 along the undetermined ones. Where
    every direction is determined that is the plain solution (LU, cheaper than eigh)."""
    good = _well_posed(matrix, floor)
    if good.all():
        return np.linalg.solve(matrix, rhs[..., None])[..., 0]
    out = np.empty_like(rhs)
    if good.any():
        out[good] = np.linalg.solve(matrix[good], rhs[good][..., None])[..., 0]
    rest = ~good
    values, vectors = np.linalg.eigh(matrix[rest])
    keep = values > floor[rest][:, None]
    inverse = np.where(keep, 1.0 / np.where(keep, values, 1.0), 0.0)
    out[rest] = _apply(vectors, inverse * np.einsum("bki,bk->bi", vectors, rhs[rest]))
    return out
