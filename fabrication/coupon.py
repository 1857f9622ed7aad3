"""The test coupon: a small design with every CAD feature, made without the design pipeline.

:func:`cylinder_design` lays an ``I x J`` grid of tiles on a patch of a cylinder (axis along
y).  Each tile is the exact frustum between radii ``R`` and ``R - h`` over one grid cell, so
its faces are planar and neighbouring tiles share their contact faces.  The flat pose puts
each tile, moved rigidly, on the ``rotating_squares_layout`` square of its cell (top faces at
one height, bottom faces on z = 0).  It carries a split with a magnet pair, a route through
every tile with lift bores, hinges on both faces and trimmed corners: what a maker checks on
a coupon before a long print (``drawstring coupon``, :func:`coupon_design`), and what the
tests and benchmarks build solids from.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import ESTIMATE_AREA_FACTOR, Profile
from drawstring.geometry.tiling.linkage import (
    Linkage,
    Split,
    build_linkage,
    rotating_squares_layout,
)

SIDE_BOTTOM, SIDE_RIGHT, SIDE_TOP, SIDE_LEFT, TOP_FACE = 0, 1, 2, 3, 4


@dataclass(frozen=True)
class SampleDesign:
    """Inputs of :func:`drawstring.cad.design.build_design_solids` for a synthetic design."""

    linkage: Linkage
    tiles_2d: NDArray[np.float64]
    tiles_3d: NDArray[np.float64]
    hinge_side: tuple[str, ...]
    route_steps: NDArray[np.int64]
    lift_tiles: NDArray[np.int64]
    magnet_pairs: NDArray[np.int64]
    trims: dict[int, list[NDArray[np.float64]]]

    def solid_inputs(self) -> tuple[Any, ...]:
        """The design's positional arguments of ``build_design_solids`` before ``profile``."""
        return (
            self.tiles_2d,
            self.tiles_3d,
            self.linkage.hinges,
            self.hinge_side,
            self.route_steps,
            self.lift_tiles,
            self.magnet_pairs,
            self.trims,
        )


def cylinder_tiles(
    cells: tuple[int, int], side: float, thickness: float, radius: float
) -> NDArray[np.float64]:
    """(T, 8, 3) float, mm: frustum tiles of an ``I x J`` grid on a cylinder (tile order of
    :func:`build_linkage`: row by row from the bottom)."""
    n_i, n_j = cells
    step = 2.0 * np.arcsin(side / (2.0 * radius))
    grid_j, grid_i = np.meshgrid(np.arange(n_j), np.arange(n_i), indexing="ij")
    ii, jj = grid_i.ravel(), grid_j.ravel()
    corner_i = ii[:, None] + np.array([0, 1, 1, 0])
    corner_j = jj[:, None] + np.array([0, 0, 1, 1])
    theta = (corner_i - 0.5 * n_i) * step
    y = corner_j * side
    tiles = np.zeros((len(ii), 8, 3))
    for offset, r in ((0, radius), (4, radius - thickness)):
        tiles[:, offset : offset + 4] = np.stack([r * np.sin(theta), y, r * np.cos(theta)], -1)
    return tiles


def _rigid_onto(source: NDArray[np.float64], target: NDArray[np.float64]) -> NDArray:
    """(4, 4) rigid motion taking the (k, 3) points ``source`` onto ``target`` (Kabsch)."""
    src_mean, dst_mean = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - src_mean).T @ (target - dst_mean))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    rotation = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    transform = np.eye(4)
    transform[:3, :3] = rotation
    transform[:3, 3] = dst_mean - rotation @ src_mean
    return transform


def _corner_chip(tile: NDArray[np.float64], corner: int, size: float) -> NDArray[np.float64]:
    """(4, 3): a tetrahedron that chips the top corner ``corner`` of a tile."""
    apex = tile[corner]
    towards = (tile[(corner + 1) % 4], tile[(corner + 3) % 4], tile[4 + corner])
    directions = [(t - apex) / np.linalg.norm(t - apex) for t in towards]
    outward = -sum(directions)
    return np.array([apex + size * d for d in directions] + [apex + 0.5 * size * outward])


