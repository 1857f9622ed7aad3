"""Hierarchical splits of a tiling into parts whose conformal scale ratio is within a bound.

Each part that exceeds the bound is cut along a grid line; the cut is chosen through the part's
interior grid vertex of highest absolute Gaussian curvature when that helps, else among every
grid line across the part (:func:`choose_splits`).  Where those greedy cuts leave a part that
no line may divide, the cut sequences are searched depth first (:func:`_searched_splits`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import numpy as np
from scipy import ndimage

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage, Split

log = logging.getLogger(__name__)

#: A split never leaves a part narrower than this many cells across the cut (a thinner strip has
#: no interior gaps to pull shut and would hang off its neighbours by magnets alone).
MIN_PART_CELLS = 3

#: Cut lines tried per part, best-scored first, when the greedy cuts leave a part over the
#: bound (:func:`_searched_splits`), and the cuts that search may try in all (each costs the
#: scale ratios of its pieces, a few ms each at 200 tiles).
SPLIT_SEARCH_LINES = 6
SPLIT_SEARCH_BUDGET = 400


def choose_splits(
    cells: BoolArray,
    base: Linkage,
    vertex_gauss: FloatArray,
    bound: float,
    part_ratio: Callable[[IntArray], float],
) -> tuple[tuple[Split, ...], int]:
    """Split hierarchically until every part's scale ratio is within ``bound``.

    Each part that exceeds the bound is cut along the grid line (vertical or horizontal) through
    its interior grid vertex of highest absolute Gaussian curvature, choosing the direction whose
    worse half has the smaller ratio.  When neither line through that point helps, every grid line
    across the part is tried.  Only cuts that leave every piece with a tile on the outer boundary
    count: the string never enters a part through a cut (paper, "Connecting splits"), so a piece
    enclosed by other parts could not be pulled into shape.  ``part_ratio`` gives the scale ratio
    of a part from its tiles' corner vertex ids ``(t, 4)``.  Returns the splits and how many
    parts still exceed the bound.

    Where the greedy cuts leave a part over the bound (they can fence a region in so that no
    line may divide it: a line must leave every piece on the outer boundary and
    :data:`MIN_PART_CELLS` wide), the cut sequences are searched depth first
    (:func:`_searched_splits`), and the search's cuts are kept when they leave no part over it.
    """
    splitter = _PartSplitter(cells, base, vertex_gauss, part_ratio)
    splits: list[Split] = []
    unmet = 0
    queue = [cells.copy()]
    while queue:
        mask = queue.pop(0)
        if splitter.ratio_of(mask) <= bound:
            continue
        lines = splitter.candidate_lines(mask)
        if not lines:
            unmet += 1
            continue
        best_vertex = splitter.peak_vertex(mask)
        through_peak = []
        if best_vertex is not None:
            through_peak = [c for c in (("x", best_vertex[0]), ("y", best_vertex[1])) if c in lines]
        current = splitter.ratio_of(mask)
        scored = sorted((splitter.score(mask, a, ln), a, ln) for a, ln in through_peak)
        if not scored or scored[0][0][0] >= current:
            scored = sorted((splitter.score(mask, a, ln), a, ln) for a, ln in lines)
        (_, _), axis, line = scored[0]
        lo, hi = splitter.cut_range(mask, axis, line)
        splits.append(Split("x" if axis == "x" else "y", line, lo, hi))
        log.info("split along %s = %d (cells %d..%d)", axis, line, lo, hi)
        queue.extend(splitter.halves(mask, axis, line))
    if unmet:
        searched = _searched_splits(splitter, cells, bound)
        if searched is not None:
            log.info("split search: every part within the bound (greedy cuts left %d over)", unmet)
            return searched, 0
    return tuple(splits), unmet


def _searched_splits(
    splitter: _PartSplitter, cells: BoolArray, bound: float
) -> tuple[Split, ...] | None:
    """Cuts that leave every part within ``bound``, found depth first, or None.

    Each part over the bound tries its :data:`SPLIT_SEARCH_LINES` best-scored lines in turn,
    its pieces searched the same way (memoized by their cells), until one line leaves no piece
    over the bound; at most :data:`SPLIT_SEARCH_BUDGET` cuts in all.
    """
    budget = [SPLIT_SEARCH_BUDGET]
    memo: dict[bytes, tuple[int, float, list[Split]]] = {}

    def search(mask: BoolArray) -> tuple[int, float, list[Split]]:
        """(parts left over the bound, their worst ratio, the cuts) for the part ``mask``."""
        key = np.packbits(mask).tobytes()
        if key in memo:
            return memo[key]
        current = splitter.ratio_of(mask)
        result: tuple[int, float, list[Split]] = (0, current, [])
        if current > bound:
            result = (1, current, [])
            lines = splitter.candidate_lines(mask) if budget[0] > 0 else []
            ranked = sorted((splitter.score(mask, a, ln), a, ln) for a, ln in lines)
            for _, axis, line in ranked[:SPLIT_SEARCH_LINES]:
                if budget[0] <= 0:
                    break
                budget[0] -= 1
                lo, hi = splitter.cut_range(mask, axis, line)
                found = [Split("x" if axis == "x" else "y", line, lo, hi)]
                over, worst = 0, 0.0
                for piece in splitter.halves(mask, axis, line):
                    n, ratio, more = search(piece)
                    over, worst = over + n, max(worst, ratio)
                    found += more
                if (over, worst) < result[:2]:
                    result = (over, worst, found)
                if over == 0:
                    break
        memo[key] = result
        return result

    over, _, found = search(cells.copy())
    return tuple(found) if over == 0 else None


class _PartSplitter:
    """The parts of one tiling as cell masks: their scale ratios (cached by mask), the grid
    lines that may cut them and the pieces a cut leaves."""

    def __init__(
        self,
        cells: BoolArray,
        base: Linkage,
        vertex_gauss: FloatArray,
        part_ratio: Callable[[IntArray], float],
    ) -> None:
        self.cells = cells
        self.base = base
        self.vertex_gauss = vertex_gauss
        self.part_ratio = part_ratio
        n_i, n_j = cells.shape
        self.tile_of_cell = -np.ones((n_i, n_j), dtype=np.int64)
        self.tile_of_cell[base.tile_cells[:, 0], base.tile_cells[:, 1]] = np.arange(base.n_tiles)
        self.vertex_of_ij = {(int(a), int(b)): k for k, (a, b) in enumerate(base.vertex_ij)}
        self.outer = np.zeros_like(cells)
        boundary = base.tile_cells[base.boundary_tile]
        self.outer[boundary[:, 0], boundary[:, 1]] = True
        self.cache: dict[bytes, float] = {}

    def ratio_of(self, mask: BoolArray) -> float:
        """Scale ratio of the part ``mask``."""
        key = np.packbits(mask).tobytes()
        if key not in self.cache:
            self.cache[key] = self.part_ratio(self.base.tile_corners[self.tile_of_cell[mask]])
        return self.cache[key]

    def halves(self, mask: BoolArray, axis: str, line: int) -> list[BoolArray]:
        """The connected pieces of ``mask`` on either side of the grid line."""
        low = mask.copy()
        high = mask.copy()
        if axis == "x":
            low[line:, :] = False
            high[:line, :] = False
        else:
            low[:, line:] = False
            high[:, :line] = False
        parts: list[BoolArray] = []
        for half in (low, high):
            labels, count = ndimage.label(half)
            parts.extend(np.asarray(labels == k) for k in range(1, count + 1))
        return parts

    def cut_range(self, mask: BoolArray, axis: str, line: int) -> tuple[int, int]:
        """First and one-past-last cell along the line that the cut separates."""
        if axis == "x":
            rows = np.nonzero(mask[line - 1, :] & mask[line, :])[0]
        else:
            rows = np.nonzero(mask[:, line - 1] & mask[:, line])[0]
        return int(rows.min()), int(rows.max()) + 1

    def candidate_lines(self, mask: BoolArray) -> list[tuple[str, int]]:
        """Grid lines that may cut the part: ``MIN_PART_CELLS`` from its ends, separating cells
        of it into pieces that each reach the outer boundary."""
        ii, jj = np.nonzero(mask)
        lines: list[tuple[str, int]] = []
        # Leave at least MIN_PART_CELLS columns (rows) of the part on each side of a cut.
        lines += [
            ("x", int(x)) for x in range(ii.min() + MIN_PART_CELLS, ii.max() + 2 - MIN_PART_CELLS)
        ]
        lines += [
            ("y", int(y)) for y in range(jj.min() + MIN_PART_CELLS, jj.max() + 2 - MIN_PART_CELLS)
        ]
        # Keep only lines that actually separate cells of the part, into pieces that each
        # reach the outer boundary.
        valid = []
        for axis, line in lines:
            if axis == "x":
                across = mask[line - 1, :] & mask[line, :]
            else:
                across = mask[:, line - 1] & mask[:, line]
            if np.any(across) and all(
                (p & self.outer).any() for p in self.halves(mask, axis, line)
            ):
                valid.append((axis, line))
        return valid

    def score(self, mask: BoolArray, axis: str, line: int) -> tuple[float, int]:
        """The worse piece's scale ratio and the size spread of the pieces of a cut."""
        parts = self.halves(mask, axis, line)
        sizes = [int(p.sum()) for p in parts]
        return max(self.ratio_of(p) for p in parts), max(sizes) - min(sizes)

    def peak_vertex(self, mask: BoolArray) -> tuple[int, int] | None:
        """Interior grid vertex of the part with the largest |K| (None: no interior vertex)."""
        n_i, n_j = mask.shape
        best_vertex: tuple[int, int] | None = None
        best_k = -1.0
        ii, jj = np.nonzero(mask)
        for i, j in zip(ii.tolist(), jj.tolist(), strict=True):
            for vi, vj in ((i + 1, j + 1),):
                if vi < n_i and vj < n_j and mask[i : i + 2, j : j + 2].all():
                    k = abs(float(self.vertex_gauss[self.vertex_of_ij[(vi, vj)]]))
                    if k > best_k:
                        best_k, best_vertex = k, (vi, vj)
        return best_vertex
