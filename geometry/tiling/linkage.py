"""Quad auxetic linkage topology on a (possibly cropped and split) regular grid.

Conventions (see docs/architecture.md, section 3):

* A tile is a grid cell ``(i, j)``; ``i`` counts columns (x), ``j`` rows (y).
* Tile corners are numbered counter-clockwise ``0 = BL, 1 = BR, 2 = TR, 3 = TL``; side ``k`` runs
  from corner ``k`` to corner ``k + 1`` (0 bottom, 1 right, 2 top, 3 left).
* Every grid vertex ``(i, j)`` carries one slit.  If ``i + j`` is even the slit is horizontal
  (the gap is *horizontal*) and the vertex hinges its upper pair of tiles (UL-UR) and its lower
  pair (LL-LR); if ``i + j`` is odd the slit is vertical and it hinges the left pair (UL-LL) and
  the right pair (UR-LR).  So every tile corner is hinged to at most one neighbour.
* A split is a cut along a grid line: hinges that cross it are removed.
* A gap sits at every grid vertex where at least two tiles meet along a slit segment and the slit
  is open: interior vertices (four tiles) always, boundary vertices (two or three tiles) when no
  hinge closes them.  Its sides are listed counter-clockwise around the void as (tile, side).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any, Literal, TypeVar, cast

import numpy as np

from drawstring.geometry.core.tile import Side
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray

GapKind = Literal["vertical", "horizontal", "boundary", "split"]
GAP_KINDS: tuple[GapKind, ...] = ("vertical", "horizontal", "boundary", "split")

BL, BR, TR, TL = 0, 1, 2, 3


def id_runs(ids: Iterable[int], most: int | None = None) -> str:
    """Sorted tile (or hinge, gap) ids written as runs, ``0-3, 7, 9-10``; with ``most``, only
    the first ``most`` runs and how many ids are left (``... and 12 more``)."""
    runs: list[list[int]] = []
    for i in sorted(int(x) for x in ids):
        if runs and i == runs[-1][1] + 1:
            runs[-1][1] = i
        else:
            runs.append([i, i])
    shown = runs if most is None else runs[:most]
    text = ", ".join(str(a) if a == b else f"{a}-{b}" for a, b in shown)
    rest = sum(b - a + 1 for a, b in runs[len(shown) :])
    return text + (f" and {rest} more" if rest else "")


@dataclass(frozen=True)
class Split:
    """A cut along a grid line.

    ``axis == "x"``: the vertical grid line ``x = line`` between cell columns ``line - 1`` and
    ``line``, cutting the rows ``lo <= j < hi``.  ``axis == "y"``: the horizontal line ``y = line``
    between cell rows ``line - 1`` and ``line``, cutting columns ``lo <= i < hi``.
    """

    axis: Literal["x", "y"]
    line: int
    lo: int
    hi: int

    def cuts(self, cell_a: tuple[int, int], cell_b: tuple[int, int]) -> bool:
        """Whether the hinge between two edge-adjacent cells crosses this split."""
        (ia, ja), (ib, jb) = sorted([cell_a, cell_b])
        if self.axis == "x":
            return ja == jb and ib == ia + 1 and ib == self.line and self.lo <= ja < self.hi
        return ia == ib and jb == ja + 1 and jb == self.line and self.lo <= ia < self.hi

    def contains_vertex(self, i: int, j: int) -> bool:
        """Whether grid vertex (i, j) lies on the cut part of this split's line."""
        if self.axis == "x":
            return i == self.line and self.lo <= j <= self.hi
        return j == self.line and self.lo <= i <= self.hi

    def to_json(self) -> dict[str, object]:
        return {"axis": self.axis, "line": self.line, "lo": self.lo, "hi": self.hi}


_Derived = TypeVar("_Derived")


