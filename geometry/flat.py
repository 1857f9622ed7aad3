"""Flat configuration K2D and its extrusion T2D (paper section 4.3).

K2D is the linkage laid out in the plane: one 2D position per linkage node (hinged corners share
a node, so every hinge pair coincides exactly).  It minimizes

    w_edge * E_edge + w_collision * E_collision + w_fab * E_fab

* ``E_edge``: every tile's 4 sides and 2 diagonals have the length of its K3D top face (paper
  eq. 3-4 with K3D targets), so tiles are congruent to their assembled top faces;
* ``E_collision``: every gap junction keeps a positive (counter-clockwise) interior angle, so no
  gap turns inside out; tile pairs found overlapping after a solve get a separating-axis group
  (:class:`~drawstring.geometry.constraints.QuadSeparation2D`) and the solve is repeated;
* ``E_fab``: the opening angle at both ends of every gap's slit (0 closed, 90 deg when the
  rhombus is a square) lies in ``[theta_min, 90 deg]``.

Initial layout
--------------
A uniform rotating-squares linkage of side ``L`` opened by ``theta`` has tile pitch
``L (cos theta/2 + sin theta/2)``, i.e. it covers ``(1 + sin theta)`` times the tiles' own area.
The conformal grid has uniform cells of area ``a``; tile ``t`` has K3D area ``s_t a``.  Placing
tile centres at ``sqrt(c) * uv`` (a uniform scaling of the conformal grid) gives every tile the
area ``c a``, so the local opening must satisfy ``s_t (1 + sin theta_t) = c``.  Choosing
``c = s_max (1 + sin theta_min)`` makes the largest tile open by exactly ``theta_min`` and all
others wider; they stay within 90 deg iff ``s_max / s_min <= 2 / (1 + sin theta_min)``.  Each
tile is placed as its K3D face (rigidly flattened, aligned with its grid cell), turned by
``-(-1)^(i+j) theta_t / 2`` about its centre; shared nodes start at the mean of their corners.
This is done per component (components share no node), and components are then moved apart.

After the local-global solve (constant factor, Anderson acceleration) a few damped Gauss-Newton
steps on the same energy sharpen the result: edge lengths are then at the least-squares optimum
to machine precision, so the remaining edge error is what the target's geometry forces (a quad
linkage with non-congruent tiles is over-constrained in the plane), not solver slack.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from drawstring.geometry.constraints import GapAngleBounds, QuadSeparation2D, quad_overlap_mtv
from drawstring.geometry.errors import InputError
from drawstring.geometry.linkage import Linkage
from drawstring.geometry.solver import EdgeLength, LocalGlobalSolver
from drawstring.geometry.tolerances import (
    FLAT_EDGE_ERROR_TOL_MM,
    FLAT_GAP_ANGLE_TOL_DEG,
    FLAT_OVERLAP_TOL_MM2,
)
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]

#: Tile edges as corner pairs: 4 sides (side k from corner k to k+1), then the 2 diagonals.
TILE_EDGES: IntArray = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [1, 3]], dtype=np.int64)

__all__ = [
    "FlatResult",
    "GapJunctions",
    "TILE_EDGES",
    "extrude_flat",
    "gap_junctions",
    "initial_flat_layout",
    "optimize_flat",
    "tile_plane_coordinates",
]


@dataclass(frozen=True)
class GapJunctions:
    """Corners where two consecutive sides of a gap meet at a shared (hinge) node.

    Attributes
    ----------
    elements : (J, 3) int
        ``(apex, q, p)`` node ids; the void's interior angle at ``apex`` is measured
        counter-clockwise from ``q - apex`` to ``p - apex``.
    gap : (J,) int
        Gap id of each junction.
    is_end : (J,) bool
        The junction is an end of the gap's slit (its angle is the opening angle); otherwise it
        is a side vertex (angle ``180 deg - opening`` in a rhombus).
    """

    elements: IntArray
    gap: IntArray
    is_end: NDArray[np.bool_]

    @property
    def ends(self) -> IntArray:
        """(E, 3) int, the slit-end junctions."""
        return self.elements[self.is_end]


def gap_junctions(linkage: Linkage) -> GapJunctions:
    """All hinge junctions of all gaps.

    Side ``(tile, k)`` runs from corner ``k`` to ``k + 1`` counter-clockwise around the tile, so
    counter-clockwise around the void it runs from corner ``k + 1`` to corner ``k``.  Consecutive
    sides that share a node form a junction; it is a slit end when its node is not at the gap's
    own grid vertex.
    """
    elements: list[tuple[int, int, int]] = []
    gaps: list[int] = []
    ends: list[bool] = []
    cn = linkage.corner_node
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        m = len(sides)
        for k in range(m):
            t0, s0 = (int(v) for v in sides[k])
            t1, s1 = (int(v) for v in sides[(k + 1) % m])
            if m == 2 and k == 1:
                pass  # both junctions of a two-sided gap are checked
            end_node = cn[t0, s0]  # side k ends (void-ccw) at corner s0
            start_node = cn[t1, (s1 + 1) % 4]
            if end_node != start_node:
                continue
            p = int(cn[t0, (s0 + 1) % 4])  # previous point along the void
            q = int(cn[t1, s1])  # next point along the void
            elements.append((int(end_node), q, p))
            gaps.append(g)
            at_vertex = linkage.tile_corners[t0, s0] == linkage.gap_vertex[g]
            ends.append(not bool(at_vertex))
    return GapJunctions(
        elements=np.array(elements, dtype=np.int64).reshape(-1, 3),
        gap=np.array(gaps, dtype=np.int64),
        is_end=np.array(ends, dtype=bool),
    )


@dataclass(frozen=True)
class FlatResult:
    """The flat configuration K2D.

    Attributes
    ----------
    nodes : (n_nodes, 2) float, mm
        Node positions; tile corners are ``nodes[linkage.corner_node]``.
    corners : (T, 4, 2) float, mm
        Tile corners BL, BR, TR, TL.
    edge_targets : (T, 6) float, mm
        K3D lengths of the sides and diagonals (order of :data:`TILE_EDGES`).
    junctions : GapJunctions
    opening_deg : (E,) float
        Opening angle at every slit end (order of ``junctions.ends``).
    min_gap_angle_deg : float
    tile_scale : (T,) float
        K3D area over flat grid cell area ``s_t``.
    layout_scale : (C,) float
        ``c`` per component (flat cell area over grid cell area).
    component_offset : (C, 2) float, mm
        Translation applied to each component to separate it from the others.
    edge_error_max_mm : float
        Max |K2D - K3D| over sides and diagonals (the optimizer's own number; ``verify``
        measures it independently).
    iterations : int
    time_s : float
    problems : tuple of str
        Targets this layout does not meet, one sentence each (empty when all are met).
    """

    nodes: FloatArray
    corners: FloatArray
    edge_targets: FloatArray
    junctions: GapJunctions
    opening_deg: FloatArray
    min_gap_angle_deg: float
    tile_scale: FloatArray
    layout_scale: FloatArray
    component_offset: FloatArray
    edge_error_max_mm: float
    iterations: int
    time_s: float
    problems: tuple[str, ...]


def tile_plane_coordinates(tile_top_3d: FloatArray) -> FloatArray:
    """Each top face rigidly laid into the plane (best-fit plane coordinates).

    Parameters
    ----------
    tile_top_3d : (T, 4, 3) float, mm
        Corners BL, BR, TR, TL.

    Returns
    -------
    (T, 4, 2) float, mm
        Counter-clockwise coordinates, centred, x along the tile's mean bottom/top side
        direction.
    """
    pts = np.asarray(tile_top_3d, dtype=np.float64)
    centred = pts - pts.mean(axis=1, keepdims=True)
    normal = np.cross(pts[:, 2] - pts[:, 0], pts[:, 3] - pts[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    ex = (pts[:, 1] - pts[:, 0]) + (pts[:, 2] - pts[:, 3])
    ex -= np.einsum("ki,ki->k", ex, normal)[:, None] * normal
    ex /= np.maximum(np.linalg.norm(ex, axis=1, keepdims=True), 1e-300)
    ey = np.cross(normal, ex)
    return np.stack(
        [np.einsum("kvi,ki->kv", centred, ex), np.einsum("kvi,ki->kv", centred, ey)], axis=-1
    )


def _rotations_2d(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _fit_rotation_2d(src: FloatArray, dst: FloatArray) -> FloatArray:
    """Angle ``(k,)`` of the rotation best mapping centred ``src (k, s, 2)`` onto ``dst``."""
    cross = np.sum(src[..., 0] * dst[..., 1] - src[..., 1] * dst[..., 0], axis=1)
    dot = np.sum(src * dst, axis=(1, 2))
    return np.asarray(np.arctan2(cross, dot))


def _average_nodes(linkage: Linkage, corners: FloatArray) -> FloatArray:
    """Mean position of the tile corners that share each node."""
    dim = corners.shape[-1]
    nodes = np.zeros((linkage.n_nodes, dim))
    count = np.zeros(linkage.n_nodes)
    np.add.at(nodes, linkage.corner_node.ravel(), corners.reshape(-1, dim))
    np.add.at(count, linkage.corner_node.ravel(), 1.0)
    return nodes / count[:, None]


def initial_flat_layout(
    linkage: Linkage,
    plane_tiles: FloatArray,
    uv: FloatArray,
    min_gap_angle: float,
) -> tuple[FloatArray, FloatArray, FloatArray, list[str]]:
    """Locally opened rotating-squares start (see the module docstring).

    Parameters
    ----------
    linkage : Linkage
    plane_tiles : (T, 4, 2) float, mm
        K3D top faces in their own plane coordinates (:func:`tile_plane_coordinates`).
    uv : (n, 2) float, mm
        Conformal grid positions of the grid vertices.
    min_gap_angle : float, rad

    Returns
    -------
    nodes : (n_nodes, 2) float, mm
    tile_scale : (T,) float
        ``s_t``.
    layout_scale : (C,) float
        ``c`` per component.
    problems : list of str
    """
    # Per-vertex grid positions, or per-tile corner positions (each component flattened alone).
    cell_uv = uv if uv.ndim == 3 else uv[linkage.tile_corners]  # (T, 4, 2)
    cell_centre = cell_uv.mean(axis=1)
    cell_area = np.abs(_polygon_signed_area(cell_uv))
    tile_area = _polygon_signed_area(plane_tiles)
    if np.any(tile_area <= 0) or np.any(cell_area <= 0):
        raise InputError("a tile or grid cell has zero or negative area; check the K3D tiles")
    tile_scale = tile_area / cell_area
    problems: list[str] = []
    comp = linkage.tile_component
    layout_scale = np.zeros(linkage.n_components)
    opening = np.zeros(linkage.n_tiles)
    sin_min = np.sin(min_gap_angle)
    for c in range(linkage.n_components):
        sel = comp == c
        s_max, s_min = float(tile_scale[sel].max()), float(tile_scale[sel].min())
        layout_scale[c] = s_max * (1.0 + sin_min)
        ratio = s_max / s_min
        limit = 2.0 / (1.0 + sin_min)
        if ratio > limit * (1.0 + 1e-9):
            problems.append(
                f"component {c}: tile area ratio {ratio:.3f} exceeds {limit:.3f}, the most a quad "
                f"linkage with gap angles in [{np.degrees(min_gap_angle):.1f}, 90] deg can absorb; "
                "lower --min-gap-angle, use more tiles, or split the surface"
            )
        sin_t = np.clip(layout_scale[c] / tile_scale[sel] - 1.0, 0.0, 1.0)
        opening[sel] = np.arcsin(sin_t)
    # Align each tile's plane shape with its grid cell, then turn it by +-opening/2.
    cell_centred = cell_uv - cell_centre[:, None, :]
    align = _fit_rotation_2d(plane_tiles, cell_centred)
    parity = (linkage.tile_cells[:, 0] + linkage.tile_cells[:, 1]) % 2
    turn = np.where(parity == 0, -1.0, 1.0) * 0.5 * opening
    rot = _rotations_2d(align + turn)
    centres = np.sqrt(layout_scale[comp])[:, None] * cell_centre
    corners = centres[:, None, :] + np.einsum("tij,tkj->tki", rot, plane_tiles)
    return _average_nodes(linkage, corners), tile_scale, layout_scale, problems


def _polygon_signed_area(poly: FloatArray) -> FloatArray:
    """Shoelace area ``(k,)`` of polygons ``(k, s, 2)`` (positive when counter-clockwise)."""
    x, y = poly[..., 0], poly[..., 1]
    return np.asarray(
        0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)
    )


def _edge_pairs(linkage: Linkage) -> IntArray:
    """(T * 6, 2) node pairs of every tile's sides and diagonals."""
    cn = linkage.corner_node
    return np.stack([cn[:, TILE_EDGES[:, 0]], cn[:, TILE_EDGES[:, 1]]], axis=-1).reshape(-1, 2)


