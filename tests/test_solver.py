"""Known answers and invariants of the projective local-global solver."""

from __future__ import annotations

import numpy as np
import pytest

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.solve.groups import (
    ClosenessToPlanes,
    ClosenessToPoints,
    ClosenessToSurface,
    EdgeLength,
    Plane,
)
from drawstring.geometry.solve.linalg import smallest_eigenvectors
from drawstring.geometry.solve.planarity import planarize_quads, quad_planarity
from drawstring.geometry.solve.shape_groups import SimilarityToSquare, Slab
from drawstring.geometry.solve.solver import LocalGlobalSolver


def grid(nx: int, ny: int, step: float = 5.0) -> tuple[np.ndarray, np.ndarray]:
    """Flat regular grid in z = 0: vertices (n, 3) and counter-clockwise quads (m, 4)."""
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    vertices = np.c_[i.ravel() * step, j.ravel() * step, np.zeros(i.size)]
    col, row = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a, b = col.ravel(), row.ravel()

    def vid(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return p * (ny + 1) + q

    quads = np.stack([vid(a, b), vid(a + 1, b), vid(a + 1, b + 1), vid(a, b + 1)], axis=1)
    return vertices, quads


def warped_grid(nx: int = 12, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    vertices, quads = grid(nx, nx)
    rng = np.random.default_rng(seed)
    x, y = vertices[:, 0], vertices[:, 1]
    vertices[:, 2] = 0.01 * (x - 30) * (y - 30) + 3 * np.sin(x / 9) + rng.normal(0, 0.2, len(x))
    return vertices, quads


def assert_monotone(history: np.ndarray) -> None:
    """Total energy never rises (up to round-off of the energy evaluation itself)."""
    rises = np.diff(history)
    assert np.all(rises <= 1e-12 * history[:-1] + 1e-15 * history[0]), rises.max()


@pytest.mark.parametrize("anderson", [0, 5])
def test_energy_never_rises_planarity_closeness(anderson: int) -> None:
    vertices, quads = warped_grid()
    solver = LocalGlobalSolver(
        len(vertices),
        [Plane(quads, 1e3), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)],
    )
    result = solver.solve(vertices, max_iter=300, anderson=anderson, rel_tol=0.0)
    assert len(result.energy_history) == result.iterations + 1
    assert_monotone(result.energy_history)
    assert result.energy_total_after < 0.5 * result.energy_total_before


@pytest.mark.parametrize("anderson", [0, 5])
def test_energy_never_rises_assembled_terms(anderson: int) -> None:
    """Planarity, edge lengths, squareness and a target surface together (paper eq. 1)."""
    vertices, quads = warped_grid(8, seed=1)
    target, tris = grid(30, 30, step=2.0)
    target[:, :2] -= 10.0
    target[:, 2] = 0.01 * (target[:, 0] - 30) * (target[:, 1] - 30)
    triangles = np.vstack([tris[:, [0, 1, 2]], tris[:, [0, 2, 3]]])
    edges = np.unique(np.sort(np.stack([quads, np.roll(quads, -1, 1)], 2).reshape(-1, 2)), axis=0)
    groups = [
        Plane(quads, 1e4),
        EdgeLength(edges, np.full(len(edges), 5.0), 10.0),
        SimilarityToSquare(quads, 10.0),
        ClosenessToSurface(np.arange(len(vertices)), target, triangles, 0.1),
    ]
    result = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=200, anderson=anderson, rel_tol=0.0
    )
    assert_monotone(result.energy_history)
    assert set(result.energy_after) == {"planarity", "edge_length", "square_shape", "surface"}


