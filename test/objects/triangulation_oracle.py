"""A slow float64 oracle of :func:`allo_mrad_ros.objects.triangulation.triangulate`, one
object and one ray at a time: the same weights, its constrained least squares solved by
SciPy's SLSQP (an independent solver) instead of the penalty active set, and SciPy's
truncated normal for the spread along the anchor."""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize
from scipy.stats import truncnorm


def triangulate_one(origins, directions, angular_variance, extra_variance, low, high):
    """``(position, covariance, free_range, free_sigma)`` for one object's rays (the last is
    the anchor); the lists are plain sequences."""
    n = len(origins)
    c = [np.array(o, dtype=np.float64) for o in origins]
    d = [np.array(v, dtype=np.float64) / np.linalg.norm(v) for v in directions]
    anchor = n - 1
    middle = 2.0 / (1.0 / low[anchor] + 1.0 / high[anchor])
    prior = c[anchor] + middle * d[anchor]

    def ranges_of(x):
        return [min(max(float(d[i] @ (x - c[i])), low[i]), high[i]) for i in range(n)]

    def weights_of(ranges):
        return [1.0 / (angular_variance[i] * ranges[i] ** 2 + extra_variance[i]) for i in range(n)]

    def objective(x, weights):
        total = 0.0
        for i in range(n):
            offset = x - c[i]
            across = offset - (d[i] @ offset) * d[i]
            total += weights[i] * float(across @ across)
        return total

    position = prior
    free = prior
    for _ in range(3):
        weights = weights_of(ranges_of(position))
        a = np.zeros((3, 3))
        b = np.zeros(3)
        for i in range(n):
            p = np.eye(3) - np.outer(d[i], d[i])
            a += weights[i] * p
            b += weights[i] * p @ c[i]
        # Least-norm about the prior point over the directions the rays determine.
        values, vectors = np.linalg.eigh(a)
        step = np.zeros(3)
        for k in range(3):
            if values[k] > 1e-12 * values.sum():
                step += vectors[:, k] * (vectors[:, k] @ (b - a @ prior)) / values[k]
        free = prior + step
        scale = max(weights)
        constraints = []
        for i in range(n):
            constraints.append(
                {"type": "ineq", "fun": lambda x, i=i: float(d[i] @ (x - c[i])) - low[i]}
            )
            constraints.append(
                {"type": "ineq", "fun": lambda x, i=i: high[i] - float(d[i] @ (x - c[i]))}
            )
        result = minimize(
            lambda x, w=weights, s=scale: objective(x, w) / s,
            free if all(low[i] <= d[i] @ (free - c[i]) <= high[i] for i in range(n)) else prior,
            method="SLSQP",
            constraints=constraints,
            options={"ftol": 1e-15, "maxiter": 500},
        )
        position = result.x
    ranges = ranges_of(position)
    weights = weights_of(ranges)
    a = sum(weights[i] * (np.eye(3) - np.outer(d[i], d[i])) for i in range(n))
    free_range = float(d[anchor] @ (free - c[anchor]))
    free_sigma = math.sqrt(float(d[anchor] @ np.linalg.inv(a) @ d[anchor])) if n > 1 else math.inf
    # Along the anchor: the rays' Gaussian in inverse range times the interval's uniform one,
    # a truncated normal (SciPy's), whose mean places the object and whose variance (to
    # range) is its spread along the anchor.
    rho_low, rho_high = 1.0 / high[anchor], 1.0 / low[anchor]
    if math.isinf(free_sigma):
        mean, variance = (rho_low + rho_high) / 2.0, (rho_high - rho_low) ** 2 / 12.0
        rays_variance = math.inf
    else:
        mu, sigma = 1.0 / free_range, free_sigma / free_range**2
        alpha, beta = (rho_low - mu) / sigma, (rho_high - mu) / sigma
        mean, variance = (float(x) for x in truncnorm.stats(alpha, beta, mu, sigma, "mv"))
        rays_variance = free_sigma**2
    along = float(d[anchor] @ (position - c[anchor]))
    position = position + (1.0 / mean - along) * d[anchor]
    extra = max(mean**4 / variance - 1.0 / rays_variance, 0.0)
    covariance = np.linalg.inv(a + extra * np.outer(d[anchor], d[anchor]))
    return position, covariance, free_range, free_sigma
