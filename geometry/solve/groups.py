"""Constraint groups of the local-global solver (:mod:`drawstring.geometry.solve.solver`).

Each group is vectorized over all its elements: a constant sparse matrix ``A`` (rows x n,
applied identically to every coordinate column) and a batched projection of ``A X`` onto the
group's constraint set.  This module holds the base class :class:`ConstraintGroup` and the
groups that pull vertices to given places or sizes: closeness to points, to planes and to a
surface (of the vertices, or of points inside the quads), edge length and planarity.  The
groups that fit a shape (similarity to a square, the frustum slab) are in
:mod:`drawstring.geometry.solve.shape_groups`; the operators and batched linear algebra they
share are in :mod:`drawstring.geometry.solve.linalg`.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Sequence

import igl
import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.linalg import (
    centering_matrix,
    centred_normals,
    closest_points_on_triangles,
    difference_matrix,
    selection_matrix,
)


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
            raise InternalError(f"weight of group {name!r} is {weight}; use a finite value >= 0")
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
            raise InternalError(
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
            raise InternalError(
                f"group {self.name!r}: give one normal and one level per index ({k}), got "
                f"normals {self.normals.shape} and levels {self.levels.shape}"
            )
        norms = np.linalg.norm(self.normals, axis=1)
        if not (np.all(np.isfinite(self.levels)) and np.allclose(norms, 1.0, atol=1e-9)):
            raise InternalError(f"group {self.name!r}: normals must be unit and levels finite")

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return selection_matrix(self.indices, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        height = np.einsum("ki,ki->k", ax, self.normals) - self.levels
        return ax - height[:, None] * self.normals


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
            raise InternalError("surface vertices must have shape (p, 3); pass a 3D triangle mesh")
        if self.surface_faces.ndim != 2 or self.surface_faces.shape[1] != 3:
            raise InternalError("surface faces must have shape (f, 3); triangulate the target mesh")
        if not 0.0 <= requery_rel < 0.5:
            raise InternalError(f"requery_rel is {requery_rel}; use a value in [0, 0.5)")
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


class FaceSamplesToSurface(ClosenessToSurface):
    """Pull points inside the quads (each quad's centre and every edge's midpoint, linear in
    the vertices) to their closest points on a triangle mesh.

    :class:`ClosenessToSurface` on the vertices alone leaves a planar quad's interior off a
    curved target by its sagitta: the 200-tile dome with every corner on the surface has its
    faces' points 2 % of a tile side off on average; with these points pulled too the quads
    straddle the surface, about half as far off.  Closest points are found as for
    :class:`ClosenessToSurface` (lazy re-query with ``requery_rel``).

    Parameters
    ----------
    quads : (m, 4) int
    edges : (e, 2) int
        The quad mesh's unique edges.
    surface_vertices, surface_faces, weight, name, requery_rel : as :class:`ClosenessToSurface`
    """

    def __init__(
        self,
        quads: ArrayLike,
        edges: ArrayLike,
        surface_vertices: ArrayLike,
        surface_faces: ArrayLike,
        weight: float = 1.0,
        name: str = "face_samples",
        requery_rel: float = 0.0,
    ) -> None:
        q = np.asarray(quads, dtype=np.int64).reshape(-1, 4)
        e = np.asarray(edges, dtype=np.int64).reshape(-1, 2)
        super().__init__(
            np.arange(len(q) + len(e)), surface_vertices, surface_faces, weight, name, requery_rel
        )
        self.quads, self.edges = q, e

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        m, k = len(self.quads), len(self.edges)
        rows = np.concatenate([np.repeat(np.arange(m), 4), m + np.repeat(np.arange(k), 2)])
        cols = np.concatenate([self.quads.ravel(), self.edges.ravel()])
        vals = np.concatenate([np.full(4 * m, 0.25), np.full(2 * k, 0.5)])
        return sp.csr_matrix((vals, (rows, cols)), shape=(m + k, n_vertices))


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
            raise InternalError(
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
            raise InternalError("Plane faces must be (k, s) with one size s >= 3; split by size")
        self.faces = arr

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(self.faces, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        k, s = self.faces.shape
        pts = ax.reshape(k, s, -1)
        normal = centred_normals(pts)
        height = np.einsum("ksi,ki->ks", pts, normal)
        return (pts - height[:, :, None] * normal[:, None, :]).reshape(ax.shape)
