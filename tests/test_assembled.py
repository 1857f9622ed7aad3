"""Assembled configuration K3D and frustum tiles T3D: known answers and quality on test shapes."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from drawstring.geometry.assembled.extrusion import extrude_tiles, thickness_advice
from drawstring.geometry.assembled.frustums import (
    folded_faces,
    measure_assembled,
    quad_mesh_edges,
    square_edge_targets,
)
from drawstring.geometry.assembled.shape import optimize_assembled
from drawstring.geometry.assembled.top import CLOSE_FIT_WEIGHTS, PAPER_WEIGHTS, eq1_energy
from drawstring.geometry.core.errors import DesignError, InputError, InternalError
from drawstring.geometry.core.tile import TILE_FACES


def grid_mesh(nx: int, ny: int, x0: float, y0: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Regular grid in the plane: (n, 2) points and counter-clockwise quads (m, 4)."""
    i, j = np.meshgrid(np.arange(nx + 1), np.arange(ny + 1), indexing="ij")
    points = np.c_[x0 + i.ravel() * step, y0 + j.ravel() * step]
    col, row = np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij")
    a, b = col.ravel(), row.ravel()

    def vid(p: np.ndarray, q: np.ndarray) -> np.ndarray:
        return p * (ny + 1) + q

    quads = np.stack([vid(a, b), vid(a + 1, b), vid(a + 1, b + 1), vid(a, b + 1)], axis=1)
    return points, quads


def triangles(quads: np.ndarray) -> np.ndarray:
    return np.vstack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])


