"""The rules a string route obeys on the flat linkage (paper section 5.3): the gap labels,
the contact partners the string may pass between, and the gap graph.

Physics.  The string runs inside a tile from one side face to another and, in the assembled
state, passes straight into the neighbouring tile through the contact face the two tiles share.
In the flat state that crossing happens across exactly one gap: two edge-adjacent tiles share a
grid edge that has a hinge at one end and the slit (the gap) at the other, and the string
crosses at the slit end.  So at every gap the string can only pass between *contact partners*:
two tiles whose sides facing the gap are the same grid segment (same two grid vertices).  For a
horizontal gap (sides ``LL.top, LR.top, UR.bottom, UL.bottom``) the partners are (LL, UL) and
(LR, UR); for a vertical gap (LL, LR) and (UL, UR); at a two-tile boundary notch its two tiles;
at a three-tile notch the one pair whose sides face each other.  Across a split the two tiles of
a cut edge are unhinged, so the gaps at *both* ends of their shared segment may serve
(:func:`contact_partners`).

A route is a cyclic sequence of steps ``(gap g_k, tile t_k)``: the string crosses gap ``g_k``
into tile ``t_k``, runs through it and leaves it into gap ``g_{k+1}``.  Valid routes:

* consecutive tiles ``t_{k-1}, t_k`` are contact partners at ``g_k`` (the enter side of ``t_k``
  and the leave side of ``t_{k-1}`` are their shared segment);
* every gap at most once and every tile at most once (two strands in one void or one tile would
  cross or crowd), no two route segments crossing in the flat layout;
* every boundary tile (a tile with a vertex on the outer boundary) and every lift gap is passed;
  every split component is visited, which ties the components together;
* split rule (paper "Connecting splits"): at a ``-2`` split gap the string may only pass between
  two boundary tiles (it runs along the boundary across the cut); it never enters the interior
  through a cut.  A lift gap on a cut is exempt.

The gap graph (paper Fig. 8) has one node per gap labelled ``0`` vertical, ``1`` horizontal,
``-1`` boundary notch (the paper's virtual entrance: where the void opens to the outside) and
``-2`` split gap.  In the contact-partner model the string passes from the boundary ring to the
interior through the shared face of a boundary tile and an interior tile, i.e. across a four-tile
gap; "no gap or tile twice" is what keeps such detours from crossing the ring (paper Fig. 9).
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Literal

import networkx as nx
import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.route.milp import RouteRules
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "NODE_ENTRANCE",
    "NODE_HORIZONTAL",
    "NODE_SPLIT",
    "NODE_VERTICAL",
    "SplitRule",
    "check_positions",
    "contact_partners",
    "gap_graph",
    "node_labels",
    "route_rules",
]

NODE_VERTICAL, NODE_HORIZONTAL, NODE_ENTRANCE, NODE_SPLIT = 0, 1, -1, -2
_LABEL = {
    "vertical": NODE_VERTICAL,
    "horizontal": NODE_HORIZONTAL,
    "boundary": NODE_ENTRANCE,
    "split": NODE_SPLIT,
}


def node_labels(linkage: Linkage) -> IntArray:
    """(G,) int label of every gap: 0 vertical, 1 horizontal, -1 entrance, -2 split."""
    return np.array([_LABEL[k] for k in linkage.gap_kind], dtype=np.int64)


def contact_partners(linkage: Linkage) -> IntArray:
    """Tile pairs the string may pass between, per gap.

    Two tiles are contact partners at gap ``g`` when their sides facing ``g`` are the same grid
    segment (the same two grid vertices): the string crosses ``g`` from one tile straight into
    the other through the contact face they share in the assembled state.  Sides facing a gap
    are those listed in ``linkage.gap_sides``; across a split, whose cut edges have no hinge,
    the sides along the cut also face the gaps at both ends of the cut edge.

    Returns
    -------
    (P, 5) int rows ``(gap, tile_a, side_a, tile_b, side_b)`` with ``tile_a < tile_b``, sorted.
    """
    corners = linkage.tile_corners
    rows: set[tuple[int, int, int, int, int]] = set()
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        segs = [
            frozenset((int(corners[t, s]), int(corners[t, (s + 1) % 4]))) for t, s in sides.tolist()
        ]
        for a in range(len(sides)):
            for b in range(a + 1, len(sides)):
                (ta, sa), (tb, sb) = sides[a].tolist(), sides[b].tolist()
                if ta != tb and segs[a] == segs[b]:
                    rows.add((g, ta, sa, tb, sb) if ta < tb else (g, tb, sb, ta, sa))
    if linkage.splits:
        gap_at_vertex = {int(v): g for g, v in enumerate(linkage.gap_vertex.tolist())}
        tile_at_cell = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
        # (side of t, neighbour offset, side of the neighbour)
        for t, (i, j) in enumerate(linkage.tile_cells.tolist()):
            for side, (di, dj), other_side in ((1, (1, 0), 3), (2, (0, 1), 0)):
                u = tile_at_cell.get((i + di, j + dj), -1)
                if u < 0 or not any(s.cuts((i, j), (i + di, j + dj)) for s in linkage.splits):
                    continue
                for v in (corners[t, side], corners[t, (side + 1) % 4]):
                    g = gap_at_vertex.get(int(v), -1)
                    if g >= 0:
                        rows.add(
                            (g, t, side, u, other_side) if t < u else (g, u, other_side, t, side)
                        )
    out = np.array(sorted(rows), dtype=np.int64)
    return out.reshape(-1, 5)


SplitRule = Literal["boundary", "same-component"]


def route_rules(
    linkage: Linkage, lifts: Iterable[int], split_rule: SplitRule = "boundary"
) -> RouteRules:
    """The contact partners the string may pass between, indexed for the solvers, with the
    split rule applied (lift gaps in ``lifts`` are exempt from it)."""
    rows = contact_partners(linkage)
    lift_set = {int(g) for g in lifts}
    boundary = linkage.boundary_tile
    kinds = linkage.gap_kind
    comp = linkage.tile_component
    sides: dict[tuple[int, int, int], tuple[int, int]] = {}
    allowed: set[tuple[int, int, int]] = set()
    tile_gaps: dict[int, set[int]] = {}
    for g, a, sa, b, sb in rows.tolist():
        sides[(g, a, b)] = (sa, sb)
        sides[(g, b, a)] = (sb, sa)
        if kinds[g] == "split" and g not in lift_set and not (boundary[a] and boundary[b]):
            if split_rule == "boundary" or comp[a] != comp[b]:
                continue  # never into the interior through a cut
        allowed.update(((g, a, b), (g, b, a)))
        tile_gaps.setdefault(a, set()).add(g)
        tile_gaps.setdefault(b, set()).add(g)
    gap_tiles: dict[int, set[int]] = {}
    for t, gs in tile_gaps.items():
        for g in gs:
            gap_tiles.setdefault(g, set()).add(t)
    return RouteRules(
        sides=sides,
        allowed=frozenset(allowed),
        tile_gaps={t: tuple(sorted(gs)) for t, gs in tile_gaps.items()},
        gap_tiles={g: tuple(sorted(ts)) for g, ts in gap_tiles.items()},
        tile_part={t: int(comp[t]) for t in tile_gaps},
    )


def _gap_tile_lists(linkage: Linkage) -> list[list[int]]:
    return [[int(t) for t in linkage.gap_tiles(g)] for g in range(linkage.n_gaps)]


def gap_graph(linkage: Linkage, gap_centroids_flat: ArrayLike) -> nx.Graph:
    """The gap graph on the flat configuration.

    Parameters
    ----------
    linkage : topology.
    gap_centroids_flat : (G, 2) float, mm, gap centroids in the flat layout.

    Returns
    -------
    networkx.Graph with node attributes ``label`` (0, 1, -1, -2), ``position`` (2,) and
    ``tiles`` (tuple), and edge attribute ``tiles``: the tiles the two gaps share (1 or 2).  A
    route step ``u -> v`` passes one of the edge's tiles; which consecutive steps may follow
    each other is decided by :func:`contact_partners`.
    """
    pos = check_positions(linkage, gap_centroids_flat)
    labels = node_labels(linkage)
    tiles = _gap_tile_lists(linkage)
    graph = nx.Graph()
    for g in range(linkage.n_gaps):
        graph.add_node(g, label=int(labels[g]), position=pos[g], tiles=tuple(tiles[g]))
    by_tile: dict[int, list[int]] = {}
    for g, ts in enumerate(tiles):
        for t in ts:
            by_tile.setdefault(t, []).append(g)
    for t, gs in by_tile.items():
        for a in range(len(gs)):
            for b in range(a + 1, len(gs)):
                u, v = sorted((gs[a], gs[b]))
                if graph.has_edge(u, v):
                    graph.edges[u, v]["tiles"] = tuple(sorted({*graph.edges[u, v]["tiles"], t}))
                else:
                    graph.add_edge(u, v, tiles=(t,))
    return graph


def check_positions(linkage: Linkage, positions: ArrayLike) -> FloatArray:
    """The flat gap positions ``(G, 2)``, mm, of ``positions`` ``(G, >= 2)``."""
    pos = np.asarray(positions, dtype=np.float64)
    if pos.ndim != 2 or pos.shape[0] != linkage.n_gaps or pos.shape[1] < 2:
        raise InternalError(
            f"gap centroids have shape {pos.shape}; pass ({linkage.n_gaps}, 2) flat positions in mm"
        )
    return pos[:, :2]
