"""Constraint groups of the local-global solver (:mod:`drawstring.geometry.solve.solver`).

Each group is vectorized over all its elements: a constant sparse matrix ``A`` (rows x n,
applied identically to every coordinate column) and a batched projection of ``A X`` onto the
group's constraint set.  This module holds the sparse operators the groups share, the batched
small linear algebra (covariances, smallest eigenvectors, plane fits, closest points on
triangles) and the groups themselves: closeness to points and to a surface, edge length, plane,
similarity to a square and the frustum slab.  The solver loop and the exact planarity polish are
in :mod:`drawstring.geometry.solve.solver`, which re-exports every public name here.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence

import igl
import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray

logger = logging.getLogger(__name__)


# --------------------------------------------------------------------------------------------
# Sparse operators shared by the groups
# --------------------------------------------------------------------------------------------


def selection_matrix(indices: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows that pick vertices: ``(A X)[r] = X[indices[r]]``.

    Parameters
    ----------
    indices : (k,) int
    n_vertices : int

    Returns
    -------
    A : (k, n_vertices) sparse
    """
    k = len(indices)
    return sp.csr_matrix(
        (np.ones(k), (np.arange(k), np.asarray(indices, dtype=np.int64))), shape=(k, n_vertices)
    )


def difference_matrix(edges: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows ``(A X)[r] = X[edges[r, 1]] - X[edges[r, 0]]``.

    Parameters
    ----------
    edges : (k, 2) int
    n_vertices : int

    Returns
    -------
    A : (k, n_vertices) sparse
    """
    k = len(edges)
    rows = np.repeat(np.arange(k), 2)
    cols = np.asarray(edges, dtype=np.int64).reshape(-1)
    vals = np.tile([-1.0, 1.0], k)
    return sp.csr_matrix((vals, (rows, cols)), shape=(k, n_vertices))


def centering_matrix(elements: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows that give each element's vertices minus the element's centroid.

    Parameters
    ----------
    elements : (k, s) int
        Vertex indices of ``k`` elements of ``s`` vertices each.
    n_vertices : int

    Returns
    -------
    A : (k * s, n_vertices) sparse
        Row ``e * s + a`` is ``X[elements[e, a]] - mean_b X[elements[e, b]]``.
    """
    elements = np.asarray(elements, dtype=np.int64)
    k, s = elements.shape
    rows = np.repeat(np.arange(k * s), s)
    cols = np.repeat(elements, s, axis=0).reshape(-1)
    block = np.eye(s) - 1.0 / s
    vals = np.tile(block.reshape(-1), k)
    return sp.csr_matrix((vals, (rows, cols)), shape=(k * s, n_vertices))


def cross3(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross products of (..., 3) arrays (cheaper than ``np.cross`` on small batches)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def covariances(points: FloatArray) -> FloatArray:
    """Scatter matrices ``sum_s p p^T`` of many point sets (points already centred).

    Parameters
    ----------
    points : (k, s, dim) float

    Returns
    -------
    scatter : (k, dim, dim) float
    """
    return np.matmul(points.transpose(0, 2, 1), points)


def smallest_eigenvectors(matrices: FloatArray) -> FloatArray:
    """Unit eigenvectors of the smallest eigenvalue of many symmetric matrices.

    3x3 matrices use the closed-form trigonometric eigenvalue and a cross product of two rows
    of ``M - lambda I`` (about 3x faster than batched ``eigh``); matrices where that is ill
    conditioned (two smallest eigenvalues nearly equal) and other sizes fall back to ``eigh``.

    Parameters
    ----------
    matrices : (k, d, d) float, symmetric

    Returns
    -------
    vectors : (k, d) float
    """
    k, d, _ = matrices.shape
    if d != 3 or k == 0:
        return np.asarray(np.linalg.eigh(matrices)[1][:, :, 0])
    return _smallest_eigenvectors_3(
        matrices[:, 0, 0],
        matrices[:, 1, 1],
        matrices[:, 2, 2],
        matrices[:, 0, 1],
        matrices[:, 0, 2],
        matrices[:, 1, 2],
        lambda bad: matrices[bad],
    )


def _smallest_eigenvectors_3(
    a00: FloatArray,
    a11: FloatArray,
    a22: FloatArray,
    a01: FloatArray,
    a02: FloatArray,
    a12: FloatArray,
    matrices_of: Callable[[BoolArray], FloatArray],
) -> FloatArray:
    """:func:`smallest_eigenvectors` of 3x3 symmetric matrices given by their six entries.

    ``matrices_of(mask)`` returns the full ``(j, 3, 3)`` matrices of the rows in ``mask`` (for
    the ``eigh`` fallback of ill-conditioned rows).
    """
    mean = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - mean, a11 - mean, a22 - mean
    spread = np.sqrt((b00**2 + b11**2 + b22**2 + 2.0 * (a01**2 + a02**2 + a12**2)) / 6.0)
    safe = np.where(spread > 0, spread, 1.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    ) / safe**3
    angle = np.arccos(np.clip(0.5 * det, -1.0, 1.0)) / 3.0
    lam = mean + 2.0 * spread * np.cos(angle + 2.0 * np.pi / 3.0)
    s00, s11, s22 = a00 - lam, a11 - lam, a22 - lam
    # cross products of the rows (0, 1), (0, 2), (1, 2) of M - lam I
    crosses = np.empty((3, 3, len(lam)))
    crosses[0] = (a01 * a12 - a02 * s11, a02 * a01 - s00 * a12, s00 * s11 - a01 * a01)
    crosses[1] = (a01 * s22 - a02 * a12, a02 * a02 - s00 * s22, s00 * a12 - a01 * a02)
    crosses[2] = (s11 * s22 - a12 * a12, a12 * a02 - a01 * s22, a01 * a12 - s11 * a02)
    norms2 = np.einsum("cik,cik->ck", crosses, crosses)
    best = np.argmax(norms2, axis=0)
    rows = np.arange(len(lam))
    best_norm2 = norms2[best, rows]
    out = crosses[best, :, rows] / np.sqrt(np.where(best_norm2 > 0, best_norm2, 1.0))[:, None]
    # well conditioned when |cross| ~ (gap between the two larger eigenvalues and lam)^2 is large
    bad = best_norm2 <= (1e-6 * spread**2) ** 2
    if np.any(bad):
        out[bad] = np.linalg.eigh(matrices_of(bad))[1][:, :, 0]
    return np.asarray(out)


class _NormalMemo:
    """The last batch of centred point sets given to :func:`centred_normals` and its result.

    In one local step of the K3D solve, :class:`Plane` and the oriented
    :class:`SimilarityToSquare` receive bitwise identical rows (both groups centre the same
    quads), so the second one reuses the first one's eigenvectors instead of recomputing them.
    """

    points: FloatArray | None = None
    normals: FloatArray | None = None
    hits = 0


def centred_normals(points: FloatArray) -> FloatArray:
    """Least-variance unit directions of many centred point sets (sign arbitrary).

    The same as ``smallest_eigenvectors(covariances(points))``; a repeated call with an equal
    array returns the previous result (read-only) without recomputing it.

    Parameters
    ----------
    points : (k, s, dim) float, each set centred on its centroid

    Returns
    -------
    normals : (k, dim) float, read-only
    """
    memo_points = _NormalMemo.points
    if (
        memo_points is not None
        and _NormalMemo.normals is not None
        and memo_points.shape == points.shape
        and np.array_equal(memo_points, points)
    ):
        _NormalMemo.hits += 1
        return _NormalMemo.normals
    if points.ndim == 3 and points.shape[2] == 3 and len(points):
        x, y, z = points[:, :, 0], points[:, :, 1], points[:, :, 2]
        normals = _smallest_eigenvectors_3(
            np.einsum("ks,ks->k", x, x),
            np.einsum("ks,ks->k", y, y),
            np.einsum("ks,ks->k", z, z),
            np.einsum("ks,ks->k", x, y),
            np.einsum("ks,ks->k", x, z),
            np.einsum("ks,ks->k", y, z),
            lambda bad: covariances(points[bad]),
        )
    else:
        normals = smallest_eigenvectors(covariances(points))
    normals.flags.writeable = False
    _NormalMemo.points = np.array(points, dtype=np.float64)
    _NormalMemo.normals = normals
    return normals


def plane_fit(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares planes (hyperplanes in 2D: lines) of many point sets at once.

    Parameters
    ----------
    points : (k, s, dim) float
        ``k`` sets of ``s`` points.

    Returns
    -------
    centroids : (k, dim) float
    normals : (k, dim) float
        Unit normals (direction of least variance; sign arbitrary).
    """
    centroids = points.mean(axis=1)
    centred = points - centroids[:, None, :]
    return centroids, smallest_eigenvectors(covariances(centred))


# --------------------------------------------------------------------------------------------
# Constraint groups
# --------------------------------------------------------------------------------------------


class ConstraintGroup(ABC):
    """A vectorized set of constraints with one weight.

    Its energy is ``weight * ||A X - P(X)||_F^2`` where ``A = matrix(n)`` is constant and
    ``P = project`` returns the closest point of the constraint set for every row block.

    Parameters
    ----------
    name : str
        Unique within a solver; keys of the energy dictionaries.
    weight : float
        Non-negative; zero removes the group from the system.
    """

    def __init__(self, name: str, weight: float) -> None:
        if not np.isfinite(weight) or weight < 0:
            raise InputError(f"weight of group {name!r} is {weight}; use a finite value >= 0")
        self.name = name
        self.weight = float(weight)

    @abstractmethod
    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        """The constant operator ``A : (rows, n_vertices)``."""

    @abstractmethod
    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        """Closest feasible targets for ``ax = A @ x``.

        Parameters
        ----------
        ax : (rows, dim) float
            The group's rows of ``A X``.
        x : (n, dim) float
            All current positions (for groups that need more than ``ax``).

        Returns
        -------
        targets : (rows, dim) float
        """

    def project_warm(self, ax: FloatArray, x: FloatArray, previous: FloatArray) -> FloatArray:
        """Targets for ``ax`` inside a solve, given this group's targets at the last accepted
        iterate (``previous``, same shape as ``ax``).

        The default is the exact :meth:`project`. A group whose projection is cheaper when
        approximate (e.g. :class:`ClosenessToSurface` with ``requery_rel > 0``) overrides this
        and must return targets, each a point of its constraint set, no farther from ``ax`` than
        ``previous`` is: then the local step never raises the energy and the solver's
        monotonicity (and Anderson's safeguard) still hold, for the energy evaluated with the
        targets actually used. Called only by :meth:`LocalGlobalSolver.solve` after its first
        local step; :meth:`LocalGlobalSolver.energies` and the first step use :meth:`project`.
        """
        return self.project(ax, x)


class ClosenessToPoints(ConstraintGroup):
    """Keep vertices near target points (anchors, lift targets).

    Parameters
    ----------
    indices : (k,) int
    targets : (k, dim) float, mm
        Can be changed later with :meth:`set_targets` without refactoring.
    """

    def __init__(
        self,
        indices: ArrayLike,
        targets: ArrayLike,
        weight: float = 1.0,
        name: str = "closeness",
    ) -> None:
        super().__init__(name, weight)
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.targets = np.zeros((0, 0))
        self.set_targets(targets)

    def set_targets(self, targets: ArrayLike) -> None:
        """Move the targets; the matrix does not change.

        Parameters
        ----------
        targets : (k, dim) float, mm
        """
        arr = np.asarray(targets, dtype=np.float64)
        if arr.ndim != 2 or arr.shape[0] != len(self.indices):
            raise InputError(
                f"group {self.name!r}: targets have shape {arr.shape}; "
                f"give one row per index ({len(self.indices)})"
            )
        self.targets = arr.copy()

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return selection_matrix(self.indices, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        return self.targets


class ClosenessToPlanes(ConstraintGroup):
    """Keep vertices near fixed planes, one plane per row (a vertex may have several rows).

    The projection is the exact closest point ``x - (n . x - level) n``; the group's energy is
    quadratic, so the solver converges on it as on :class:`ClosenessToPoints`.

    Parameters
    ----------
    indices : (k,) int
    normals : (k, dim) float, unit
    levels : (k,) float, mm
        Row ``r`` pulls vertex ``indices[r]`` onto ``{x : normals[r] . x = levels[r]}``.
    """

    def __init__(
        self,
        indices: ArrayLike,
        normals: ArrayLike,
        levels: ArrayLike,
        weight: float = 1.0,
        name: str = "planes",
    ) -> None:
        super().__init__(name, weight)
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.normals = np.asarray(normals, dtype=np.float64)
        self.levels = np.asarray(levels, dtype=np.float64).reshape(-1)
        k = len(self.indices)
        if self.normals.ndim != 2 or self.normals.shape[0] != k or self.levels.shape != (k,):
            raise InputError(
                f"group {self.name!r}: give one normal and one level per index ({k}), got "
                f"normals {self.normals.shape} and levels {self.levels.shape}"
            )
        norms = np.linalg.norm(self.normals, axis=1)
        if not (np.all(np.isfinite(self.levels)) and np.allclose(norms, 1.0, atol=1e-9)):
            raise InputError(f"group {self.name!r}: normals must be unit and levels finite")

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return selection_matrix(self.indices, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        height = np.einsum("ki,ki->k", ax, self.normals) - self.levels
        return ax - height[:, None] * self.normals


def closest_points_on_triangles(
    points: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray
) -> tuple[FloatArray, IntArray]:
    """Closest point of each triangle ``(a, b, c)`` to each point, and the feature it lies on.

    Ericson, "Real-Time Collision Detection" (2005), 5.1.5, batched.

    Parameters
    ----------
    points, a, b, c : (k, 3) float

    Returns
    -------
    closest : (k, 3) float
    feature : (k,) int
        0, 1, 2: corner ``a``, ``b``, ``c``; 3, 4, 5: edge ``ab``, ``ac``, ``bc`` (inside it);
        6: the interior of the triangle.
    """
    ab, ac = b - a, c - a
    ap, bp, cp = points - a, points - b, points - c
    d1 = np.einsum("ki,ki->k", ab, ap)
    d2 = np.einsum("ki,ki->k", ac, ap)
    d3 = np.einsum("ki,ki->k", ab, bp)
    d4 = np.einsum("ki,ki->k", ac, bp)
    d5 = np.einsum("ki,ki->k", ab, cp)
    d6 = np.einsum("ki,ki->k", ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    feature = np.select(
        [
            (d1 <= 0) & (d2 <= 0),
            (d3 >= 0) & (d4 <= d3),
            (d6 >= 0) & (d5 <= d6),
            (vc <= 0) & (d1 >= 0) & (d3 <= 0),
            (vb <= 0) & (d2 >= 0) & (d6 <= 0),
            (va <= 0) & (d4 >= d3) & (d5 >= d6),
        ],
        [0, 1, 2, 3, 4, 5],
        6,
    )
    # barycentric weights (of b and c) of the closest point, feature by feature
    with np.errstate(divide="ignore", invalid="ignore"):
        edge_ab = d1 / (d1 - d3)
        edge_ac = d2 / (d2 - d6)
        edge_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        total = va + vb + vc
        inner_v, inner_w = vb / total, vc / total
    zero = np.zeros(len(points))
    one = np.ones(len(points))
    v = np.choose(feature, [zero, one, zero, edge_ab, zero, 1.0 - edge_bc, inner_v])
    w = np.choose(feature, [zero, zero, one, zero, edge_ac, edge_bc, inner_w])
    closest = a + v[:, None] * ab + w[:, None] * ac
    return closest, np.asarray(feature, dtype=np.int64)


class ClosenessToSurface(ConstraintGroup):
    """Pull vertices to their closest points on a triangle mesh (re-queried every iteration).

    The AABB tree of the surface is built once here.

    A query is several times slower for a point several triangle sizes off the surface than for
    one on it, and the points of a converging solve move little per iteration. With
    ``requery_rel > 0`` the solver's iterations (:meth:`project_warm`) query the tree only for
    points that moved more than ``requery_rel`` times their distance to the surface since their
    last query, or whose closest point on the triangle found then has moved to another feature
    of it (from its interior to an edge, from an edge to a corner, ...); every other point gets
    the closest point of that triangle. That target is off the true closest point of the mesh
    by at most ``2 requery_rel / (1 - requery_rel)`` of the point's distance (and is the true
    one unless another part of the mesh came closer by moving less than that), and it is never
    farther from the point than the previous target, which keeps the solve monotone. The first
    step of a solve and :meth:`LocalGlobalSolver.energies` always query every point.

    Parameters
    ----------
    indices : (k,) int
    surface_vertices : (p, 3) float, mm
    surface_faces : (f, 3) int
    requery_rel : float
        In ``[0, 0.5)``; 0 (default) queries every point in every iteration.
    """

    def __init__(
        self,
        indices: ArrayLike,
        surface_vertices: ArrayLike,
        surface_faces: ArrayLike,
        weight: float = 1.0,
        name: str = "surface",
        requery_rel: float = 0.0,
    ) -> None:
        super().__init__(name, weight)
        self.indices = np.asarray(indices, dtype=np.int64).reshape(-1)
        self.surface_vertices = np.ascontiguousarray(surface_vertices, dtype=np.float64)
        self.surface_faces = np.ascontiguousarray(surface_faces, dtype=np.int64)
        if self.surface_vertices.ndim != 2 or self.surface_vertices.shape[1] != 3:
            raise InputError("surface vertices must have shape (p, 3); pass a 3D triangle mesh")
        if self.surface_faces.ndim != 2 or self.surface_faces.shape[1] != 3:
            raise InputError("surface faces must have shape (f, 3); triangulate the target mesh")
        if not 0.0 <= requery_rel < 0.5:
            raise InputError(f"requery_rel is {requery_rel}; use a value in [0, 0.5)")
        self.requery_rel = float(requery_rel)
        self.tree = igl.AABB()
        self.tree.init(self.surface_vertices, self.surface_faces)
        #: Points queried through the tree so far (a statistic of the lazy re-query).
        self.points_queried = 0
        # lazy re-query state, per row: position at the last query, its closest triangle, the
        # feature of that triangle the closest point lay on, and how far it may move
        self._anchor = np.zeros((0, 3))
        self._face = np.zeros(0, dtype=np.int64)
        self._feature = np.zeros(0, dtype=np.int64)
        self._reach2 = np.zeros(0)

    def _query(self, points: FloatArray) -> tuple[FloatArray, IntArray, FloatArray]:
        sqd, face, closest = self.tree.squared_distance(
            self.surface_vertices, self.surface_faces, np.ascontiguousarray(points)
        )
        self.points_queried += len(points)
        return (
            np.asarray(sqd, dtype=np.float64),
            np.asarray(face, dtype=np.int64),
            np.asarray(closest, dtype=np.float64),
        )

    def _triangles(self, faces: IntArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        tri = self.surface_vertices[self.surface_faces[faces]]
        return tri[:, 0], tri[:, 1], tri[:, 2]

    def _remember(self, rows: IntArray | slice, points: FloatArray) -> FloatArray:
        """Query ``points`` (the rows ``rows``) and store them as the anchors of those rows."""
        sqd, face, closest = self._query(points)
        self._anchor[rows] = points
        self._face[rows] = face
        self._feature[rows] = closest_points_on_triangles(points, *self._triangles(face))[1]
        self._reach2[rows] = self.requery_rel**2 * sqd
        return closest

    def closest_points(self, points: FloatArray) -> FloatArray:
        """Closest points on the surface.

        Parameters
        ----------
        points : (k, 3) float, mm

        Returns
        -------
        closest : (k, 3) float, mm
        """
        return self._query(points)[2]

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return selection_matrix(self.indices, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        if self.requery_rel <= 0:
            return self._query(ax)[2]
        k = len(ax)
        self._anchor = np.zeros((k, 3))
        self._face = np.zeros(k, dtype=np.int64)
        self._feature = np.zeros(k, dtype=np.int64)
        self._reach2 = np.zeros(k)
        return self._remember(slice(None), np.asarray(ax, dtype=np.float64))

    def project_warm(self, ax: FloatArray, x: FloatArray, previous: FloatArray) -> FloatArray:
        if self.requery_rel <= 0 or self._anchor.shape != ax.shape:
            return self.project(ax, x)
        moved2 = np.einsum("ki,ki->k", ax - self._anchor, ax - self._anchor)
        near = np.flatnonzero(moved2 <= self._reach2)
        out = np.empty_like(ax)
        keep = np.zeros(len(ax), dtype=bool)
        if near.size:
            closest, feature = closest_points_on_triangles(
                ax[near], *self._triangles(self._face[near])
            )
            same = (feature == self._feature[near]) & np.all(np.isfinite(closest), axis=1)
            out[near[same]] = closest[same]
            keep[near[same]] = True
        fresh = np.flatnonzero(~keep)
        if fresh.size:
            out[fresh] = self._remember(fresh, ax[fresh])
        # the kept targets are exact for their triangle; never let one be worse than the last
        kept_rows = np.flatnonzero(keep)
        if kept_rows.size:
            to_new = ax[kept_rows] - out[kept_rows]
            to_old = ax[kept_rows] - previous[kept_rows]
            worse = np.einsum("ki,ki->k", to_new, to_new) > np.einsum("ki,ki->k", to_old, to_old)
            out[kept_rows[worse]] = previous[kept_rows[worse]]
        return out


class EdgeLength(ConstraintGroup):
    """Edge vectors projected to their target lengths, keeping their directions (paper eq. 3–4).

    Parameters
    ----------
    edges : (k, 2) int
    lengths : (k,) float, mm
        Per-edge targets; change them with :meth:`set_lengths` (no refactor).
    """

    def __init__(
        self,
        edges: ArrayLike,
        lengths: ArrayLike,
        weight: float = 1.0,
        name: str = "edge_length",
    ) -> None:
        super().__init__(name, weight)
        self.edges = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        self.lengths = np.zeros(0)
        self.set_lengths(lengths)

    def set_lengths(self, lengths: ArrayLike) -> None:
        """Replace the target lengths.

        Parameters
        ----------
        lengths : (k,) float, mm
        """
        arr = np.asarray(lengths, dtype=np.float64).reshape(-1)
        if arr.shape[0] != len(self.edges) or np.any(arr < 0) or not np.all(np.isfinite(arr)):
            raise InputError(
                f"group {self.name!r}: need {len(self.edges)} finite non-negative target lengths"
            )
        self.lengths = arr.copy()

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return difference_matrix(self.edges, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        norms = np.linalg.norm(ax, axis=1)
        direction = np.zeros_like(ax)
        ok = norms > 0
        direction[ok] = ax[ok] / norms[ok, None]
        direction[~ok, 0] = 1.0  # a collapsed edge gets an arbitrary direction
        return direction * self.lengths[:, None]


class Plane(ConstraintGroup):
    """Each face's vertices projected onto the face's least-squares plane (paper eq. 2).

    ``A`` centres each face (vertex minus face centroid), so the group does not pin translation.
    All faces are projected with one batched ``eigh`` of the ``(dim, dim)`` covariances.

    Parameters
    ----------
    faces : (k, s) int or sequence of k index arrays of one size s >= 3
    """

    def __init__(
        self,
        faces: ArrayLike | Sequence[ArrayLike],
        weight: float = 1.0,
        name: str = "planarity",
    ) -> None:
        super().__init__(name, weight)
        arr = np.asarray(faces, dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] < 3:
            raise InputError("Plane faces must be (k, s) with one size s >= 3; split by size")
        self.faces = arr

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(self.faces, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        k, s = self.faces.shape
        pts = ax.reshape(k, s, -1)
        normal = centred_normals(pts)
        height = np.einsum("ksi,ki->ks", pts, normal)
        return (pts - height[:, :, None] * normal[:, None, :]).reshape(ax.shape)


def _square_template(dim: int) -> FloatArray:
    """Corners of a centred square of side 2, counter-clockwise, padded to ``dim`` columns."""
    template = np.zeros((4, dim))
    template[:, :2] = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]
    return template


def _closest_squares_planar_template(pts: FloatArray) -> FloatArray:
    """Closed-form batched Umeyama fit of a square to centred quads in 2D or 3D.

    With the template ``T`` in the first two coordinates, ``Sigma = Q^T T`` has two non-zero
    columns ``c1, c2``; the optimal rotated template axes are the orthonormal polar factor
    ``[u1 u2] = [c1 c2] S^(-1/2)`` with ``S = [c1 c2]^T [c1 c2]`` (2x2, closed-form square root),
    which in 3D can always be completed to a proper rotation. In 2D the rotation angle is
    ``atan2(c1_y - c2_x, c1_x + c2_y)`` (no reflection). Scale is ``trace(S^(1/2)) / |T|^2``.
    Degenerate quads (collapsed to a segment or point) fall back to the SVD route.

    Parameters
    ----------
    pts : (k, 4, dim) float, centred quads, dim in {2, 3}

    Returns
    -------
    squares : (k, 4, dim) float
    """
    k, _, dim = pts.shape
    tx = np.array([-1.0, 1.0, 1.0, -1.0])
    ty = np.array([-1.0, -1.0, 1.0, 1.0])
    norm_t = 8.0
    c1 = np.einsum("ksi,s->ki", pts, tx)
    c2 = np.einsum("ksi,s->ki", pts, ty)
    if dim == 2:
        a = c1[:, 0] + c2[:, 1]
        b = c1[:, 1] - c2[:, 0]
        r = np.hypot(a, b)
        cos = np.where(r > 0, a / np.where(r > 0, r, 1.0), 1.0)
        sin = np.where(r > 0, b / np.where(r > 0, r, 1.0), 0.0)
        scale = r / norm_t
        u1 = np.stack([cos, sin], axis=1) * scale[:, None]
        u2 = np.stack([-sin, cos], axis=1) * scale[:, None]
    else:
        s11 = np.einsum("ki,ki->k", c1, c1)
        s12 = np.einsum("ki,ki->k", c1, c2)
        s22 = np.einsum("ki,ki->k", c2, c2)
        det = s11 * s22 - s12 * s12
        root_det = np.sqrt(np.maximum(det, 0.0))
        trace_root = np.sqrt(np.maximum(s11 + s22 + 2.0 * root_det, 0.0))  # trace of S^(1/2)
        ok = root_det > 1e-12 * np.maximum(s11 + s22, 1e-300)
        # S^(1/2) = (S + sqrt(det) I) / trace_root ; its inverse in closed form (2x2)
        safe_tr = np.where(ok, trace_root, 1.0)
        r11 = (s11 + root_det) / safe_tr
        r22 = (s22 + root_det) / safe_tr
        r12 = s12 / safe_tr
        root_det2 = r11 * r22 - r12 * r12
        inv_det = np.where(ok, 1.0 / np.where(ok, root_det2, 1.0), 0.0)
        i11, i22, i12 = r22 * inv_det, r11 * inv_det, -r12 * inv_det
        scale = trace_root / norm_t
        u1 = (c1 * i11[:, None] + c2 * i12[:, None]) * scale[:, None]
        u2 = (c1 * i12[:, None] + c2 * i22[:, None]) * scale[:, None]
        if not np.all(ok):
            bad = ~ok
            fallback = _closest_squares_svd(pts[bad])
            out = tx[None, :, None] * u1[:, None, :] + ty[None, :, None] * u2[:, None, :]
            out[bad] = fallback
            return np.asarray(out)
    return np.asarray(tx[None, :, None] * u1[:, None, :] + ty[None, :, None] * u2[:, None, :])


def _closest_squares_svd(pts: FloatArray) -> FloatArray:
    """Batched Umeyama closest square through an SVD (any dimension).

    Parameters
    ----------
    pts : (k, 4, dim) float, centred quads

    Returns
    -------
    squares : (k, 4, dim) float
    """
    dim = pts.shape[2]
    template = _square_template(dim)
    cross = np.einsum("ksi,sj->kij", pts, template)  # Sigma = Q^T T
    u, sing, vt = np.linalg.svd(cross)
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sign[sign == 0] = 1.0
    u[:, :, -1] *= sign[:, None]
    rot = u @ vt
    sing[:, -1] *= sign
    scale = sing.sum(axis=1) / np.sum(template * template)
    return np.asarray(scale[:, None, None] * np.einsum("sj,kij->ksi", template, rot))


class SimilarityToSquare(ConstraintGroup):
    """Each quad projected onto the closest similarity transform of a square.

    Without ``reference_normals`` (and always in 2D): batched Umeyama (1991) closest similarity
    (rotation with ``det R = +1``, uniform scale) of a square template to the centred quad, the
    exact closest square. In 3D a rotation can turn the square over, so a quad that folded over
    still counts as a perfect square.

    With ``reference_normals`` (3D): the square lies in the quad's best-fit plane, whose normal
    is oriented to agree with the quad's reference normal, and runs counter-clockwise about it
    (no reflection within the plane). A quad that turned over relative to its reference then
    projects onto a far-away square, which keeps tiles from folding over; the projection is the
    closest square in that oriented plane (for a planar quad, the closest oriented square).

    Parameters
    ----------
    quads : (k, 4) int
        Corners in cyclic order.
    reference_normals : (k, 3) float, optional
        Outward direction of each quad (e.g. its initial normal).
    """

    def __init__(
        self,
        quads: ArrayLike,
        weight: float = 1.0,
        name: str = "square_shape",
        reference_normals: ArrayLike | None = None,
    ) -> None:
        super().__init__(name, weight)
        arr = np.asarray(quads, dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 4:
            raise InputError("SimilarityToSquare needs quads of shape (k, 4)")
        self.quads = arr
        self.reference_normals: FloatArray | None = None
        if reference_normals is not None:
            ref = np.asarray(reference_normals, dtype=np.float64)
            if ref.shape != (len(arr), 3):
                raise InputError("reference_normals must have shape (k, 3), one per quad")
            self.reference_normals = ref

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(self.quads, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        dim = ax.shape[1]
        pts = ax.reshape(-1, 4, dim)
        if dim == 3 and self.reference_normals is not None:
            return _closest_oriented_squares(pts, self.reference_normals).reshape(ax.shape)
        if dim in (2, 3):
            return _closest_squares_planar_template(pts).reshape(ax.shape)
        return _closest_squares_svd(pts).reshape(ax.shape)


def _closest_oriented_squares(pts: FloatArray, reference: FloatArray) -> FloatArray:
    """Closest counter-clockwise squares in each quad's best-fit plane, oriented by ``reference``.

    In an in-plane frame ``(e1, e2, n)`` the 2D Umeyama fit (see
    :func:`_closest_squares_planar_template`) puts the square's first axis along ``(a, b)``
    with ``a = c1.e1 + c2.e2`` and ``b = c1.e2 - c2.e1`` (``c1, c2`` the template-weighted sums
    of the corners) and scales it by ``|(a, b)| / 8``; that axis is the in-plane vector
    ``q = c1 - (c1.n) n - n x c2``, so the square is ``tx q / 8 + ty (n x q) / 8`` without any
    frame.

    Parameters
    ----------
    pts : (k, 4, 3) float, centred quads
    reference : (k, 3) float

    Returns
    -------
    squares : (k, 4, 3) float
    """
    normal = centred_normals(pts)
    n = normal * np.where(np.einsum("ki,ki->k", normal, reference) < 0, -1.0, 1.0)[:, None]
    c1 = pts[:, 1] + pts[:, 2] - pts[:, 0] - pts[:, 3]  # template x: -1, 1, 1, -1
    c2 = pts[:, 2] + pts[:, 3] - pts[:, 0] - pts[:, 1]  # template y: -1, -1, 1, 1
    u1 = 0.125 * (c1 - np.einsum("ki,ki->k", c1, n)[:, None] * n - cross3(n, c2))
    u2 = cross3(n, u1)
    out = np.empty_like(pts)
    out[:, 0] = -u1 - u2
    out[:, 1] = u1 - u2
    out[:, 2] = u1 + u2
    out[:, 3] = u2 - u1
    return out


def _unit_normal_with_offset(matrix: FloatArray, linear: FloatArray) -> FloatArray:
    """Minimize ``n^T M n - 2 g^T n`` over unit vectors ``n``, for many (M, g) at once.

    The minimizer is ``n = (M - lam I)^{-1} g`` with ``lam <= lambda_min(M)`` and ``|n| = 1``
    (the trust-region boundary problem); ``lam`` is found by Newton's method on
    ``1 / |n(lam)| - 1`` in the eigenbasis of ``M``, which converges monotonically from the left.

    Parameters
    ----------
    matrix : (k, d, d) float, symmetric
    linear : (k, d) float

    Returns
    -------
    n : (k, d) float, unit
    """
    mu, vecs = np.linalg.eigh(matrix)
    gam = np.einsum("kji,kj->ki", vecs, linear)
    gnorm = np.linalg.norm(gam, axis=1)
    hard = np.abs(gam[:, 0]) <= 1e-12 * np.maximum(gnorm, 1e-300)
    # shift t = mu_0 - lam > 0; Newton on phi(t) = 1/|p(t)| - 1 with p_i = gam_i / (mu_i - mu_0 + t)
    # from the left of the root: |p(t)| >= |gam_i| / (gap_i + t) = 1 at t = |gam_i| - gap_i, so
    # the largest of those (and |gam_0|) is a lower bound; for a slab the offset runs along the
    # largest eigenvector and that bound is within a few Newton steps of the root
    gap = mu - mu[:, :1]
    t = np.where(hard, 1.0, np.maximum(np.abs(gam[:, 0]), np.max(np.abs(gam) - gap, axis=1)))
    round_off = 4.0 * np.finfo(np.float64).eps
    for _ in range(60):
        denom = gap + t[:, None]
        p = gam / denom
        pn = np.linalg.norm(p, axis=1)
        dpn = -np.sum(gam * gam / denom**3, axis=1) / pn  # d|p|/dt
        phi = 1.0 / pn - 1.0
        dphi = -dpn / pn**2
        step = phi / dphi
        t_new = np.maximum(t - step, 0.5 * t)
        # converged: no more progress from the left, or |p| = 1 to round-off (where the step
        # would only flip by an ulp)
        done = (t_new - t <= 1e-15 * np.maximum(t, 1e-300)) | (np.abs(phi) <= round_off)
        t = t_new
        if np.all(done | hard):
            break
    p = gam / (gap + t[:, None])
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    if np.any(hard):
        p[hard] = 0.0
        p[hard, 0] = 1.0
    return np.einsum("kij,kj->ki", vecs, p)


class Slab(ConstraintGroup):
    """Tile top and bottom on two parallel planes a given distance apart (frustum extrusion).

    Each tile's top vertices are projected onto one plane and its bottom vertices onto the
    parallel plane ``thickness`` below it (along the common normal, which points from bottom to
    top). The common normal solves the exact closest-point problem, a unit-sphere quadratic
    ``n^T (C + s/2 d d^T) n - s h d^T n`` (``C`` the summed covariances of top and bottom, ``d``
    the top-minus-bottom centroid offset, ``s`` the vertices per face), batched over all tiles.

    Parameters
    ----------
    top : (k, s) int
        Top face vertex indices of each tile.
    bottom : (k, s) int
        Bottom face vertex indices, ``bottom[t, a]`` under ``top[t, a]``.
    thickness : (k,) float or float, mm
    """

    def __init__(
        self,
        top: ArrayLike,
        bottom: ArrayLike,
        thickness: ArrayLike,
        weight: float = 1.0,
        name: str = "slab",
    ) -> None:
        super().__init__(name, weight)
        top_arr = np.asarray(top, dtype=np.int64)
        bottom_arr = np.asarray(bottom, dtype=np.int64)
        if top_arr.ndim != 2 or top_arr.shape != bottom_arr.shape or top_arr.shape[1] < 3:
            raise InputError("Slab top and bottom must both be (k, s) index arrays with s >= 3")
        self.top = top_arr
        self.bottom = bottom_arr
        thick = np.broadcast_to(np.asarray(thickness, dtype=np.float64), (len(top_arr),)).copy()
        if np.any(thick < 0) or not np.all(np.isfinite(thick)):
            raise InputError("Slab thickness must be finite and >= 0")
        self.thickness = thick

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(np.hstack([self.top, self.bottom]), n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        k, s = self.top.shape
        dim = ax.shape[1]
        pts = ax.reshape(k, 2 * s, dim)
        top, bottom = pts[:, :s], pts[:, s:]
        top_c, bottom_c = top.mean(axis=1), bottom.mean(axis=1)
        dt, db = top - top_c[:, None], bottom - bottom_c[:, None]
        cov = np.einsum("ksi,ksj->kij", dt, dt) + np.einsum("ksi,ksj->kij", db, db)
        offset = top_c - bottom_c
        half = 0.5 * s
        quad = cov + half * np.einsum("ki,kj->kij", offset, offset)
        lin = half * self.thickness[:, None] * offset
        normal = _unit_normal_with_offset(quad, lin)
        a = np.einsum("ki,ki->k", normal, top_c)
        b = np.einsum("ki,ki->k", normal, bottom_c)
        level_top = 0.5 * (a + b + self.thickness)
        level_bottom = level_top - self.thickness
        h_top = np.einsum("ksi,ki->ks", top, normal) - level_top[:, None]
        h_bottom = np.einsum("ksi,ki->ks", bottom, normal) - level_bottom[:, None]
        out = np.empty_like(pts)
        out[:, :s] = top - h_top[:, :, None] * normal[:, None, :]
        out[:, s:] = bottom - h_bottom[:, :, None] * normal[:, None, :]
        return out.reshape(ax.shape)