def height_field_case(
    f: Callable[[np.ndarray, np.ndarray], np.ndarray], n: int = 10, size: float = 120.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A regular grid lifted onto z = f(x, y) and a finer triangulation of the same field."""
    uv, quads = grid_mesh(n, n, -size / 2, -size / 2, size / n)
    fine_uv, fine_quads = grid_mesh(60, 60, -0.55 * size, -0.55 * size, 1.1 * size / 60)
    vertices = np.c_[uv, f(uv[:, 0], uv[:, 1])]
    target = np.c_[fine_uv, f(fine_uv[:, 0], fine_uv[:, 1])]
    return vertices, quads, target, triangles(fine_quads)


def face_normals(tiles: np.ndarray) -> np.ndarray:
    """(m, 6, 3) unit normals of each tile face from its vertex order (outward)."""
    pts = tiles[:, TILE_FACES]
    normal = np.cross(pts[:, :, 2] - pts[:, :, 0], pts[:, :, 3] - pts[:, :, 1])
    return normal / np.linalg.norm(normal, axis=2, keepdims=True)


def test_flat_grid_extrudes_to_boxes() -> None:
    uv, quads = grid_mesh(5, 4, 0.0, 0.0, 10.0)
    top = np.c_[uv, np.zeros(len(uv))]
    target_uv, target_quads = grid_mesh(8, 8, -10.0, -10.0, 10.0)
    target = np.c_[target_uv, np.zeros(len(target_uv))]
    result = optimize_assembled(top, quads, target, triangles(target_quads), thickness=4.0)

    assert np.allclose(result.top, top, atol=1e-9)
    assert np.allclose(result.bottom, top - [0.0, 0.0, 4.0], atol=1e-9)
    normals = face_normals(result.tiles)
    cos_top_side = np.einsum("mi,mki->mk", normals[:, 0], normals[:, 2:])
    assert np.abs(np.pi / 2 - np.arccos(cos_top_side)).max() < 1e-9
    # outward orientation: top faces +z, bottom faces -z
    assert np.allclose(normals[:, 0], [0, 0, 1]) and np.allclose(normals[:, 1], [0, 0, -1])
    m = result.metrics
    for key in ("planarity_max_mm", "contact_gap_max_mm", "surface_distance_max_mm"):
        assert m[key] < 1e-9
    assert m["contact_angle_max_deg"] < 1e-6
    assert m["tile_side_spread"] == pytest.approx(1.0)
    assert m["thickness_min_mm"] == pytest.approx(4.0)
    assert m["thickness_max_mm"] == pytest.approx(4.0)


def cylinder_case(
    radius: float, phi: float, columns: int, rows: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """Square quads on a cylinder (axis z), each spanning the angle phi; and a finer target."""
    chord = 2 * radius * np.sin(phi / 2)
    ang, quads = grid_mesh(columns, rows, 0.0, 0.0, 1.0)
    theta, z = ang[:, 0] * phi, ang[:, 1] * chord
    vertices = np.c_[radius * np.cos(theta), radius * np.sin(theta), z]
    fine, fine_quads = grid_mesh(4 * columns + 8, 4 * rows + 8, -2.0, -2.0, 0.25)
    ft, fz = fine[:, 0] * phi, fine[:, 1] * chord
    target = np.c_[radius * np.cos(ft), radius * np.sin(ft), fz]
    return vertices, quads, target, triangles(fine_quads), chord


def test_cylinder_dihedral_and_radial_contact_faces() -> None:
    radius, phi, thickness = 60.0, np.radians(15.0), 3.0
    vertices, quads, target, tris, _ = cylinder_case(radius, phi, 6, 4)
    result = optimize_assembled(vertices, quads, target, tris, thickness=thickness)
    assert np.allclose(result.top, vertices, atol=1e-8)

    # dihedral between top faces of tiles that share an axial edge: pi - phi
    edges = quad_mesh_edges(result.quads)
    normals = face_normals(result.tiles)[:, 0]
    inner = edges.interior
    a, b = edges.quads[inner, 0], edges.quads[inner, 1]
    axial = np.abs(vertices[edges.edges[inner, 0], 2] - vertices[edges.edges[inner, 1], 2]) > 1e-9
    dihedral = np.pi - np.arccos(np.einsum("ki,ki->k", normals[a[axial]], normals[b[axial]]))
    assert np.allclose(dihedral, np.pi - phi, atol=1e-9)

    # contact faces over axial edges lie in radial planes: all four points at the edge's angle
    for i, j in edges.edges[inner][axial]:
        angle = np.arctan2(vertices[i, 1], vertices[i, 0])
        radial_normal = np.array([-np.sin(angle), np.cos(angle), 0.0])
        face = np.vstack([result.top[[i, j]], result.bottom[[i, j]]])
        assert np.abs(face @ radial_normal).max() < 1e-8

    # interior bottom vertices: top scaled towards the axis so face planes are `thickness` apart
    plane_radius = radius * np.cos(phi / 2)
    scale = (plane_radius - thickness) / plane_radius
    theta = np.arctan2(vertices[:, 1], vertices[:, 0])
    interior = (theta > 1e-9) & (theta < 6 * phi - 1e-9)
    expected = vertices[interior] * [scale, scale, 1.0]
    assert np.allclose(result.bottom[interior], expected, atol=1e-8)
    assert result.metrics["thickness_min_mm"] == pytest.approx(thickness, abs=1e-8)
    assert result.metrics["thickness_max_mm"] == pytest.approx(thickness, abs=1e-8)


def test_extrusion_with_the_top_fixed_keeps_it_bit_for_bit() -> None:
    # on the cylinder the frustums are known (see above); holding the top fixed reaches them
    # with the top untouched, as the re-extrusion after the co-optimization needs
    radius, phi, thickness = 60.0, np.radians(15.0), 3.0
    vertices, quads, *_ = cylinder_case(radius, phi, 6, 4)
    free = extrude_tiles(vertices, quads, thickness, rel_tol=1e-12, max_iter=2000, anderson=8)
    fixed = extrude_tiles(
        vertices, quads, thickness, fix_top=True, rel_tol=1e-12, max_iter=2000, anderson=8
    )
    assert np.array_equal(fixed[1], vertices)
    assert set(fixed[0].energy_after) == {"planar", "slab", "keep_bottom"}
    assert np.abs(fixed[2] - free[2]).max() < 1e-6
    plane_radius = radius * np.cos(phi / 2)
    scale = (plane_radius - thickness) / plane_radius
    theta = np.arctan2(vertices[:, 1], vertices[:, 0])
    interior = (theta > 1e-9) & (theta < 6 * phi - 1e-9)
    assert np.allclose(fixed[2][interior], vertices[interior] * [scale, scale, 1.0], atol=1e-6)


FIELDS: dict[str, Callable[[np.ndarray, np.ndarray], np.ndarray]] = {
    "saddle": lambda x, y: x * y / 150.0,
    "dome": lambda x, y: np.sqrt(110.0**2 - x**2 - y**2),
    "wave": lambda x, y: 8.0 * np.sin(2 * np.pi * x / 100.0) * np.cos(2 * np.pi * y / 140.0),
}


@pytest.mark.parametrize("name", sorted(FIELDS))
def test_height_field_quality(name: str) -> None:
    """Default (paper) weights: exact planarity, coinciding contact faces, nothing folds."""
    vertices, quads, target, tris = height_field_case(FIELDS[name])
    result = optimize_assembled(vertices, quads, target, tris, thickness=3.0)
    m = result.metrics
    side = m["tile_side_mean_mm"]
    assert m["planarity_max_mm"] <= 1e-6 * m["bbox_diagonal_mm"]
    assert m["planarity_max_before_mm"] > 100 * m["planarity_max_mm"]
    assert m["contact_gap_max_mm"] <= 1e-3 * side
    assert m["contact_angle_max_deg"] < 0.01
    assert m["flipped_tiles"] == 0
    assert m["tile_side_spread"] < 1.5
    assert 2.7 < m["thickness_min_mm"] <= m["thickness_max_mm"] < 3.3
    for solve in (result.top_solve, result.extrusion_solve):
        history = solve.energy_history
        assert np.all(np.diff(history) <= 1e-12 * history[:-1] + 1e-15 * history[0])
    # tile layout contract
    assert result.tiles.shape == (len(quads), 8, 3)
    assert np.array_equal(result.tiles[:, :4], result.top[result.quads])
    assert np.array_equal(result.tiles[:, 4:], result.bottom[result.quads])
    # bottom is on the inside: below the top along the outward normals
    assert np.all(face_normals(result.tiles)[:, 0, 2] > 0)


def enneper(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Enneper's minimal surface in isothermal (conformal) coordinates turned by 20 degrees."""
    a = np.radians(20.0)
    u, v = np.cos(a) * s - np.sin(a) * t, np.sin(a) * s + np.cos(a) * t
    return 60.0 * np.c_[u - u**3 / 3 + u * v**2, v - v**3 / 3 + v * u**2, u**2 - v**2]


def sphere_cap(s: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Inverse stereographic projection onto a sphere of radius 100 mm (conformal)."""
    d = 1 + s**2 + t**2
    return 100.0 * np.c_[2 * s / d, 2 * t / d, (1 - s**2 - t**2) / d]


def conformal_case(
    mapping: Callable[[np.ndarray, np.ndarray], np.ndarray], half: float, n: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A square grid mapped conformally (like the pipeline's lifted tiling) and a finer target."""
    uv, quads = grid_mesh(n, n, -half, -half, 2 * half / n)
    fine_uv, fine_quads = grid_mesh(80, 80, -1.1 * half, -1.1 * half, 2.2 * half / 80)
    target = mapping(fine_uv[:, 0], fine_uv[:, 1])
    return mapping(uv[:, 0], uv[:, 1]), quads, target, triangles(fine_quads)


@pytest.mark.parametrize("name", ["enneper", "sphere"])
def test_close_fit_weights_stay_on_conformal_grids(name: str) -> None:
    mapping, half = (enneper, 0.7) if name == "enneper" else (sphere_cap, 0.6)
    vertices, quads, target, tris = conformal_case(mapping, half, 8)
    w_planar, w_square, w_surface = CLOSE_FIT_WEIGHTS
    result = optimize_assembled(
        vertices,
        quads,
        target,
        tris,
        thickness=2.0,
        w_planar=w_planar,
        w_square=w_square,
        w_surface=w_surface,
    )
    m = result.metrics
    assert m["surface_distance_mean_mm"] <= 0.02 * m["tile_side_mean_mm"]
    assert m["planarity_max_mm"] <= 1e-6 * m["bbox_diagonal_mm"]
    assert m["contact_gap_max_mm"] <= 1e-3 * m["tile_side_mean_mm"]
    assert m["flipped_tiles"] == 0


def test_quads_given_inward_are_flipped_outward() -> None:
    vertices, quads, target, tris = height_field_case(FIELDS["saddle"], n=4)
    result = optimize_assembled(vertices, quads[:, ::-1], target, tris, thickness=2.0)
    normals = face_normals(result.tiles)[:, 0]
    assert np.all(normals[:, 2] > 0)
    assert np.all(result.bottom[:, 2] < result.top[:, 2])


def test_metrics_detect_a_moved_vertex() -> None:
    uv, quads = grid_mesh(3, 3, 0.0, 0.0, 10.0)
    top = np.c_[uv, np.zeros(len(uv))]
    tiles = np.concatenate([top[quads], (top - [0, 0, 3.0])[quads]], axis=1)
    target = np.c_[uv, np.zeros(len(uv))]
    exact = measure_assembled(tiles, quads, target, triangles(quads))
    assert exact["planarity_max_mm"] < 1e-12 and exact["contact_gap_max_mm"] < 1e-12
    assert exact["surface_distance_max_mm"] < 1e-12 and exact["contact_angle_max_deg"] < 1e-9

    moved = tiles.copy()
    delta = 0.01
    # tile 4 is the centre tile; its vertex 5 (bottom of corner 1) lies on its x-facing side 1
    moved[4, 5, 0] += delta
    bad = measure_assembled(moved, quads, target, triangles(quads))
    assert bad["contact_gap_max_mm"] == pytest.approx(delta, rel=1e-6)
    assert bad["planarity_max_mm"] == pytest.approx(delta / 4, rel=1e-3)
    assert bad["contact_angle_max_deg"] > 0.01


def test_square_edge_targets_average_neighbouring_quads() -> None:
    uv = np.array([[0, 0], [1, 0], [3, 0], [0, 1], [1, 1], [3, 1]], dtype=float)
    vertices = np.c_[uv, np.zeros(6)]
    quads = np.array([[0, 1, 4, 3], [1, 2, 5, 4]])
    edges = quad_mesh_edges(quads)
    targets = square_edge_targets(vertices, quads, edges)
    mean_a = 1.0
    mean_b = (2 + 1 + 2 + 1) / 4
    shared = np.flatnonzero(edges.interior)
    assert len(shared) == 1
    assert targets[shared[0]] == pytest.approx((mean_a + mean_b) / 2)
    boundary_of_a = edges.quads[:, 0] == 0
    assert np.allclose(targets[boundary_of_a & ~edges.interior], mean_a)


def test_eq1_energy_is_zero_on_a_square_grid_on_its_target_and_counts_a_lifted_vertex() -> None:
    points, quads = grid_mesh(4, 4, 0.0, 0.0, 10.0)
    vertices = np.c_[points, np.zeros(len(points))]
    # the target: the plane z = 0, larger than the grid
    target_v = np.array([[-50.0, -50, 0], [100, -50, 0], [100, 100, 0], [-50, 100, 0]])
    target_f = np.array([[0, 1, 2], [0, 2, 3]])
    zero = eq1_energy(vertices, quads, target_v, target_f, vertices)
    assert zero["total"] == pytest.approx(0.0, abs=1e-18)
    moved = vertices.copy()
    centre = int(np.flatnonzero((points == [20.0, 20.0]).all(axis=1))[0])
    moved[centre, 2] = 0.5
    energy = eq1_energy(vertices, quads, target_v, target_f, moved)
    w_planar, w_square, w_surface = PAPER_WEIGHTS
    assert energy["surface"] == pytest.approx(w_surface * 0.5**2)
    # each of the 4 quads at the vertex is twisted by h = 0.5 at one corner: the best plane
    # leaves +-h/4 at every corner (the bilinear term's part off the linear fit), h^2/4 per
    # quad measured vertically, a hair less orthogonally (the plane tilts by about 1 deg)
    assert energy["planar"] == pytest.approx(w_planar * 4 * 0.5**2 / 4, rel=2e-3)
    assert energy["square_length"] > 0 and energy["square_shape"] > 0
    assert energy["total"] == pytest.approx(sum(v for k, v in energy.items() if k != "total"))
    halved = eq1_energy(vertices, quads, target_v, target_f, moved, (w_planar, w_square, 0.05))
    assert halved["surface"] == pytest.approx(0.5 * energy["surface"])


def test_bad_inputs_raise() -> None:
    vertices, quads, target, tris = height_field_case(FIELDS["saddle"], n=3)
    # thickness and weights are the user's (--thickness, a profile, --weights); the meshes come
    # from drawstring's own stages, so a malformed one is a bug
    with pytest.raises(InputError):
        optimize_assembled(vertices, quads, target, tris, thickness=0.0)
    with pytest.raises(InternalError):
        optimize_assembled(vertices, quads + 100, target, tris, thickness=2.0)
    inconsistent = quads.copy()
    inconsistent[0] = inconsistent[0, ::-1]
    with pytest.raises(InternalError):
        optimize_assembled(vertices, inconsistent, target, tris, thickness=2.0)
    with pytest.raises(InputError):
        optimize_assembled(vertices, quads, target, tris, thickness=2.0, w_square=-1.0)


def test_convex_corners_unfold_a_dart_and_leave_convex_quads_alone() -> None:
    """A plain K3D solve can fold quads into darts (three-shell, ~210 tiles). The convexity
    group pushes a reflex corner back out past the margin and is inert on convex quads."""
    from drawstring.geometry.assembled.frustums import corner_margins
    from drawstring.geometry.assembled.top import CONVEX_MARGIN, ConvexCorners
    from drawstring.geometry.solve.groups import ClosenessToPoints, Plane
    from drawstring.geometry.solve.solver import LocalGlobalSolver

    square = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    dart = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 4.0, 0.0]])
    quads = np.array([[0, 1, 2, 3]])
    up = np.array([[0.0, 0.0, 1.0]])
    assert corner_margins(square, quads, up) == pytest.approx([0.5])
    assert corner_margins(dart, quads, up)[0] < 0
    assert corner_margins(square[::-1].copy(), quads, up) == pytest.approx([-0.5])  # turned over

    group = ConvexCorners(quads, up)
    a = group.matrix(4)
    assert np.allclose(group.project(a @ square, square), a @ square)

    solver = LocalGlobalSolver(
        4,
        [
            Plane(quads, 1e4, name="planar"),
            ClosenessToPoints(np.arange(4), dart, 1.0, name="keep"),
            ConvexCorners(quads, up, 1e4, name="convex"),
        ],
    )
    result = solver.solve(dart, max_iter=500)
    assert corner_margins(result.X, quads, up)[0] >= CONVEX_MARGIN - 1e-3
    assert np.all(np.diff(result.energy_history) <= 1e-9 * result.energy_history[0])


