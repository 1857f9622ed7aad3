"""Co-optimization of the assembled top faces K3D with the flat layout K2D.

With K3D fixed, ``optimize_flat`` stops at a least-squares optimum
(a quad linkage of rigid tiles is over-determined in the plane).  :func:`co_optimize_top` moves
both, so every flat tile becomes congruent to its assembled top face while the flat layout's
hard rows (gap-angle bounds, gap orientation) hold; it reuses the flat stage's augmented
Lagrangian solver.
"""

from __future__ import annotations

import hashlib
import logging
import time
from dataclasses import dataclass

import igl
import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import FLAT_SOLVER_ANGLE_TOL_DEG
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flat.bounds import flat_constraints
from drawstring.geometry.flat.cofit import (
    CO_CONVEX_WEIGHT_REL,
    convex_corner_rows,
    face_sample_matrix,
    quad_normals,
)
from drawstring.geometry.flat.conical import VertexStars, vertex_stars
from drawstring.geometry.flat.initial import tile_plane_coordinates
from drawstring.geometry.flat.junctions import TILE_EDGES, gap_junctions
from drawstring.geometry.flat.layout import FlatResult
from drawstring.geometry.flat.pose import HingeFaces, hinge_points
from drawstring.geometry.solve.constrained_lsq import (
    AngleRows,
    SeparationRows,
    constrained_least_squares,
)
from drawstring.geometry.solve.linalg import plane_fit
from drawstring.geometry.tiling.linkage import Linkage

logger = logging.getLogger(__name__)


__all__ = [
    "CO_CONICAL",
    "CO_STAGES",
    "CO_STEPS",
    "CoOptimizedTop",
    "co_optimize_top",
]

#: Continuation of :func:`co_optimize_top`: (planarity weight, edge weight) per stage, both
#: relative to the pull towards the starting K3D (weight 1 per mm^2).  The last stage leaves
#: the quads planar to a few 1e-6 mm: at 1e5 they stayed about 1e-4 mm off, and making them
#: exactly planar (the re-extrusion's polish) moved the top by up to 1.5e-3 mm, which the
#: flat layout solved again under it then had to absorb (200-tile cloud: 3.3e-4 mm with two
#: stages, 6e-5 mm with three).
CO_STAGES: tuple[tuple[float, float], ...] = ((100.0, 100.0), (1e5, 1e5), (1e7, 1e7))
#: Gauss-Newton steps per stage.  More steps per stage move K3D further from the eq.-1 shape
#: without making the re-solved flat layout more accurate (the pipeline's rounds re-solve it
#: anyway): with 15 the 1600-tile saddle's top moved up to 0.30 mm and its layout ended
#: 2.9e-5 mm off in 93 steps, with 8 it moved 0.18 mm and ended 2.5e-5 mm off in 51; every
#: 200-tile built-in (both hinge strategies) and the 1600-tile wave and dome meet the 1e-3 mm
#: targets with 8.  With 5 the pipeline does as well, but one joint solve alone leaves the quads
#: 3e-5 mm from planar where 8 leaves 4e-7 mm.
CO_STEPS = 8
#: Pull of every K3D vertex towards its start (weight per mm^2; the other weights are relative
#: to it), which keeps the squareness eq. 1 gave while the tiles become flat-foldable.
CO_KEEP = 1.0
#: Starting penalty of the joint solve's hard rows relative to its edge weight (``optimize_flat``
#: starts at 10 with edge weight 1).
CO_RHO_REL = 10.0
#: The joint solve's few steps leave the angle bounds met to a few hundredths of a degree, so
#: it keeps this much inside them; ``optimize_flat`` afterwards holds them exactly.
CO_ANGLE_MARGIN_DEG = 0.1
#: Weight of the conical condition (:func:`vertex_stars`) relative to planarity in every stage
#: of a ``conical`` joint solve.  At 200 tiles, with the bottom corners pulled to equal depths
#: every round, 3 left the largest 3D hinge gap of the seven built-ins with bottom hinges at
#: 0.07-0.92 um where 10 and 30 gave the wave and the cloud flat errors over 1e-3 mm.
CO_CONICAL = 3.0


@dataclass(frozen=True)
class CoOptimizedTop:
    """Result of :func:`co_optimize_top`.

    Attributes
    ----------
    top : (n, 3) float, mm
        K3D vertices, quads planar and congruent (sides and diagonals) to the K2D tiles.
    nodes : (n_nodes, 2) float, mm
        K2D, a start for ``optimize_flat`` on the new K3D.
    edge_error_max_mm : float
        Largest side or diagonal mismatch between K2D and the new K3D.
    move_max_mm : float
        Largest K3D vertex move.
    steps : int
    time_s : float
    """

    top: FloatArray
    nodes: FloatArray
    edge_error_max_mm: float
    move_max_mm: float
    steps: int
    time_s: float


