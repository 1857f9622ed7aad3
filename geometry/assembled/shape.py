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

import logging
import math
import time
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.assembled.extrusion import extrude_tiles, initial_bottom, thickness_advice
from drawstring.geometry.assembled.frustums import (
    QuadMeshEdges,
    corner_margins,
    folded_faces,
    measure_assembled,
    orient_outward,
    quad_mesh_edges,
    quad_vector_areas,
    side_quads,
    tile_vertices,
)
from drawstring.geometry.assembled.top import (
    CONVEX_MARGIN,
    CONVEX_WEIGHT_REL,
    DEFAULT_WEIGHTS,
    SURFACE_REQUERY_REL,
    optimize_top,
)
from drawstring.geometry.core.errors import InputError, InternalError, ThicknessError
from drawstring.geometry.core.tolerances import (
    ASSEMBLED_PLANARITY_REL,
    ASSEMBLED_SOLVER_REL_TOL,
)
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.planarity import PlanarizeResult, planarize_quads
from drawstring.geometry.solve.solver import SolverResult

logger = logging.getLogger(__name__)


#: Iterations between checks of the plain K3D solve for corners folded over.
FOLD_CHECK_EVERY: int = 25

#: Anderson history of the assembled solves. On the built-ins at ~200 tiles (three starts each)
#: and at 1600 tiles, m = 8 needs 10-40 % fewer iterations than the solver's default m = 5 at
#: about the same cost per iteration (with the Gram mixing), and about 700 instead of 800-950 in
#: the three-shell's convexity re-solve; where both stop at ``max_iter`` (seashell) m = 8 gets
#: further (energy 2-4 % lower).
ANDERSON_HISTORY: int = 8


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
        raise InternalError("quad_vertices must be a finite (n, 3) array in mm")
    if faces.ndim != 2 or faces.shape[1] != 4 or len(faces) == 0:
        raise InternalError("quads must be a non-empty (m, 4) integer array")
    if not np.issubdtype(faces.dtype, np.integer):
        raise InternalError("quads must hold integer vertex indices")
    if faces.min() < 0 or faces.max() >= len(verts):
        raise InternalError("quads refer to vertices that do not exist; check the vertex indices")
    if np.any(np.sort(faces, axis=1)[:, 1:] == np.sort(faces, axis=1)[:, :-1]):
        raise InternalError("a quad repeats a vertex; remove degenerate quads")
    if t_verts.ndim != 2 or t_verts.shape[1] != 3 or not np.all(np.isfinite(t_verts)):
        raise InternalError("target vertices must be a finite (p, 3) array in mm")
    if t_faces.ndim != 2 or t_faces.shape[1] != 3 or len(t_faces) == 0:
        raise InternalError("target faces must be a non-empty (f, 3) triangle array")
    if t_faces.min() < 0 or t_faces.max() >= len(t_verts):
        raise InternalError("target faces refer to vertices that do not exist")
    if not np.isfinite(thickness) or thickness <= 0:
        raise InputError(f"thickness is {thickness} mm; give a positive thickness")
    for name, value in weights.items():
        if not np.isfinite(value) or value < 0:
            raise InputError(f"{name} is {value}; weights must be finite and >= 0")
    return verts, faces.astype(np.int64), t_verts, t_faces.astype(np.int64)


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
    w_samples: float = 0.0,
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
    convex_margin : float (see :data:`CONVEX_MARGIN`)
    square_rounds : int
        Outer rounds; each recomputes the edge-length targets from the current mesh.
    rel_tol, max_iter, anderson : local-global solver options (each solve).
    requery_rel : float
        Lazy closest-point re-query of the K3D surface term (see
        :class:`~drawstring.geometry.solve.groups.ClosenessToSurface`; 0: every vertex, always).
    w_samples : float
        Weight of the quads' centres and edge midpoints pulled to the target too
        (:class:`~drawstring.geometry.solve.groups.FaceSamplesToSurface`; 0: not used).

    Returns
    -------
    AssembledResult

    Raises
    ------
    InputError
        A thickness or weight out of range.
    InternalError
        Malformed meshes or solver options.
    DesignError
        The extrusion inverts tiles (thickness too large for the curvature).
    """
    start = time.perf_counter()
    weights = (w_planar, w_square, w_surface)
    solver = (rel_tol, max_iter, anderson)
    verts, faces, target, before = _prepared(
        quad_vertices, quads, target_vertices, target_faces, thickness, weights, square_rounds
    )
    edges = quad_mesh_edges(faces)
    bbox_diag = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    polish_tol = ASSEMBLED_PLANARITY_REL * bbox_diag

    t0 = time.perf_counter()
    rounds = _TopRounds(
        verts=verts,
        faces=faces,
        target=target,
        reference=quad_vector_areas(verts, faces),
        n_edges=len(edges.edges),
        weights=weights,
        w_convex=w_convex,
        convex_margin=convex_margin,
        square_rounds=square_rounds,
        solver=solver,
        requery_rel=requery_rel,
        w_samples=w_samples,
    )
    k3d = rounds.run(0.1 * polish_tol)
    t1 = time.perf_counter()
    ext, ext_polish = _extruded(k3d.polish.X, faces, edges, thickness, 0.1 * polish_tol, solver)
    t2 = time.perf_counter()
    times = (t1 - t0, t2 - t1)
    return _assembled_result(
        k3d, ext, ext_polish, edges, thickness, target, before, bbox_diag, times, start
    )


class _FoldWatch:
    """Callback of the plain K3D solve: stops it once a corner has stayed folded over (margin
    < 0) at two checks ``FOLD_CHECK_EVERY`` iterations apart.  The solve then ends below the
    margin (a dart), as on the three-shell at ~210 tiles, and the convexity re-solve follows
    anyway.  Corners that only dip below the margin in the first iterations (seashell, peanut)
    recover."""

    def __init__(self, faces: IntArray, reference: FloatArray) -> None:
        self.faces = faces
        self.reference = reference
        self.seen = False

    def __call__(self, iteration: int, x: FloatArray) -> bool:
        if iteration % FOLD_CHECK_EVERY:
            return False
        folded = float(corner_margins(x, self.faces, self.reference).min()) < 0.0
        stop = folded and self.seen
        self.seen = folded
        return stop


@dataclass(frozen=True)
class _TopRounds:
    """The K3D solves of one :func:`optimize_assembled` call: ``square_rounds`` rounds of
    :func:`~drawstring.geometry.assembled.top.optimize_top` from the lifted mesh ``verts``, and
    the same again with :class:`~drawstring.geometry.assembled.top.ConvexCorners` when the
    plain rounds leave a corner below the margin.  ``reference``: the lifted quads' vector
    areas (their outward directions); ``weights``: ``(w_planar, w_square, w_surface)``;
    ``solver``: ``(rel_tol, max_iter, anderson)``; ``w_samples``: the face samples' weight
    (:func:`optimize_assembled`)."""

    verts: FloatArray
    faces: IntArray
    target: tuple[FloatArray, IntArray]
    reference: FloatArray
    n_edges: int
    weights: tuple[float, float, float]
    w_convex: float
    convex_margin: float
    square_rounds: int
    solver: tuple[float, int, int]
    requery_rel: float
    w_samples: float = 0.0

    def run(self, polish_tol: float) -> _K3D:
        """The rounds, the convexity re-solve when the plain rounds need it, and the exact
        planarity polish (to ``polish_tol``, mm)."""
        # The convexity group is stiff even where it is inactive (it adds w_convex A^T A to the
        # global matrix), so it is only brought in when the plain solve leaves a corner below
        # the margin; a plain solution that meets it is already a stationary point of the
        # constrained problem. A plain solve in which a corner stays folded over is stopped
        # early (:class:`_FoldWatch`).
        top, solves, targets, folded = self.solve(0.0)
        margin_plain = float(corner_margins(top, self.faces, self.reference).min())
        convex_resolve = self.w_convex > 0 and (folded or margin_plain < self.convex_margin)
        if convex_resolve:
            logger.info(
                "assembled: a quad corner reached %.3g of its diagonal (< %.3g); solving again "
                "with the convexity constraint",
                margin_plain,
                self.convex_margin,
            )
            top, more, targets, _ = self.solve(self.w_convex)
            solves += more
        polish = planarize_quads(top, self.faces, tol_mm=polish_tol)
        return _K3D(
            polish, solves, targets, margin_plain, convex_resolve, self.faces, self.reference
        )

    def solve(
        self, weight_convex: float
    ) -> tuple[FloatArray, list[SolverResult], FloatArray, bool]:
        """The rounds with convexity weight ``weight_convex``: K3D, the solves, the last edge
        targets, and whether a folded corner stopped them."""
        x = self.verts
        done: list[SolverResult] = []
        used = np.zeros(self.n_edges)
        watch = (
            _FoldWatch(self.faces, self.reference)
            if weight_convex == 0.0 and self.w_convex > 0
            else None
        )
        w_planar, w_square, w_surface = self.weights
        rel_tol, max_iter, anderson = self.solver
        t_verts, t_faces = self.target
        for _ in range(self.square_rounds):
            result, used = optimize_top(
                x,
                self.faces,
                t_verts,
                t_faces,
                w_planar=w_planar,
                w_square=w_square,
                w_surface=w_surface,
                rel_tol=rel_tol,
                max_iter=max_iter,
                anderson=anderson,
                w_convex=weight_convex,
                convex_margin=self.convex_margin,
                requery_rel=self.requery_rel,
                callback=watch,
                w_samples=self.w_samples,
            )
            done.append(result)
            x = result.X
            if result.stopped:
                return x, done, used, True
        return x, done, used, False


@dataclass(frozen=True)
class _K3D:
    """The outcome of :meth:`_TopRounds.run`: K3D made exactly planar (``polish``), every
    solve, the last edge targets, the plain solve's smallest corner margin, whether the
    convexity re-solve ran, and the quads with their reference normals."""

    polish: PlanarizeResult
    solves: list[SolverResult]
    targets: FloatArray
    margin_plain: float
    convex_resolve: bool
    faces: IntArray
    reference: FloatArray

    def metrics(
        self,
        top: FloatArray,
        before: dict[str, float],
        bbox_diag: float,
        ext_polish: PlanarizeResult,
    ) -> dict[str, float]:
        """The metrics of :class:`AssembledResult` besides :func:`measure_assembled`'s and the
        timings, for the final K3D ``top``."""
        return {
            "planarity_max_before_mm": before["planarity_max_mm"],
            "corner_margin_min": float(corner_margins(top, self.faces, self.reference).min()),
            "corner_margin_min_unconstrained": self.margin_plain,
            "convex_resolve": float(self.convex_resolve),
            "bbox_diagonal_mm": bbox_diag,
            "polish_move_max_mm": max(self.polish.max_move_mm, ext_polish.max_move_mm),
        }


def _assembled_result(
    k3d: _K3D,
    ext: SolverResult,
    ext_polish: PlanarizeResult,
    edges: QuadMeshEdges,
    thickness: float,
    target: tuple[FloatArray, IntArray],
    before: dict[str, float],
    bbox_diag: float,
    times: tuple[float, float],
    start: float,
) -> AssembledResult:
    """The :class:`AssembledResult` of K3D and of its extrusion (stacked ``[top; bottom]`` in
    ``ext_polish``), measured against the ``target`` mesh; ``times``: the seconds of the two
    stages, ``start``: when :func:`optimize_assembled` began (``time.perf_counter``)."""
    t_verts, t_faces = target
    faces = k3d.faces
    n = len(k3d.polish.X)
    top, bottom = ext_polish.X[:n], ext_polish.X[n:]
    tiles = tile_vertices(top, bottom, faces)
    metrics = measure_assembled(tiles, faces, t_verts, t_faces)
    metrics.update(k3d.metrics(top, before, bbox_diag, ext_polish))
    metrics["time_top_s"], metrics["time_extrusion_s"] = times
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
        edge_targets=k3d.targets,
        metrics=metrics,
        top_solve=k3d.solves[-1],
        extrusion_solve=ext,
        top_polish=k3d.polish,
        extrusion_polish=ext_polish,
        time_s=elapsed,
        top_solves=tuple(k3d.solves),
    )


def _prepared(
    quad_vertices: ArrayLike,
    quads: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    thickness: float,
    weights: tuple[float, float, float],
    square_rounds: int,
) -> tuple[FloatArray, IntArray, tuple[FloatArray, IntArray], dict[str, float]]:
    """The checked inputs of :func:`optimize_assembled` (quads facing outward, the target mesh
    as a pair) and the metrics of the lifted mesh extruded along its normals (before any
    optimization)."""
    w_planar, w_square, w_surface = weights
    named = {"w_planar": w_planar, "w_square": w_square, "w_surface": w_surface}
    verts, faces, t_verts, t_faces = _check_inputs(
        quad_vertices, quads, target_vertices, target_faces, thickness, named
    )
    if square_rounds < 1:
        raise InternalError("square_rounds must be at least 1")
    faces = orient_outward(verts, faces, t_verts, t_faces)
    before = measure_assembled(
        tile_vertices(verts, initial_bottom(verts, faces, thickness), faces),
        faces,
        t_verts,
        t_faces,
    )
    return verts, faces, (t_verts, t_faces), before


def _extruded(
    top: FloatArray,
    faces: IntArray,
    edges: QuadMeshEdges,
    thickness: float,
    polish_tol: float,
    solver: tuple[float, int, int],
) -> tuple[SolverResult, PlanarizeResult]:
    """T3D under the planar K3D ``top``: the extrusion solve and its exact planarity polish
    over every top, bottom and side face (to ``polish_tol``, mm), whose positions are the
    stacked ``[top; bottom]``.  Raises :class:`ThicknessError` when a tile turned inside out."""
    rel_tol, max_iter, anderson = solver
    ext, top, bottom = extrude_tiles(
        top, faces, thickness, rel_tol=rel_tol, max_iter=max_iter, anderson=anderson
    )
    n = len(top)
    all_faces = np.vstack([faces, faces + n, side_quads(faces, edges, n)])
    ext_polish = planarize_quads(np.vstack([top, bottom]), all_faces, tol_mm=polish_tol)
    _refuse_inverted(ext_polish.X[:n], ext_polish.X[n:], faces, thickness)
    return ext, ext_polish


def _refuse_inverted(
    top: FloatArray, bottom: FloatArray, faces: IntArray, thickness: float
) -> None:
    """Raise :class:`ThicknessError` when a tile's bottom faces against its top or a face
    folds into a dart (:func:`~.frustums.folded_faces`), with the thickness to use instead
    (:func:`thickness_advice`, two significant digits)."""
    inverted = int(np.count_nonzero(folded_faces(top, bottom, faces)))
    if not inverted:
        return
    advice = thickness_advice(top, faces)
    # two significant digits, rounded down so that the value quoted is within the bound
    step = 10.0 ** (math.floor(math.log10(advice)) - 1) if advice > 0 else 1.0
    quoted = math.floor(advice / step) * step
    thinner = f"{quoted:g} or less" if 0 < quoted < thickness else "a smaller value"
    raise ThicknessError(
        f"thickness {thickness:g} mm turns {inverted} tile(s) inside out or folds them where "
        f"the target curves tighter than that; use --thickness {thinner}, or fewer tiles (larger "
        "tiles smooth tight spots over)",
        thickness=float(thickness),
        inverted=inverted,
        advice=float(quoted) if 0 < quoted < thickness else 0.0,
    )
