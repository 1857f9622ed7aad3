"""Minimum lift points from the gaps' gravitational potential energy (paper section 5.2).

Pipeline (one function each):

1. ``tile_masses_from_volumes``: mass of every rigid tile from its closed 8-vertex solid.
2. ``gap_potential_energy``: ``g_i = sum_k 1/4 m_k g (z_k - z_min)`` over the tiles around gap i.
3. ``morse_smale_basins``: discrete Morse-Smale segmentation of ``g`` on the gap graph (gaps
   adjacent when they share a tile): peaks and the basin (peak reached by steepest ascent) of
   every gap.
4. ``peak_barriers``: for every pair of peaks, the lightest edge on their path in the maximum
   spanning tree whose edge weights are ``min(g_u, g_v)`` (Kruskal; computed while merging).
5. ``cluster_peaks``: coupling ``c(i, j) = barrier(i, j) / g_j`` for ``g_i >= g_j``; a DAG edge
   ``i -> j`` for the strongest coupling into ``j`` when it reaches ``tau``; weakly connected
   components are clusters and each cluster's root (zero in-degree) is a lift point.
6. ``select_lift_points``: the threshold sweep ``tau = tau0, tau0 + step, ... , 1.0`` and past
   1.0 every peak on its own, stopping at the first ``tau`` whose deployment check passes.

The deployment check is a callable so that the actuation simulation can plug in.  Until it
exists ``geometric_deploy_check`` stands in; its name says so and is stored in the result.

"Higher" is a strict total order on gaps: larger energy first, equal energies broken by the
smaller gap index (deterministic).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import LIFT_SHARE_MIN, LIFT_SUPPORT_MIN
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)

GRAVITY = 9.81  # m/s^2


class DeployCheck(Protocol):
    """A deployment check: ``check(lift_gaps) -> bool`` with a human-readable ``name``."""

    @property
    def name(self) -> str: ...

    def __call__(self, lift_gaps: IntArray) -> bool: ...


@dataclass(frozen=True)
class LiftPoints:
    """Selected lift points and the analysis behind them.

    Attributes
    ----------
    lift_gaps : (k,) int, gap id of each lift point (sorted from highest energy down).
    peaks : (p,) int, gap ids of the energy peaks (sorted from highest down).
    basin : (G,) int, index into ``peaks`` of the basin each gap belongs to.
    gap_energy : (G,) float, J, gravitational potential energy of each gap.
    coupling : (p, p) float, ``coupling[i, j] = barrier(i, j) / g_j`` when peak i is higher
        than peak j, else 0.
    clusters : (p,) int, cluster id of each peak; cluster ``c`` is lifted at ``lift_gaps[c]``.
    tau : float, the coupling threshold used (``inf`` when every peak is its own lift point).
    positions : (k, 3) float, mm, position of each lift point.
    pull_directions : (k, 3) float, unit pull direction at each lift point.
    check_name : str, which deployment check accepted (or last rejected) the selection.
    check_passed : bool, whether the check passed at ``tau``.
    sweep : list of ``(tau, n_lift, passed)`` for every threshold tried.
    """

    lift_gaps: IntArray
    peaks: IntArray
    basin: IntArray
    gap_energy: FloatArray
    coupling: FloatArray
    clusters: IntArray
    tau: float
    positions: FloatArray
    pull_directions: FloatArray
    check_name: str
    check_passed: bool
    sweep: tuple[tuple[float, int, bool], ...]

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON summary: per lift point its gap, position (mm) and pull direction."""
        return {
            "count": int(len(self.lift_gaps)),
            "tau": None if not np.isfinite(self.tau) else float(self.tau),
            "check": self.check_name,
            "check_passed": bool(self.check_passed),
            "peaks": [int(p) for p in self.peaks],
            "sweep": [
                {"tau": None if not np.isfinite(t) else float(t), "lift_points": n, "passed": ok}
                for t, n, ok in self.sweep
            ],
            "points": [
                {
                    "gap": int(g),
                    "position_mm": [float(c) for c in p],
                    "pull_direction": [float(c) for c in d],
                }
                for g, p, d in zip(
                    self.lift_gaps, self.positions, self.pull_directions, strict=True
                )
            ],
        }


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


def _unit(vector: ArrayLike, what: str) -> FloatArray:
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
    height = c @ _unit(up, "up axis")
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


# --------------------------------------------------------------------------------------------
# deployment check stand-in


@dataclass(frozen=True)
class _RidgeSupportCheck:
    """Callable behind ``geometric_deploy_check``."""

    name: str
    peaks: IntArray
    peak_energy: FloatArray
    basin_share: FloatArray
    barrier: FloatArray
    share_min: float
    support_min: float

    def __call__(self, lift_gaps: IntArray) -> bool:
        lifted = np.isin(self.peaks, np.asarray(lift_gaps))
        if not lifted.any():
            return len(self.peaks) == 0
        support = self.barrier[:, lifted].max(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.peak_energy > 0, support / self.peak_energy, 1.0)
        significant = self.basin_share >= self.share_min
        ok = lifted | ~significant | (ratio >= self.support_min)
        return bool(ok.all())