@dataclass(frozen=True)
class Linkage:
    """Topology of a quad auxetic linkage.

    Attributes
    ----------
    grid_shape : (I, J) number of cell columns and rows of the full grid.
    tile_cells : (T, 2) int, grid cell ``(i, j)`` of each tile.
    tile_corners : (T, 4) int, grid-vertex ids of each tile's corners BL, BR, TR, TL.
    vertex_ij : (n, 2) int, grid coordinates of each grid vertex used by a tile.
    hinges : (H, 4) int, rows ``(tile_a, corner_a, tile_b, corner_b)``.
    hinge_vertex : (H,) int, grid vertex where each hinge sits (both corners lie there).
    corner_node : (T, 4) int, linkage node of each tile corner; hinged corners share a node.
    n_nodes : number of linkage nodes (hinges plus unhinged corners).
    gap_vertex : (G,) int, grid vertex of each gap.
    gap_kind : tuple of G kinds, ``vertical | horizontal | boundary | split``.
    gap_sides : (G, 4, 2) int, ``(tile, side)`` around the void counter-clockwise, ``-1`` padded.
    gap_slit : (G,) str, ``"h"`` or ``"v"``: direction of the slit the gap opens from.
    tile_component : (T,) int, component id after splits (components share no hinge).
    boundary_tile : (T,) bool, tile has a vertex on the outer boundary of the tile set.
    splits : the cuts applied.
    """

    grid_shape: tuple[int, int]
    tile_cells: IntArray
    tile_corners: IntArray
    vertex_ij: IntArray
    hinges: IntArray
    hinge_vertex: IntArray
    corner_node: IntArray
    n_nodes: int
    gap_vertex: IntArray
    gap_kind: tuple[GapKind, ...]
    gap_sides: IntArray
    gap_slit: tuple[str, ...]
    tile_component: IntArray
    boundary_tile: BoolArray
    splits: tuple[Split, ...] = field(default=())

    @property
    def n_tiles(self) -> int:
        return int(self.tile_cells.shape[0])

    @property
    def n_hinges(self) -> int:
        return int(self.hinges.shape[0])

    @property
    def n_gaps(self) -> int:
        return int(self.gap_vertex.shape[0])

    @property
    def n_components(self) -> int:
        return int(self.tile_component.max()) + 1 if self.n_tiles else 0

    def gap_tiles(self, gap: int) -> IntArray:
        """Distinct tiles around gap ``gap``, in counter-clockwise order."""
        tiles = self.gap_sides[gap, :, 0]
        return tiles[tiles >= 0]

    def hinge_edges(self) -> IntArray:
        """(H, 2) tile pairs joined by a hinge."""
        return self.hinges[:, [0, 2]]

    def derived(self, key: str, build: Callable[[Linkage], _Derived]) -> _Derived:
        """``build(self)``, computed once per linkage and kept with it (tables that follow
        from the topology alone, e.g. :func:`slit_ends`; their arrays come back read-only)."""
        cache: dict[str, Any] | None = self.__dict__.get("_derived")
        if cache is None:
            cache = {}
            object.__setattr__(self, "_derived", cache)  # frozen: not a field, not compared
        if key not in cache:
            value = build(self)
            for item in vars(value).values() if hasattr(value, "__dict__") else ():
                if isinstance(item, np.ndarray):
                    item.setflags(write=False)
            cache[key] = value
        return cast("_Derived", cache[key])

    def counts(self) -> dict[str, int]:
        return {
            "tiles": self.n_tiles,
            "hinges": self.n_hinges,
            "gaps": self.n_gaps,
            "splits": len(self.splits),
            "components": self.n_components,
            "boundary_tiles": int(self.boundary_tile.sum()),
        }


def _neighbour_cells(i: int, j: int) -> dict[str, tuple[int, int]]:
    """The four cells around grid vertex (i, j)."""
    return {"LL": (i - 1, j - 1), "LR": (i, j - 1), "UL": (i - 1, j), "UR": (i, j)}


# Corner of each of the four cells that lies on the shared grid vertex.
_CORNER_AT_VERTEX = {"LL": TR, "LR": TL, "UL": BR, "UR": BL}
# Hinged pairs per slit direction (horizontal slit: upper and lower pairs; vertical: left, right).
_HINGE_PAIRS = {"h": (("UL", "UR"), ("LL", "LR")), "v": (("UL", "LL"), ("UR", "LR"))}
# Sides bounding the void, counter-clockwise, per slit direction.
_GAP_SIDES = {
    "h": (("LL", Side.TOP), ("LR", Side.TOP), ("UR", Side.BOTTOM), ("UL", Side.BOTTOM)),
    "v": (("LR", Side.LEFT), ("UR", Side.LEFT), ("UL", Side.RIGHT), ("LL", Side.RIGHT)),
}


