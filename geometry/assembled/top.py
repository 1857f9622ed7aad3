"""K3D: the top faces of the assembled shape, planar and near-square quads near the target
(paper section 4.2, equation 1).

:func:`optimize_top` runs one local-global solve of ``w_planar E_planar + w_square (E_length +
E_shape) + w_surface E_surface`` over the lifted quad mesh, with edge-length targets from the
mesh it starts from; :class:`ConvexCorners` keeps every quad convex when the plain solve leaves
a dart; :func:`eq1_energy` measures any configuration on that energy.  The rounds and the
convexity re-solve are driven by :func:`~drawstring.geometry.assembled.shape.optimize_assembled`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.assembled.frustums import (
    quad_mesh_edges,
    quad_vector_areas,
    square_edge_targets,
)
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.groups import (
    ClosenessToSurface,
    ConstraintGroup,
    EdgeLength,
    FaceSamplesToSurface,
    Plane,
)
from drawstring.geometry.solve.linalg import centering_matrix, cross3
from drawstring.geometry.solve.shape_groups import SimilarityToSquare
from drawstring.geometry.solve.solver import LocalGlobalSolver, SolverResult

#: Paper eq. 1 weights (w_planar, w_square, w_surface) from section 5.4.
PAPER_WEIGHTS: tuple[float, float, float] = (1e4, 10.0, 0.1)

#: Close-fit alternative (w_planar, w_square, w_surface): closeness to the target outweighs
#: squareness. Measured at ~200 tiles on the built-ins it keeps K3D within 2 % of a tile side of
#: the target on 6 of 8 shapes (paper weights: 0 of 8), but lets tiles shear, change size and,
#: on coarse strongly non-conformal grids, fold over; see the benchmark notes.
CLOSE_FIT_WEIGHTS: tuple[float, float, float] = (1e4, 1.0, 100.0)

#: Default weights: the paper's.
DEFAULT_WEIGHTS: tuple[float, float, float] = PAPER_WEIGHTS


@dataclass(frozen=True)
class Eq1Weights:
    """The weights of one eq.-1 solve: planar, square, surface (the paper's three) and the
    face samples' (:class:`~drawstring.geometry.solve.groups.FaceSamplesToSurface`; 0 leaves
    them out, as the paper does)."""

    planar: float
    square: float
    surface: float
    samples: float = 0.0

    @classmethod
    def of(cls, weights: tuple[float, float, float]) -> Eq1Weights:
        """The paper's three weights (``--weights``), no face samples."""
        return cls(float(weights[0]), float(weights[1]), float(weights[2]))

    def to_json(self) -> dict[str, float]:
        return {
            "planar": self.planar,
            "square": self.square,
            "surface": self.surface,
            "face_samples": self.samples,
        }


#: Convexity margin of every quad corner (:class:`ConvexCorners`): the corner must stand at least
#: this fraction of the diagonal joining its two neighbours outside that diagonal (0.5 for a
#: square's corner, 0 for a straight angle); 0.2 keeps every corner angle below about 136 deg and
#: every side at least about a fifth of the other sides (a dart or a collapsing side violates it).
CONVEX_MARGIN: float = 0.2

#: Lazy closest-point re-query of the surface term (:class:`ClosenessToSurface`): a vertex is
#: queried again once it moved more than this fraction of its distance to the target.
SURFACE_REQUERY_REL: float = 0.1

#: Weight of :class:`ConvexCorners` relative to ``w_planar``: a hard constraint (it is zero on
#: every quad that is convex with the margin, so it does not change the paper's energy there).
CONVEX_WEIGHT_REL: float = 1.0


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
            raise InternalError("ConvexCorners needs quads of shape (m, 4)")
        ref = np.asarray(reference_normals, dtype=np.float64)
        if ref.shape != (len(arr), 3):
            raise InternalError("reference_normals must have shape (m, 3), one per quad")
        if not 0.0 <= margin < 0.5:
            raise InternalError(f"convexity margin is {margin}; use a value in [0, 0.5)")
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


def _eq1_groups(
    vertices: FloatArray,
    quads: IntArray,
    target_vertices: FloatArray,
    target_faces: IntArray,
    weights: tuple[float, float, float],
    *,
    requery_rel: float = SURFACE_REQUERY_REL,
    w_samples: float = 0.0,
) -> tuple[list[ConstraintGroup], FloatArray]:
    """The constraint groups of paper eq. 1 (planar, square length and shape, surface) for the
    quad mesh ``vertices`` (whose edges and quads set the square targets), and the edge
    targets.  With ``w_samples`` > 0 the quads' centres and edge midpoints are pulled to the
    target too (:class:`FaceSamplesToSurface`, that weight), not only their corners."""
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
    if w_samples > 0:
        groups.append(
            FaceSamplesToSurface(
                quads,
                edges.edges,
                target_vertices,
                target_faces,
                w_samples,
                requery_rel=requery_rel,
            )  # fmt: skip
        )
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
    w_samples: float = 0.0,
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
    w_samples : float
        Weight of :class:`~drawstring.geometry.solve.groups.FaceSamplesToSurface` (0: eq. 1 as
        the paper states it, corners only).

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
        w_samples=w_samples,
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