def geometric_deploy_check(
    linkage: Linkage,
    gap_energy: ArrayLike,
    *,
    share_min: float = LIFT_SHARE_MIN,
    support_min: float = LIFT_SUPPORT_MIN,
) -> DeployCheck:
    """A geometric STAND-IN for the deployment simulation (named as such in the output).

    Criterion ("ridge support"): every peak whose basin holds at least ``share_min`` of the
    total gap potential energy must either be a lift point or be joined to some lift point by a
    ridge whose lowest energy (the barrier on the maximum spanning tree) is at least
    ``support_min`` times the peak's own energy.

    Why this is defensible: pulling a lift point raises the region around it, and the load
    reaches another heavy region only through the gaps between them; if every path to the
    nearest lift point dips into a valley far below the heavy peak (a slack region in between)
    that region has to be raised by the boundary string alone, which is what the paper's
    simulation reports as a stuck deployment for heavy structures.  Light basins are ignored
    because the boundary string alone assembles light structures (paper section 5.1).  It is a
    proxy: it knows nothing of friction, hinge stiffness or dynamics.

    Parameters
    ----------
    linkage : topology.
    gap_energy : (G,) float, J, from ``gap_potential_energy``.
    share_min : fraction of the total energy above which a basin counts as heavy.
    support_min : required ridge height as a fraction of the peak's energy.

    Returns
    -------
    A callable ``check(lift_gaps) -> bool`` with a ``name``.
    """
    energy = np.asarray(gap_energy, dtype=np.float64)
    edges = gap_adjacency(linkage)
    peaks, basin = morse_smale_basins(energy, edges)
    total = float(energy.sum())
    share = np.bincount(basin, weights=energy, minlength=len(peaks)) / (total if total else 1.0)
    return _RidgeSupportCheck(
        name=(
            f"geometric stand-in (ridge support >= {support_min:g} of peak energy for basins "
            f">= {share_min:.0%} of total energy; not a simulation)"
        ),
        peaks=peaks,
        peak_energy=energy[peaks],
        basin_share=share,
        barrier=peak_barriers(energy, edges, peaks),
        share_min=share_min,
        support_min=support_min,
    )


# --------------------------------------------------------------------------------------------
# selection


def _check_name(check: Callable[[IntArray], bool]) -> str:
    return str(getattr(check, "name", getattr(check, "__name__", type(check).__name__)))


def select_lift_points(
    linkage: Linkage,
    tile_centroids: ArrayLike,
    tile_masses: ArrayLike,
    *,
    up: ArrayLike = (0.0, 0.0, 1.0),
    tau0: float = 0.8,
    tau_step: float = 0.1,
    deploy_check: Callable[[IntArray], bool] | None = None,
    gap_positions: ArrayLike | None = None,
    gap_normals: ArrayLike | None = None,
) -> LiftPoints:
    """Minimum set of lift points by energetic coupling of the gap energy peaks.

    Parameters
    ----------
    linkage : topology.
    tile_centroids : (T, 3) float, mm, assembled tile centres of mass.
    tile_masses : (T,) float, kg.
    up : (3,) resting up axis of the assembled shape.
    tau0, tau_step : threshold sweep: ``tau0, tau0 + tau_step, ...`` up to 1.0 inclusive; if
        the check still fails every peak becomes its own lift point (``tau = inf``) and the
        result reports whether that passed.  A split linkage that fails even then tries the
        peaks of each part on its own (no ascent through seam gaps), every one lifted; that
        set is kept only if it passes.
    deploy_check : ``check(lift_gaps) -> bool``; default ``geometric_deploy_check`` (a stand-in).
    gap_positions : (G, 3) float, mm, optional lift-point positions (e.g. mean of the tiles'
        top-face centroids); default: mean of the surrounding tiles' centroids.
    gap_normals : (G, 3) float, optional outward normals; if given the pull direction is the
        normalized normal of the lift gap, else the ``up`` axis.

    Returns
    -------
    LiftPoints
    """
    up_axis = _unit(up, "up axis")
    if not 0.0 < tau_step:
        raise InternalError(f"tau step {tau_step} must be positive; the paper uses 0.1")
    energy = gap_potential_energy(linkage, tile_centroids, tile_masses, up=up_axis)
    edges = gap_adjacency(linkage)
    peaks, basin = morse_smale_basins(energy, edges)
    barrier = peak_barriers(energy, edges, peaks)
    coupling = peak_coupling(energy, peaks, barrier)
    check = deploy_check or geometric_deploy_check(linkage, energy)
    name = _check_name(check)

    taus: list[float] = []
    t = float(tau0)
    while t <= 1.0 + 1e-9:
        taus.append(round(t, 10))
        t += tau_step
    taus.append(float("inf"))

    sweep: list[tuple[float, int, bool]] = []
    for tau in taus:
        clusters, roots = cluster_peaks(coupling, tau)
        lift_gaps = interior_lift_gaps(linkage, energy, edges, peaks[roots])
        passed = bool(check(lift_gaps))
        sweep.append((tau, int(len(lift_gaps)), passed))
        log.info("lift points: tau=%s -> %d lift points, check passed=%s", tau, len(roots), passed)
        if passed:
            break
    if not passed and linkage.n_components > 1:
        # Split parts share no hinge, so each must rise on its own; but one peak's basin can
        # reach across a seam (the 1600-tile dome: its one peak lies just right of the cut
        # and drains the left part too).  Last try: peaks part by part, every one lifted.
        seam = np.asarray(linkage.gap_kind) == "split"
        field = energy.copy()
        field[seam] = energy.min() - 1.0  # nothing climbs through a seam gap
        part_peaks, part_basin = morse_smale_basins(field, edges)
        part_lifts = interior_lift_gaps(linkage, energy, edges, part_peaks)
        if set(part_lifts.tolist()) != set(lift_gaps.tolist()):
            part_passed = bool(check(part_lifts))
            sweep.append((float("inf"), int(len(part_lifts)), part_passed))
            log.info(
                "lift points: peaks part by part -> %d lift points, check passed=%s",
                len(part_lifts),
                part_passed,
            )
            if part_passed:
                passed, lift_gaps, peaks, basin = True, part_lifts, part_peaks, part_basin
                coupling = np.zeros((len(peaks), len(peaks)))
                clusters = np.arange(len(peaks), dtype=np.int64)
                tau = float("inf")
    if not passed:
        # returned in ``sweep``; the pipeline lists it where the user reads it
        log.info("lift points: deployment check '%s' failed for every threshold", name)

    if gap_positions is None:
        tiles = linkage.gap_sides[:, :, 0]
        cent = np.asarray(tile_centroids, dtype=np.float64)
        valid = tiles >= 0
        pos_all = (cent[np.maximum(tiles, 0)] * valid[..., None]).sum(1) / valid.sum(1)[:, None]
    else:
        pos_all = np.asarray(gap_positions, dtype=np.float64)
    positions = pos_all[lift_gaps]
    if gap_normals is None:
        pulls = np.tile(up_axis, (len(lift_gaps), 1))
    else:
        nrm = np.asarray(gap_normals, dtype=np.float64)[lift_gaps]
        pulls = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    return LiftPoints(
        lift_gaps=lift_gaps.astype(np.int64),
        peaks=peaks,
        basin=basin,
        gap_energy=energy,
        coupling=coupling,
        clusters=clusters,
        tau=tau,
        positions=np.asarray(positions, dtype=np.float64),
        pull_directions=np.asarray(pulls, dtype=np.float64),
        check_name=name,
        check_passed=passed,
        sweep=tuple(sweep),
    )


