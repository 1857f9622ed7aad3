"""Linkage topology on full and cropped grids: counts against formulas, hinge rules, splits."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from drawstring.geometry.tiling.linkage import Split, build_linkage, rotating_squares_layout


def boundary_hinge_count(n_i: int, n_j: int) -> int:
    """Hinges on the outer boundary of a full I x J grid (slit parity rule, worked by hand).

    Bottom edge vertex (i, 0) joins its two cells when its slit is horizontal (i even); top edge
    (i, J) when i + J is even; left edge (0, j) when the slit is vertical (j odd); right edge
    (I, j) when I + j is odd.
    """
    bottom = sum(1 for i in range(1, n_i) if i % 2 == 0)
    top = sum(1 for i in range(1, n_i) if (i + n_j) % 2 == 0)
    left = sum(1 for j in range(1, n_j) if j % 2 == 1)
    right = sum(1 for j in range(1, n_j) if (n_i + j) % 2 == 1)
    return bottom + top + left + right


@pytest.mark.parametrize("shape", [(2, 2), (3, 2), (4, 4), (5, 3), (7, 6), (10, 10)])
def test_counts_match_formulas(shape: tuple[int, int]) -> None:
    n_i, n_j = shape
    link = build_linkage(np.ones(shape, dtype=bool))
    interior = (n_i - 1) * (n_j - 1)
    boundary_vertices = 2 * (n_i - 1) + 2 * (n_j - 1)
    b_hinges = boundary_hinge_count(n_i, n_j)
    assert link.n_tiles == n_i * n_j
    assert link.n_hinges == 2 * interior + b_hinges
    # Each interior vertex carries a 4-tile gap; each unhinged boundary vertex a 2-tile notch.
    assert link.n_gaps == interior + boundary_vertices - b_hinges
    kinds = Counter(link.gap_kind)
    assert kinds["horizontal"] + kinds["vertical"] == interior
    assert kinds["boundary"] == boundary_vertices - b_hinges
    assert link.n_components == 1
    # Tiles touching the outer boundary: the ring of the grid.
    ring = n_i * n_j - max(n_i - 2, 0) * max(n_j - 2, 0)
    assert int(link.boundary_tile.sum()) == ring


def test_4x4_matches_design_document() -> None:
    """ARCHITECTURE.md section 3: 24 hinges on 4 x 4 tiles, horizontal gaps where i + j even."""
    link = build_linkage(np.ones((4, 4), dtype=bool))
    assert link.n_hinges == 24
    for g in range(link.n_gaps):
        i, j = link.vertex_ij[link.gap_vertex[g]]
        if link.gap_kind[g] == "horizontal":
            assert (i + j) % 2 == 0
        if link.gap_kind[g] == "vertical":
            assert (i + j) % 2 == 1


@pytest.mark.parametrize("shape", [(4, 4), (6, 5)])
def test_every_corner_hinged_at_most_once_and_interior_exactly_once(shape: tuple[int, int]) -> None:
    link = build_linkage(np.ones(shape, dtype=bool))
    uses = Counter()
    for ta, ca, tb, cb in link.hinges:
        uses[(ta, ca)] += 1
        uses[(tb, cb)] += 1
        # Hinged corners sit on the same grid vertex, and the two tiles are edge neighbours.
        assert link.tile_corners[ta, ca] == link.tile_corners[tb, cb]
        assert np.abs(link.tile_cells[ta] - link.tile_cells[tb]).sum() == 1
    assert max(uses.values()) == 1
    n_i, n_j = shape
    for t, (i, j) in enumerate(link.tile_cells):
        for c, (di, dj) in enumerate([(0, 0), (1, 0), (1, 1), (0, 1)]):
            vi, vj = i + di, j + dj
            if 0 < vi < n_i and 0 < vj < n_j:
                assert uses[(t, c)] == 1, "interior corner must have exactly one hinge"


def test_checkerboard_of_gap_kinds() -> None:
    link = build_linkage(np.ones((6, 6), dtype=bool))
    kind_at = {
        tuple(link.vertex_ij[v]): k for v, k in zip(link.gap_vertex, link.gap_kind, strict=True)
    }
    for i in range(1, 6):
        for j in range(1, 6):
            expected = "horizontal" if (i + j) % 2 == 0 else "vertical"
            assert kind_at[(i, j)] == expected
            # Neighbouring interior gaps alternate.
            if i + 1 < 6:
                assert kind_at[(i + 1, j)] != expected


def test_rotating_squares_layout_closes_every_hinge() -> None:
    link = build_linkage(np.ones((5, 4), dtype=bool))
    corners = rotating_squares_layout(link, opening=np.deg2rad(40))
    h = link.hinges
    gap = np.linalg.norm(corners[h[:, 0], h[:, 1]] - corners[h[:, 2], h[:, 3]], axis=1)
    assert gap.max() < 1e-12
    # Tile sides keep unit length.
    sides = np.linalg.norm(corners - np.roll(corners, -1, axis=1), axis=2)
    assert np.allclose(sides, 1.0)


def test_gap_sides_bound_a_counter_clockwise_rhombus() -> None:
    """In the opened layout the sides listed for a gap trace its void counter-clockwise."""
    link = build_linkage(np.ones((4, 4), dtype=bool))
    corners = rotating_squares_layout(link, opening=np.deg2rad(50))
    for g in range(link.n_gaps):
        if link.gap_kind[g] not in ("horizontal", "vertical"):
            continue
        poly = []
        for tile, side in link.gap_sides[g]:
            # The void lies to the right of each tile's own counter-clockwise side, so trace the
            # side backwards (from corner side+1 to corner side).
            poly.append(corners[tile, (side + 1) % 4])
        p = np.array(poly)
        area = 0.5 * np.sum(p[:, 0] * np.roll(p[:, 1], -1) - np.roll(p[:, 0], -1) * p[:, 1])
        assert area > 0
        # All four sides of the rhombus have unit length.
        assert np.allclose(np.linalg.norm(p - np.roll(p, -1, axis=0), axis=1), 1.0)


def test_split_removes_crossing_hinges_and_separates_components() -> None:
    cells = np.ones((6, 4), dtype=bool)
    split = Split("x", 3, 0, 4)
    link = build_linkage(cells, (split,))
    assert link.n_components == 2
    for ta, _, tb, _ in link.hinges:
        # No hinge crosses the split line between columns 2 and 3.
        left = {link.tile_cells[ta, 0] < 3, link.tile_cells[tb, 0] < 3}
        assert len(left) == 1
        assert link.tile_component[ta] == link.tile_component[tb]
    comp = link.tile_component
    assert set(comp[link.tile_cells[:, 0] < 3]) != set(comp[link.tile_cells[:, 0] >= 3])
    kinds = [
        link.gap_kind[g] for g in range(link.n_gaps) if link.vertex_ij[link.gap_vertex[g]][0] == 3
    ]
    assert kinds and all(k == "split" for k in kinds)


def test_cropped_grid_has_three_tile_gap() -> None:
    cells = np.ones((3, 3), dtype=bool)
    cells[2, 2] = False  # remove a corner cell: vertex (2, 2) becomes a concave corner
    link = build_linkage(cells)
    three = [g for g in range(link.n_gaps) if len(link.gap_tiles(g)) == 3]
    assert len(three) == 1
    assert link.gap_kind[three[0]] == "boundary"
    assert tuple(link.vertex_ij[link.gap_vertex[three[0]]]) == (2, 2)


def test_derived_tables_are_built_once_per_linkage_and_read_only() -> None:
    from drawstring.geometry.flat.junctions import gap_junctions
    from drawstring.geometry.tiling.linkage import slit_ends

    linkage = build_linkage(np.ones((4, 3), dtype=bool))
    calls: list[int] = []

    def build(lk: object) -> int:
        calls.append(1)
        return 7

    assert linkage.derived("probe", build) == 7
    assert linkage.derived("probe", build) == 7
    assert len(calls) == 1
    ends = slit_ends(linkage)
    assert slit_ends(linkage) is ends
    with pytest.raises(ValueError):
        ends.hinge[0] = 0  # a caller cannot corrupt the kept table
    # a linkage with other tiles gets its own tables
    other = build_linkage(np.ones((3, 3), dtype=bool))
    assert len(slit_ends(other).hinge) != len(ends.hinge)
    assert gap_junctions(linkage) is gap_junctions(linkage)
