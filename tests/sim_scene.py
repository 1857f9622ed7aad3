"""Known-answer scene for the deployment simulation's tests and benchmarks: a cylinder patch
of exactly planar frustum tiles, its flat rotating-squares layout and a boundary-loop route.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.inputs import hinge_vertex_pairs
from drawstring.geometry.simulate.tiles import kabsch
from drawstring.geometry.tiling.linkage import Linkage, build_linkage, rotating_squares_layout

__all__ = ["DeploymentScene", "boundary_loop_route", "cylinder_scene"]


@dataclass(frozen=True)
class DeploymentScene:
    """A linkage with exactly congruent flat and assembled tiles, for tests and benchmarks.

    Attributes
    ----------
    linkage : topology of the full grid.
    tiles_flat : (T, 8, 3) float, mm, rotating-squares layout, tops at ``z = thickness``.
    tiles_assembled : (T, 8, 3) float, mm, frustums on a cylinder patch.
    hinge_vertices : (H, 2) int, top hinges.
    route : closed boundary loop, steps ``(gap, tile, enter_side, leave_side)``.
    thickness : float, mm.
    """

    linkage: Linkage
    tiles_flat: FloatArray
    tiles_assembled: FloatArray
    hinge_vertices: IntArray
    route: tuple[tuple[int, int, int, int], ...]
    thickness: float


def boundary_loop_route(linkage: Linkage) -> tuple[tuple[int, int, int, int], ...]:
    """Counter-clockwise loop through the boundary tiles of a full rectangular grid.

    Each step is ``(gap, tile, enter_side, leave_side)``; ``gap`` is the gap between the
    previous tile's leaving side and this tile's entering side (``-1`` if none).
    """
    n_i, n_j = linkage.grid_shape
    if n_i < 2 or n_j < 2:
        raise InternalError("the boundary loop needs a grid of at least 2 x 2 tiles")
    cells = (
        [(i, 0) for i in range(n_i)]
        + [(n_i - 1, j) for j in range(1, n_j)]
        + [(i, n_j - 1) for i in range(n_i - 2, -1, -1)]
        + [(0, j) for j in range(n_j - 2, 0, -1)]
    )
    index = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
    tiles = [index[c] for c in cells]
    side_of = {(1, 0): (1, 3), (0, 1): (2, 0), (-1, 0): (3, 1), (0, -1): (0, 2)}
    m = len(cells)
    leave = []
    enter = [0] * m
    for k in range(m):
        a, b = cells[k], cells[(k + 1) % m]
        s_leave, s_enter = side_of[(b[0] - a[0], b[1] - a[1])]
        leave.append(s_leave)
        enter[(k + 1) % m] = s_enter
    gap_of_side: dict[tuple[int, int], set[int]] = {}
    for g in range(linkage.n_gaps):
        for t, s in linkage.gap_sides[g]:
            if t >= 0:
                gap_of_side.setdefault((int(t), int(s)), set()).add(g)
    steps = []
    for k in range(m):
        prev = (k - 1) % m
        common = gap_of_side.get((tiles[prev], leave[prev]), set()) & gap_of_side.get(
            (tiles[k], enter[k]), set()
        )
        gap = min(common) if common else -1
        steps.append((gap, tiles[k], enter[k], leave[k]))
    return tuple(steps)


def cylinder_scene(
    n_i: int,
    n_j: int,
    *,
    side: float = 10.0,
    depth: float = 3.0,
    radius: float | None = None,
    opening: float = 0.5,
) -> DeploymentScene:
    """Frustum tiles on a cylinder patch and their flat rotating-squares layout.

    The cylinder axis is y; tile ``(i, j)`` spans angles ``theta_i .. theta_{i+1}`` (top chord
    ``side``) and ``y_j .. y_{j+1}`` (length ``side``), so every top face is an exact square of
    side ``side`` and every face of every tile is exactly planar; bottom faces lie on the
    cylinder of radius ``radius - depth``.  Neighbouring tiles share whole side faces.  The flat
    tiles are the same solids moved rigidly so that their top squares form the rotating-squares
    layout (``opening`` rad) at ``z = thickness``.

    Parameters
    ----------
    n_i, n_j : tiles along the curved and the straight direction.
    side : float, mm
    depth : float, mm, radial extrusion depth.
    radius : float, mm, default ``1.2 * n_i * side / (pi / 2)`` (about a 75 degree arc).
    opening : float, rad, gap angle of the flat layout.
    """
    if n_i < 2 or n_j < 2:
        raise InternalError("a cylinder scene needs at least 2 x 2 tiles")
    link = build_linkage(np.ones((n_i, n_j), dtype=bool))
    r_out = radius if radius is not None else 1.2 * n_i * side / (0.5 * np.pi)
    dtheta = 2.0 * np.arcsin(side / (2.0 * r_out))
    theta = (np.arange(n_i + 1) - 0.5 * n_i) * dtheta
    ys = (np.arange(n_j + 1) - 0.5 * n_j) * side

    def point(i: IntArray, j: IntArray, r: float) -> FloatArray:
        return np.stack([r * np.sin(theta[i]), ys[j], r * np.cos(theta[i])], axis=-1)

    ci, cj = link.tile_cells[:, 0], link.tile_cells[:, 1]
    corner_i = np.stack([ci, ci + 1, ci + 1, ci], axis=1)
    corner_j = np.stack([cj, cj, cj + 1, cj + 1], axis=1)
    top = point(corner_i, corner_j, r_out)
    bottom = point(corner_i, corner_j, r_out - depth)
    assembled = np.concatenate([top, bottom], axis=1)
    assembled[..., 2] -= assembled[..., 2].min()
    thickness = float(depth * np.cos(0.5 * dtheta))

    squares = rotating_squares_layout(link, opening, side)  # (T, 4, 2)
    flat = np.empty_like(assembled)
    for t in range(link.n_tiles):
        target = np.concatenate([squares[t], np.full((4, 1), thickness)], axis=1)
        rot, shift = kabsch(assembled[t, :4], target)
        flat[t] = assembled[t] @ rot.T + shift
    flat[..., 2] -= flat[..., 2].min()
    return DeploymentScene(
        linkage=link,
        tiles_flat=flat,
        tiles_assembled=assembled,
        hinge_vertices=hinge_vertex_pairs(link),
        route=boundary_loop_route(link),
        thickness=thickness,
    )