def _overlapping_pairs(
    linkage: Linkage, corners: FloatArray, tol: float
) -> tuple[IntArray, FloatArray]:
    """Tile pairs whose footprints overlap deeper than ``tol`` (separating-axis broad phase)."""
    centres = corners.mean(axis=1)
    radius = float(np.max(np.linalg.norm(corners - centres[:, None], axis=2)))
    pairs = cKDTree(centres).query_pairs(2.0 * radius + 1e-9, output_type="ndarray")
    if len(pairs) == 0:
        return np.zeros((0, 2), dtype=np.int64), np.zeros(0)
    depth, _ = quad_overlap_mtv(corners[pairs[:, 0]], corners[pairs[:, 1]])
    hit = depth > tol
    return pairs[hit].astype(np.int64), depth[hit]


def _gauss_newton_edges(
    nodes: FloatArray,
    edges: IntArray,
    targets: FloatArray,
    weights: FloatArray,
    angle_group: GapAngleBounds | None,
    angle_weight: float,
    steps: int,
    step_tol: float = 1e-9,
) -> FloatArray:
    """Damped Gauss-Newton on ``sum w (|x_j - x_i| - L)^2`` plus active angle-bound residuals.

    Angle residuals use the local-global projection distance ``sqrt((|u|^2 + |v|^2) / 4) * excess``
    linearised in the angle.  Gauge freedom (rigid motions) is removed by a tiny Levenberg term.
    """
    x = nodes.copy()
    n = len(x)
    k = len(edges)
    sw = np.sqrt(weights)

    def residual_jac(x: FloatArray) -> tuple[FloatArray, sp.csr_matrix]:
        d = x[edges[:, 1]] - x[edges[:, 0]]
        length = np.linalg.norm(d, axis=1)
        unit = d / np.maximum(length, 1e-300)[:, None]
        res = [sw * (length - targets)]
        rows = np.repeat(np.arange(k), 4)
        cols = np.stack(
            [2 * edges[:, 0], 2 * edges[:, 0] + 1, 2 * edges[:, 1], 2 * edges[:, 1] + 1], axis=1
        ).ravel()
        vals = (sw[:, None] * np.concatenate([-unit, unit], axis=1)).ravel()
        blocks = [sp.csr_matrix((vals, (rows, cols)), shape=(k, 2 * n))]
        if angle_group is not None and angle_weight > 0:
            el = angle_group.elements
            u = x[el[:, 1]] - x[el[:, 0]]
            v = x[el[:, 2]] - x[el[:, 0]]
            ang = angle_group.angles(x)
            excess = ang - np.clip(ang, angle_group.lo, angle_group.hi)
            act = np.flatnonzero(excess != 0)
            if act.size:
                uu, vv = u[act], v[act]
                nu = np.einsum("ki,ki->k", uu, uu)
                nv = np.einsum("ki,ki->k", vv, vv)
                scale = np.sqrt(angle_weight * (nu + nv) / 4.0)
                res.append(scale * excess[act])
                dv = np.stack([-vv[:, 1], vv[:, 0]], axis=1) / nv[:, None]
                du = -np.stack([-uu[:, 1], uu[:, 0]], axis=1) / nu[:, None]
                da = -(du + dv)
                m = act.size
                e = el[act]
                rows_a = np.repeat(np.arange(m), 6)
                cols_a = np.stack(
                    [
                        2 * e[:, 0],
                        2 * e[:, 0] + 1,
                        2 * e[:, 1],
                        2 * e[:, 1] + 1,
                        2 * e[:, 2],
                        2 * e[:, 2] + 1,
                    ],
                    axis=1,
                ).ravel()
                vals_a = (scale[:, None] * np.concatenate([da, du, dv], axis=1)).ravel()
                blocks.append(sp.csr_matrix((vals_a, (rows_a, cols_a)), shape=(m, 2 * n)))
        return np.concatenate(res), sp.vstack(blocks, format="csr")

    r, jac = residual_jac(x)
    cost = float(r @ r)
    lam = 1e-6
    for _ in range(steps):
        jtj = (jac.T @ jac).tocsc()
        mu = lam * float(jtj.diagonal().mean())
        step = spla.splu(
            (jtj + mu * sp.identity(2 * n, format="csc")).tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        ).solve(-(jac.T @ r))
        trial = x + step.reshape(n, 2)
        r_new, jac_new = residual_jac(trial)
        cost_new = float(r_new @ r_new)
        logger.debug("gauss-newton: cost %.3e -> %.3e, step %.2e", cost, cost_new, abs(step).max())
        if cost_new < cost:
            x, r, jac = trial, r_new, jac_new
            done = cost - cost_new <= 1e-10 * cost or float(np.abs(step).max()) < step_tol
            cost = cost_new
            lam = max(lam * 0.5, 1e-12)
            if done:
                break
        else:
            lam *= 8.0
            if lam > 1e3:
                break
    return x