@pytest.mark.parametrize("anderson", [0, 5])
def test_lazy_surface_requery_is_monotone_and_close_to_exact(anderson: int) -> None:
    """ClosenessToSurface(requery_rel > 0) queries far fewer points, the energy still never
    rises, and the result is as good as the exact-query result (without Anderson: the same up to
    a small fraction of the distance)."""
    vertices, quads = warped_grid(8, seed=1)
    vertices[:, 2] += 4.0  # several mm off the target, like K3D at the paper's weights
    target, tris = grid(30, 30, step=2.0)
    target[:, :2] -= 10.0
    target[:, 2] = 0.01 * (target[:, 0] - 30) * (target[:, 1] - 30)
    triangles = np.vstack([tris[:, [0, 1, 2]], tris[:, [0, 2, 3]]])
    edges = np.unique(np.sort(np.stack([quads, np.roll(quads, -1, 1)], 2).reshape(-1, 2)), axis=0)

    def run(requery_rel: float) -> tuple[np.ndarray, float, ClosenessToSurface]:
        surface = ClosenessToSurface(
            np.arange(len(vertices)), target, triangles, 0.1, requery_rel=requery_rel
        )
        groups = [
            Plane(quads, 1e4),
            EdgeLength(edges, np.full(len(edges), 5.0), 10.0),
            SimilarityToSquare(quads, 10.0),
            surface,
        ]
        solver = LocalGlobalSolver(len(vertices), groups)
        result = solver.solve(vertices, max_iter=300, anderson=anderson, rel_tol=0.0)
        assert result.iterations == 300
        assert_monotone(result.energy_history)
        # energies() queries exactly: the lazy targets are never closer than the true ones
        exact = solver.energies(result.X)
        assert exact["surface"] <= result.energy_after["surface"] * (1 + 1e-12)
        assert result.energy_after["surface"] <= 1.01 * exact["surface"]
        return result.X, sum(exact.values()), surface

    x_exact, energy_exact, exact_group = run(0.0)
    x_lazy, energy_lazy, lazy_group = run(0.1)
    assert lazy_group.points_queried < 0.4 * exact_group.points_queried
    if anderson == 0:
        assert energy_lazy <= 1.01 * energy_exact
    else:
        # Anderson's accelerated path reacts to the lazy targets and to round-off, and after
        # 300 steps the two runs sit in nearby minima, a few percent apart depending on the
        # numpy and scipy versions
        assert energy_lazy <= 1.1 * energy_exact
    if anderson == 0:  # the same plain iterations; Anderson's path reacts to round-off
        distance = np.linalg.norm(x_exact - exact_group.closest_points(x_exact), axis=1).mean()
        assert np.abs(x_lazy - x_exact).max() < 0.02 * distance


@pytest.mark.parametrize("anderson", [0, 5])
def test_planar_grid_does_not_move(anderson: int) -> None:
    """A grid of exact squares in a tilted plane is a fixed point of every group: 50 real
    iterations (the stopping tests switched off) leave it where it is."""
    flat, quads = grid(6, 5)
    angle = np.radians(35.0)
    tilt = np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]]
    )
    turn = np.array([[np.cos(1.0), -np.sin(1.0), 0.0], [np.sin(1.0), np.cos(1.0), 0.0], [0, 0, 1]])
    vertices = flat @ (turn @ tilt).T + [3.0, -7.0, 11.0]
    edges = np.unique(np.sort(np.stack([quads, np.roll(quads, -1, 1)], 2).reshape(-1, 2)), axis=0)
    groups = [
        Plane(quads, 1e4),
        EdgeLength(edges, np.full(len(edges), 5.0), 10.0),
        SimilarityToSquare(quads, 10.0),
        ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0),
    ]
    result = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=50, rel_tol=-1.0, abs_tol=-1.0, anderson=anderson
    )
    assert result.iterations == 50
    assert not result.converged
    assert np.abs(result.X - vertices).max() < 1e-10
    assert result.energy_total_after < 1e-18


def test_planar_grid_test_would_catch_a_moving_projection() -> None:
    """The same 50 iterations with a plane projection that is off by 1 % (it also scales the
    face) do move the grid: the test above can fail."""

    class ScalingPlane(Plane):
        def project(self, ax: np.ndarray, x: np.ndarray) -> np.ndarray:
            return 1.01 * super().project(ax, x)

    vertices, quads = grid(6, 5)
    groups = [ScalingPlane(quads, 1e4), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)]
    result = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=50, rel_tol=-1.0, abs_tol=-1.0
    )
    assert result.iterations == 50
    assert np.abs(result.X - vertices).max() > 1e-3