#: Targets searched lately, by their bytes: the arrays, their AABB tree and face normals.
_TARGET_SEARCHES: dict[bytes, tuple[tuple[FloatArray, IntArray], igl.AABB, FloatArray]] = {}


def _target_search(
    vertices: ArrayLike, faces: ArrayLike
) -> tuple[tuple[FloatArray, IntArray], igl.AABB, FloatArray]:
    """The target's contiguous arrays, an AABB tree over it and its unit face normals, built
    once per target (a design's joint solves all search the same one; 6 ms per build at the
    CLI default resolution)."""
    target = (  # own copies
        np.array(vertices, dtype=np.float64, order="C"),
        np.array(faces, dtype=np.int64, order="C"),
    )
    key = hashlib.sha1(b"".join([repr(a.shape).encode() + a.tobytes() for a in target])).digest()
    if key not in _TARGET_SEARCHES:
        tree = igl.AABB()
        tree.init(*target)
        tri = target[0][target[1]]
        normals = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
        for array in (*target, normals):
            array.flags.writeable = False
        if len(_TARGET_SEARCHES) >= 2:
            _TARGET_SEARCHES.pop(next(iter(_TARGET_SEARCHES)))
        _TARGET_SEARCHES[key] = (target, tree, normals)
    _TARGET_SEARCHES[key] = _TARGET_SEARCHES.pop(key)  # the latest last: evicted last
    return _TARGET_SEARCHES[key]


