"""Tiles of the flat layout kept apart: overlapping tile pairs within a component (which get
separating rows in the solve), and components moved apart after it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import cKDTree

from drawstring.geometry.core.rigid import rigid_fit
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flat.initial import polygon_signed_area, shadow_coordinates
from drawstring.geometry.solve.constraints import convex_overlap_mtv, quad_overlap_mtv
from drawstring.geometry.tiling.linkage import Linkage


def overlapping_pairs(
    linkage: Linkage, corners: FloatArray, tol: float, within_components: bool = True
) -> tuple[IntArray, FloatArray]:
    """Tile pairs whose footprints overlap deeper than ``tol`` (separating-axis broad phase)."""
    centres = corners.mean(axis=1)
    radius = float(np.max(np.linalg.norm(corners - centres[:, None], axis=2)))
    pairs = cKDTree(centres).query_pairs(2.0 * radius + 1e-9, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    if within_components:  # components are moved apart after the solve
        comp = linkage.tile_component
        pairs = pairs[comp[pairs[:, 0]] == comp[pairs[:, 1]]]
    depth, _ = quad_overlap_mtv(corners[pairs[:, 0]], corners[pairs[:, 1]])
    hit = depth > tol
    return pairs[hit].astype(np.int64), depth[hit]


def separate_components(
    linkage: Linkage,
    nodes: FloatArray,
    cell_corners_uv: FloatArray,
    clearance: float,
    shadows: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Translate components apart (away from each other along their uv offsets).

    ``cell_corners_uv`` (T, 4, 2) are the tiles' corners in the flat domain.  Parts are placed
    from the middle out: the one nearest the tiles' centre stays, and each next one moves
    away from that centre until it clears those placed, so parts keep the order in which they
    meet (a middle part moved last would pass the outer ones, and the string between parts
    would cross them).  With ``shadows`` ``(T, 8, 2)``, the whole tiles seen from above in the
    layout (see :func:`~drawstring.geometry.flat.initial.shadow_coordinates`), parts clear
    those instead of their top faces: on a strongly curved target a wedge-shaped tile's bottom
    reaches several millimetres beyond its top face (5.9 mm under 6 mm thick tiles on the
    300-tile scanned face), so parts whose top faces clear by half a cell can still overlap,
    and the rigid hinge layout would pull every hinge of such a part apart to resolve it.

    Returns the new nodes and the ``(C, 2)`` offsets applied.
    """
    n_comp = linkage.n_components
    offsets = np.zeros((n_comp, 2))
    if n_comp <= 1:
        return nodes, offsets
    comp_of_node = np.zeros(linkage.n_nodes, dtype=np.int64)
    comp_of_node[linkage.corner_node.ravel()] = np.repeat(linkage.tile_component, 4)
    cell_uv = cell_corners_uv.mean(axis=1)
    overall = cell_uv.mean(axis=0)
    sizes = np.bincount(linkage.tile_component)
    centres = np.array([cell_uv[linkage.tile_component == c].mean(axis=0) for c in range(n_comp)])
    distance = np.linalg.norm(centres - overall, axis=1)
    order = np.lexsort((-sizes, distance))  # nearest first, the larger of equals first
    out = nodes.copy()
    moved = np.zeros((linkage.n_tiles, 2))  # shift of each tile's shadow so far

    def outline(tiles: IntArray, shift: FloatArray) -> FloatArray:
        if shadows is None:
            return np.asarray(out[linkage.corner_node[tiles]] + shift)
        return np.asarray(shadows[tiles] + (moved[tiles] + shift)[:, None])

    overlap = quad_overlap_mtv if shadows is None else convex_overlap_mtv
    placed: list[int] = [int(order[0])]
    for c in order[1:]:
        c = int(c)
        tiles_c = np.flatnonzero(linkage.tile_component == c)
        direction = cell_uv[tiles_c].mean(axis=0) - overall
        norm = np.linalg.norm(direction)
        direction = direction / norm if norm > 0 else np.array([1.0, 0.0])
        placed_tiles = np.flatnonzero(np.isin(linkage.tile_component, placed))
        placed_corners = outline(placed_tiles, np.zeros(2))
        tree = cKDTree(placed_corners.mean(axis=1))
        shift = np.zeros(2)
        for _ in range(400):
            corners_c = outline(tiles_c, shift)
            centres = corners_c.mean(axis=1)
            radius = float(
                max(
                    np.max(np.linalg.norm(corners_c - centres[:, None], axis=2)),
                    np.max(
                        np.linalg.norm(placed_corners - placed_corners.mean(1)[:, None], axis=2)
                    ),
                )
            )
            hits = tree.query_ball_point(centres, 2 * radius + clearance)
            pa = np.array([i for i, h in enumerate(hits) for _ in h], dtype=np.int64)
            pb = np.array([j for h in hits for j in h], dtype=np.int64)
            if pa.size == 0:
                break
            depth, _ = overlap(corners_c[pa], placed_corners[pb])
            if np.all(depth < -clearance):
                break
            shift = shift + direction * max(0.25 * clearance, float(depth.max() + clearance) / 2)
        offsets[c] = shift
        nodes_c = np.flatnonzero(comp_of_node == c)
        out[nodes_c] += shift
        moved[tiles_c] += shift
        placed.append(c)
    return out, offsets


def components_apart(
    linkage: Linkage,
    nodes: FloatArray,
    uv: FloatArray,
    plane: FloatArray,
    anchor: FloatArray,
    tiles_3d: ArrayLike | None,
) -> tuple[FloatArray, FloatArray]:
    """The layout's components moved apart by half a median grid cell
    (:func:`separate_components`): by their whole tiles seen from above when the T3D
    ``tiles_3d`` are given, else by their corners.

    ``uv`` is the flat grid (per vertex or per tile corner, as
    :func:`~drawstring.geometry.flat.layout.optimize_flat` takes it), ``plane`` the tiles'
    anchor polygons in their own planes
    (:func:`~drawstring.geometry.flat.initial.tile_plane_coordinates` of ``anchor``, the K3D
    points the nodes stand for).  Returns the new nodes and the ``(C, 2)`` offsets applied.
    """
    cn = linkage.corner_node
    cell_uv = uv if uv.ndim == 3 else uv[linkage.tile_corners]
    cell = float(np.sqrt(np.median(np.abs(polygon_signed_area(cell_uv)))))
    shadows = None
    if tiles_3d is not None:
        rotation, translation = rigid_fit(plane, nodes[cn])
        shadows = (
            np.matmul(
                shadow_coordinates(anchor, np.asarray(tiles_3d, dtype=np.float64)),
                rotation.transpose(0, 2, 1),
            )
            + translation[:, None]
        )
    return separate_components(linkage, nodes, cell_uv, 0.5 * cell, shadows)
