"""T3D: the frustum tiles extruded from K3D, with planar faces and parallel tops and bottoms
(paper section 4.2).

:func:`initial_bottom` offsets the top inwards along vertex normals; :func:`extrude_tiles`
optimizes top and bottom vertices together (or only the bottoms under a fixed top);
:func:`thickness_advice` is the largest thickness that keeps every tile right side out and
unfolded.
"""

from __future__ import annotations

import numpy as np

from drawstring.geometry.assembled.frustums import (
    folded_faces,
    quad_mesh_edges,
    quad_vector_areas,
    side_quads,
    vertex_normals,
)
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.groups import (
    ClosenessToPlanes,
    ClosenessToPoints,
    ConstraintGroup,
    Plane,
)
from drawstring.geometry.solve.shape_groups import Slab
from drawstring.geometry.solve.solver import LocalGlobalSolver, SolverResult

#: :func:`thickness_advice` keeps every bottom face at least this fraction of its top's area.
THICKNESS_ADVICE_AREA = 0.25


def thickness_advice(top: FloatArray, quads: IntArray) -> float:
    """The largest thickness (mm) whose starting extrusion keeps every bottom face facing the
    same way as its top with at least ``THICKNESS_ADVICE_AREA`` of its area, and no top or
    bottom face folded (:func:`~.frustums.folded_faces`).

    The start bottom (:func:`initial_bottom`) is linear in the thickness, so each face's area
    is a quadratic in it; bisection finds the bound.  The optimized extrusion stays close to the
    start, so this is the thickness to suggest when a thicker one turns tiles inside out.
    """
    top_area = quad_vector_areas(top, quads)
    direction = top - initial_bottom(top, quads, 1.0)  # bottom = top - t * direction

    def worst(t: float) -> float:
        bottom = top - t * direction
        if folded_faces(top, bottom, quads).any():
            return -1.0
        area = quad_vector_areas(bottom, quads)
        ratio = np.einsum("ki,ki->k", top_area, area) / np.einsum("ki,ki->k", top_area, top_area)
        return float(ratio.min(initial=1.0))

    lo, hi = 0.0, 1.0
    while worst(hi) >= THICKNESS_ADVICE_AREA and hi < 1e6:
        lo, hi = hi, 2.0 * hi
    for _ in range(50):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if worst(mid) >= THICKNESS_ADVICE_AREA else (lo, mid)
    return lo


def initial_bottom(top: FloatArray, quads: IntArray, thickness: float) -> FloatArray:
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
    bottom0 = initial_bottom(top, quads, thickness)
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