class _JointTopLeastSquares:
    """Least squares over K2D nodes and K3D vertices together (:func:`co_optimize_top`).

    The variables travel as one ``(rows, 2)`` array for :func:`constrained_least_squares`: rows
    ``0 .. n_nodes - 1`` are the K2D nodes, the rest hold the K3D coordinates ``x0 y0 z0 x1 ...``
    two per row (padded with one zero when their count is odd).  Residuals: every tile side and
    diagonal equal in K2D and K3D (``w_edge``), every K3D quad planar (distance to its best-fit
    plane, ``w_planar``), K3D close to the target along the closest face's normal
    (``w_surface``) and to its start (``CO_KEEP``).
    """

    def __init__(
        self,
        linkage: Linkage,
        quads: IntArray,
        top0: FloatArray,
        target_vertices: FloatArray,
        target_faces: IntArray,
        w_surface: float,
        corner_shift: FloatArray | None = None,
        stars: VertexStars | None = None,
        w_samples: float = 0.0,
    ) -> None:
        self.corner_node = linkage.corner_node
        self.n_nodes = linkage.n_nodes
        self.quads = quads
        self.top0 = top0
        self.n = len(top0)
        self.pad = (3 * self.n) % 2
        self.rows = self.n_nodes + (3 * self.n + self.pad) // 2
        self.target, self.tree, self.target_normals = _target_search(target_vertices, target_faces)
        self.sqrt_surface = float(np.sqrt(max(w_surface, 0.0)))
        #: the quads' centres and edge midpoints as rows of vertex weights, pulled to the
        #: target with ``w_samples`` (None without)
        self.samples = face_sample_matrix(quads, self.n) if w_samples > 0 else None
        self.sqrt_samples = float(np.sqrt(max(w_samples, 0.0)))
        self.normals0 = quad_normals(top0, quads)
        self.sqrt_edge = 1.0
        self.sqrt_planar = 1.0
        self.node_i = self.corner_node[:, TILE_EDGES[:, 0]].ravel()
        self.node_j = self.corner_node[:, TILE_EDGES[:, 1]].ravel()
        self.vert_i = quads[:, TILE_EDGES[:, 0]].ravel()
        self.vert_j = quads[:, TILE_EDGES[:, 1]].ravel()
        # constant offset of each side / diagonal in K3D (hinge points below the top corners)
        if corner_shift is None:
            self.edge_shift = np.zeros((len(self.vert_i), 3))
        else:
            sh = np.asarray(corner_shift, dtype=np.float64)
            self.edge_shift = (sh[:, TILE_EDGES[:, 1]] - sh[:, TILE_EDGES[:, 0]]).reshape(-1, 3)
        self.stars = stars
        self.sqrt_conical = 0.0
        self.side = float(
            np.mean(np.linalg.norm(top0[quads] - top0[np.roll(quads, 1, axis=1)], axis=2))
        )
        #: CSR order of the Jacobian's entries, its column indices and row pointers
        self._pattern: tuple[IntArray, NDArray[np.int32], NDArray[np.int32]] | None = None
        #: the last K3D evaluated, its quads' best-fit planes and its closest target points:
        #: the solver asks for the residual of a trial point and, once it is accepted, for
        #: the Jacobian at the same point
        self._seen: tuple[FloatArray, tuple[FloatArray, ...]] | None = None

    def _planes_and_closest(self, top: FloatArray) -> tuple[FloatArray, ...]:
        """Best-fit plane (centroid, normal) of every quad of ``top``, and every vertex's
        closest target point with the normal of its face (zeros without ``w_surface``); with
        face samples, also the samples, their closest points and those faces' normals."""
        if self._seen is not None and np.array_equal(self._seen[0], top):
            return self._seen[1]
        centroid, normal = plane_fit(top[self.quads])
        if self.sqrt_surface > 0:
            _, face, closest = self.tree.squared_distance(*self.target, np.ascontiguousarray(top))
            face_normal = self.target_normals[np.asarray(face, dtype=np.int64)]
        else:
            closest = face_normal = np.zeros((0, 3))
        found: tuple[FloatArray, ...] = (centroid, normal, np.asarray(closest), face_normal)
        if self.samples is not None:
            points = np.ascontiguousarray(self.samples @ top)
            _, face, near = self.tree.squared_distance(*self.target, points)
            found += (points, np.asarray(near), self.target_normals[np.asarray(face, np.int64)])
        self._seen = (top.copy(), found)
        return found

    def pack(self, nodes: FloatArray, top: FloatArray) -> FloatArray:
        z = np.zeros((self.rows, 2))
        z[: self.n_nodes] = nodes
        z[self.n_nodes :] = np.concatenate([top.ravel(), np.zeros(self.pad)]).reshape(-1, 2)
        return z

    def unpack(self, z: FloatArray) -> tuple[FloatArray, FloatArray]:
        return z[: self.n_nodes], z[self.n_nodes :].ravel()[: 3 * self.n].reshape(self.n, 3)

    def edge_errors(self, z: FloatArray) -> FloatArray:
        nodes, top = self.unpack(z)
        l2 = np.linalg.norm(nodes[self.node_j] - nodes[self.node_i], axis=1)
        l3 = np.linalg.norm(top[self.vert_j] - top[self.vert_i] + self.edge_shift, axis=1)
        return np.asarray(l2 - l3)

    def residual_jacobian(self, z: FloatArray) -> tuple[FloatArray, sp.csr_matrix]:
        res, jac = self._evaluate(z, True)
        assert jac is not None
        return res, jac

    def residual(self, z: FloatArray) -> FloatArray:
        return self._evaluate(z, False)[0]

    def _evaluate(
        self, z: FloatArray, with_jacobian: bool
    ) -> tuple[FloatArray, sp.csr_matrix | None]:
        nodes, top = self.unpack(z)
        acc = _Rows()
        self._edge_rows(acc, nodes, top, with_jacobian)
        centroid, normal, closest, fn, *sampled = self._planes_and_closest(top)
        self._planar_rows(acc, top, centroid, normal, with_jacobian)
        if self.sqrt_surface > 0:
            self._surface_rows(acc, top, closest, fn, with_jacobian)
        if sampled:
            self._sample_rows(acc, sampled[0], sampled[1], sampled[2], with_jacobian)
            self._convex_rows(acc, top, with_jacobian)
        if self.stars is not None and self.sqrt_conical > 0:
            self._conical_rows(acc, self.stars, top, with_jacobian)
        self._keep_rows(acc, top, with_jacobian)
        out = np.concatenate(acc.res)
        if not with_jacobian:
            return out, None
        return out, self._jacobian(acc)

    def _edge_rows(self, acc: _Rows, nodes: FloatArray, top: FloatArray, jac: bool) -> None:
        """Sides and diagonals: K2D length minus K3D length."""
        base = 2 * self.n_nodes  # column of the first K3D coordinate
        w = self.sqrt_edge
        ni, nj, vi, vj = self.node_i, self.node_j, self.vert_i, self.vert_j
        d2 = nodes[nj] - nodes[ni]
        l2 = np.linalg.norm(d2, axis=1)
        d3 = top[vj] - top[vi] + self.edge_shift
        l3 = np.linalg.norm(d3, axis=1)
        acc.res.append(w * (l2 - l3))
        if jac:
            u2 = d2 / np.maximum(l2, 1e-300)[:, None]
            u3 = d3 / np.maximum(l3, 1e-300)[:, None]
            r = acc.row0 + np.arange(len(ni))
            for c in range(2):
                acc.rows += [r, r]
                acc.cols += [2 * ni + c, 2 * nj + c]
                acc.vals += [-w * u2[:, c], w * u2[:, c]]
            for c in range(3):
                acc.rows += [r, r]
                acc.cols += [base + 3 * vi + c, base + 3 * vj + c]
                acc.vals += [w * u3[:, c], -w * u3[:, c]]
        acc.row0 += len(ni)

    def _planar_rows(
        self, acc: _Rows, top: FloatArray, centroid: FloatArray, normal: FloatArray, jac: bool
    ) -> None:
        """Planarity: distances to the best-fit plane (Jacobian by the envelope theorem)."""
        base = 2 * self.n_nodes
        w = self.sqrt_planar
        pts = top[self.quads]
        dist = np.einsum("qki,qi->qk", pts - centroid[:, None], normal)
        acc.res.append(w * dist.ravel())
        if jac:
            r = (acc.row0 + np.arange(dist.size)).reshape(dist.shape)
            coef = np.eye(4) - 0.25  # d dist_k / d p_m = normal (delta_km - 1/4)
            for m in range(4):
                for c in range(3):
                    acc.rows.append(r.ravel())
                    acc.cols.append(np.repeat(base + 3 * self.quads[:, m] + c, 4))
                    acc.vals.append((w * coef[None, :, m] * normal[:, None, c]).ravel())
        acc.row0 += dist.size

    def _surface_rows(
        self, acc: _Rows, top: FloatArray, closest: FloatArray, fn: FloatArray, jac: bool
    ) -> None:
        """Closeness to the target along the closest face's normal."""
        base = 2 * self.n_nodes
        w = self.sqrt_surface
        acc.res.append(w * np.einsum("vi,vi->v", top - closest, fn))
        if jac:
            r = acc.row0 + np.arange(self.n)
            for c in range(3):
                acc.rows.append(r)
                acc.cols.append(base + 3 * np.arange(self.n) + c)
                acc.vals.append(w * fn[:, c])
        acc.row0 += self.n

    def _sample_rows(
        self, acc: _Rows, points: FloatArray, closest: FloatArray, fn: FloatArray, jac: bool
    ) -> None:
        """Closeness of the face samples to the target along the closest face's normal."""
        assert self.samples is not None
        base = 2 * self.n_nodes
        w = self.sqrt_samples
        acc.res.append(w * np.einsum("vi,vi->v", points - closest, fn))
        if jac:
            coo = self.samples.tocoo()
            for c in range(3):
                acc.rows.append(acc.row0 + coo.row)
                acc.cols.append(base + 3 * coo.col + c)
                acc.vals.append(w * coo.data * fn[coo.row, c])
        acc.row0 += len(points)

    def _convex_rows(self, acc: _Rows, top: FloatArray, jac: bool) -> None:
        """With face samples: every quad corner kept convex (``cofit.convex_corner_rows``)."""
        base = 2 * self.n_nodes
        w = self.sqrt_planar * float(np.sqrt(CO_CONVEX_WEIGHT_REL))
        res, vertices, grads = convex_corner_rows(top, self.quads, self.normals0, self.side)
        acc.res.append(w * res)
        if jac:
            r = acc.row0 + np.arange(len(res))
            for j in range(3):
                for c in range(3):
                    acc.rows.append(r)
                    acc.cols.append(base + 3 * vertices[:, j] + c)
                    acc.vals.append(w * grads[:, j, c])
        acc.row0 += len(res)

    def _conical_rows(self, acc: _Rows, stars: VertexStars, top: FloatArray, jac: bool) -> None:
        """Conical: opposite angles at every inner vertex sum equal (scaled by the mean side)."""
        base = 2 * self.n_nodes
        sums, grads = stars.angle_sums(top, jac)
        w = self.sqrt_conical * self.side
        acc.res.append(w * sums)
        if jac:
            assert grads is not None
            r = acc.row0 + np.arange(len(sums))
            members = stars.members
            for j in range(members.shape[1]):
                for c in range(3):
                    acc.rows.append(r)
                    acc.cols.append(base + 3 * members[:, j] + c)
                    acc.vals.append(w * grads[:, j, c])
        acc.row0 += len(sums)

    def _keep_rows(self, acc: _Rows, top: FloatArray, jac: bool) -> None:
        """Pull towards the starting K3D."""
        base = 2 * self.n_nodes
        w = float(np.sqrt(CO_KEEP))
        acc.res.append(w * (top - self.top0).ravel())
        if jac:
            idx = np.arange(3 * self.n)
            acc.rows.append(acc.row0 + idx)
            acc.cols.append(base + idx)
            acc.vals.append(np.full(3 * self.n, w))
        acc.row0 += 3 * self.n

    def _jacobian(self, acc: _Rows) -> sp.csr_matrix:
        """The Jacobian of the gathered triplets in CSR form."""
        if self._pattern is None:
            # The pattern never changes and no row repeats a column: sort the coordinates
            # into CSR order once; every later Jacobian only reorders its values.
            r_all, c_all = np.concatenate(acc.rows), np.concatenate(acc.cols)
            order = np.lexsort((c_all, r_all))
            indptr = np.concatenate([[0], np.cumsum(np.bincount(r_all, minlength=acc.row0))])
            self._pattern = (order, c_all[order].astype(np.int32), indptr.astype(np.int32))
        order, indices, indptr = self._pattern
        return sp.csr_matrix(
            (np.concatenate(acc.vals)[order], indices, indptr), shape=(acc.row0, 2 * self.rows)
        )