def slit_direction(i: int, j: int) -> str:
    """``"h"`` where ``i + j`` is even (horizontal gap), else ``"v"``."""
    return "h" if (i + j) % 2 == 0 else "v"


def build_linkage(cells: BoolArray, splits: tuple[Split, ...] = ()) -> Linkage:
    """Build the linkage topology of the tiles marked in ``cells``.

    Parameters
    ----------
    cells : (I, J) bool, which grid cells carry a tile.
    splits : cuts along grid lines; hinges crossing them are removed.

    Returns
    -------
    Linkage
        Tiles are numbered in row-major order of ``(j, i)`` (row by row from the bottom).
    """
    cells = np.asarray(cells, dtype=bool)
    n_i, n_j = cells.shape
    jj, ii = np.nonzero(cells.T)  # row-major over j then i
    tile_cells = np.stack([ii, jj], axis=1).astype(np.int64)
    tile_of_cell = -np.ones((n_i, n_j), dtype=np.int64)
    tile_of_cell[ii, jj] = np.arange(len(ii))

    # Grid vertices used by tiles.
    corner_offsets = np.array([[0, 0], [1, 0], [1, 1], [0, 1]])
    corner_ij = tile_cells[:, None, :] + corner_offsets[None, :, :]
    vertex_key = corner_ij[..., 0] * (n_j + 1) + corner_ij[..., 1]
    unique_keys, inverse = np.unique(vertex_key.ravel(), return_inverse=True)
    tile_corners = inverse.reshape(-1, 4).astype(np.int64)
    vertex_ij = np.stack([unique_keys // (n_j + 1), unique_keys % (n_j + 1)], axis=1)
    vertex_id = {(int(a), int(b)): k for k, (a, b) in enumerate(vertex_ij)}

    def tile_at(cell: tuple[int, int]) -> int:
        ci, cj = cell
        if 0 <= ci < n_i and 0 <= cj < n_j:
            return int(tile_of_cell[ci, cj])
        return -1

    hinge_rows: list[tuple[int, int, int, int]] = []
    hinge_vertex: list[int] = []
    gap_vertex: list[int] = []
    gap_kind: list[GapKind] = []
    gap_sides: list[list[tuple[int, int]]] = []
    gap_slit: list[str] = []

    for (vi, vj), vid in vertex_id.items():
        around = {name: tile_at(c) for name, c in _neighbour_cells(vi, vj).items()}
        n_present = sum(t >= 0 for t in around.values())
        slit = slit_direction(vi, vj)
        hinged_here = False
        for a, b in _HINGE_PAIRS[slit]:
            ta, tb = around[a], around[b]
            if ta < 0 or tb < 0:
                continue
            cell_a = (int(tile_cells[ta, 0]), int(tile_cells[ta, 1]))
            cell_b = (int(tile_cells[tb, 0]), int(tile_cells[tb, 1]))
            if any(s.cuts(cell_a, cell_b) for s in splits):
                continue
            hinge_rows.append((ta, _CORNER_AT_VERTEX[a], tb, _CORNER_AT_VERTEX[b]))
            hinge_vertex.append(vid)
            hinged_here = True
        # The sides along this vertex's slit that carry a tile bound the (possible) void.
        sides = [(around[name], side) for name, side in _GAP_SIDES[slit] if around[name] >= 0]
        if n_present < 2 or len(sides) < 2:
            continue  # a convex corner of the tile set: no void
        if n_present == 2 and hinged_here:
            continue  # a boundary hinge point: the two tiles are joined, nothing opens
        kind: GapKind
        if any(s.contains_vertex(vi, vj) for s in splits):
            kind = "split"
        elif n_present < 4:
            kind = "boundary"
        else:
            kind = "horizontal" if slit == "h" else "vertical"
        gap_vertex.append(vid)
        gap_kind.append(kind)
        gap_sides.append(sides)
        gap_slit.append(slit)

    hinges = np.array(hinge_rows, dtype=np.int64).reshape(-1, 4)
    corner_node = _corner_nodes(len(tile_cells), hinges)
    sides_arr = -np.ones((len(gap_sides), 4, 2), dtype=np.int64)
    for g, sides in enumerate(gap_sides):
        sides_arr[g, : len(sides)] = sides

    return Linkage(
        grid_shape=(n_i, n_j),
        tile_cells=tile_cells,
        tile_corners=tile_corners,
        vertex_ij=vertex_ij.astype(np.int64),
        hinges=hinges,
        hinge_vertex=np.array(hinge_vertex, dtype=np.int64),
        corner_node=corner_node,
        n_nodes=int(corner_node.max()) + 1 if corner_node.size else 0,
        gap_vertex=np.array(gap_vertex, dtype=np.int64),
        gap_kind=tuple(gap_kind),
        gap_sides=sides_arr,
        gap_slit=tuple(gap_slit),
        tile_component=hinged_components(len(tile_cells), hinges),
        boundary_tile=_boundary_tiles(cells, tile_cells),
        splits=tuple(splits),
    )


def _corner_nodes(n_tiles: int, hinges: IntArray) -> IntArray:
    """Number tile corners so that the two corners of a hinge share one node."""
    node = np.arange(n_tiles * 4, dtype=np.int64).reshape(n_tiles, 4)
    for ta, ca, tb, cb in hinges:
        node[tb, cb] = node[ta, ca]
    _, relabelled = np.unique(node.ravel(), return_inverse=True)
    return relabelled.reshape(n_tiles, 4).astype(np.int64)


def hinged_components(n_tiles: int, hinges: IntArray) -> IntArray:
    """The part of each tile: connected components of the tile graph whose edges are hinges
    (rows ``(a, corner_a, b, corner_b)``), numbered in the order of their first tile."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    if n_tiles == 0:
        return np.zeros(0, dtype=np.int64)
    graph = sp.coo_matrix(
        (np.ones(len(hinges)), (hinges[:, 0], hinges[:, 2])), shape=(n_tiles, n_tiles)
    )
    _, labels = connected_components(graph, directed=False)
    # Renumber so components are ordered by their first tile (deterministic).
    _, first = np.unique(labels, return_index=True)
    order = np.argsort(first)
    remap = np.empty_like(order)
    remap[order] = np.arange(len(order))
    return remap[labels].astype(np.int64)


def _boundary_tiles(cells: BoolArray, tile_cells: IntArray) -> BoolArray:
    """Tiles with at least one corner on the outer boundary of the tile set.

    A grid vertex is on the boundary when fewer than four of its cells carry tiles.
    """
    n_i, n_j = cells.shape
    padded = np.zeros((n_i + 2, n_j + 2), dtype=np.int64)
    padded[1:-1, 1:-1] = cells
    # Number of present cells around each grid vertex (i, j), i in 0..n_i, j in 0..n_j.
    around = padded[:-1, :-1] + padded[1:, :-1] + padded[:-1, 1:] + padded[1:, 1:]
    on_boundary = around < 4
    i, j = tile_cells[:, 0], tile_cells[:, 1]
    corners = on_boundary[i, j] | on_boundary[i + 1, j]
    return np.asarray(corners | on_boundary[i + 1, j + 1] | on_boundary[i, j + 1])


def rotating_squares_layout(linkage: Linkage, opening: float, side: float = 1.0) -> FloatArray:
    """Flat layout of a uniform linkage opened by ``opening`` radians (the gap angle).

    Tile ``(i, j)`` is a square of side ``side`` turned by ``-(-1)**(i + j) * opening / 2``
    about its centre, centres spaced ``side * (cos + sin)(opening / 2)`` apart.  Every hinge pair
    coincides and every gap is a rhombus whose sharp angle is ``opening``.  Useful as a known
    answer and as a starting layout.

    Returns
    -------
    (T, 4, 2) float, corner positions BL, BR, TR, TL of every tile.
    """
    half = 0.5 * opening
    pitch = side * (np.cos(half) + np.sin(half))
    cells = linkage.tile_cells
    sign = np.where((cells[:, 0] + cells[:, 1]) % 2 == 0, -1.0, 1.0)
    angle = sign * half
    centres = (cells + 0.5) * pitch
    square = 0.5 * side * np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]])
    cos, sin = np.cos(angle), np.sin(angle)
    rot = np.stack([np.stack([cos, -sin], -1), np.stack([sin, cos], -1)], -2)  # (T, 2, 2)
    return np.asarray(centres[:, None, :] + np.einsum("tij,kj->tki", rot, square))


def gap_centroids(linkage: Linkage, corners: FloatArray) -> FloatArray:
    """Centroid of every gap: the mean of the endpoints of the tile sides bounding it.

    Parameters
    ----------
    linkage : topology.
    corners : (T, 4, d) float, tile corner positions (flat top faces, or assembled tops).

    Returns
    -------
    (G, d) float.
    """
    corners = np.asarray(corners, dtype=np.float64)
    sides = linkage.gap_sides
    valid = sides[..., 0] >= 0
    tile = np.where(valid, sides[..., 0], 0)
    side = np.where(valid, sides[..., 1], 0)
    start = corners[tile, side]
    end = corners[tile, (side + 1) % 4]
    weight = valid[..., None].astype(np.float64)
    total = ((start + end) * weight).sum(axis=1)
    return np.asarray(total / (2.0 * weight.sum(axis=1)))


@dataclass(frozen=True)
class SlitEnds:
    """Slit ends of all gaps: the hinged corner pairs whose opening angle is bounded.

    At slit end ``j`` the void's side of tile ``t0`` (side ``s0``) meets the side of tile
    ``t1`` (side ``s1``) at a hinge.  The opening angle measured on face ``f`` (0 top, 4 bottom)
    is the counter-clockwise angle from ``x[t1, f + s1] - x[t1, f + s1 + 1]`` to
    ``x[t0, f + s0 + 1] - x[t0, f + s0]``.

    Attributes
    ----------
    tiles : (E, 2) int, ``(t0, t1)``.
    sides : (E, 2) int, ``(s0, s1)``.
    hinge : (E,) int, index into ``linkage.hinges`` of the hinge at the slit end.
    """

    tiles: IntArray
    sides: IntArray
    hinge: IntArray

    def angles(self, tiles: FloatArray, face: IntArray | int) -> FloatArray:
        """Opening angles ``(E,)`` in rad of tiles ``(T, 8, 2+)`` (or top corners
        ``(T, 4, 2+)`` with ``face`` 0) on ``face`` (0 top or 4 bottom, per end)."""
        f = np.broadcast_to(np.asarray(face, dtype=np.int64), (len(self.hinge),))
        t0, t1 = self.tiles[:, 0], self.tiles[:, 1]
        s0, s1 = self.sides[:, 0], self.sides[:, 1]
        u = tiles[t1, f + s1, :2] - tiles[t1, f + (s1 + 1) % 4, :2]
        v = tiles[t0, f + (s0 + 1) % 4, :2] - tiles[t0, f + s0, :2]
        cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
        return np.asarray(np.arctan2(cross, np.einsum("ki,ki->k", u, v)))


def slit_ends(linkage: Linkage) -> SlitEnds:
    """Every slit end of ``linkage``, gap by gap, in the order of ``gap_sides`` (computed once
    per linkage)."""
    return linkage.derived("slit_ends", _slit_ends)


def _slit_ends(linkage: Linkage) -> SlitEnds:
    nodes = linkage.corner_node
    hinge_at = -np.ones((linkage.n_tiles, 4), dtype=np.int64)
    h = linkage.hinges
    hinge_at[h[:, 0], h[:, 1]] = np.arange(linkage.n_hinges)
    hinge_at[h[:, 2], h[:, 3]] = np.arange(linkage.n_hinges)
    rows: list[tuple[int, int, int, int, int]] = []
    for g in range(linkage.n_gaps):
        sides = linkage.gap_sides[g]
        sides = sides[sides[:, 0] >= 0]
        count = len(sides)
        for k in range(count):
            t0, s0 = (int(v) for v in sides[k])
            t1, s1 = (int(v) for v in sides[(k + 1) % count])
            if nodes[t0, s0] != nodes[t1, (s1 + 1) % 4]:
                continue  # the two sides do not meet at a hinge
            if linkage.tile_corners[t0, s0] == linkage.gap_vertex[g]:
                continue  # a side vertex of the gap, not a slit end
            rows.append((t0, t1, s0, s1, int(hinge_at[t0, s0])))
    arr = np.array(rows, dtype=np.int64).reshape(-1, 5)
    return SlitEnds(tiles=arr[:, :2], sides=arr[:, 2:4], hinge=arr[:, 4])