def test_one_warped_quad_becomes_planar() -> None:
    quad = np.array([[0.0, 0.0, 0.3], [10.0, 0.0, -0.2], [10.0, 10.0, 0.4], [0.0, 10.0, -0.1]])
    solver = LocalGlobalSolver(4, [Plane([[0, 1, 2, 3]])])
    result = solver.solve(quad, max_iter=20)
    assert quad_planarity(result.X, np.array([[0, 1, 2, 3]]))[0] <= 1e-9 * 10.0
    # the centroid (a translation) is not affected by the centred planarity rows
    assert np.allclose(result.X.mean(axis=0), quad.mean(axis=0), atol=1e-12)


def test_zero_weight_group_has_no_effect() -> None:
    vertices, quads = warped_grid(6)
    base = [Plane(quads, 1e3), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)]
    without = LocalGlobalSolver(len(vertices), base).solve(vertices, max_iter=40)
    extra = SimilarityToSquare(quads, 0.0)
    with_zero = LocalGlobalSolver(len(vertices), [*base, extra]).solve(vertices, max_iter=40)
    assert np.array_equal(without.X, with_zero.X)
    assert with_zero.energy_after["square_shape"] == 0.0


def test_edge_length_chain_reaches_targets() -> None:
    points = np.c_[np.arange(6.0), np.zeros(6), np.zeros(6)] + np.array([0, 0.3, 0])[None] * (
        np.arange(6)[:, None] % 2
    )
    edges = np.c_[np.arange(5), np.arange(1, 6)]
    targets = np.array([1.0, 2.0, 1.5, 0.5, 3.0])
    solver = LocalGlobalSolver(6, [EdgeLength(edges, targets)], fixed=[0])
    result = solver.solve(points, max_iter=2000, rel_tol=0.0, abs_tol=1e-24)
    lengths = np.linalg.norm(result.X[edges[:, 1]] - result.X[edges[:, 0]], axis=1)
    assert np.allclose(lengths, targets, atol=1e-9)
    assert np.array_equal(result.X[0], points[0])


@pytest.mark.parametrize("dim", [2, 3])
def test_similarity_turns_rhombus_into_square(dim: int) -> None:
    p, q = 6.0, 2.0  # half diagonals
    rhombus = np.zeros((4, dim))
    rhombus[:, :2] = [[p, 0], [0, q], [-p, 0], [0, -q]]
    rhombus += 1.5  # off the origin
    solver = LocalGlobalSolver(4, [SimilarityToSquare([[0, 1, 2, 3]])])
    result = solver.solve(rhombus, max_iter=10)
    x = result.X
    sides = np.linalg.norm(np.roll(x, -1, axis=0) - x, axis=1)
    # closest square has half diagonal (p + q) / 2, i.e. side sqrt(2) (p + q) / 2
    assert np.allclose(sides, np.sqrt(2) * (p + q) / 2, atol=1e-9)
    diag = x[2] - x[0], x[3] - x[1]
    assert abs(np.dot(*diag)) < 1e-9
    # same orientation (no reflection) and same centre
    assert np.allclose(x.mean(axis=0), rhombus.mean(axis=0))
    assert np.dot(x[0] - x.mean(axis=0), rhombus[0] - rhombus.mean(axis=0)) > 0


def test_oriented_square_matches_the_planar_fit_in_a_tilted_plane() -> None:
    """With reference normals, a planar quad in a tilted plane projects onto the 2D Umeyama
    square of its in-plane coordinates; the same quad seen from the other side (reference
    flipped, i.e. it turned over) does not count as a square."""
    quad2d = np.array([[0.0, 0.0], [7.0, 1.0], [8.0, 6.0], [-1.0, 5.0]])
    quad2d -= quad2d.mean(axis=0)
    angle = np.radians(40.0)
    rot = np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(angle), -np.sin(angle)], [0.0, np.sin(angle), np.cos(angle)]]
    )
    quad3d = np.c_[quad2d, np.zeros(4)] @ rot.T + [1.0, 2.0, 3.0]
    up = rot @ [0.0, 0.0, 1.0]
    group = SimilarityToSquare([[0, 1, 2, 3]], reference_normals=up[None])
    a = group.matrix(4)
    square3d = group.project(a @ quad3d, quad3d)
    expected = SimilarityToSquare([[0, 1, 2, 3]]).project(quad2d, quad2d)
    assert np.allclose(square3d @ rot, np.c_[expected, np.zeros(4)], atol=1e-12)
    flipped = SimilarityToSquare([[0, 1, 2, 3]], reference_normals=-up[None])
    residual = np.linalg.norm(flipped.project(a @ quad3d, quad3d) - a @ quad3d)
    assert residual > np.linalg.norm(square3d - a @ quad3d) + 1.0