def cylinder_design(
    cells: tuple[int, int] = (3, 3),
    side: float = 12.0,
    thickness: float = 6.0,
    radius: float = 40.0,
    opening: float = 0.5,
) -> SampleDesign:
    """A design with every feature on an ``I x J`` grid of tiles.

    * one split: the hinge between cells ``(I-2, 1)`` and ``(I-1, 1)`` is cut; its two
      touching faces carry a magnet pair;
    * a route that snakes row by row through every tile, entering the first tile and leaving
      the last through the top face (lift points), and one extra lift bore in cell ``(1, 1)``;
    * hinges on the bottom faces except every third one, on the top;
    * a trim (corner chip) at top corner 0 of the tiles whose hinges are all on the bottom and
      whose corner 0 is not hinged (stands in for the top-hinge overlap trims).
    """
    n_i, n_j = cells
    if n_i < 3 or n_j < 2:
        raise ValueError("the sample needs at least 3 x 2 cells")
    splits = (Split("x", n_i - 1, 1, 2),)
    linkage = build_linkage(np.ones((n_i, n_j), dtype=bool), splits)
    tiles_3d = cylinder_tiles(cells, side, thickness, radius)
    squares = rotating_squares_layout(linkage, opening, side)
    step = 2.0 * np.arcsin(side / (2.0 * radius))
    top_height = thickness * np.cos(0.5 * step)
    tiles_2d = np.empty_like(tiles_3d)
    for t in range(linkage.n_tiles):
        target = np.hstack([squares[t], np.full((4, 1), top_height)])
        transform = _rigid_onto(tiles_3d[t, :4], target)
        tiles_2d[t] = tiles_3d[t] @ transform[:3, :3].T + transform[:3, 3]

    def tile_of(i: int, j: int) -> int:
        return j * n_i + i

    steps = []
    for j in range(n_j):
        order = range(n_i) if j % 2 == 0 else range(n_i - 1, -1, -1)
        forward, backward = (SIDE_RIGHT, SIDE_LEFT) if j % 2 == 0 else (SIDE_LEFT, SIDE_RIGHT)
        for k, i in enumerate(order):
            enter = backward if k > 0 else (TOP_FACE if j == 0 else SIDE_BOTTOM)
            leave = forward if k < n_i - 1 else (TOP_FACE if j == n_j - 1 else SIDE_TOP)
            steps.append((tile_of(i, j), enter, leave))
    route = np.array(steps, dtype=np.int64)
    lifts = np.array([[tile_of(1, 1), SIDE_BOTTOM]], dtype=np.int64)
    magnets = np.array(
        [[tile_of(n_i - 2, 1), SIDE_RIGHT, tile_of(n_i - 1, 1), SIDE_LEFT]], dtype=np.int64
    )
    hinge_side = tuple("top" if h % 3 == 0 else "bottom" for h in range(linkage.n_hinges))
    hinged = {(int(a), int(ca)) for a, ca, _, _ in linkage.hinges}
    hinged |= {(int(b), int(cb)) for _, _, b, cb in linkage.hinges}
    top_tiles = {int(linkage.hinges[h, k]) for h in range(0, linkage.n_hinges, 3) for k in (0, 2)}
    trims = {
        t: [_corner_chip(tiles_2d[t], 0, 0.12 * side)]
        for t in range(linkage.n_tiles)
        if (t, 0) not in hinged and t not in top_tiles
    }
    return SampleDesign(linkage, tiles_2d, tiles_3d, hinge_side, route, lifts, magnets, trims)


#: Cells of the coupon, each way.
COUPON_CELLS = (3, 3)


def coupon_side_mm(profile: Profile) -> float:
    """The coupon's tile side (mm): a tile of the profile's default design (its default tiles
    covering ``ESTIMATE_AREA_FACTOR`` times its default size squared)."""
    area = ESTIMATE_AREA_FACTOR * profile.default_size_mm**2
    return round(float(np.sqrt(area / profile.default_tiles)), 1)


def coupon_design(profile: Profile) -> SampleDesign:
    """The coupon of a profile: 3 x 3 tiles of its default design's size and thickness on a
    cylinder of its default size's radius (:func:`cylinder_design`)."""
    return cylinder_design(
        COUPON_CELLS,
        side=coupon_side_mm(profile),
        thickness=profile.thickness_mm,
        radius=profile.default_size_mm,
    )