def interior_lift_gaps(
    linkage: Linkage,
    energy: FloatArray,
    edges: IntArray,
    gaps: IntArray,
) -> IntArray:
    """Move lift points off split and boundary gaps onto the best interior gap next to them.

    The string reaches a lift point from the boundary through interior gaps and may not enter
    through a split gap (paper sec. 5.3), and a gap on a split seam joins two separate parts, so
    a peak that falls on a split (or boundary) gap is lifted at the highest-energy horizontal or
    vertical gap sharing a tile with it.  Order is kept; duplicates are dropped.
    """
    interior = np.array([k in ("horizontal", "vertical") for k in linkage.gap_kind], dtype=bool)
    neighbours: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    moved: list[int] = []
    for gap in np.asarray(gaps, dtype=np.int64).tolist():
        if not interior[gap]:
            options = [n for n in neighbours.get(gap, []) if interior[n]]
            if options:
                gap = max(options, key=lambda n: (energy[n], -n))
        if gap not in moved:
            moved.append(gap)
    return np.array(moved, dtype=np.int64)


def nearby_lift_gaps(linkage: Linkage, gap: int, positions: ArrayLike, steps: int = 2) -> IntArray:
    """Interior gaps of ``gap``'s part within ``steps`` hops of it (a hop joins two gaps that
    share a tile), nearest first: where a lift point may move when the string cannot reach it.

    Parameters
    ----------
    linkage : topology.
    gap : the lift gap.
    positions : (G, d) float, gap positions that decide "nearest" (ties: lower gap id).
    steps : largest number of hops.

    Returns
    -------
    (c,) int, without ``gap`` itself.
    """
    pos = np.asarray(positions, dtype=np.float64)
    interior = np.array([k in ("horizontal", "vertical") for k in linkage.gap_kind], dtype=bool)
    parts = {int(linkage.tile_component[t]) for t in linkage.gap_tiles(gap)}
    neighbours: dict[int, set[int]] = {}
    for a, b in gap_adjacency(linkage).tolist():
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    seen, frontier = {int(gap)}, {int(gap)}
    for _ in range(steps):
        frontier = {n for f in frontier for n in neighbours.get(f, ())} - seen
        seen |= frontier
    found = [
        g
        for g in seen - {int(gap)}
        if interior[g] and {int(linkage.tile_component[t]) for t in linkage.gap_tiles(g)} <= parts
    ]
    dist = [float(np.linalg.norm(pos[g] - pos[gap])) for g in found]
    order = sorted(range(len(found)), key=lambda i: (dist[i], found[i]))
    return np.array([found[i] for i in order], dtype=np.int64)