def test_two_dimensional_problem() -> None:
    """dim = 2: a square-ish 2D quad mesh under edge lengths, squareness and an anchor."""
    vertices, quads = grid(3, 3, step=2.0)
    flat = vertices[:, :2] + np.random.default_rng(4).normal(0, 0.2, (len(vertices), 2))
    edges = np.unique(np.sort(np.stack([quads, np.roll(quads, -1, 1)], 2).reshape(-1, 2)), axis=0)
    groups = [
        EdgeLength(edges, np.full(len(edges), 2.0)),
        SimilarityToSquare(quads),
        ClosenessToPoints([0], flat[:1], 1.0, name="anchor"),
    ]
    result = LocalGlobalSolver(len(flat), groups).solve(flat, max_iter=3000, rel_tol=1e-14)
    assert result.X.shape == flat.shape
    lengths = np.linalg.norm(result.X[edges[:, 1]] - result.X[edges[:, 0]], axis=1)
    assert np.allclose(lengths, 2.0, atol=1e-6)
    assert_monotone(result.energy_history)


def test_closeness_to_surface_projects_onto_plane() -> None:
    target, quads = grid(4, 4, step=10.0)
    triangles = np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    points = np.array([[12.0, 7.0, 5.0], [33.0, 21.0, -2.0]])
    group = ClosenessToSurface([0, 1], target, triangles)
    result = LocalGlobalSolver(2, [group]).solve(points, max_iter=200, rel_tol=0.0, abs_tol=1e-20)
    assert np.allclose(result.X[:, 2], 0.0, atol=1e-9)
    assert np.allclose(result.X[:, :2], points[:, :2], atol=1e-9)


def test_closeness_to_planes_meets_at_the_planes_intersection() -> None:
    # one vertex pulled onto x = 1 and onto y = 2 (two rows) settles on their common line,
    # where it started along it (z); another onto a slanted plane lands on its closest point
    normal = np.array([1.0, 1.0, 1.0]) / np.sqrt(3.0)
    group = ClosenessToPlanes(
        [0, 0, 1], [[1.0, 0, 0], [0, 1.0, 0], normal], [1.0, 2.0, 3.0], weight=2.0
    )
    points = np.array([[5.0, -4.0, 7.0], [0.0, 0.0, 0.0]])
    projected = group.project(group.matrix(2) @ points, points)
    assert np.allclose(projected, [[1.0, -4.0, 7.0], [5.0, 2.0, 7.0], 3.0 * normal])
    result = LocalGlobalSolver(2, [group]).solve(points, max_iter=500, rel_tol=0.0, abs_tol=1e-24)
    assert np.allclose(result.X, [[1.0, 2.0, 7.0], 3.0 * normal], atol=1e-9)
    assert_monotone(result.energy_history)


def test_closeness_to_planes_refuses_bad_planes() -> None:
    with pytest.raises(InternalError, match="one normal and one level per index"):
        ClosenessToPlanes([0, 1], [[0, 0, 1.0]], [0.0, 1.0])
    with pytest.raises(InternalError, match="unit"):
        ClosenessToPlanes([0], [[0, 0, 2.0]], [0.0])


