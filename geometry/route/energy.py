"""The gaps' gravitational potential energy and its landscape (paper section 5.2), from which
:mod:`~drawstring.geometry.route.lift` picks the lift points.  One function each:

1. ``tile_masses_from_volumes``: mass of every rigid tile from its closed 8-vertex solid.
2. ``gap_potential_energy``: ``g_i = sum_k 1/4 m_k g (z_k - z_min)`` over the tiles around gap i.
3. ``morse_smale_basins``: discrete Morse-Smale segmentation of ``g`` on the gap graph (gaps
   adjacent when they share a tile, :func:`gap_adjacency`): peaks and the basin (peak reached
   by steepest ascent) of every gap.
4. ``peak_barriers``: for every pair of peaks, the lightest edge on their path in the maximum
   spanning tree whose edge weights are ``min(g_u, g_v)`` (Kruskal; computed while merging).
5. ``cluster_peaks``: coupling ``c(i, j) = barrier(i, j) / g_j`` for ``g_i >= g_j``
   (``peak_coupling``); a DAG edge ``i -> j`` for the strongest coupling into ``j`` when it
   reaches ``tau``; weakly connected components are clusters and each cluster's root (zero
   in-degree) is a lift point.

"Higher" is a strict total order on gaps: larger energy first, equal energies broken by the
smaller gap index (deterministic).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "GRAVITY",
    "cluster_peaks",
    "gap_adjacency",
    "gap_potential_energy",
    "morse_smale_basins",
    "peak_barriers",
    "peak_coupling",
    "tile_masses_from_volumes",
    "unit_direction",
]

GRAVITY = 9.81  # m/s^2


# --------------------------------------------------------------------------------------------
# masses and energies


def tile_masses_from_volumes(tile_vertices: ArrayLike, density: float) -> FloatArray:
    """Mass of every closed 8-vertex tile from its exact volume.

    Parameters
    ----------
    tile_vertices : (T, 8, 3) float, mm.  Vertices 0-3 are one cap (corners BL, BR, TR, TL),
        vertices 4-7 the other cap in the same corner order; side ``k`` is the quad
        ``(k, k+1, k+5, k+4)``.  Faces may be non-planar: each quad is split into two triangles
        along a fixed diagonal, the same one on both sides of every shared edge, so the surface
        is closed and the divergence theorem gives its exact volume.
    density : float, kg/m^3.

    Returns
    -------
    (T,) float, kg.  The absolute volume is used, so either cap may come first.
    """
    v = np.asarray(tile_vertices, dtype=np.float64)
    if v.ndim != 3 or v.shape[1:] != (8, 3):
        raise InternalError(
            f"tile vertices have shape {v.shape}; pass a (T, 8, 3) array of tile corners in mm"
        )
    if not np.isfinite(density) or density <= 0:
        raise InternalError(f"density {density} kg/m^3 is not positive; use the material's density")
    # Closed surface, outward for a bottom cap 0-3 counter-clockwise seen from +z and top 4-7.
    quads = [(0, 3, 2, 1), (4, 5, 6, 7)] + [
        (k, (k + 1) % 4, (k + 1) % 4 + 4, k + 4) for k in range(4)
    ]
    tris = np.array(
        [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))], dtype=np.int64
    )  # (12, 3)
    p = v[:, tris]  # (T, 12, 3, 3)
    signed = np.einsum("tfi,tfi->tf", p[:, :, 0], np.cross(p[:, :, 1], p[:, :, 2])).sum(1) / 6.0
    volume_m3 = np.abs(signed) * 1e-9
    return np.asarray(volume_m3 * density, dtype=np.float64)


def unit_direction(vector: ArrayLike, what: str) -> FloatArray:
    """``vector`` ``(3,)`` scaled to unit length (``what`` names it in the error)."""
    u = np.asarray(vector, dtype=np.float64).reshape(3)
    n = float(np.linalg.norm(u))
    if not np.isfinite(n) or n == 0.0:
        raise InternalError(f"{what} {u.tolist()} is not a direction; pass a non-zero 3-vector")
    return u / n


def _gap_tile_matrix(linkage: Linkage) -> sp.csr_matrix:
    """(G, T) 0/1 incidence of gaps and the tiles around them."""
    tiles = linkage.gap_sides[:, :, 0]
    rows, slots = np.nonzero(tiles >= 0)
    data = np.ones(len(rows))
    return sp.csr_matrix(
        (data, (rows, tiles[rows, slots])), shape=(linkage.n_gaps, linkage.n_tiles)
    )


def gap_adjacency(linkage: Linkage) -> IntArray:
    """(E, 2) int pairs ``u < v`` of gaps that share at least one tile."""
    inc = _gap_tile_matrix(linkage)
    adj = sp.triu(inc @ inc.T, k=1).tocoo()
    pairs = np.stack([adj.row, adj.col], axis=1).astype(np.int64)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def gap_potential_energy(
    linkage: Linkage,
    tile_centroids: ArrayLike,
    tile_masses: ArrayLike,
    up: ArrayLike = (0.0, 0.0, 1.0),
    g: float = GRAVITY,
    z_min: float | None = None,
) -> FloatArray:
    """Gravitational potential energy of every gap.

    ``g_i = sum over the tiles k around gap i of 1/4 m_k g (z_k - z_min)`` with ``z`` the height
    along ``up``.

    Parameters
    ----------
    linkage : topology (which tiles surround each gap).
    tile_centroids : (T, 3) float, mm, tile centres of mass in the assembled configuration.
    tile_masses : (T,) float, kg.
    up : (3,) the resting up axis of the assembled shape (normalized here).
    g : float, m/s^2.
    z_min : float, mm, height of the lowest point of the structure; defaults to the lowest
        tile centroid, so the lowest tiles contribute zero.

    Returns
    -------
    (G,) float, J (non-negative).
    """
    c = np.asarray(tile_centroids, dtype=np.float64)
    m = np.asarray(tile_masses, dtype=np.float64)
    if c.shape != (linkage.n_tiles, 3) or m.shape != (linkage.n_tiles,):
        raise InternalError(
            f"tile centroids {c.shape} / masses {m.shape} do not match {linkage.n_tiles} tiles; "
            "pass (T, 3) centroids in mm and (T,) masses in kg"
        )
    if np.any(m < 0) or not np.all(np.isfinite(m)):
        raise InternalError(
            "tile masses must be finite and non-negative; check density and volumes"
        )
    height = c @ unit_direction(up, "up axis")
    base = float(height.min()) if z_min is None else float(z_min)
    tile_energy = 0.25 * m * g * np.maximum(height - base, 0.0) * 1e-3  # mm -> m
    return np.asarray(_gap_tile_matrix(linkage) @ tile_energy, dtype=np.float64)


# --------------------------------------------------------------------------------------------
# Morse-Smale segmentation, barriers, clusters


def _rank(values: FloatArray) -> IntArray:
    """Rank in the strict order 'higher' (0 is the highest): by value, ties by smaller index."""
    order = np.lexsort((np.arange(len(values)), -values))
    rank = np.empty(len(values), dtype=np.int64)
    rank[order] = np.arange(len(values))
    return rank


def morse_smale_basins(energy: FloatArray, edges: IntArray) -> tuple[IntArray, IntArray]:
    """Peaks and steepest-ascent basins of a scalar field on a graph.

    Parameters
    ----------
    energy : (G,) float, the field.
    edges : (E, 2) int, undirected adjacency.

    Returns
    -------
    peaks : (p,) int, nodes higher than all their neighbours, highest first.
    basin : (G,) int, index into ``peaks`` reached from each node by always moving to its
        highest neighbour while that neighbour is higher.
    """
    n = len(energy)
    rank = _rank(energy)
    # For every node, its highest neighbour (smallest rank), or itself if it is higher.
    best = np.arange(n, dtype=np.int64)
    if len(edges):
        u = np.concatenate([edges[:, 0], edges[:, 1]])
        v = np.concatenate([edges[:, 1], edges[:, 0]])
        order = np.lexsort((rank[v], u))  # per u, neighbours by rank ascending
        u, v = u[order], v[order]
        first = np.ones(len(u), dtype=bool)
        first[1:] = u[1:] != u[:-1]
        cand = np.full(n, -1, dtype=np.int64)
        cand[u[first]] = v[first]
        up = (cand >= 0) & (rank[np.maximum(cand, 0)] < rank)
        best[up] = cand[up]
    # Pointer jumping to the peak at the end of every ascent.
    target = best.copy()
    while True:
        nxt = target[target]
        if np.array_equal(nxt, target):
            break
        target = nxt
    peak_nodes = np.nonzero(best == np.arange(n))[0]
    peaks = peak_nodes[np.argsort(rank[peak_nodes])].astype(np.int64)
    index = -np.ones(n, dtype=np.int64)
    index[peaks] = np.arange(len(peaks))
    return peaks, index[target]


def peak_barriers(energy: FloatArray, edges: IntArray, peaks: IntArray) -> FloatArray:
    """Barrier between every pair of peaks on the maximum spanning tree.

    Edge weight ``w(u, v) = min(g_u, g_v)``; Kruskal adds edges heaviest first, and the edge that
    first joins the components holding peaks i and j is the lightest edge of their tree path.

    Returns
    -------
    (p, p) float, J, symmetric; 0 between peaks in different components of the graph, and the
    peak's own energy on the diagonal.
    """
    p = len(peaks)
    barrier = np.zeros((p, p))
    barrier[np.arange(p), np.arange(p)] = energy[peaks]
    if p < 2 or len(edges) == 0:
        return barrier
    weight = np.minimum(energy[edges[:, 0]], energy[edges[:, 1]])
    order = np.lexsort((edges[:, 1], edges[:, 0], -weight))
    parent = np.arange(len(energy))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = int(parent[a])
        return a

    members: dict[int, list[int]] = {int(n): [k] for k, n in enumerate(peaks)}
    for e in order:
        ra, rb = find(int(edges[e, 0])), find(int(edges[e, 1]))
        if ra == rb:
            continue
        a_peaks, b_peaks = members.pop(ra, []), members.pop(rb, [])
        if a_peaks and b_peaks:
            ia, ib = np.array(a_peaks), np.array(b_peaks)
            barrier[np.ix_(ia, ib)] = weight[e]
            barrier[np.ix_(ib, ia)] = weight[e]
        if len(a_peaks) < len(b_peaks):
            ra, rb = rb, ra
        parent[rb] = ra
        if a_peaks or b_peaks:
            members[ra] = a_peaks + b_peaks
    return barrier


def peak_coupling(energy: FloatArray, peaks: IntArray, barrier: FloatArray) -> FloatArray:
    """``c[i, j] = barrier(i, j) / g_j`` where peak i is higher than peak j, else 0.

    ``peaks`` must be sorted highest first (as ``morse_smale_basins`` returns them), so the
    coupling matrix is strictly upper triangular.  A peak of zero energy is fully coupled (1).
    """
    g = energy[peaks]
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(g[None, :] > 0, barrier / np.where(g > 0, g, 1.0)[None, :], 1.0)
    return np.asarray(np.triu(c, k=1), dtype=np.float64)


def cluster_peaks(coupling: FloatArray, tau: float) -> tuple[IntArray, IntArray]:
    """Clusters of the coupling DAG at threshold ``tau`` and each cluster's root.

    Edge ``i -> j`` when ``c(i, j)`` is the largest coupling into ``j`` (ties: the higher peak i)
    and ``c(i, j) >= tau``.  Every peak has in-degree at most one, so the DAG is a forest; its
    roots (zero in-degree) are the lift points.

    Returns
    -------
    clusters : (p,) int, cluster id per peak, clusters numbered by their root's rank.
    roots : (k,) int, peak index of each cluster's root.
    """
    p = coupling.shape[0]
    parent = np.arange(p, dtype=np.int64)
    if p > 1:
        strongest = np.argmax(coupling, axis=0)  # first maximum = highest peak on ties
        value = coupling[strongest, np.arange(p)]
        has = (np.arange(p) > 0) & (value >= tau)
        parent[has] = strongest[has]
    root = parent.copy()
    while True:  # parents are always higher peaks (smaller index), so this ends
        nxt = root[root]
        if np.array_equal(nxt, root):
            break
        root = nxt
    roots = np.unique(root)
    cluster = np.searchsorted(roots, root).astype(np.int64)
    return cluster, roots.astype(np.int64)
