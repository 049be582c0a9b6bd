"""Triangulation against closed-form geometry, its covariance against noisy draws, and the
vectorised batch against a slow float64 oracle."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from triangulation_oracle import triangulate_one

from allo_mrad_ros.objects import triangulation
from allo_mrad_ros.objects.params import ObjectsError
from allo_mrad_ros.objects.triangulation import RayBatch, triangulate

# P(chi-square with 3 dof <= 14.156) = 0.9973, the coverage of +-3 sigma in one dimension:
# the "3-sigma ellipsoid" of a 3-D estimate.
CHI2_3_THREE_SIGMA = 14.156


def rays_through(point, origins, variance=1e-6, low=0.3, high=50.0):
    origins = np.asarray(origins, float)
    return RayBatch.single(origins, np.asarray(point, float) - origins, variance, low, high)


@pytest.mark.parametrize("seed", range(20))
def test_noise_free_rays_meet_at_the_point_to_a_micrometre(seed):
    rng = np.random.default_rng(seed)
    point = rng.uniform(-20.0, 20.0, 3)
    count = int(rng.integers(2, 12))
    origins = point + rng.normal(size=(count, 3)) * rng.uniform(0.5, 10.0)
    solution = triangulate(rays_through(point, origins, rng.uniform(1e-8, 1e-4)))
    assert np.linalg.norm(solution.position[0] - point) < 1e-6
    np.testing.assert_allclose(
        solution.ranges[0], np.linalg.norm(origins - point, axis=1), atol=1e-6
    )


def test_two_perpendicular_rays_meet_where_the_lines_cross():
    # x axis from the origin, and the line x = 5 in the y direction: they cross at (5, 0, 0).
    rays = RayBatch.single(
        [[0.0, 0.0, 0.0], [5.0, -4.0, 0.0]], [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], 1e-6, 0.3, 50.0
    )
    solution = triangulate(rays)
    assert np.abs(solution.position[0] - [5.0, 0.0, 0.0]).max() < 1e-9
    assert solution.free_range[0] == pytest.approx(4.0, abs=1e-9)
    # Each ray pins the other's range: sigma along ray 2 = sigma_angle * range along ray 1.
    assert solution.free_range_sigma[0] == pytest.approx(1e-3 * 5.0, rel=1e-6)


def test_one_ray_sits_mid_interval_in_inverse_range_with_the_interval_s_spread():
    low, high = 0.5, 20.0
    direction = np.array([1.0, 2.0, 2.0]) / 3.0
    solution = triangulate(RayBatch.single([[1.0, 1.0, 1.0]], [direction], 1e-6, low, high))
    middle = 2.0 / (1.0 / low + 1.0 / high)
    np.testing.assert_allclose(solution.position[0], [1.0, 1.0, 1.0] + middle * direction)
    along = direction @ solution.covariance[0] @ direction
    expected = middle**2 * (1.0 / low - 1.0 / high) / math.sqrt(12.0)
    assert math.sqrt(along) == pytest.approx(expected, rel=1e-6)
    assert math.isinf(solution.free_range_sigma[0])  # the ray alone fixes no range


def test_parallel_rays_place_the_point_at_infinity():
    # Rays that keep one direction while the camera translates meet at infinity: inverse
    # range 0, with the spread a linear regression of the directions on the baselines gives
    # (sigma over the root of the baselines' squared deviations across the rays).
    origins = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.5, 0.0]])
    rays = RayBatch.single(origins, np.tile([0.0, 0.0, 1.0], (3, 1)), 1e-6, 0.3, 50.0)
    solution = triangulate(rays)
    rho, sigma = solution.free_inverse_range()
    across = origins[:, :2] - origins[:, :2].mean(axis=0)
    assert abs(rho[0]) < 1e-9
    assert sigma[0] == pytest.approx(1e-3 / math.sqrt(np.sum(across**2)), rel=1e-6)
    # The interval (up to 50 m) is contradicted by hundreds of sigma: the point stays on the
    # rays' direction, as far as the triangulation places anything (1000 times the
    # interval's far end), so that it projects where the next such ray will point.
    assert solution.ranges[0, -1] == pytest.approx(50.0e3)


def test_a_bound_holds_where_the_rays_cross_beyond_it_within_their_noise():
    point = np.array([0.0, 0.0, 10.0])
    origins = np.array([[-0.1, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]])
    # 3 mrad rays over a 0.2 m baseline: inverse range 0.1 +- 0.02. The newest ray sees
    # surface at 9.5 m (inverse 0.105, a quarter sigma off): the object lies in front of it.
    high = np.array([50.0, 50.0, 9.5])
    rays = RayBatch.single(origins, point - origins, 1e-5, 0.3, high)
    solution = triangulate(rays)
    assert 0.3 <= solution.ranges[0, 2] <= 9.5
    # The truncated normal's mean: well inside, where most of the cut mass lies.
    assert solution.ranges[0, 2] < 9.0
    # Parallax alone still says 10 m (what the tracker checks against the surface).
    assert solution.free_range[0] == pytest.approx(np.linalg.norm(point - origins[2]), abs=1e-6)
    oracle, *_ = triangulate_one(origins, point - origins, [1e-5] * 3, [0.0] * 3, [0.3] * 3, high)
    assert np.linalg.norm(solution.position[0] - oracle) < 1e-5


def test_rays_that_meet_far_beyond_a_bound_keep_their_own_crossing():
    # 1 mrad rays over 2 m meet 4 m behind the surface the newest one sees (40 sigma of
    # inverse range): the intervals are contradicted (glare, a reflection), so the point is
    # where the rays meet and parallax alone places it behind (the tracker does not confirm).
    point = np.array([0.0, 0.0, 10.0])
    origins = np.array([[-1.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    high = np.array([50.0, 50.0, 6.0])
    solution = triangulate(RayBatch.single(origins, point - origins, 1e-6, 0.3, high))
    assert np.linalg.norm(solution.position[0] - point) < 1e-6
    rho, sigma = solution.free_inverse_range()
    assert rho[0] + 3.0 * sigma[0] < 1.0 / 6.0


def test_the_true_point_lies_in_the_3_sigma_ellipsoid_in_99_percent_of_noisy_draws():
    rng = np.random.default_rng(2024)
    focal, pixel_sigma = 800.0, 1.5
    angle = pixel_sigma / focal
    point = np.array([0.4, -0.3, 8.0])
    # A camera sweeping 1.2 m past the point: ten views.
    origins = np.c_[np.linspace(-0.6, 0.6, 10), np.zeros(10), np.zeros(10)]
    inside = 0
    draws = 1000
    for _ in range(draws):
        directions = point - origins
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        # Noise of pixel_sigma pixels in the image: angle across the ray, both axes.
        noise = rng.normal(scale=angle, size=(10, 3))
        noise -= np.sum(noise * directions, axis=1, keepdims=True) * directions
        solution = triangulate(RayBatch.single(origins, directions + noise, angle**2, 0.3, 50.0))
        error = solution.position[0] - point
        inside += (
            float(error @ np.linalg.solve(solution.covariance[0], error)) <= CHI2_3_THREE_SIGMA
        )
    assert inside >= 0.99 * draws, inside


@pytest.mark.parametrize("seed", range(8))
def test_the_vectorised_batch_matches_the_slow_oracle(seed, monkeypatch):
    # Converged to rounding (the shipped triangulation stops within half a standard
    # deviation of inverse range, a speed trade-off), so both sit at the same optimum.
    monkeypatch.setattr(triangulation, "_CONVERGED", 1e-9)
    rng = np.random.default_rng(100 + seed)
    batch, capacity = 5, 9
    counts = rng.integers(1, capacity + 1, batch)
    origins = rng.normal(scale=3.0, size=(batch, capacity, 3))
    targets = rng.uniform(-10, 10, (batch, 1, 3)) + rng.normal(scale=0.2, size=(batch, capacity, 3))
    directions = targets - origins
    directions /= np.linalg.norm(directions, axis=-1, keepdims=True)
    variance = rng.uniform(1e-7, 1e-4, (batch, capacity))
    extra = rng.uniform(0.0, 0.05, (batch, capacity))
    low = np.full((batch, capacity), 0.3)
    high = rng.uniform(5.0, 40.0, (batch, capacity))
    valid = np.arange(capacity)[None, :] < counts[:, None]
    rays = RayBatch(origins, directions, variance, extra, low, high, valid, counts - 1)
    solution = triangulate(rays, iterations=12)
    for b in range(batch):
        n = counts[b]
        position, covariance, free_range, free_sigma = triangulate_one(
            origins[b, :n],
            directions[b, :n],
            variance[b, :n],
            extra[b, :n],
            low[b, :n],
            high[b, :n],
        )
        assert np.linalg.norm(solution.position[b] - position) < 1e-5 * (
            1 + np.linalg.norm(position)
        )
        np.testing.assert_allclose(solution.covariance[b], covariance, rtol=1e-3, atol=1e-9)
        if n > 1:
            assert solution.free_range[b] == pytest.approx(free_range, rel=1e-6, abs=1e-6)
            assert solution.free_range_sigma[b] == pytest.approx(free_sigma, rel=1e-4)


def test_a_malformed_batch_is_refused_naming_the_array():
    rays = RayBatch.single([[0.0, 0.0, 0.0]], [[0.0, 0.0, 1.0]], 1e-6, 0.3, 50.0)
    with pytest.raises(ObjectsError, match="anchor"):
        RayBatch(
            rays.origins,
            rays.directions,
            rays.angular_variance,
            rays.extra_variance,
            rays.low,
            rays.high,
            np.zeros((1, 1), bool),
            rays.anchor,
        )
    with pytest.raises(ObjectsError, match="low"):
        RayBatch(
            rays.origins,
            rays.directions,
            rays.angular_variance,
            rays.extra_variance,
            rays.low[:, :0],
            rays.high,
            rays.valid,
            rays.anchor,
        )


def test_an_unchecked_batch_holds_the_arrays_given_and_triangulates_as_a_checked_one():
    rng = np.random.default_rng(5)
    point = np.array([1.0, 2.0, 12.0])
    checked = rays_through(point, point + rng.normal(size=(6, 3)) * 3.0, variance=1e-5)
    arrays = {field.name: getattr(checked, field.name) for field in dataclasses.fields(RayBatch)}
    unchecked = RayBatch.unchecked(**arrays)
    for name, array in arrays.items():
        assert getattr(unchecked, name) is array
    ours, theirs = triangulate(unchecked), triangulate(checked)
    for field in dataclasses.fields(ours):
        np.testing.assert_array_equal(getattr(ours, field.name), getattr(theirs, field.name))


def test_the_truncated_normal_moments_match_scipy_and_its_tail_limit():
    from scipy.stats import truncnorm

    from allo_mrad_ros.objects.triangulation import truncated_normal_moments

    rng = np.random.default_rng(7)
    low = rng.uniform(0.01, 0.5, 2000)
    high = low + rng.uniform(0.01, 3.0, 2000)
    sigma = 10 ** rng.uniform(-3, 1, 2000)
    mean = rng.uniform(-3.0, 5.0, 2000)
    alpha, beta = (low - mean) / sigma, (high - mean) / sigma
    # SciPy's own formulas lose their digits far in a tail: compared within 25 sigma.
    near = np.minimum(np.abs(alpha), np.abs(beta)) < 25
    got_mean, got_variance = truncated_normal_moments(mean, sigma, low, high)
    want_mean, want_variance = truncnorm.stats(
        alpha[near], beta[near], loc=mean[near], scale=sigma[near], moments="mv"
    )
    assert np.all(np.abs(got_mean[near] - want_mean) <= 1e-7 * sigma[near])
    spread_error = np.abs(np.sqrt(got_variance[near]) - np.sqrt(want_variance))
    assert np.all(spread_error <= 1e-7 * sigma[near])
    # Far past a bound: the bound plus sigma / distance (in sigmas), spread the same.
    m, v = truncated_normal_moments(
        np.array([0.0]), np.array([1.0]), np.array([1e3]), np.array([2e3])
    )
    assert m[0] - 1e3 == pytest.approx(1e-3, rel=1e-5) and math.sqrt(v[0]) == pytest.approx(
        1e-3, rel=1e-5
    )
    # No information: the uniform distribution.
    m, v = truncated_normal_moments(
        np.array([0.0]), np.array([np.inf]), np.array([1.0]), np.array([3.0])
    )
    assert m[0] == 2.0 and v[0] == pytest.approx(4.0 / 12.0)


def test_weak_parallax_leaves_no_range_bias():
    # An object 9 m ahead of a camera sliding 0.3 m sideways, 30 views with 3 px of centroid
    # noise at 667 px focal length: parallax of 22 mrad against 4.5 mrad of noise. Minimising
    # the rays' distances from the point (the noise in the regressor) pulled the range
    # towards the camera (about 5 m of 9); the angular residuals in inverse range are
    # linear in it, so its estimate is unbiased: the mean over 500 draws within three
    # standard errors of the truth.
    rng = np.random.default_rng(11)
    angle = 3.0 / 667.0
    point = np.array([0.3, -0.2, 9.0])
    origins = np.c_[np.linspace(0.0, 0.3, 30), np.zeros(30), np.zeros(30)]
    estimates = []
    for _ in range(500):
        directions = point - origins
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        noise = rng.normal(scale=angle, size=(30, 3))
        noise -= np.sum(noise * directions, axis=1, keepdims=True) * directions
        solution = triangulate(RayBatch.single(origins, directions + noise, angle**2, 0.3, 5e4))
        estimates.append(solution.free_inverse_range()[0][0])
    estimates = np.array(estimates)
    truth = 1.0 / np.linalg.norm(point - origins[-1])
    standard_error = estimates.std() / math.sqrt(len(estimates))
    assert abs(estimates.mean() - truth) < 3.0 * standard_error
    assert np.median(1.0 / estimates) == pytest.approx(1.0 / truth, rel=0.05)


def test_camera_position_noise_counted_across_the_rays_keeps_the_3_sigma_coverage():
    # Camera positions reported with 2 cm of noise per axis (the generator's pose error) and
    # an object 3 m away: that noise, given as variance across each ray, keeps the true
    # point inside the 3-sigma ellipsoid in at least 99 % of 1,000 draws.
    rng = np.random.default_rng(5)
    angle, position_sigma = 2.0 / 667.0, 0.02
    point = np.array([0.2, 0.1, 3.0])
    true_origins = np.c_[np.linspace(-0.3, 0.3, 12), np.zeros(12), np.zeros(12)]
    inside = 0
    for _ in range(1000):
        directions = point - true_origins
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        noise = rng.normal(scale=angle, size=(12, 3))
        noise -= np.sum(noise * directions, axis=1, keepdims=True) * directions
        reported = true_origins + rng.normal(scale=position_sigma, size=(12, 3))
        rays = RayBatch.single(
            reported, directions + noise, angle**2, 0.3, 50.0, extra_variance=position_sigma**2
        )
        solution = triangulate(rays)
        error = solution.position[0] - point
        inside += (
            float(error @ np.linalg.solve(solution.covariance[0], error)) <= CHI2_3_THREE_SIGMA
        )
    assert inside >= 990, inside