def test_assembled_tiles_stay_convex_on_a_strongly_curved_cap() -> None:
    """A deep cap at the paper's weights: every top face of T3D is convex and no tiles clash."""
    from drawstring.geometry.flat.verify import assembled_overlap

    vertices, quads, target, target_faces = height_field_case(
        lambda x, y: np.sqrt(np.maximum(80.0**2 - x**2 - y**2, 0.0)), n=8, size=100.0
    )
    result = optimize_assembled(vertices, quads, target, target_faces, thickness=4.0)
    overlap = assembled_overlap(result.tiles)
    assert overlap.nonconvex_faces == 0
    assert overlap.depth_max_mm <= 1e-3
    assert result.metrics["corner_margin_min"] > 0


@pytest.fixture(scope="module")
def three_shell_front() -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float]:
    """The real pipeline front of the three-shell at ~200 tiles (as benchmarks/bench_solver.py):
    default profile size and resolution, rectangle flattening, tiling with splits."""
    from drawstring.fabrication.profiles import load_profile
    from drawstring.geometry.flatten.conformal import flatten
    from drawstring.geometry.target.surface import load_target
    from drawstring.geometry.tiling.grid import tile_surface
    from drawstring.pipeline.layout_stage import split_bound
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import resolve_options

    options = DesignOptions(tiles=200)
    resolved = resolve_options(options, load_profile(options.profile))
    loaded = load_target("three-shell", size_mm=resolved.size_mm, resolution=resolved.resolution)
    flat = flatten(loaded.vertices, loaded.faces, mode="rectangle", corners=resolved.corners)
    tiling = tile_surface(
        loaded.vertices,
        loaded.faces,
        flat.uv,
        tiles=200,
        grid=resolved.grid,
        max_scale_factor=split_bound(resolved),
    )
    return tiling.vertices, tiling.quads, loaded.vertices, loaded.faces, resolved.thickness_mm