def test_slab_projects_to_parallel_planes_at_thickness() -> None:
    rng = np.random.default_rng(2)
    top = np.array([[0, 0, 0], [10, 0, 0], [10, 10, 0], [0, 10, 0]], dtype=float)
    bottom = top - [0, 0, 3.0]
    points = np.vstack([top, bottom]) + rng.normal(0, 0.3, (8, 3))
    group = Slab([[0, 1, 2, 3]], [[4, 5, 6, 7]], 3.0)
    solver = LocalGlobalSolver(8, [group])
    x = solver.solve(points, max_iter=5).X
    top_n = np.linalg.svd(x[:4] - x[:4].mean(0))[2][-1]
    bottom_n = np.linalg.svd(x[4:] - x[4:].mean(0))[2][-1]
    assert abs(abs(top_n @ bottom_n) - 1) < 1e-12
    assert np.abs((x[:4] - x[:4].mean(0)) @ top_n).max() < 1e-10
    assert np.abs((x[4:] - x[:4].mean(0)) @ top_n).max() == pytest.approx(3.0, abs=1e-10)


def test_slab_projection_is_the_closest_point() -> None:
    """Compare the batched normal with a dense search over the unit sphere."""
    rng = np.random.default_rng(5)
    top = np.array([[0, 0, 0], [6, 0, 0], [6, 6, 0], [0, 6, 0]], dtype=float)
    pts = np.vstack([top, top - [0, 0, 2.0]]) + rng.normal(0, 0.6, (8, 3))
    pts -= pts.mean(axis=0)
    group = Slab([[0, 1, 2, 3]], [[4, 5, 6, 7]], 2.0)
    projected = group.project(pts, pts)
    best = np.sum((projected - pts) ** 2)

    theta, phi = np.meshgrid(np.linspace(0, np.pi, 400), np.linspace(0, 2 * np.pi, 800))
    normals = np.c_[
        (np.sin(theta) * np.cos(phi)).ravel(),
        (np.sin(theta) * np.sin(phi)).ravel(),
        np.cos(theta).ravel(),
    ]
    t, b = pts[:4], pts[4:]
    ht, hb = t @ normals.T, b @ normals.T
    a, c = ht.mean(0), hb.mean(0)
    cost = ((ht - a) ** 2).sum(0) + ((hb - c) ** 2).sum(0) + 2 * (a - c - 2.0) ** 2
    assert best <= cost.min() + 1e-9
    assert best == pytest.approx(cost.min(), rel=1e-3)


@pytest.mark.parametrize("anderson", [0, 5])
def test_energy_never_rises_extrusion(anderson: int) -> None:
    vertices, quads = warped_grid(5, seed=3)
    n = len(vertices)
    bottom = vertices - [0, 0, 2.0]
    faces = np.vstack([quads, quads + n])
    groups = [
        Plane(faces),
        Slab(quads, quads + n, 2.0),
        ClosenessToPoints(np.arange(n), vertices, 1.0),
    ]
    result = LocalGlobalSolver(2 * n, groups).solve(
        np.vstack([vertices, bottom]), max_iter=150, anderson=anderson, rel_tol=0.0
    )
    assert_monotone(result.energy_history)


def test_factor_is_reused_and_refreshed_on_weight_change() -> None:
    vertices, quads = warped_grid(4)
    solver = LocalGlobalSolver(
        len(vertices),
        [Plane(quads, 10.0), ClosenessToPoints(np.arange(len(vertices)), vertices, name="keep")],
    )
    assert solver.solve(vertices, max_iter=3).factorizations == 1
    assert solver.solve(vertices, max_iter=3).factorizations == 0
    solver.set_weight("keep", 2.0)
    assert solver.solve(vertices, max_iter=3).factorizations == 1
    group = solver.group("keep")
    assert isinstance(group, ClosenessToPoints)
    group.set_targets(vertices + 1.0)  # moving targets need no refactor
    assert solver.solve(vertices, max_iter=3).factorizations == 0


def test_fixed_vertices_do_not_move() -> None:
    vertices, quads = warped_grid(5)
    fixed = np.array([0, 7, 20])
    solver = LocalGlobalSolver(len(vertices), [Plane(quads)], fixed=fixed)
    result = solver.solve(vertices, max_iter=100)
    assert np.array_equal(result.X[fixed], vertices[fixed])
    assert quad_planarity(result.X, quads).max() < quad_planarity(vertices, quads).max()


