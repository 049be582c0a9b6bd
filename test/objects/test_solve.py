"""The triangulation's linear solve: LU where every direction is determined, the least-norm
eigen-solution elsewhere, against a float64 least-norm solution computed per matrix with
eigen-filtering on well-conditioned, rank-deficient and nearly rank-deficient 3x3 systems."""

from __future__ import annotations

import numpy as np
import pytest

from allo_mrad_ros.objects.triangulation import _NULL, _solve, _well_posed


def least_norm(matrix: np.ndarray, rhs: np.ndarray, floor: float) -> np.ndarray:
    values, vectors = np.linalg.eigh(matrix)
    keep = values > floor
    return vectors[:, keep] @ ((vectors[:, keep].T @ rhs) / values[keep])


def systems(seed: int, count: int = 60):
    rng = np.random.default_rng(seed)
    matrices = []
    for k in range(count):
        basis, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        scale = 10.0 ** rng.uniform(-3, 6)
        values = scale * rng.uniform(0.1, 1.0, 3)
        kind = k % 4
        if kind == 1:  # parallel rays: one direction undetermined
            values[0] = 0.0
        elif kind == 2:  # one ray: two directions undetermined
            values[:2] = 0.0
        elif kind == 3:  # nearly parallel: just above or below the floor
            values[0] = values.sum() * _NULL * rng.choice([0.3, 3.0, 30.0])
        matrices.append(basis @ np.diag(values) @ basis.T)
    matrices = np.array(matrices)
    rhs = rng.normal(size=(count, 3)) * np.abs(matrices).max(axis=(1, 2))[:, None]
    return matrices, rhs


@pytest.mark.parametrize("seed", range(5))
def test_the_solve_is_the_least_norm_solution_over_the_determined_directions(seed):
    matrices, rhs = systems(seed)
    floor = _NULL * np.trace(matrices, axis1=1, axis2=2)
    got = _solve(matrices, rhs, floor)
    for matrix, b, f, x in zip(matrices, rhs, floor, got, strict=True):
        expected = least_norm(matrix, b, f)
        # Two backward-stable solvers agree to the kept directions' condition number times
        # the rounding unit (norm-wise); a wrong direction kept or dropped is far beyond it.
        values = np.linalg.eigvalsh(matrix)
        condition = values[-1] / values[values > f].min()
        bound = 100.0 * condition * np.finfo(float).eps * np.linalg.norm(expected)
        assert np.linalg.norm(x - expected) <= bound + 1e-300


def test_well_posed_never_claims_an_eigenvalue_at_or_below_the_floor():
    matrices, _ = systems(7, count=400)
    floor = _NULL * np.trace(matrices, axis1=1, axis2=2)
    claimed = _well_posed(matrices, floor)
    smallest = np.linalg.eigvalsh(matrices)[:, 0]
    assert np.all(smallest[claimed] > floor[claimed])
    # and it takes the plain solve for the well-conditioned ones
    assert claimed[::4].all()
