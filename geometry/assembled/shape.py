"""Assembled configuration: planar, square-ish quads near the target (K3D) and frustum tiles (T3D).

Paper section 4.2, equations 1-4. Two optimizations run through the shared local-global solver
(:mod:`drawstring.geometry.solve.solver`), each followed by an exact planarity polish:

1. **K3D** (top faces): ``w_planar E_planar + w_square (E_length + E_shape) + w_surface
   E_surface`` over the lifted quad mesh. Edge-length targets are the mean of the two adjacent
   quads' mean side lengths (one quad's on the boundary), computed from the current mesh at the
   start of each of ``square_rounds`` outer rounds (default 1: targets from the input mesh,
   fixed during the solve, so each solve is a fixed-energy problem that converges
   monotonically). The closest points of E_surface are re-queried lazily (only for vertices
   that moved more than ``SURFACE_REQUERY_REL`` of their distance to the target, see
   :class:`~drawstring.geometry.solve.groups.ClosenessToSurface`). A plain solve that folds a
   quad is replaced by one with :class:`ConvexCorners` (see :func:`optimize_assembled`). Then
   :func:`~drawstring.geometry.solve.planarity.planarize_quads` moves the vertices by the least
   amount that makes every quad exactly planar.
2. **T3D** (extrusion): bottom vertices start at the top offset along area-weighted vertex
   normals (inwards, by ``thickness / mean cos`` to the adjacent face normals). Then top and
   bottom vertices are optimized together: every top, bottom and side (contact) face planar,
   each tile's bottom on the plane parallel to its top at ``thickness`` (``Slab``), the top close
   to K3D and the bottom close to its start (which fixes the in-plane sliding freedom of the
   bottom). A final exact planarity polish over all top, bottom and side faces follows.

Tiles share vertices: tile ``t`` is ``top[quads[t]]`` then ``bottom[quads[t]]``, so neighbouring
tiles' contact faces are the same four points and coincide by construction; the metrics measure
it anyway from the per-tile vertex arrays.

Tile vertex order (also the order of ``AssembledResult.tiles``): ``0..3`` top corners in quad
order (counter-clockwise seen from outside, i.e. from the top side), ``4..7`` the bottom corners
under them. :data:`TILE_FACES` lists the six faces, each counter-clockwise seen from outside the
tile: top ``(0, 1, 2, 3)``, bottom ``(4, 7, 6, 5)``, side ``k`` (under top edge ``k -> k+1``)
``(k, 4 + k, 4 + (k+1) % 4, (k+1) % 4)``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.assembled.frustums import (
    corner_margins,
    measure_assembled,
    orient_outward,
    quad_mesh_edges,
    quad_vector_areas,
    side_quads,
    square_edge_targets,
    tile_vertices,
    vertex_normals,
)
from drawstring.geometry.core.errors import InputError, ThicknessError
from drawstring.geometry.core.tolerances import (
    ASSEMBLED_PLANARITY_REL,
    ASSEMBLED_SOLVER_REL_TOL,
)
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.groups import (
    ClosenessToPlanes,
    ClosenessToPoints,
    ClosenessToSurface,
    ConstraintGroup,
    EdgeLength,
    Plane,
)
from drawstring.geometry.solve.linalg import centering_matrix, cross3
from drawstring.geometry.solve.planarity import LinearPull, PlanarizeResult, planarize_quads
from drawstring.geometry.solve.shape_groups import SimilarityToSquare, Slab
from drawstring.geometry.solve.solver import LocalGlobalSolver, SolverResult

logger = logging.getLogger(__name__)


#: Paper eq. 1 weights (w_planar, w_square, w_surface) from section 5.4.
PAPER_WEIGHTS: tuple[float, float, float] = (1e4, 10.0, 0.1)

#: Close-fit alternative (w_planar, w_square, w_surface): closeness to the target outweighs
#: squareness. Measured at ~200 tiles on the built-ins it keeps K3D within 2 % of a tile side of
#: the target on 6 of 8 shapes (paper weights: 0 of 8), but lets tiles shear, change size and,
#: on coarse strongly non-conformal grids, fold over; see the benchmark notes.
CLOSE_FIT_WEIGHTS: tuple[float, float, float] = (1e4, 1.0, 100.0)

#: Default weights: the paper's.
DEFAULT_WEIGHTS: tuple[float, float, float] = PAPER_WEIGHTS

#: Convexity margin of every quad corner (:class:`ConvexCorners`): the corner must stand at least
#: this fraction of the diagonal joining its two neighbours outside that diagonal (0.5 for a
#: square's corner, 0 for a straight angle); 0.2 keeps every corner angle below about 136 deg and
#: every side at least about a fifth of the other sides (a dart or a collapsing side violates it).
CONVEX_MARGIN: float = 0.2

#: Iterations between checks of the plain K3D solve for corners folded over.
FOLD_CHECK_EVERY: int = 25

#: Lazy closest-point re-query of the surface term (:class:`ClosenessToSurface`): a vertex is
#: queried again once it moved more than this fraction of its distance to the target.
SURFACE_REQUERY_REL: float = 0.1

#: Anderson history of the assembled solves. Measured on the built-ins at ~200 tiles (three
#: starts each) and at 1600 tiles, m = 8 needs 10-40 % fewer iterations than the solver's
#: default m = 5 at about the same cost per iteration (with the Gram mixing), and about 700
#: instead of 800-950 in the three-shell's convexity re-solve; only where both stop at
#: ``max_iter`` (seashell) is it no faster, but it gets further (energy 2-4 % lower).
ANDERSON_HISTORY: int = 8

#: Weight of :class:`ConvexCorners` relative to ``w_planar``: a hard constraint (it is zero on
#: every quad that is convex with the margin, so it does not change the paper's energy there).
CONVEX_WEIGHT_REL: float = 1.0


@dataclass(frozen=True)
class AssembledResult:
    """Assembled configuration of the linkage.

    Attributes
    ----------
    top : (n, 3) float, mm
        K3D: top-face vertices, same vertex ids as the input quad mesh.
    bottom : (n, 3) float, mm
        Bottom vertices of T3D, one per quad-mesh vertex, under ``top``.
    quads : (m, 4) int
        Counter-clockwise seen from the outward (top) side.
    tiles : (m, 8, 3) float, mm
        T3D tile vertices: ``top[quads[t]]`` then ``bottom[quads[t]]`` (see :data:`TILE_FACES`).
    thickness : float, mm
    edges : (e, 2) int
        Unique mesh edges (the squareness edges).
    edge_targets : (e,) float, mm
        Their target lengths in the last round.
    metrics : dict[str, float]
        :func:`measure_assembled` of the result plus ``planarity_max_before_mm`` (the input quads
        extruded along normals, before any optimization), ``bbox_diagonal_mm`` (of the input
        quad mesh), ``polish_move_max_mm`` (largest vertex move of the exact planarity polishes)
        and the stage timings ``time_top_s``, ``time_extrusion_s``; ``corner_margin_min`` (of
        K3D, :func:`corner_margins`; negative means a folded quad), the same before the
        convexity re-solve (``corner_margin_min_unconstrained``) and ``convex_resolve``.
    top_solve, extrusion_solve : SolverResult
        Local-global solves of the K3D stage (last round) and of the extrusion.
    top_polish, extrusion_polish : PlanarizeResult
        Exact planarity polishes after each stage.
    time_s : float
    top_solves : tuple of SolverResult
        Every K3D round's solve: ``square_rounds`` of them, then as many again when the plain
        solve left a corner below ``convex_margin`` and K3D was solved again with
        :class:`ConvexCorners` (``metrics["convex_resolve"]`` is then 1). A plain solve stopped
        early because a corner stayed folded (``SolverResult.stopped``) ends its rounds; it is
        listed too, and its margin is ``corner_margin_min_unconstrained``.
    """

    top: FloatArray
    bottom: FloatArray
    quads: IntArray
    tiles: FloatArray
    thickness: float
    edges: IntArray
    edge_targets: FloatArray
    metrics: dict[str, float]
    top_solve: SolverResult
    extrusion_solve: SolverResult
    top_polish: PlanarizeResult
    extrusion_polish: PlanarizeResult
    time_s: float
    top_solves: tuple[SolverResult, ...] = field(default=())


# --------------------------------------------------------------------------------------------
# Topology helpers
# --------------------------------------------------------------------------------------------


class ConvexCorners(ConstraintGroup):
    """Keep every quad convex: each corner stays outside the diagonal joining its neighbours.

    One element per quad corner ``k``: the triple ``(v[k-1], v[k], v[k+1])``. Its height ``h``
    over the line ``v[k-1] v[k+1]``, measured in the quad's tangent plane towards the outside of
    the quad (positive for a convex corner), must be at least ``margin * |v[k+1] - v[k-1]|``.
    Satisfied triples project onto themselves (zero energy); a violating one projects onto the
    triple with the two diagonal ends moved by ``-d/3`` and the corner by ``+2d/3`` along that
    outward direction, ``d`` the deficit, which keeps the diagonal and the centroid and meets the
    bound exactly. With all four corners above their diagonals both diagonals cross, so the quad
    is convex, and no corner angle approaches 180 deg (a dart, or a quad folding over).

    Parameters
    ----------
    quads : (m, 4) int
        Counter-clockwise about ``reference_normals``.
    reference_normals : (m, 3) float
        Outward direction of each quad; the current normal (from its diagonals) is flipped to
        agree with it, so a quad that turned over still has a well-defined outside.
    margin : float
        See :data:`CONVEX_MARGIN`.
    """

    def __init__(
        self,
        quads: ArrayLike,
        reference_normals: ArrayLike,
        weight: float = 1.0,
        name: str = "convex",
        margin: float = CONVEX_MARGIN,
    ) -> None:
        super().__init__(name, weight)
        arr = np.asarray(quads, dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 4:
            raise InputError("ConvexCorners needs quads of shape (m, 4)")
        ref = np.asarray(reference_normals, dtype=np.float64)
        if ref.shape != (len(arr), 3):
            raise InputError("reference_normals must have shape (m, 3), one per quad")
        if not 0.0 <= margin < 0.5:
            raise InputError(f"convexity margin is {margin}; use a value in [0, 0.5)")
        self.quads = arr
        self.reference_normals = ref
        self.margin = float(margin)
        #: (4m, 3) corner triples, quad-major.
        self.triples = np.stack(
            [np.roll(arr, 1, axis=1), arr, np.roll(arr, -1, axis=1)], axis=2
        ).reshape(-1, 3)

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(self.triples, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        pts = ax.reshape(-1, 3, 3)
        corners = x[self.quads]
        normal = cross3(corners[:, 2] - corners[:, 0], corners[:, 3] - corners[:, 1])
        normal *= np.where(np.einsum("ki,ki->k", normal, self.reference_normals) < 0, -1.0, 1.0)[
            :, None
        ]
        bad = ~np.any(normal != 0.0, axis=1)
        normal[bad] = self.reference_normals[bad]
        diagonal = pts[:, 2] - pts[:, 0]
        out = cross3(diagonal, np.repeat(normal, 4, axis=0))
        out_len = np.sqrt(np.einsum("ki,ki->k", out, out))
        length = np.sqrt(np.einsum("ki,ki->k", diagonal, diagonal))
        # height * |out| of each corner over its diagonal; only violating corners move
        scaled = np.einsum("ki,ki->k", pts[:, 1] - pts[:, 0], out)
        low = np.flatnonzero((out_len > 1e-300) & (scaled < self.margin * length * out_len))
        target = ax.copy()
        if low.size:
            direction = out[low] / out_len[low, None]
            deficit = self.margin * length[low] - scaled[low] / out_len[low]
            move = (deficit[:, None] / 3.0) * direction
            rows = 3 * low
            target[rows] -= move
            target[rows + 1] += 2.0 * move
            target[rows + 2] -= move
        return np.asarray(target)


# --------------------------------------------------------------------------------------------
# Metrics
# --------------------------------------------------------------------------------------------


# --------------------------------------------------------------------------------------------
# Optimization
# --------------------------------------------------------------------------------------------


def _check_inputs(
    quad_vertices: ArrayLike,
    quads: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    thickness: float,
    weights: dict[str, float],
) -> tuple[FloatArray, IntArray, FloatArray, IntArray]:
    verts = np.asarray(quad_vertices, dtype=np.float64)
    faces = np.asarray(quads)
    t_verts = np.asarray(target_vertices, dtype=np.float64)
    t_faces = np.asarray(target_faces)
    if verts.ndim != 2 or verts.shape[1] != 3 or not np.all(np.isfinite(verts)):
        raise InputError("quad_vertices must be a finite (n, 3) array in mm")
    if faces.ndim != 2 or faces.shape[1] != 4 or len(faces) == 0:
        raise InputError("quads must be a non-empty (m, 4) integer array")
    if not np.issubdtype(faces.dtype, np.integer):
        raise InputError("quads must hold integer vertex indices")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InputError("quads refer to vertices that do not exist; check the vertex indices")
    if np.any(np.sort(faces, axis=1)[:, 1:] == np.sort(faces, axis=1)[:, :-1]):
        raise InputError("a quad repeats a vertex; remove degenerate quads")
    if t_verts.ndim != 2 or t_verts.shape[1] != 3 or not np.all(np.isfinite(t_verts)):
        raise InputError("target vertices must be a finite (p, 3) array in mm")
    if t_faces.ndim != 2 or t_faces.shape[1] != 3 or len(t_faces) == 0:
        raise InputError("target faces must be a non-empty (f, 3) triangle array")
    if t_faces.min() < 0 or t_faces.max() >= len(t_verts):
        raise InputError("target faces refer to vertices that do not exist")
    if not np.isfinite(thickness) or thickness <= 0:
        raise InputError(f"thickness is {thickness} mm; give a positive thickness")
    for name, value in weights.items():
        if not np.isfinite(value) or value < 0:
            raise InputError(f"{name} is {value}; weights must be finite and >= 0")
    return verts, faces.astype(np.int64), t_verts, t_faces.astype(np.int64)


#: :func:`thickness_advice` keeps every bottom face at least this fraction of its top's area.
THICKNESS_ADVICE_AREA = 0.25


def thickness_advice(top: FloatArray, quads: IntArray) -> float:
    """The largest thickness (mm) whose starting extrusion keeps every bottom face facing the
    same way as its top with at least ``THICKNESS_ADVICE_AREA`` of its area.

    The start bottom (:func:`_initial_bottom`) is linear in the thickness, so each face's area
    is a quadratic in it; bisection finds the bound.  The optimized extrusion stays close to the
    start, so this is the thickness to suggest when a thicker one turns tiles inside out.
    """
    top_area = quad_vector_areas(top, quads)
    direction = top - _initial_bottom(top, quads, 1.0)  # bottom = top - t * direction

    def worst(t: float) -> float:
        area = quad_vector_areas(top - t * direction, quads)
        ratio = np.einsum("ki,ki->k", top_area, area) / np.einsum("ki,ki->k", top_area, top_area)
        return float(ratio.min(initial=1.0))

    lo, hi = 0.0, 1.0
    while worst(hi) >= THICKNESS_ADVICE_AREA and hi < 1e6:
        lo, hi = hi, 2.0 * hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst(mid) >= THICKNESS_ADVICE_AREA else (lo, mid)
    return lo


def _initial_bottom(top: FloatArray, quads: IntArray, thickness: float) -> FloatArray:
    """Bottom vertices: top offset inwards along vertex normals so face planes sit ~thickness apart.

    The offset distance is ``thickness / mean_f(N_v . n_f)`` over the faces ``f`` at the vertex,
    which is exact for conical meshes (e.g. a cylinder's interior vertices).
    """
    normals = vertex_normals(top, quads)
    areas = quad_vector_areas(top, quads)
    face_n = areas / np.maximum(np.linalg.norm(areas, axis=1, keepdims=True), 1e-300)
    cos_sum = np.zeros(len(top))
    count = np.zeros(len(top))
    for corner in range(4):
        v = quads[:, corner]
        np.add.at(cos_sum, v, np.einsum("ki,ki->k", normals[v], face_n))
        np.add.at(count, v, 1.0)
    mean_cos = np.clip(cos_sum / np.maximum(count, 1.0), 0.5, 1.0)
    return np.asarray(top - normals * (thickness / mean_cos)[:, None])


def _eq1_groups(
    vertices: FloatArray,
    quads: IntArray,
    target_vertices: FloatArray,
    target_faces: IntArray,
    weights: tuple[float, float, float],
    *,
    requery_rel: float = SURFACE_REQUERY_REL,
) -> tuple[list[ConstraintGroup], FloatArray]:
    """The constraint groups of paper eq. 1 (planar, square length and shape, surface) for the
    quad mesh ``vertices`` (whose edges and quads set the square targets), and the edge
    targets."""
    w_planar, w_square, w_surface = weights
    edges = quad_mesh_edges(quads)
    targets = square_edge_targets(vertices, quads, edges)
    groups: list[ConstraintGroup] = [
        Plane(quads, w_planar, name="planar"),
        EdgeLength(edges.edges, targets, w_square, name="square_length"),
        SimilarityToSquare(
            quads,
            w_square,
            name="square_shape",
            reference_normals=quad_vector_areas(vertices, quads),
        ),
        ClosenessToSurface(
            np.arange(len(vertices)),
            target_vertices,
            target_faces,
            w_surface,
            name="surface",
            requery_rel=requery_rel,
        ),
    ]
    return groups, targets


def eq1_energy(
    start: ArrayLike,
    quads: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    positions: ArrayLike,
    weights: tuple[float, float, float] = PAPER_WEIGHTS,
) -> dict[str, float]:
    """Weighted paper eq. 1 energy of every term at ``positions``, with the square targets of
    the lifted mesh ``start`` (as :func:`optimize_top` sets them), and their ``total``.

    Compares K3D solutions found under different weights on one energy: when a closer fit has
    the higher energy, the weights themselves, not the solver, keep K3D off the target.
    """
    verts = np.asarray(start, dtype=np.float64)
    groups, _ = _eq1_groups(
        verts,
        np.asarray(quads, dtype=np.int64),
        np.asarray(target_vertices, dtype=np.float64),
        np.asarray(target_faces, dtype=np.int64),
        weights,
        requery_rel=0.0,
    )
    energies = LocalGlobalSolver(len(verts), groups).energies(positions)
    energies["total"] = float(sum(energies.values()))
    return energies


def optimize_top(
    vertices: FloatArray,
    quads: IntArray,
    target_vertices: FloatArray,
    target_faces: IntArray,
    *,
    w_planar: float,
    w_square: float,
    w_surface: float,
    rel_tol: float,
    max_iter: int,
    anderson: int,
    w_convex: float = 0.0,
    convex_margin: float = CONVEX_MARGIN,
    requery_rel: float = SURFACE_REQUERY_REL,
    callback: Callable[[int, FloatArray], bool] | None = None,
) -> tuple[SolverResult, FloatArray]:
    """One K3D solve of paper eq. 1 with edge targets from ``vertices``.

    Parameters
    ----------
    vertices : (n, 3) float, mm
    quads : (m, 4) int
    target_vertices : (p, 3) float, mm
    target_faces : (f, 3) int
    w_planar, w_square, w_surface : float
    rel_tol, max_iter, anderson : solver options
    w_convex : float
        Weight of :class:`ConvexCorners` (0: not used).
    convex_margin : float
        Its margin.
    requery_rel : float
        :class:`~drawstring.geometry.solve.groups.ClosenessToSurface` lazy re-query threshold (0:
        query every vertex in every iteration).
    callback : callable, optional
        Passed to :meth:`~drawstring.geometry.solve.solver.LocalGlobalSolver.solve` (may stop it).

    Returns
    -------
    result : SolverResult
    targets : (e,) float, mm
        Edge-length targets used.
    """
    groups, targets = _eq1_groups(
        vertices,
        quads,
        target_vertices,
        target_faces,
        (w_planar, w_square, w_surface),
        requery_rel=requery_rel,
    )
    reference_normals = quad_vector_areas(vertices, quads)
    if w_convex > 0:
        groups.append(
            ConvexCorners(quads, reference_normals, w_convex, name="convex", margin=convex_margin)
        )
    solver = LocalGlobalSolver(len(vertices), groups)
    result = solver.solve(
        vertices,
        rel_tol=rel_tol,
        max_iter=max_iter,
        anderson=anderson,
        callback=callback,
        anderson_gram=True,
    )
    return result, targets


def extrude_tiles(
    top: FloatArray,
    quads: IntArray,
    thickness: float,
    *,
    w_planar: float = 1.0,
    w_slab: float = 1.0,
    w_keep_top: float = 1.0,
    w_keep_bottom: float = 1e-2,
    fix_top: bool = False,
    rel_tol: float,
    max_iter: int,
    anderson: int,
) -> tuple[SolverResult, FloatArray, FloatArray]:
    """Extrude K3D into frustum tiles with planar faces and parallel top/bottom (T3D).

    Parameters
    ----------
    top : (n, 3) float, mm
        K3D, quads counter-clockwise seen from outside.
    quads : (m, 4) int
    thickness : float, mm
    w_planar : float
        Planarity of every top, bottom and side face.
    w_slab : float
        Bottom parallel to top at ``thickness``.
    w_keep_top, w_keep_bottom : float
        Closeness of the top to K3D and of the bottom to its normal offset.
    fix_top : bool
        Hold the top exactly where it is (its quads must be planar already): only the bottom
        vertices are unknowns, the top faces' planarity and ``w_keep_top`` drop out, and the
        slab pulls each bottom corner onto the plane parallel to its tile's top face
        ``thickness`` below it (:class:`ClosenessToPlanes`: the top's planes are known, so the
        common normal the free slab fits is not needed; a third of the time per iteration).
    rel_tol, max_iter, anderson : solver options

    Returns
    -------
    result : SolverResult
        Over the stacked ``[top; bottom]`` positions.
    top, bottom : (n, 3) float, mm
    """
    n = len(top)
    edges = quad_mesh_edges(quads)
    bottom0 = _initial_bottom(top, quads, thickness)
    faces = np.vstack([quads + n, side_quads(quads, edges, n)])
    keep_bottom = ClosenessToPoints(np.arange(n, 2 * n), bottom0, w_keep_bottom, name="keep_bottom")
    groups: list[ConstraintGroup]
    if fix_top:
        areas = quad_vector_areas(top, quads)
        normals = areas / np.linalg.norm(areas, axis=1, keepdims=True)
        levels = np.einsum("ki,ki->k", top[quads].mean(axis=1), normals) - thickness
        groups = [
            Plane(faces, w_planar, name="planar"),
            ClosenessToPlanes(
                (quads + n).reshape(-1),
                np.repeat(normals, 4, axis=0),
                np.repeat(levels, 4),
                w_slab,
                name="slab",
            ),
            keep_bottom,
        ]
    else:
        groups = [
            Plane(np.vstack([quads, faces]), w_planar, name="planar"),
            Slab(quads, quads + n, thickness, w_slab, name="slab"),
            ClosenessToPoints(np.arange(n), top, w_keep_top, name="keep_top"),
            keep_bottom,
        ]
    solver = LocalGlobalSolver(2 * n, groups, fixed=np.arange(n) if fix_top else None)
    result = solver.solve(
        np.vstack([top, bottom0]),
        rel_tol=rel_tol,
        max_iter=max_iter,
        anderson=anderson,
        anderson_gram=True,
    )
    return result, result.X[:n], result.X[n:]


def optimize_assembled(
    quad_vertices: ArrayLike,
    quads: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    *,
    thickness: float,
    w_planar: float = DEFAULT_WEIGHTS[0],
    w_square: float = DEFAULT_WEIGHTS[1],
    w_surface: float = DEFAULT_WEIGHTS[2],
    w_convex: float = DEFAULT_WEIGHTS[0] * CONVEX_WEIGHT_REL,
    convex_margin: float = CONVEX_MARGIN,
    square_rounds: int = 1,
    rel_tol: float = ASSEMBLED_SOLVER_REL_TOL,
    max_iter: int = 1000,
    anderson: int = ANDERSON_HISTORY,
    requery_rel: float = SURFACE_REQUERY_REL,
) -> AssembledResult:
    """Optimize the lifted quad mesh into K3D and extrude it into frustum tiles T3D.

    Parameters
    ----------
    quad_vertices : (n, 3) float, mm
        Lifted quad mesh M3D.
    quads : (m, 4) int
        Consistently oriented; flipped if they face against the target's normals.
    target_vertices : (p, 3) float, mm
    target_faces : (f, 3) int
        Target surface, oriented outward.
    thickness : float, mm
        Tile thickness (distance between a tile's top and bottom planes).
    w_planar, w_square, w_surface : float
        Weights of paper eq. 1; defaults are the paper's (1e4, 10, 0.1). With them squareness
        outweighs the surface and the converged mesh drifts off the target (0.5-6 mm mean at
        ~200 tiles on the built-ins); :data:`CLOSE_FIT_WEIGHTS` trade squareness for closeness.
    w_convex : float
        Weight of :class:`ConvexCorners` (0 disables it). The plain solve runs first; only if
        it leaves a quad corner below ``convex_margin`` (e.g. darts on the three-shell at ~210
        tiles) is K3D solved again from the lifted mesh with the group, which keeps the solve
        out of folded local minima without changing the energy of convex configurations. A
        plain solve in which a corner stays folded over (negative margin at two checks
        ``FOLD_CHECK_EVERY`` iterations apart) is stopped there and re-solved at once.
    convex_margin : float
        See :data:`CONVEX_MARGIN`.
    square_rounds : int
        Outer rounds; each recomputes the edge-length targets from the current mesh.
    rel_tol, max_iter, anderson : local-global solver options (each solve).
    requery_rel : float
        Lazy closest-point re-query of the K3D surface term (see
        :class:`~drawstring.geometry.solve.groups.ClosenessToSurface`; 0 queries every vertex in
        every iteration).

    Returns
    -------
    AssembledResult

    Raises
    ------
    InputError
        Malformed meshes or options.
    DesignError
        The extrusion inverts tiles (thickness too large for the curvature).
    """
    start = time.perf_counter()
    weights = {"w_planar": w_planar, "w_square": w_square, "w_surface": w_surface}
    verts, faces, t_verts, t_faces = _check_inputs(
        quad_vertices, quads, target_vertices, target_faces, thickness, weights
    )
    if square_rounds < 1:
        raise InputError("square_rounds must be at least 1")
    faces = orient_outward(verts, faces, t_verts, t_faces)
    edges = quad_mesh_edges(faces)
    before = measure_assembled(
        tile_vertices(verts, _initial_bottom(verts, faces, thickness), faces),
        faces,
        t_verts,
        t_faces,
    )
    bbox_diag = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    polish_tol = ASSEMBLED_PLANARITY_REL * bbox_diag

    t0 = time.perf_counter()

    reference = quad_vector_areas(verts, faces)

    def folding(iteration: int, x: FloatArray) -> bool:
        """Stop the plain solve once a corner has stayed folded over (margin < 0) for at
        least ``FOLD_CHECK_EVERY`` iterations: it then ends below the margin (a dart), as on
        the three-shell at ~210 tiles, and the convexity re-solve follows anyway. Corners that
        only dip below the margin in the first iterations (seashell, peanut) recover."""
        if iteration % FOLD_CHECK_EVERY:
            return False
        folded = float(corner_margins(x, faces, reference).min()) < 0.0
        stop = folded and fold_seen[0]
        fold_seen[0] = folded
        return stop

    fold_seen = [False]

    def solve_rounds(
        weight_convex: float,
    ) -> tuple[FloatArray, list[SolverResult], FloatArray, bool]:
        x = verts
        done: list[SolverResult] = []
        used = np.zeros(len(edges.edges))
        watch = folding if weight_convex == 0.0 and w_convex > 0 else None
        for _ in range(square_rounds):
            result, used = optimize_top(
                x,
                faces,
                t_verts,
                t_faces,
                w_planar=w_planar,
                w_square=w_square,
                w_surface=w_surface,
                rel_tol=rel_tol,
                max_iter=max_iter,
                anderson=anderson,
                w_convex=weight_convex,
                convex_margin=convex_margin,
                requery_rel=requery_rel,
                callback=watch,
            )
            done.append(result)
            x = result.X
            if result.stopped:
                return x, done, used, True
        return x, done, used, False

    # The convexity group is stiff even where it is inactive (it adds w_convex A^T A to the
    # global matrix), so it is only brought in when the plain solve leaves a corner below the
    # margin; a plain solution that meets it is already a stationary point of the constrained
    # problem. A plain solve in which a corner stays folded over is stopped early (`folding`).
    top, solves, targets, folded = solve_rounds(0.0)
    margin_plain = float(corner_margins(top, faces, reference).min())
    convex_resolve = w_convex > 0 and (folded or margin_plain < convex_margin)
    if convex_resolve:
        logger.info(
            "assembled: a quad corner reached %.3g of its diagonal (< %.3g); solving again with "
            "the convexity constraint",
            margin_plain,
            convex_margin,
        )
        top, more, targets, _ = solve_rounds(w_convex)
        solves += more
    top_polish = planarize_quads(top, faces, tol_mm=0.1 * polish_tol)
    top = top_polish.X
    t1 = time.perf_counter()

    ext, top, bottom = extrude_tiles(
        top, faces, thickness, rel_tol=rel_tol, max_iter=max_iter, anderson=anderson
    )
    n = len(top)
    all_faces = np.vstack([faces, faces + n, side_quads(faces, edges, n)])
    ext_polish = planarize_quads(np.vstack([top, bottom]), all_faces, tol_mm=0.1 * polish_tol)
    top, bottom = ext_polish.X[:n], ext_polish.X[n:]
    t2 = time.perf_counter()

    tiles = tile_vertices(top, bottom, faces)
    top_area = quad_vector_areas(top, faces)
    bottom_area = quad_vector_areas(bottom, faces)
    inverted = int(np.count_nonzero(np.einsum("ki,ki->k", top_area, bottom_area) <= 0))
    if inverted:
        advice = thickness_advice(top, faces)
        # two significant digits, rounded down so that the value quoted is within the bound
        step = 10.0 ** (math.floor(math.log10(advice)) - 1) if advice > 0 else 1.0
        quoted = math.floor(advice / step) * step
        thinner = f"{quoted:g} or less" if 0 < quoted < thickness else "a smaller value"
        raise ThicknessError(
            f"thickness {thickness:g} mm turns {inverted} tile(s) inside out where the target "
            f"curves tighter than that; use --thickness {thinner}, or fewer tiles (larger "
            "tiles smooth tight spots over)",
            thickness=float(thickness),
            inverted=inverted,
            advice=float(quoted) if 0 < quoted < thickness else 0.0,
        )
    metrics = measure_assembled(tiles, faces, t_verts, t_faces)
    metrics["planarity_max_before_mm"] = before["planarity_max_mm"]
    metrics["corner_margin_min"] = float(corner_margins(top, faces, reference).min())
    metrics["corner_margin_min_unconstrained"] = margin_plain
    metrics["convex_resolve"] = float(convex_resolve)
    metrics["bbox_diagonal_mm"] = bbox_diag
    metrics["polish_move_max_mm"] = max(top_polish.max_move_mm, ext_polish.max_move_mm)
    metrics["time_top_s"] = t1 - t0
    metrics["time_extrusion_s"] = t2 - t1
    elapsed = time.perf_counter() - start
    logger.info(
        "assembled: %d tiles, planarity %.2e -> %.2e mm, %.2f s",
        len(faces),
        metrics["planarity_max_before_mm"],
        metrics["planarity_max_mm"],
        elapsed,
    )
    return AssembledResult(
        top=top,
        bottom=bottom,
        quads=faces,
        tiles=tiles,
        thickness=float(thickness),
        edges=edges.edges,
        edge_targets=targets,
        metrics=metrics,
        top_solve=solves[-1],
        extrusion_solve=ext,
        top_polish=top_polish,
        extrusion_polish=ext_polish,
        time_s=elapsed,
        top_solves=tuple(solves),
    )


def reextrude(
    result: AssembledResult,
    top: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    *,
    rel_tol: float = ASSEMBLED_SOLVER_REL_TOL,
    max_iter: int = 1000,
    anderson: int = ANDERSON_HISTORY,
    measure: bool = True,
    start_bottom: ArrayLike | None = None,
    pull: LinearPull | None = None,
) -> AssembledResult | None:
    """T3D extruded again under a new K3D that must not move (its quads already planar).

    Used after the flat layout moved K3D (:func:`~drawstring.geometry.flat.layout.co_optimize_top`):
    the extrusion holds the top fixed (only the bottom vertices are unknowns) and the exact
    planarity polish moves only bottom vertices, so the flat tiles stay congruent to the new top
    faces.  With ``measure=False`` the :func:`measure_assembled` metrics are left as ``result``
    had them (rounds that may be thrown away skip them; :func:`remeasured` adds them later).

    With ``start_bottom`` (bottom vertices carried along with the moved top, e.g. each moved
    by its top vertex's move) the extrusion solve is skipped and only the exact polish runs
    from them.  The co-optimization's rounds do so: the solve's soft slab and planarity
    settle 0.2 mm from the polished bottoms whatever it starts from, so every round moved
    the bottom corners (the bottom hinges' points) by that much and the re-solved layout had
    to follow; polished from the carried bottoms they move by hundredths of a millimetre
    (thickness within 0.01 mm of the extruded one).

    Returns
    -------
    AssembledResult, or None when the new top would turn a tile inside out.
    """
    new_top = np.array(top, dtype=np.float64)
    faces = result.quads
    n = len(new_top)
    edges = quad_mesh_edges(faces)
    bbox_diag = float(result.metrics.get("bbox_diagonal_mm", 1.0))
    polish_tol = ASSEMBLED_PLANARITY_REL * bbox_diag
    top_polish = planarize_quads(new_top, faces, tol_mm=0.1 * polish_tol)
    new_top = top_polish.X
    if start_bottom is None:
        ext, _, bottom = extrude_tiles(
            new_top, faces, result.thickness, fix_top=True, rel_tol=rel_tol, max_iter=max_iter,
            anderson=anderson,
        )  # fmt: skip
    else:
        ext, bottom = result.extrusion_solve, np.asarray(start_bottom, dtype=np.float64)
    all_faces = np.vstack([faces, faces + n, side_quads(faces, edges, n)])
    polish = planarize_quads(
        np.vstack([new_top, bottom]), all_faces, fixed=np.arange(n), tol_mm=0.1 * polish_tol,
        pull=pull, max_iter=8 if pull is None else 20,
    )  # fmt: skip
    bottom = polish.X[n:]
    top_area = quad_vector_areas(new_top, faces)
    if np.any(np.einsum("ki,ki->k", top_area, quad_vector_areas(bottom, faces)) <= 0):
        return None
    tiles = tile_vertices(new_top, bottom, faces)
    metrics = dict(result.metrics)
    if measure:
        metrics.update(_measured_metrics(tiles, faces, target_vertices, target_faces))
    metrics["corner_margin_min"] = float(
        corner_margins(new_top, faces, quad_vector_areas(result.top, faces)).min()
    )
    metrics["polish_move_max_mm"] = max(
        metrics.get("polish_move_max_mm", 0.0), top_polish.max_move_mm, polish.max_move_mm
    )
    return dataclasses.replace(
        result,
        top=new_top,
        bottom=bottom,
        tiles=tiles,
        metrics=metrics,
        extrusion_solve=ext,
        top_polish=top_polish,
        extrusion_polish=polish,
    )


#: Weight of the bottom hinges' equal depths against moving the bottom vertices
#: (:func:`hinge_depth_pull`): 1e3 took the 200-tile three-shell's largest depth difference from
#: 0.245 to 0.030 mm, moving bottom corners by up to 0.4 mm.
HINGE_DEPTH_WEIGHT = 1e3


def hinge_depth_pull(
    result: AssembledResult, hinge_vertices: IntArray, tile_a: IntArray, tile_b: IntArray
) -> LinearPull:
    """Equal depths of bottom hinges, for :func:`reextrude`: a bottom hinge's two tiles lie flat
    with their top faces in one plane, so their shared bottom corner meets itself only if it
    is as deep under one tile's top face as under the other's, ``(b - t) . (n_a - n_b) = 0``
    (``t`` its top vertex, ``n`` the unit top normals).  Pulled on the stacked ``[top;
    bottom]`` vertices, the bottoms only."""
    normals = quad_vector_areas(result.top, result.quads)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    directions = normals[tile_a] - normals[tile_b]
    targets = np.einsum("ki,ki->k", directions, result.top[hinge_vertices])
    return LinearPull(
        len(result.top) + np.asarray(hinge_vertices, dtype=np.int64),
        directions,
        targets,
        HINGE_DEPTH_WEIGHT,
    )


def _measured_metrics(
    tiles: FloatArray, quads: IntArray, target_vertices: ArrayLike, target_faces: ArrayLike
) -> dict[str, float]:
    return measure_assembled(
        tiles,
        quads,
        np.asarray(target_vertices, dtype=np.float64),
        np.asarray(target_faces, dtype=np.int64),
    )


def remeasured(
    result: AssembledResult, target_vertices: ArrayLike, target_faces: ArrayLike
) -> AssembledResult:
    """``result`` with its :func:`measure_assembled` metrics taken on its own tiles (after
    ``reextrude(..., measure=False)``)."""
    metrics = dict(result.metrics)
    metrics.update(_measured_metrics(result.tiles, result.quads, target_vertices, target_faces))
    return dataclasses.replace(result, metrics=metrics)