def test_anderson_reaches_lower_energy_in_same_iterations() -> None:
    vertices, quads = warped_grid(12)
    groups = [Plane(quads, 1e3), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)]
    plain = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=100, anderson=0, rel_tol=0.0
    )
    fast = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=100, anderson=5, rel_tol=0.0
    )
    assert fast.accelerated_accepted > 0
    assert fast.energy_history[-1] < plain.energy_history[-1]


def test_anderson_gram_mixing_is_monotone_and_as_fast() -> None:
    """Anderson through the small Gram matrix: monotone, and about as far in 100 iterations as
    with lstsq on the tall matrix (the two differ by round-off, which Anderson amplifies)."""
    vertices, quads = warped_grid(12)
    groups = [Plane(quads, 1e3), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)]
    tall = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=100, anderson=8, rel_tol=0.0
    )
    gram = LocalGlobalSolver(len(vertices), groups).solve(
        vertices, max_iter=100, anderson=8, rel_tol=0.0, anderson_gram=True
    )
    assert_monotone(gram.energy_history)
    assert gram.accelerated_accepted > 0
    assert gram.energy_history[-1] < 1.1 * tall.energy_history[-1]
    assert gram.energy_history[10] == pytest.approx(tall.energy_history[10], rel=1e-6)


def test_planarize_quads_exact_and_respects_fixed() -> None:
    vertices, quads = warped_grid(8)
    fixed = np.array([0, 1, 2])
    result = planarize_quads(vertices, quads, fixed=fixed, max_iter=20)
    assert result.planarity_after_mm < 1e-10
    assert result.planarity_before_mm > 0.1
    assert np.array_equal(result.X[fixed], vertices[fixed])


def test_planarize_quads_pull_trades_a_wanted_move_against_distance() -> None:
    """A pull the planarity allows is met to w / (1 + w) (nearest point of |s|^2 + w (s - d)^2);
    one the planarity forbids moves nothing out of the plane."""
    from drawstring.geometry.solve.planarity import LinearPull

    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    quads = np.array([[0, 1, 2, 3]])
    fixed = np.array([1, 2, 3])
    weight = 1e3
    along = LinearPull(np.array([0]), np.array([[1.0, 0.0, 0.0]]), np.array([0.5]), weight)
    moved = planarize_quads(square, quads, fixed=fixed, pull=along, max_iter=20).X
    assert moved[0] == pytest.approx([0.5 * weight / (1 + weight), 0.0, 0.0], abs=1e-9)
    assert np.array_equal(moved[1:], square[1:])
    up = LinearPull(np.array([0]), np.array([[0.0, 0.0, 1.0]]), np.array([0.3]), weight)
    held = planarize_quads(square, quads, fixed=fixed, pull=up, max_iter=20)
    assert held.X[0, 2] == pytest.approx(0.0, abs=1e-9) and held.planarity_after_mm < 1e-9


def test_smallest_eigenvectors_match_eigh() -> None:
    rng = np.random.default_rng(7)
    pts = rng.normal(size=(500, 4, 3)) * [1.0, 2.0, 1e-3]
    pts -= pts.mean(axis=1, keepdims=True)
    cov = pts.transpose(0, 2, 1) @ pts
    cov[:3] = np.eye(3)  # fully degenerate: any unit vector is fine
    fast = smallest_eigenvectors(cov)
    ref = np.linalg.eigh(cov)[1][:, :, 0]
    assert np.allclose(np.linalg.norm(fast, axis=1), 1.0)
    assert np.allclose(np.abs(np.einsum("ki,ki->k", fast[3:], ref[3:])), 1.0, atol=1e-9)


def test_bad_input_raises() -> None:
    # the groups and the solver get their data from drawstring's own stages: a bad one is a bug
    with pytest.raises(InternalError):
        Plane(np.array([[0, 1]]))
    with pytest.raises(InternalError):
        EdgeLength([[0, 1]], [-1.0])
    with pytest.raises(InternalError):
        LocalGlobalSolver(3, [Plane([[0, 1, 2]], 0.0)]).solve(np.zeros((3, 3)))
    solver = LocalGlobalSolver(3, [Plane([[0, 1, 2]])])
    with pytest.raises(InternalError):
        solver.solve(np.zeros((4, 3)))
    with pytest.raises(InternalError):
        solver.set_weight("planarity", -1.0)
