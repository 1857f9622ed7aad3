"""The vocabulary of the flat layout: tile edges and the junctions of the gaps.

A gap junction is a corner where two consecutive sides of a gap meet at a shared (hinge) node;
the junctions at the ends of a gap's slit carry the opening angles the layout bounds.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drawstring.geometry.core.types import BoolArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage

#: Tile edges as corner pairs: 4 sides (side k from corner k to k+1), then the 2 diagonals.
TILE_EDGES: IntArray = np.array([[0, 1], [1, 2], [2, 3], [3, 0], [0, 2], [1, 3]], dtype=np.int64)


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
    tiles : (J, 2) int
        ``(t0, t1)``: the tile whose side arrives at the apex (arm ``p``) and the tile whose side
        leaves it (arm ``q``), counter-clockwise around the void.
    sides : (J, 2) int
        ``(s0, s1)``: those sides' indices.
    """

    elements: IntArray
    gap: IntArray
    is_end: BoolArray
    tiles: IntArray
    sides: IntArray

    @property
    def ends(self) -> IntArray:
        """(E, 3) int, the slit-end junctions."""
        return self.elements[self.is_end]


def gap_junctions(linkage: Linkage) -> GapJunctions:
    """All hinge junctions of all gaps (computed once per linkage).

    Side ``(tile, k)`` runs from corner ``k`` to ``k + 1`` counter-clockwise around the tile, so
    counter-clockwise around the void it runs from corner ``k + 1`` to corner ``k``.  Consecutive
    sides that share a node form a junction; it is a slit end when its node is not at the gap's
    own grid vertex.
    """
    return linkage.derived("gap_junctions", _gap_junctions)


def _gap_junctions(linkage: Linkage) -> GapJunctions:
    elements: list[tuple[int, int, int]] = []
    gaps: list[int] = []
    ends: list[bool] = []
    tile_side: list[tuple[int, int, int, int]] = []
    cn = linkage.corner_node
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        m = len(sides)
        for k in range(m):
            t0, s0 = (int(v) for v in sides[k])
            t1, s1 = (int(v) for v in sides[(k + 1) % m])
            end_node = cn[t0, s0]  # side k ends (void-ccw) at corner s0
            start_node = cn[t1, (s1 + 1) % 4]
            if end_node != start_node:
                continue
            p = int(cn[t0, (s0 + 1) % 4])  # previous point along the void
            q = int(cn[t1, s1])  # next point along the void
            elements.append((int(end_node), q, p))
            gaps.append(g)
            tile_side.append((t0, t1, s0, s1))
            at_vertex = linkage.tile_corners[t0, s0] == linkage.gap_vertex[g]
            ends.append(not bool(at_vertex))
    return GapJunctions(
        elements=np.array(elements, dtype=np.int64).reshape(-1, 3),
        gap=np.array(gaps, dtype=np.int64),
        is_end=np.array(ends, dtype=bool),
        tiles=np.array(tile_side, dtype=np.int64).reshape(-1, 4)[:, :2],
        sides=np.array(tile_side, dtype=np.int64).reshape(-1, 4)[:, 2:],
    )


def edge_pairs(linkage: Linkage) -> IntArray:
    """(T * 6, 2) node pairs of every tile's sides and diagonals."""
    cn = linkage.corner_node
    return np.stack([cn[:, TILE_EDGES[:, 0]], cn[:, TILE_EDGES[:, 1]]], axis=-1).reshape(-1, 2)