def _separate_components(
    linkage: Linkage, nodes: FloatArray, cell_corners_uv: FloatArray, clearance: float
) -> tuple[FloatArray, FloatArray]:
    """Translate components apart (away from each other along their uv offsets).

    ``cell_corners_uv`` (T, 4, 2) are the tiles' corners in the flat domain.

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
    order = np.argsort(-sizes, kind="stable")
    out = nodes.copy()
    placed: list[int] = [int(order[0])]
    for c in order[1:]:
        c = int(c)
        tiles_c = np.flatnonzero(linkage.tile_component == c)
        direction = cell_uv[tiles_c].mean(axis=0) - overall
        norm = np.linalg.norm(direction)
        direction = direction / norm if norm > 0 else np.array([1.0, 0.0])
        placed_tiles = np.flatnonzero(np.isin(linkage.tile_component, placed))
        placed_corners = out[linkage.corner_node[placed_tiles]]
        tree = cKDTree(placed_corners.mean(axis=1))
        shift = np.zeros(2)
        for _ in range(400):
            corners_c = out[linkage.corner_node[tiles_c]] + shift
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
            depth, _ = quad_overlap_mtv(corners_c[pa], placed_corners[pb])
            if np.all(depth < -clearance):
                break
            shift = shift + direction * max(0.25 * clearance, float(depth.max() + clearance) / 2)
        offsets[c] = shift
        nodes_c = np.flatnonzero(comp_of_node == c)
        out[nodes_c] += shift
        placed.append(c)
    return out, offsets


def optimize_flat(
    linkage: Linkage,
    tile_top_3d: ArrayLike,
    *,
    uv: ArrayLike,
    min_gap_angle_deg: float = 10.0,
    w_edge: float = 1.0,
    w_collision: float = 1.0,
    w_fab: float = 0.001,
    max_iter: int = 400,
    anderson: int = 5,
    polish_steps: int = 30,
    separate_components: bool = True,
) -> FlatResult:
    """Optimize the flat configuration K2D (paper eq. 5).

    Parameters
    ----------
    linkage : Linkage
    tile_top_3d : (T, 4, 3) float, mm
        K3D top face corners BL, BR, TR, TL of every tile.
    uv : (n, 2) or (T, 4, 2) float, mm
        Flat (conformal) grid vertex positions, or every tile's corners in a flattening of its
        own component (``Tiling.layout_uv``); only shapes within a component matter.
    min_gap_angle_deg : float, deg
        ``theta_min``; the maximum is 90 deg.
    w_edge, w_collision, w_fab : float
        Energy weights (paper defaults 1, 1, 0.001).
    max_iter, anderson : local-global solver options.
    polish_steps : int
        Damped Gauss-Newton steps after the local-global solve (0 to skip).
    separate_components : bool
        Move components apart after the solve.

    Returns
    -------
    FlatResult
    """
    start = time.perf_counter()
    top = np.asarray(tile_top_3d, dtype=np.float64)
    uv_arr = np.asarray(uv, dtype=np.float64)
    if top.shape != (linkage.n_tiles, 4, 3):
        raise InputError(f"tile_top_3d has shape {top.shape}; pass (T, 4, 3) K3D corners")
    per_vertex = (
        uv_arr.ndim == 2
        and uv_arr.shape[1] == 2
        and len(uv_arr) >= int(linkage.tile_corners.max()) + 1
    )
    if not per_vertex and uv_arr.shape != (linkage.n_tiles, 4, 2):
        raise InputError(
            "uv must be (n, 2) flat grid-vertex positions or (T, 4, 2) flat tile corners"
        )
    if not 0.0 <= min_gap_angle_deg < 90.0:
        raise InputError(f"--min-gap-angle {min_gap_angle_deg} deg must be in [0, 90)")
    theta_min = np.radians(min_gap_angle_deg)
    plane = tile_plane_coordinates(top)
    nodes0, tile_scale, layout_scale, problems = initial_flat_layout(
        linkage, plane, uv_arr, theta_min
    )
    edges = _edge_pairs(linkage)
    targets = np.linalg.norm(top[:, TILE_EDGES[:, 1]] - top[:, TILE_EDGES[:, 0]], axis=2)
    junctions = gap_junctions(linkage)
    groups: list = [EdgeLength(edges, targets.ravel(), weight=w_edge, name="edge")]
    fab = GapAngleBounds(junctions.ends, theta_min, 0.5 * np.pi, weight=w_fab, name="fab")
    if len(junctions.ends) and w_fab > 0:
        groups.append(fab)
    orient = GapAngleBounds(junctions.elements, 1e-6, np.pi, weight=w_collision, name="orient")
    if len(junctions.elements) and w_collision > 0:
        groups.append(orient)
    solver = LocalGlobalSolver(linkage.n_nodes, groups)
    result = solver.solve(nodes0, max_iter=max_iter, anderson=anderson)
    nodes = result.X
    iterations = result.iterations
    for round_ in range(3):
        if polish_steps > 0:
            nodes = _polish(nodes, edges, targets.ravel(), w_edge, fab, w_fab, polish_steps)
            # E_fab is a soft penalty; raise its weight until the bounds hold (continuation).
            w_fab_now = w_fab
            for _ in range(6):
                if not len(junctions.ends) or w_fab <= 0:
                    break
                ang = np.degrees(fab.angles(nodes))
                excess = max(min_gap_angle_deg - ang.min(), ang.max() - 90.0)
                if excess <= 0.5 * FLAT_GAP_ANGLE_TOL_DEG:
                    break
                w_fab_now *= 10.0
                nodes = _polish(nodes, edges, targets.ravel(), w_edge, fab, w_fab_now, polish_steps)
        pairs, _ = _overlapping_pairs(linkage, nodes[linkage.corner_node], FLAT_OVERLAP_TOL_MM2)
        if len(pairs) == 0 or w_collision <= 0:
            break
        logger.info(
            "flat: %d overlapping tile pairs, adding separation (round %d)", len(pairs), round_
        )
        cn = linkage.corner_node
        name = f"separation{round_}"
        solver.add_group(
            QuadSeparation2D(cn[pairs[:, 0]], cn[pairs[:, 1]], weight=w_collision, name=name)
        )
        result = solver.solve(nodes, max_iter=max_iter, anderson=anderson)
        nodes = result.X
        iterations += result.iterations
    if separate_components:
        cell_uv = uv_arr if uv_arr.ndim == 3 else uv_arr[linkage.tile_corners]
        cell = float(np.sqrt(np.median(np.abs(_polygon_signed_area(cell_uv)))))
        nodes, offsets = _separate_components(linkage, nodes, cell_uv, 0.5 * cell)
    else:
        offsets = np.zeros((linkage.n_components, 2))
    corners = nodes[linkage.corner_node]
    lengths = np.linalg.norm(corners[:, TILE_EDGES[:, 1]] - corners[:, TILE_EDGES[:, 0]], axis=2)
    edge_error = float(np.max(np.abs(lengths - targets), initial=0.0))
    opening = np.degrees(fab.angles(nodes)) if len(junctions.ends) else np.zeros(0)
    if edge_error > FLAT_EDGE_ERROR_TOL_MM:
        problems.append(
            f"flat edge error {edge_error:.3g} mm exceeds {FLAT_EDGE_ERROR_TOL_MM:g} mm: the tiles "
            "cannot all keep their assembled shape in the plane (least-squares optimum reached)"
        )
    if opening.size:
        lo, hi = float(opening.min()), float(opening.max())
        if lo < min_gap_angle_deg - FLAT_GAP_ANGLE_TOL_DEG or hi > 90.0 + FLAT_GAP_ANGLE_TOL_DEG:
            problems.append(
                f"gap opening angles span [{lo:.2f}, {hi:.2f}] deg, outside the bounds "
                f"[{min_gap_angle_deg:g}, 90] deg"
            )
    elapsed = time.perf_counter() - start
    return FlatResult(
        nodes=nodes,
        corners=corners,
        edge_targets=targets,
        junctions=junctions,
        opening_deg=opening,
        min_gap_angle_deg=float(min_gap_angle_deg),
        tile_scale=tile_scale,
        layout_scale=layout_scale,
        component_offset=offsets,
        edge_error_max_mm=edge_error,
        iterations=iterations,
        time_s=elapsed,
        problems=tuple(problems),
    )


def _polish(
    nodes: FloatArray,
    edges: IntArray,
    targets: FloatArray,
    w_edge: float,
    fab: GapAngleBounds,
    w_fab: float,
    steps: int,
) -> FloatArray:
    weights = np.full(len(edges), w_edge)
    return _gauss_newton_edges(nodes, edges, targets, weights, fab, w_fab, steps)


def _kabsch(src: FloatArray, dst: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Proper rotations ``(k, 3, 3)`` and translations ``(k, 3)`` with ``R src + t ~ dst``."""
    cs, cd = src.mean(axis=1), dst.mean(axis=1)
    h = np.einsum("ksi,ksj->kij", src - cs[:, None], dst - cd[:, None])
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(np.einsum("kij,kjl->kil", u, vt)))
    d[d == 0] = 1.0
    fix = np.ones((len(src), 3))
    fix[:, 2] = d
    rot = np.einsum("kji,kj,klj->kil", vt, fix, u)  # V diag(1,1,d) U^T
    trans = cd - np.einsum("kij,kj->ki", rot, cs)
    return rot, trans