@pytest.mark.parametrize("anderson", [0, 5])
def test_energy_never_rises_on_a_builtin_target(
    three_shell_front: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, float], anderson: int
) -> None:
    """Every local-global solve of the assembled stage on a real target, the discarded plain
    K3D solve included: the three-shell at ~210 tiles folds a corner in the plain solve, which
    is stopped and followed by the convexity re-solve."""
    vertices, quads, target, target_faces, thickness = three_shell_front
    result = optimize_assembled(
        vertices, quads, target, target_faces, thickness=thickness, anderson=anderson
    )
    assert 150 <= len(quads) <= 250
    assert result.metrics["convex_resolve"] == 1.0, "the three-shell no longer folds: pick another"
    assert len(result.top_solves) == 2
    assert result.top_solves[0].stopped  # the plain solve, discarded
    for solve in (*result.top_solves, result.extrusion_solve):
        assert solve.iterations > 0
        history = solve.energy_history
        assert np.all(np.diff(history) <= 1e-12 * history[:-1] + 1e-15 * history[0])
    if anderson:  # without Anderson 1000 iterations leave a corner at about -0.001
        assert sum(s.accelerated_accepted for s in result.top_solves) > 0
        assert result.metrics["corner_margin_min"] > 0


def test_too_thick_tiles_are_refused_with_a_thickness_that_works() -> None:
    # On a 4 mm cylinder the flat face planes sit 3.97 mm from the axis: 6 mm turns tiles inside
    # out. The advice keeps every bottom face at least a quarter of its top (for a cylinder the
    # area shrinks in one direction only: t <= 0.75 * 3.97 mm), and that thickness extrudes.
    vertices, quads, target, tris, _ = cylinder_case(4.0, np.radians(15.0), 6, 4)
    plane_radius = 4.0 * np.cos(np.radians(7.5))
    advice = thickness_advice(vertices, quads)
    assert advice == pytest.approx(0.75 * plane_radius, rel=1e-6)
    with pytest.raises(DesignError, match=r"inside out.*--thickness 2\.9 or less"):
        optimize_assembled(vertices, quads, target, tris, thickness=6.0)
    result = optimize_assembled(vertices, quads, target, tris, thickness=2.9)
    assert result.metrics["thickness_min_mm"] == pytest.approx(2.9, abs=1e-6)


