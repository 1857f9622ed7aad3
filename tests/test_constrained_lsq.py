"""The augmented-Lagrangian least squares of the flat layout and the joint solve."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from drawstring.geometry.solve.constrained_lsq import (
    EdgeLeastSquares,
    SeparationRows,
    _secant_minimum,
    constrained_least_squares,
)


@pytest.mark.parametrize("line_search", [False, True])
def test_an_infeasible_problem_stops_with_finite_numbers_and_reports_its_violation(
    line_search: bool,
) -> None:
    # A right triangle whose first side must be 2 mm long one way and 2 mm long the other:
    # no point satisfies both rows.  The solver must say so (violation above 1 tolerance) and
    # stop without numerical overflow: an unbounded damping would grow eightfold with every
    # refused trial of every multiplier round until it overflowed (RuntimeWarnings on the
    # user's terminal, eight wasted factorizations per round).
    x0 = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    objective = EdgeLeastSquares(
        np.array([[0, 1], [0, 2], [1, 2]]), np.array([1.0, 1.0, np.sqrt(2.0)]), np.ones(3)
    )
    rows = SeparationRows(
        np.array([0, 0]), np.array([1, 1]), np.array([[1.0, 0.0], [-1.0, 0.0]]), np.full(2, 2.0)
    )
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # any overflow or invalid value fails the test
        x, steps, violation = constrained_least_squares(
            x0, objective, [rows], max_steps=5000, angle_tol=1e-3, length_tol=1e-4,
            line_search=line_search,
        )  # fmt: skip
    assert np.all(np.isfinite(x))
    assert violation > 1.0  # infeasible, and reported as such
    assert steps < 200  # stalled rounds end at once instead of refactoring the same matrix


@pytest.mark.parametrize("line_search", [False, True])
def test_a_feasible_problem_meets_its_rows_and_its_targets(line_search: bool) -> None:
    # The same triangle with one row it can meet: the first side 1 mm along +x.  Known answer:
    # the triangle itself (already optimal), violation within the tolerance.
    x0 = np.array([[0.0, 0.0], [1.2, 0.1], [0.1, 0.9]])
    objective = EdgeLeastSquares(
        np.array([[0, 1], [0, 2], [1, 2]]), np.array([1.0, 1.0, np.sqrt(2.0)]), np.ones(3)
    )
    rows = SeparationRows(np.array([0]), np.array([1]), np.array([[1.0, 0.0]]), np.full(1, 0.5))
    x, _, violation = constrained_least_squares(
        x0, objective, [rows], max_steps=500, angle_tol=1e-3, length_tol=1e-6,
        line_search=line_search,
    )  # fmt: skip
    assert violation <= 1.0
    assert np.allclose(objective.residual(x), 0.0, atol=1e-6)
    assert (x[1] - x[0]) @ np.array([1.0, 0.0]) >= 0.5 - 1e-6


def test_the_secant_minimum_of_a_step_is_the_least_of_its_piecewise_quadratic_model() -> None:
    # no rows: (2 - 4 t)^2 is least half way
    empty = np.zeros(0)
    assert _secant_minimum(np.array([2.0]), np.array([-2.0]), empty, empty, 1.0) == 0.5
    # a residual falling (1 - t)^2 and a row switching on at t = 1/4, (4 t - 1)^2 with
    # rho = 1/2: least where -2 (1 - t) + 8 (4 t - 1) = 0, t = 10/34
    t = _secant_minimum(np.array([1.0]), np.array([0.0]), np.array([-1.0]), np.array([3.0]), 0.5)
    assert t == pytest.approx(10.0 / 34.0, rel=1e-12)
    # against the model sampled finely, with rows switching on and off along the step
    rng = np.random.default_rng(7)
    r0, r1 = rng.normal(size=30), rng.normal(size=30)
    c0, c1 = rng.normal(size=40), rng.normal(size=40)
    rho = 0.3
    grid = np.linspace(0.0, 1.0, 200_001)
    r = r0[None] + grid[:, None] * (r1 - r0)[None]
    c = np.maximum(c0[None] + grid[:, None] * (c1 - c0)[None], 0.0)
    model = np.einsum("ij,ij->i", r, r) + np.einsum("ij,ij->i", c, c) / (2.0 * rho)
    best = _secant_minimum(r0, r1, c0, c1, rho)
    assert best == pytest.approx(grid[np.argmin(model)], abs=2e-5)
    r_best = r0 + best * (r1 - r0)
    c_best = np.maximum(c0 + best * (c1 - c0), 0.0)
    assert r_best @ r_best + c_best @ c_best / (2.0 * rho) <= model.min() + 1e-12


def test_the_line_search_reaches_the_same_optimum_with_fewer_factorizations() -> None:
    # A 12 x 12 grid of points whose edges want to be up to 1.6 times longer, each point kept
    # within 1.2 mm to the right of its left neighbour: growing, the grid runs into rows that
    # were inactive where its steps were computed.  Known outcome (this seed): both reach the
    # same optimum; the damped steps alone take 611 factorizations, with the line search 271.
    n = 12
    ij = np.array([(i, j) for j in range(n) for i in range(n)], dtype=float)
    idx = np.arange(n * n).reshape(n, n)
    edges = np.concatenate(
        [
            np.c_[idx[:, :-1].ravel(), idx[:, 1:].ravel()],
            np.c_[idx[:-1, :].ravel(), idx[1:, :].ravel()],
            np.c_[idx[:-1, :-1].ravel(), idx[1:, 1:].ravel()],
        ]
    )
    rng = np.random.default_rng(4)
    x0 = ij + 0.05 * rng.standard_normal(ij.shape)
    length = np.linalg.norm(ij[edges[:, 1]] - ij[edges[:, 0]], axis=1)
    objective = EdgeLeastSquares(
        edges, length * (1.0 + 1.6 * rng.random(len(edges))), np.ones(len(edges))
    )
    left, right = idx[:, :-1].ravel(), idx[:, 1:].ravel()
    rows = SeparationRows(
        right, left, np.tile([[1.0, 0.0]], (len(left), 1)), np.full(len(left), -1.2)
    )
    outcomes = []
    for line_search in (False, True):
        x, steps, violation = constrained_least_squares(
            x0, objective, [rows], max_steps=2000, angle_tol=1e-4, length_tol=1e-6,
            line_search=line_search,
        )  # fmt: skip
        assert violation <= 1.0
        r = objective.residual(x)
        outcomes.append((float(r @ r), steps))
    (plain_cost, plain_steps), (searched_cost, searched_steps) = outcomes
    assert searched_cost == pytest.approx(plain_cost, rel=1e-9)
    assert searched_steps < 0.6 * plain_steps