class _Rows:
    """Residuals and Jacobian triplets (rows, columns, values) gathered term by term; ``row0``
    is the first row of the next term."""

    def __init__(self) -> None:
        self.res: list[FloatArray] = []
        self.rows: list[IntArray] = []
        self.cols: list[IntArray] = []
        self.vals: list[FloatArray] = []
        self.row0 = 0


def co_optimize_top(
    linkage: Linkage,
    flat: FlatResult,
    top: ArrayLike,
    quads: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    *,
    tiles_3d: ArrayLike | None = None,
    w_surface: float = 0.1,
    stages: tuple[tuple[float, float], ...] | None = None,
    steps_per_stage: int | None = None,
    start_nodes: ArrayLike | None = None,
    hinges: HingeFaces | None = None,
    conical: bool = False,
    conical_weight: float | None = None,
    w_samples: float = 0.0,
) -> CoOptimizedTop:
    """Move K3D and K2D together until every flat tile is congruent to its assembled top face
    (with ``hinges``: to its hinge points).

    A quad linkage of rigid tiles is over-determined in the plane (about four hinge equations
    per tile against three degrees of freedom), so with K3D fixed ``optimize_flat`` stops
    at a least-squares optimum with edge errors of 0.05-0.5 mm.  K3D has freedom to spare: here
    its vertices move too, pulled towards their start, while the K2D sides and diagonals are
    made equal to K3D's and every K3D quad planar, with weights raised stage by stage
    (``stages``); the same hard rows as in ``optimize_flat`` (gap-angle bounds, gap
    orientation) hold throughout.  Overlaps are not modelled here; ``optimize_flat``, run
    again on the new K3D from these nodes, checks and separates them.

    Parameters
    ----------
    linkage : Linkage
    flat : FlatResult
        The layout to start from (``optimize_flat`` on the same K3D).
    top : (n, 3) float, mm
        K3D vertices; quads ``quads`` (tile order of the linkage).
    quads : (T, 4) int
    target_vertices, target_faces : the target surface.
    tiles_3d : (T, 8, 3) float, mm, optional
        T3D, for the bottom-face angle bounds.
    w_surface, w_samples : float
        Closeness to the target (paper eq. 1's ``w_3``), relative to the pull of ``CO_KEEP``,
        of the vertices and of the quads' centres and edge midpoints (0: none).
    stages, steps_per_stage : continuation schedule (default ``CO_STAGES``, ``CO_STEPS``).
    start_nodes : (n_nodes, 2) float, mm, optional
        K2D to start from instead of ``flat.nodes`` (a previous round's nodes).
    hinges : HingeFaces, optional
        Hinge faces of a ``dual`` layout (needs ``tiles_3d``): the K2D nodes are then the hinge
        points, each offset from its K3D top corner by the tile's bottom corner offset in
        ``tiles_3d`` (held during the solve), with ``optimize_flat``'s clearance bounds.
    conical : bool
        With ``hinges`` that put any hinge on the bottom faces, also make K3D conical
        (:class:`VertexStars`, weight ``CO_CONICAL`` relative to planarity), so that the
        bottom corners can be extruded to equal depths under both tiles of each bottom hinge.
    conical_weight : float, optional
        That weight instead of ``CO_CONICAL``.

    Returns
    -------
    CoOptimizedTop
    """
    start = time.perf_counter()
    top0 = np.asarray(top, dtype=np.float64)
    problem, constraints, side = _joint_problem(
        linkage, flat, top0, quads, (target_vertices, target_faces), tiles_3d, w_surface,
        hinges, conical, w_samples,
    )  # fmt: skip
    nodes0 = flat.nodes if start_nodes is None else np.asarray(start_nodes, dtype=np.float64)
    z = problem.pack(nodes0, top0)
    angle_tol = np.radians(FLAT_SOLVER_ANGLE_TOL_DEG)
    steps = 0
    per_stage = CO_STEPS if steps_per_stage is None else steps_per_stage
    for w_planar, w_edge in CO_STAGES if stages is None else stages:
        problem.sqrt_planar = float(np.sqrt(w_planar))
        problem.sqrt_edge = float(np.sqrt(w_edge))
        problem.sqrt_conical = float(
            np.sqrt(w_planar * (CO_CONICAL if conical_weight is None else conical_weight))
        )
        z, used, _ = constrained_least_squares(
            z, problem, constraints, max_steps=per_stage, angle_tol=angle_tol,
            length_tol=angle_tol * side, rho0=CO_RHO_REL * w_edge,
        )  # fmt: skip
        steps += used
    nodes, new_top = problem.unpack(z)
    error = float(np.abs(problem.edge_errors(z)).max(initial=0.0))
    move = float(np.linalg.norm(new_top - top0, axis=1).max(initial=0.0))
    elapsed = time.perf_counter() - start
    logger.info(
        "co-optimization: %d steps, %.2f s, edge error %.3g -> %.3g mm, K3D moved <= %.3g mm",
        steps, elapsed, flat.edge_error_max_mm, error, move,
    )  # fmt: skip
    return CoOptimizedTop(
        top=np.array(new_top),
        nodes=np.array(nodes),
        edge_error_max_mm=error,
        move_max_mm=move,
        steps=steps,
        time_s=elapsed,
    )


