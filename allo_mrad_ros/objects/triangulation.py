"""Where rays meet: weighted least squares with range-interval constraints, for many objects
at once.

An object seen in views ``i`` lies near each ray ``c_i + r d_i``. Its position ``X``
minimises the weighted squared distances from the rays,

    sum_i w_i |(I - d_i d_i^T)(X - c_i)|^2,   w_i = 1 / (sigma_i^2 r_i^2 + q_i),

where ``sigma_i`` is the ray's angular noise (pixel noise over the focal length), ``r_i``
the range along it (the weights are re-evaluated at the estimate, a few iterations) and
``q_i`` a variance added for the ray's age (a drifting object: old rays count less).
Every ray also bounds the range: ``low_i <= d_i . (X - c_i) <= high_i`` (one view's range
evidence, :mod:`.rays`); violated bounds are enforced as stiff penalties, added one active
set at a time.

The newest ray is the *anchor*. Along it the object is placed at the mean, with the
variance, of the rays' inverse range (a normal, from the rays alone) cut to the anchor's
interval (uniform in inverse range): a truncated normal. Where the rays do not fix the range
(one view, rays that keep one direction, or a baseline too short for the pixel noise) that
is the middle of the interval in inverse range with the interval's spread, so that an
object's projection into a later view spans the epipolar segment the interval allows; where
they do, it is their own estimate and spread.

:func:`triangulate` works on a batch of objects (rays padded to one count); test/objects
holds a loop-by-loop float64 oracle of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import erfcx, ndtr

from allo_mrad_ros.objects.params import ObjectsError

# Penalty stiffness of an active range bound, relative to the object's largest ray weight.
_STIFFNESS = 1e8
# An eigenvalue of the rays' information below this fraction of its trace is a direction the
# rays do not determine (parallel rays along it): the solution keeps the anchor's prior there.
_NULL = 1e-12
# Beyond this many standard deviations past a bound, the truncated normal's moments are taken
# from its exponential limit.
_FAR_TAIL = 30.0
# Passes of the active set (each adds or releases at most one bound per object).
_ACTIVE_PASSES = 12
# Multiplier updates that take an active bound's residual from force / stiffness to rounding.
_REFINEMENTS = 2


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
        (B, 3) the constrained least-squares position, moved along the anchor to the
        truncated normal's mean (module text).
    covariance : numpy.ndarray
        (B, 3, 3) its covariance: the rays' information, plus along the anchor what takes
        its variance there to the truncated normal's.
    ranges : numpy.ndarray
        (B, R) the range of ``position`` along each ray (0 for padding).
    free_range : numpy.ndarray
        (B,) range along the anchor ray of the rays-only solution (no bounds, no interval
        information): what parallax alone says; may be negative or huge.
    free_range_sigma : numpy.ndarray
        (B,) its standard deviation from the rays alone (inf where they are parallel).
    """

    position: np.ndarray
    covariance: np.ndarray
    ranges: np.ndarray
    free_range: np.ndarray
    free_range_sigma: np.ndarray

    def free_inverse_range(self) -> tuple[np.ndarray, np.ndarray]:
        """(B,) inverse range along the anchor from parallax alone and its standard
        deviation (linearised): ``1/r`` and ``sigma_r / r^2``."""
        with np.errstate(divide="ignore", invalid="ignore"):
            rho = 1.0 / self.free_range
            sigma = self.free_range_sigma / self.free_range**2
        return rho, np.where(np.isfinite(sigma), sigma, np.inf)


