"""A slow float64 oracle of :func:`allo_mrad_ros.objects.triangulation.triangulate`, one
object and one ray at a time: the same cost (each ray's angular residual, weighted by its
angular variance plus its drift variance over its range squared), minimised over the point
by SciPy's ``least_squares`` (an independent solver) instead of Gauss-Newton in inverse
range; the feasible inverse ranges found on a dense grid instead of in closed form; finite
differences for the Jacobian; SciPy's truncated normal along the anchor."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import truncnorm

CONFLICT = 3.0  # the triangulation's _CONFLICT


def _basis(direction):
    axis = np.zeros(3)
    axis[int(np.argmin(np.abs(direction)))] = 1.0
    e1 = np.cross(direction, axis)
    e1 /= np.linalg.norm(e1)
    return np.array([e1, np.cross(direction, e1), direction])


def triangulate_one(origins, directions, angular_variance, extra_variance, low, high):
    """``(position, covariance, free_range, free_sigma)`` for one object's rays (the last is
    the anchor); the lists are plain sequences."""
    n = len(origins)
    c = [np.array(o, dtype=np.float64) for o in origins]
    d = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in directions]
    anchor = n - 1
    basis = _basis(d[anchor])

    def point(theta):
        alpha, beta, rho = theta
        return c[anchor] + basis.T @ np.array([alpha, beta, 1.0]) / rho

    def residuals(theta, weights):
        x = point(theta)
        out = []
        for i in range(n):
            offset = x - c[i]
            along = float(d[i] @ offset)
            frame = _basis(d[i])
            out += [math.sqrt(weights[i]) * float(frame[k] @ offset) / along for k in (0, 1)]
        return np.array(out)

    def weights_at(theta):
        x = point(theta)
        return [
            1.0 / (angular_variance[i] + extra_variance[i] / float(d[i] @ (x - c[i])) ** 2)
            for i in range(n)
        ]

    middle = 2.0 / (1.0 / low[anchor] + 1.0 / high[anchor])
    theta = np.array([0.0, 0.0, 1.0 / middle])
    if n > 1:
        # Started where the lines pass nearest (their plain least squares), whose direction
        # from the anchor and inverse range are the parameters.
        a = sum(np.eye(3) - np.outer(v, v) for v in d)
        b = sum((np.eye(3) - np.outer(v, v)) @ o for v, o in zip(d, c, strict=True))
        local = basis @ (np.linalg.lstsq(a, b, rcond=None)[0] - c[anchor])
        if local[2] > 0:
            theta = np.array([local[0] / local[2], local[1] / local[2], 1.0 / local[2]])
        # Each ray's weight at the solution (held while solving, as the triangulation does).
        for _ in range(6):
            weights = weights_at(theta)
            theta = least_squares(
                residuals, theta, args=(weights,), xtol=1e-15, ftol=1e-15, gtol=1e-15
            ).x
    weights = weights_at(theta)
    # The Gauss-Newton Hessian by central differences of the residuals.
    jacobian = np.zeros((2 * n, 3))
    for k in range(3):
        step = np.zeros(3)
        step[k] = 1e-6 * max(abs(theta[k]), 1e-3)
        jacobian[:, k] = (residuals(theta + step, weights) - residuals(theta - step, weights)) / (
            2 * step[k]
        )
    hessian = jacobian.T @ jacobian
    h_ab = hessian[:2, :2]
    slope = -np.linalg.solve(h_ab, hessian[:2, 2])
    information = hessian[2, 2] + hessian[2, :2] @ slope
    informed = n > 1 and information > 1e-9 * hessian[2, 2]
    rho = theta[2]
    sigma = 1.0 / math.sqrt(information) if informed else math.inf
    # Feasible inverse ranges: every ray's range in its interval, on a dense grid.
    m = basis.T @ np.array([theta[0], theta[1], 1.0])
    own_low, own_high = 1.0 / high[anchor], 1.0 / low[anchor]
    grid = np.geomspace(own_low, own_high, 400_001)
    ok = np.ones_like(grid, dtype=bool)
    for i in range(n):
        ranges = float(d[i] @ (c[anchor] - c[i])) + float(d[i] @ m) / grid
        ok &= (ranges >= low[i]) & (ranges <= high[i])
    rho_low, rho_high = (grid[ok][0], grid[ok][-1]) if ok.any() else (own_low, own_high)
    if not informed:
        mean, variance = (rho_low + rho_high) / 2.0, (rho_high - rho_low) ** 2 / 12.0
    elif rho + CONFLICT * sigma < rho_low or rho - CONFLICT * sigma > rho_high:
        mean, variance = rho, sigma**2
    else:
        alpha, beta = (rho_low - rho) / sigma, (rho_high - rho) / sigma
        mean, variance = (float(x) for x in truncnorm.stats(alpha, beta, rho, sigma, "mv"))
    ab = theta[:2] + slope * (mean - rho)
    position = point(np.array([ab[0], ab[1], mean]))
    cov_theta = np.zeros((3, 3))
    cov_theta[:2, :2] = np.linalg.inv(h_ab) + np.outer(slope, slope) * variance
    cov_theta[:2, 2] = cov_theta[2, :2] = slope * variance
    cov_theta[2, 2] = variance
    m = basis.T @ np.array([ab[0], ab[1], 1.0])
    to_point = np.column_stack([basis[0] / mean, basis[1] / mean, -m / mean**2])
    covariance = to_point @ cov_theta @ to_point.T
    free_range = 1.0 / rho
    free_sigma = sigma / rho**2 if informed else math.inf
    return position, covariance, free_range, free_sigma