def _joint_problem(
    linkage: Linkage,
    flat: FlatResult,
    top0: FloatArray,
    quads: ArrayLike,
    target: tuple[ArrayLike, ArrayLike],
    tiles_3d: ArrayLike | None,
    w_surface: float,
    hinges: HingeFaces | None,
    conical: bool,
    w_samples: float = 0.0,
) -> tuple[_JointTopLeastSquares, list[AngleRows | SeparationRows], float]:
    """The least squares of :func:`co_optimize_top` (its arguments checked), the flat layout's
    hard rows on the tiles' corners (the hinge points of a dual layout), ``CO_ANGLE_MARGIN_DEG``
    inside the gap-angle bounds, and the mean tile side (mm)."""
    q = np.asarray(quads, dtype=np.int64)
    if q.shape != (linkage.n_tiles, 4) or top0.ndim != 2 or top0.shape[1] != 3:
        raise InternalError("co_optimize_top needs (n, 3) K3D vertices and (T, 4) quads")
    shift = None
    if hinges is not None:
        if tiles_3d is None or hinges.bottom.shape != (linkage.n_hinges,):
            raise InternalError("hinges needs one face per hinge and the T3D tiles_3d")
        t3 = np.asarray(tiles_3d, dtype=np.float64)
        shift = hinge_points(linkage, t3, hinges.bottom) - t3[:, :4]
    corners = top0[q] if shift is None else top0[q] + shift
    plane = tile_plane_coordinates(corners)
    theta_min = np.radians(flat.min_gap_angle_deg + CO_ANGLE_MARGIN_DEG)
    side = float(np.mean(flat.edge_targets[:, :4]))
    junctions = gap_junctions(linkage)
    constraints = flat_constraints(
        linkage,
        junctions,
        plane,
        tiles_3d,
        theta_min,
        side,
        True,
        True,
        theta_max=np.radians(90.0 - CO_ANGLE_MARGIN_DEG),
        hinges=hinges,
    )
    problem = _JointTopLeastSquares(
        linkage,
        q,
        top0,
        np.asarray(target[0]),
        np.asarray(target[1]),
        w_surface,
        shift,
        vertex_stars(q) if conical and hinges is not None and hinges.bottom.any() else None,
        w_samples,
    )
    return problem, constraints, side
