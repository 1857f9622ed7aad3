"""T3D extruded again under a K3D that the flat layout moved (the co-optimization's rounds),
and the pull that gives the bottom hinges equal depths.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.assembled.extrusion import extrude_tiles
from drawstring.geometry.assembled.frustums import (
    corner_margins,
    folded_faces,
    measure_assembled,
    quad_mesh_edges,
    quad_vector_areas,
    side_quads,
    tile_vertices,
)
from drawstring.geometry.assembled.shape import ANDERSON_HISTORY, AssembledResult
from drawstring.geometry.core.tolerances import (
    ASSEMBLED_PLANARITY_REL,
    ASSEMBLED_SOLVER_REL_TOL,
)
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.solve.planarity import LinearPull, planarize_quads


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

    Used after the flat layout moved K3D (:func:`~drawstring.geometry.flat.coflat.co_optimize_top`):
    the extrusion holds the top fixed (only the bottom vertices are unknowns) and the exact
    planarity polish moves only bottom vertices, so the flat tiles stay congruent to the new top
    faces.  With ``measure=False`` the :func:`measure_assembled` metrics are left as ``result``
    had them (rounds that may be thrown away skip them; :func:`remeasured` adds them later).

    With ``start_bottom`` (bottom vertices carried along with the moved top, e.g. each moved
    by its top vertex's move) the extrusion solve is skipped and only the exact polish runs
    from them.  The co-optimization's rounds do so: the solve's soft slab and planarity
    settle 0.2 mm from the polished bottoms whatever it starts from, which would move the
    bottom corners (the bottom hinges' points) by that much in every round for the re-solved
    layout to follow; polished from the carried bottoms they move by hundredths of a
    millimetre (thickness within 0.01 mm of the extruded one).

    Returns
    -------
    AssembledResult, or None when the new top would turn a tile inside out or fold a face.
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
    if folded_faces(new_top, bottom, faces).any():  # inside out or folded into a dart
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
#: (:func:`hinge_depth_pull`): at 1e3 the 200-tile three-shell's largest depth difference is
#: 0.030 mm (0.245 mm without the pull), with bottom corners moved by up to 0.4 mm.
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