def extrude_flat(
    flat: FlatResult | ArrayLike, tiles_3d: ArrayLike, thickness: float | None = None
) -> FloatArray:
    """Extrude K2D into T2D by moving every T3D tile rigidly onto its flat top face.

    Parameters
    ----------
    flat : FlatResult or (T, 4, 2) float, mm
        K2D top corners.
    tiles_3d : (T, 8, 3) float, mm
        T3D tiles: top BL, BR, TR, TL then the bottom vertices under them.
    thickness : float, mm, optional
        Height of the flat top faces; default the mean T3D top-to-bottom distance, so the
        structure's bottom lies near ``z = 0``.

    Returns
    -------
    (T, 8, 3) float, mm
        T2D: for each tile the proper rigid motion (Kabsch, no reflection) that best maps its
        T3D top face onto its K2D top face at ``z = thickness``, applied to all 8 vertices.
    """
    corners = flat.corners if isinstance(flat, FlatResult) else np.asarray(flat, dtype=np.float64)
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    if tiles.ndim != 3 or tiles.shape[1:] != (8, 3) or len(tiles) != len(corners):
        raise InputError(
            f"tiles_3d has shape {tiles.shape}; pass (T, 8, 3) matching the flat tiles"
        )
    if thickness is None:
        thickness = float(np.mean(np.linalg.norm(tiles[:, :4] - tiles[:, 4:], axis=2)))
    dst = np.concatenate([corners, np.full((len(corners), 4, 1), float(thickness))], axis=2)
    rot, trans = _kabsch(tiles[:, :4], dst)
    return np.asarray(np.einsum("kij,kvj->kvi", rot, tiles) + trans[:, None, :])