def anchor_prior_range(low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """The middle of ``[low, high]`` in inverse range."""
    return 2.0 / (1.0 / low + 1.0 / high)


def triangulate(rays: RayBatch, *, iterations: int = 3) -> Triangulation:
    """Each object's position from its rays, with the range bounds (see module text).

    Parameters
    ----------
    rays : RayBatch
        ``B`` objects' rays.
    iterations : int
        Re-evaluations of the weights at the estimate (the first uses the anchor's prior).

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
    low, high = rays.low, rays.high
    # d . c of every ray: the projector (I - d d^T) is applied through it, never built.
    origin_along = np.einsum("brj,brj->br", d, c)
    anchor_d = d[index, rays.anchor]
    anchor_c = c[index, rays.anchor]
    anchor_low, anchor_high = low[index, rays.anchor], high[index, rays.anchor]
    prior_point = anchor_c + anchor_prior_range(anchor_low, anchor_high)[:, None] * anchor_d
    anchor_outer = anchor_d[:, :, None] * anchor_d[:, None, :]
    position = prior_point
    ranges = _clipped_ranges(position, d, origin_along, low, high)
    for _ in range(max(1, iterations)):
        weights = np.where(
            valid, 1.0 / (rays.angular_variance * ranges**2 + rays.extra_variance), 0.0
        )
        a_rays, b_rays = _information(weights, c, d, origin_along)
        floor = _NULL * np.trace(a_rays, axis1=1, axis2=2)
        free = prior_point + _solve(a_rays, b_rays - _apply(a_rays, prior_point), floor)
        position = _bounded(
            free, prior_point, a_rays, b_rays, floor, weights, d, origin_along, low, high, valid
        )
        ranges = _clipped_ranges(position, d, origin_along, low, high)
    weights = np.where(valid, 1.0 / (rays.angular_variance * ranges**2 + rays.extra_variance), 0.0)
    a_rays, _ = _information(weights, c, d, origin_along)
    # Rays-only spread along the anchor: inf where the rays leave it undetermined.
    floor = _NULL * np.trace(a_rays, axis1=1, axis2=2)
    along = np.zeros(batch)
    undetermined = np.zeros(batch, dtype=bool)
    good = _well_posed(a_rays, floor)
    if good.any():  # every direction determined: d^T A^-1 d
        inverse_d = np.linalg.solve(a_rays[good], anchor_d[good][..., None])[..., 0]
        along[good] = np.einsum("bi,bi->b", anchor_d[good], inverse_d)
    if not good.all():
        rest = ~good
        values, vectors = np.linalg.eigh(a_rays[rest])
        share = np.einsum("bi,bik->bk", anchor_d[rest], vectors) ** 2
        determined = values > floor[rest][:, None]
        spread = share / np.where(determined, values, 1.0)
        along[rest] = np.where(determined, spread, 0.0).sum(axis=1)
        # A share of the anchor in an undetermined direction beyond rounding: parallel rays.
        undetermined[rest] = np.where(determined, 0.0, share).sum(axis=1) > 1e-12
    free_sigma = np.where(undetermined, np.inf, np.sqrt(along))
    free_range = np.einsum("bi,bi->b", anchor_d, free - anchor_c)
    # Along the anchor the rays' likelihood (Gaussian in inverse range, where parallax is
    # linear) times the interval (uniform in inverse range) is a truncated normal. Its mode
    # (the constrained least squares) is what noise makes it while parallax is weak: on a
    # bound, where the curvature claims a spread far below the interval's. Its mean and
    # variance are what the next view can be gated with: where the rays say little they are
    # the interval's middle and spread, where they say much, the rays' own.
    rho_low, rho_high = 1.0 / anchor_high, 1.0 / anchor_low
    with np.errstate(divide="ignore", invalid="ignore"):
        rho_free = 1.0 / free_range
        rho_sigma = free_sigma / free_range**2
    informed = np.isfinite(rho_free) & np.isfinite(rho_sigma) & (rho_sigma > 0)
    mean, variance = truncated_normal_moments(
        np.where(informed, rho_free, 0.0),
        np.where(informed, rho_sigma, np.inf),
        rho_low,
        rho_high,
    )
    rho = np.clip(mean, rho_low, rho_high)
    anchor_range = np.einsum("bi,bi->b", anchor_d, position - anchor_c)
    position = position + (1.0 / rho - anchor_range)[:, None] * anchor_d
    ranges = _clipped_ranges(position, d, origin_along, low, high)
    # The covariance holds the rays' information and as much along the anchor as takes its
    # variance there to the truncated normal's (linearised to range).
    # (A spread below a billionth of the range is rounding: floored there.)
    range_information = rho**4 / np.maximum(variance, (1e-9 * rho) ** 2)
    rays_information = np.where(undetermined, 0.0, 1.0 / np.maximum(along, 1e-300))
    extra = np.maximum(range_information - rays_information, 0.0)
    covariance = np.linalg.inv(a_rays + extra[:, None, None] * anchor_outer)
    covariance = (covariance + covariance.transpose(0, 2, 1)) / 2.0
    return Triangulation(
        position=position,
        covariance=covariance,
        ranges=np.where(valid, ranges, 0.0),
        free_range=free_range,
        free_range_sigma=free_sigma,
    )


def truncated_normal_moments(
    mean: np.ndarray, sigma: np.ndarray, low: np.ndarray, high: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Mean and variance of ``N(mean, sigma^2)`` restricted to ``[low, high]`` (elementwise);
    an infinite ``sigma`` gives the uniform distribution on the interval.

    An interval on one side of the mean is taken in the normal's upper tail through the
    scaled complementary error function (``erfcx``), where the tail's mass would round to 0:
    far past a bound the mean is the bound plus about ``sigma^2 / distance``.
    """
    width = np.maximum(high - low, 0.0)
    uniform = ~np.isfinite(sigma) | (sigma <= 0)
    scale = np.where(uniform, 1.0, sigma)
    alpha = (low - mean) / scale
    beta = (high - mean) / scale
    left = beta < 0
    tail = left | (alpha > 0)
    # Standardised bounds with the interval right of the mean (mirrored where it is left).
    a = np.where(left, -beta, alpha)
    b = np.where(left, -alpha, beta)
    root2pi = math.sqrt(2.0 * math.pi)
    # In the tail (0 <= a <= b): every term carries exp(-a^2/2), divided out.
    at = np.where(tail, a, 0.0)
    bt = np.where(tail, b, 0.0)
    decay = np.exp(-0.5 * (bt - at) * (bt + at))
    tail_mass = 0.5 * (erfcx(at / math.sqrt(2.0)) - erfcx(bt / math.sqrt(2.0)) * decay)
    tail_mass = np.where(tail_mass > 0, tail_mass, 1.0)
    tail_shift = (1.0 - decay) / root2pi / tail_mass
    tail_spread = 1.0 + (at - bt * decay) / root2pi / tail_mass - tail_shift**2
    # Across the mean: plain normal probabilities (the mass is not small).
    phi_a = np.exp(-0.5 * a * a) / root2pi
    phi_b = np.exp(-0.5 * b * b) / root2pi
    mass = ndtr(b) - ndtr(a)
    mass = np.where(mass > 0, mass, 1.0)
    # Far in the tail (the two formulas above cancel to rounding) the density on [a, b] is
    # exponential with rate a: its truncated mean and variance, relative error ~ 1 / a^2.
    far = tail & (at > _FAR_TAIL)
    rate = np.where(far, at, 1.0)
    length = np.where(far, bt - at, 1.0)
    ratio = np.exp(-rate * length) / -np.expm1(-rate * length)  # e^(-kL) / (1 - e^(-kL))
    far_offset = 1.0 / rate - length * ratio
    far_spread = 1.0 / rate**2 - length**2 * ratio * (1.0 + ratio)
    tail_shift = np.where(far, at + far_offset, tail_shift)
    tail_spread = np.where(far, far_spread, tail_spread)
    shift = np.where(tail, tail_shift, (phi_a - phi_b) / mass)
    spread = np.where(
        tail, tail_spread, 1.0 + (a * phi_a - b * phi_b) / mass - ((phi_a - phi_b) / mass) ** 2
    )
    out_mean = mean + np.where(left, -shift, shift) * scale
    out_variance = scale**2 * np.maximum(spread, 0.0)
    out_mean = np.where(uniform, (low + high) / 2.0, out_mean)
    out_variance = np.where(uniform, width**2 / 12.0, out_variance)
    return np.clip(out_mean, low, high), np.minimum(out_variance, width**2 / 12.0)


def _information(
    weights: np.ndarray, c: np.ndarray, d: np.ndarray, origin_along: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The rays' normal equations ``A X = b``: ``A = sum w (I - d d^T)`` and
    ``b = sum w (I - d d^T) c`` (matrix products, no per-ray 3x3 projector)."""
    # Batched matrix products over the rays (numpy's einsum and 3-D sums are slower here).
    a = (
        weights.sum(axis=1)[:, None, None] * np.eye(3)
        - (d.transpose(0, 2, 1) * weights[:, None, :]) @ d
    )
    b = (weights[:, None, :] @ c)[:, 0] - ((weights * origin_along)[:, None, :] @ d)[:, 0]
    return a, b


def _along(position: np.ndarray, d: np.ndarray, origin_along: np.ndarray) -> np.ndarray:
    """(B, R) the range of each object's ``position`` along each of its rays (unclipped)."""
    return (d @ position[:, :, None])[..., 0] - origin_along


def _clipped_ranges(
    position: np.ndarray,
    d: np.ndarray,
    origin_along: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
) -> np.ndarray:
    """The range of ``position`` along each ray, within its interval."""
    return np.clip(_along(position, d, origin_along), low, high)


def _apply(matrix: np.ndarray, vector: np.ndarray) -> np.ndarray:
    return np.einsum("bij,bj->bi", matrix, vector)


def _well_posed(matrix: np.ndarray, floor: np.ndarray) -> np.ndarray:
    """(B,) whether every eigenvalue of each symmetric positive semi-definite 3x3 ``matrix``
    surely exceeds ``floor``: the least is at least ``4 det / trace^2`` (the other two
    multiply to at most a quarter of the trace squared); twice the floor leaves room for
    the determinant's rounding."""
    trace = np.trace(matrix, axis1=1, axis2=2)
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


def _bounded(
    free: np.ndarray,
    prior_point: np.ndarray,
    a_rays: np.ndarray,
    b_rays: np.ndarray,
    floor: np.ndarray,
    weights: np.ndarray,
    d: np.ndarray,
    origin_along: np.ndarray,
    low: np.ndarray,
    high: np.ndarray,
    valid: np.ndarray,
) -> np.ndarray:
    """``free`` moved so that every range bound holds, by a primal active set: per pass and
    object, the most violated bound becomes a stiff penalty pulling the range onto it, or,
    where none is violated, the active bound the solution presses away from most (the
    optimum lies inside it) is released."""
    tolerance = 1e-9 * (1.0 + high)
    along = _along(free, d, origin_along)
    if not (valid & ((low - along > tolerance) | (along - high > tolerance))).any():
        return free  # no bound violated: the free solution is the bounded one
    batch = len(free)
    index = np.arange(batch)
    position = free
    target = np.zeros_like(low)
    active = np.zeros_like(valid)
    is_low = np.zeros_like(valid)
    stiffness = _STIFFNESS * weights.max(axis=1)[:, None]
    for _ in range(_ACTIVE_PASSES):
        along = _along(position, d, origin_along)
        violation = (
            np.where(valid & ~active, np.maximum(low - along, along - high), 0.0) - tolerance
        )
        inside = np.where(active, np.where(is_low, along - target, target - along), 0.0) - tolerance
        worst = violation.argmax(axis=1)
        adding = violation[index, worst] > 0
        loosest = inside.argmax(axis=1)
        releasing = ~adding & (inside[index, loosest] > 0)
        if not (adding.any() or releasing.any()):
            break
        rows = index[adding]
        columns = worst[adding]
        below = along[rows, columns] < low[rows, columns]
        target[rows, columns] = np.where(below, low[rows, columns], high[rows, columns])
        is_low[rows, columns] = below
        active[rows, columns] = True
        active[index[releasing], loosest[releasing]] = False
        position = _penalised(
            prior_point, a_rays, b_rays, floor, active, stiffness, d, origin_along + target
        )
    if not active.any():
        return position
    # A stiff penalty leaves the range off its bound by force / stiffness: moving the
    # penalty's aim by what is left (the method of multipliers) closes the gap.
    aim = origin_along + target
    for _ in range(_REFINEMENTS):
        along = _along(position, d, origin_along)
        aim = aim + np.where(active, target - along, 0.0)
        position = _penalised(prior_point, a_rays, b_rays, floor, active, stiffness, d, aim)
    return position


def _penalised(
    prior_point: np.ndarray,
    a_rays: np.ndarray,
    b_rays: np.ndarray,
    floor: np.ndarray,
    active: np.ndarray,
    stiffness: np.ndarray,
    d: np.ndarray,
    aim: np.ndarray,
) -> np.ndarray:
    """The rays' least squares with each active ray's ``d . X`` pulled stiffly to ``aim``."""
    penalty = np.where(active, stiffness, 0.0)
    a = a_rays + (penalty[..., None] * d).transpose(0, 2, 1) @ d
    b = b_rays + ((penalty * aim)[:, None, :] @ d)[:, 0]
    return prior_point + _solve(a, b - _apply(a, prior_point), floor)