def test_a_bottom_face_folded_into_a_dart_or_turned_over_counts_as_folded() -> None:
    quads = np.array([[0, 1, 2, 3]] * 3) + np.arange(3)[:, None] * 4
    square = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [2.0, 2.0, 0.0], [0.0, 2.0, 0.0]])
    top = np.vstack([square, square, square])
    whole = square * 0.8 + [0.2, 0.2, -1.0]
    dart = whole.copy()
    dart[2] = [0.5, 0.5, -1.0]  # the corner folded in past the diagonal: one reflex corner
    turned = whole[[0, 3, 2, 1]]  # wound the other way: inside out
    bottom = np.vstack([whole, dart, turned])
    np.testing.assert_array_equal(folded_faces(top, bottom, quads), [False, True, True])


def test_rigid_fit_undoes_a_known_rigid_motion() -> None:
    # Planar quads of a translational surface z = f(x) + g(y) (no continuous symmetry), the
    # target their own triangles; the quads moved by a known rotation (4 deg about a skew
    # axis) and shift: the fit brings them back onto the target, its motion the inverse one.
    from drawstring.geometry.assembled.fit import rigid_fit, top_face_distances

    xs, ys = np.linspace(-40, 40, 9), np.linspace(-30, 30, 7)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    vertices = np.stack([gx, gy, 0.02 * gx**2 + 0.04 * gy**2 + 0.01 * gx**3 / 40], axis=-1)
    vertices = vertices.reshape(-1, 3)
    ids = np.arange(len(vertices)).reshape(len(xs), len(ys))
    quads = np.stack([ids[:-1, :-1], ids[1:, :-1], ids[1:, 1:], ids[:-1, 1:]], axis=-1).reshape(
        -1, 4
    )
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    axis = np.array([1.0, 2.0, 3.0]) / np.sqrt(14.0)
    angle = np.radians(4.0)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    turn = np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
    tiles = vertices[quads]
    moved = tiles @ turn.T + np.array([1.5, -2.0, 0.8])
    assert top_face_distances(moved, vertices, faces).mean > 0.5
    rotation, shift = rigid_fit(moved, vertices, faces)
    np.testing.assert_allclose(rotation @ turn, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(moved @ rotation.T + shift, tiles, atol=1e-4)
    assert top_face_distances(moved @ rotation.T + shift, vertices, faces).max < 1e-4
