"""Hinged tiles lying flat: where their hinges are and how far they must open to clear.

:func:`hinge_points` gives each tile's hinge points seen from above (a bottom hinge's point is
its bottom corner), which the flat layout makes meet.  :func:`free_openings` gives the openings
at which the two tiles of a hinge do not collide.

In the flat pose every tile is a frustum standing on the plane: its top and bottom faces are
horizontal and lie at the same two heights for all tiles (up to their thickness differences).
Two tiles hinged at a corner ``H`` of one face (the *hinge face*, top or bottom) can only turn
about the vertical axis through ``H`` relative to each other, so whether they interpenetrate
depends on one number: the opening angle of the void between them at ``H``, measured on the
hinge face.

Two convex frustums in one slab are disjoint exactly when a plane separates them, and such a
plane meets the two face heights in two parallel lines.  For a hinged pair the line at the hinge
face passes through ``H``; the one at the other face may sit anywhere.  So the pair is separable
along a horizontal unit direction ``n`` when

* every hinge-face vertex of tile ``b`` lies at least ``clearance`` beyond ``H`` along ``n``
  and every one of tile ``a`` at least ``clearance`` behind it (``H`` itself excepted), and
* along ``n`` the other face of ``b`` starts at least ``2 * clearance`` beyond the end of
  ``a``'s other face (the corners above or below ``H``, shared in T3D, may come within
  ``touch`` of crossing it: where the side faces at the hinge are vertical they sit on it).

:func:`free_openings` finds, per slit end, the first interval of hinge-face openings at which
some ``n`` passes both tests: openings on a grid, then each end of the interval bisected, with
``n`` sampled across the void at the hinge and refined.  The flat layout keeps each slit end's
opening inside it, so the hinge stage starts from tiles that already clear each other.  Tiles
are treated as the convex hulls of their eight vertices (conservative for dart-shaped tiles).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.parallel import map_blocks, thread_count
from drawstring.geometry.core.rigid import apply_rigid, rigid_fit
from drawstring.geometry.core.tolerances import (
    FLAT_FREE_MARGIN_DEG,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_TOUCH_MM,
)
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.tiling.linkage import Linkage, slit_ends

__all__ = ["HingeFaces", "free_openings", "hinge_faces", "hinge_points", "lay_flat"]

#: Separating-line directions sampled across the void at the hinge, then within one sample
#: spacing of the best one.
_WEDGE_SAMPLES = 16
_FINE_SAMPLES = 17
#: Openings tested on a grid over [0, 90] deg, then each end of the separable run bisected
#: (resolution 6 / 2**10 deg).
_GRID = 15
_BISECTIONS = 10
#: Most (end, opening) checks in one block: their (rows, 16) direction samples stay in the
#: caches (1600 tiles, 50k checks: 0.29 s in two blocks, 0.20 s in blocks of 2048).
_CHECK_BLOCK_ROWS = 2048

#: :meth:`HingeFaces.closing`: an opening this close to its window's end (beyond
#: ``FLAT_FREE_MARGIN_DEG``) is held by it, and a window end that moved more than
#: ``CLOSING_SHIFT_DEG`` towards the opening has closed on it.  On the 200-tile seashell's two
#: parts one slit end's window shrank from 16.5 to 14.2 deg over seven co-optimization rounds,
#: every joint solve pressing the opening against it, and the re-solved layouts stalled at
#: 3e-3 mm (hinge layout 5.3e-4 mm); released after its second round the rounds end in three
#: at 5.9e-4 mm.
CLOSING_BIND_DEG = 0.05
CLOSING_SHIFT_DEG = 0.01


@dataclass(frozen=True)
class HingeFaces:
    """The faces of a ``dual`` layout's hinges and where their tiles clear each other.

    Attributes
    ----------
    bottom : (H,) bool
        True: the hinge joins bottom corners.
    clear_lo, clear_hi : (E,) float, rad
        :func:`free_openings` of the tiles they were made for, per slit end.
    released : (E,) bool or None
        Slit ends laid out without their clear openings, like those that never clear: the
        co-optimization releases an end whose window kept closing on it from one round to the
        next (:meth:`closing`); the hinge stage trims such a pair's overlap.
    """

    bottom: BoolArray
    clear_lo: FloatArray
    clear_hi: FloatArray
    released: BoolArray | None = None

    def window(self, lo: ArrayLike, hi: ArrayLike) -> tuple[FloatArray, FloatArray, BoolArray]:
        """The openings within the bounds ``lo``, ``hi`` (rad, per slit end or one for all) at
        which each slit end's tiles clear each other, ``FLAT_FREE_MARGIN_DEG`` inside the clear
        interval: ``(E,)`` lower and upper ends, and whether that window is not empty."""
        margin = np.radians(FLAT_FREE_MARGIN_DEG)
        new_lo = np.maximum(lo, self.clear_lo + margin)
        new_hi = np.minimum(hi, self.clear_hi - margin)
        fits = new_lo <= new_hi
        if self.released is not None:
            fits &= ~self.released
        return new_lo, new_hi, np.asarray(fits)

    def closing(self, newer: HingeFaces, opening: ArrayLike) -> BoolArray:
        """Slit ends ``(E,)`` whose ``opening`` (rad, on the hinge face, laid out in this
        window) stands at an end of the window, within :data:`CLOSING_BIND_DEG`, and whose
        window in ``newer`` (the same hinges on moved tiles) moved inwards past that end by more
        than :data:`CLOSING_SHIFT_DEG`."""
        at = np.asarray(opening, dtype=np.float64)
        margin = np.radians(FLAT_FREE_MARGIN_DEG + CLOSING_BIND_DEG)
        shift = np.radians(CLOSING_SHIFT_DEG)
        at_hi = (at >= self.clear_hi - margin) & (newer.clear_hi < self.clear_hi - shift)
        at_lo = (at <= self.clear_lo + margin) & (newer.clear_lo > self.clear_lo + shift)
        return np.asarray(at_hi | at_lo)


def lay_flat(tiles_3d: ArrayLike) -> FloatArray:
    """Every tile moved rigidly so that its top face lies in ``z = 0``, facing up ``(T, 8, 3)``."""
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    top = tiles[:, :4]
    normal = np.cross(top[:, 2] - top[:, 0], top[:, 3] - top[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    ex = top[:, 1] - top[:, 0]
    ex -= np.einsum("ki,ki->k", ex, normal)[:, None] * normal
    ex /= np.maximum(np.linalg.norm(ex, axis=1, keepdims=True), 1e-300)
    ey = np.cross(normal, ex)
    centred = top - top.mean(axis=1, keepdims=True)
    flat = np.stack(
        [
            np.einsum("kvi,ki->kv", centred, ex),
            np.einsum("kvi,ki->kv", centred, ey),
            np.einsum("kvi,ki->kv", centred, normal),
        ],
        axis=-1,
    )
    rot, trans = rigid_fit(top, flat)
    return apply_rigid(rot, trans, tiles)


def hinge_faces(linkage: Linkage, tiles_3d: ArrayLike, bottom: ArrayLike) -> HingeFaces:
    """:class:`HingeFaces` of T3D tiles with hinge sides ``bottom`` (clearances as the rigid
    hinge layout asks them)."""
    side = np.asarray(bottom, dtype=bool)
    lo, hi = free_openings(
        linkage, lay_flat(tiles_3d), side,
        clearance=HINGE_LAYOUT_CLEARANCE_MM, touch=HINGE_LAYOUT_TOUCH_MM,
    )  # fmt: skip
    return HingeFaces(side, lo, hi)


def hinge_points(linkage: Linkage, tiles_3d: ArrayLike, bottom: ArrayLike) -> FloatArray:
    """Every tile's hinge points in its top plane ``(T, 4, 3)``, mm (T3D).

    A corner with a top hinge (or none) keeps its top vertex ``P``; at a bottom hinge it is
    ``P`` plus the bottom vertex's offset ``Q - P`` projected onto the tile's top plane, which
    is where the bottom corner lies seen from above once the tile lies flat.  A flat layout of
    these points (``optimize_flat(..., anchor_3d=...)``) makes hinged corners meet on the face
    that carries their hinge.

    Parameters
    ----------
    linkage : Linkage
    tiles_3d : (T, 8, 3) float, mm
    bottom : (H,) bool
        Hinge sides (True: bottom face).
    """
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    side = np.asarray(bottom, dtype=bool)
    top = tiles[:, :4]
    normal = np.cross(top[:, 2] - top[:, 0], top[:, 3] - top[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    offset = tiles[:, 4:] - top
    offset -= np.einsum("tci,ti->tc", offset, normal)[..., None] * normal[:, None]
    h = linkage.hinges
    at_bottom = np.zeros((linkage.n_tiles, 4), dtype=bool)
    at_bottom[h[side, 0], h[side, 1]] = True
    at_bottom[h[side, 2], h[side, 3]] = True
    return np.asarray(top + np.where(at_bottom[..., None], offset, 0.0))


def _separable(
    a_hinge: FloatArray,
    b_hinge: FloatArray,
    a_other: FloatArray,
    b_other: FloatArray,
    need_a: FloatArray,
    need_b: FloatArray,
    clearance: float,
    turn: FloatArray,
) -> BoolArray:
    """Whether each pair ``(E,)`` is separable once tile ``b`` turned by ``turn`` about ``H``.

    The separating line through ``H`` runs through the void between the two hinge-face sides
    that meet at ``H`` (``b``'s side to its corner ``rest[2]``, ``a``'s to ``rest[0]``), so its
    direction is sampled across that wedge only, then refined around the best sample.
    """
    c, s = np.cos(turn)[:, None], np.sin(turn)[:, None]

    def turned(p: FloatArray) -> FloatArray:
        return np.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], axis=-1)

    bh, bo = turned(b_hinge), turned(b_other)
    lo_a = need_a[:, :, None]  # (E, v, 1)
    lo_b = need_b[:, :, None]

    def margins(az: FloatArray) -> FloatArray:
        cx, sy = np.cos(az), np.sin(az)  # (E, K)

        def extreme(p: FloatArray, pick: np.ufunc, shift: FloatArray | None = None) -> FloatArray:
            # the smallest or largest of ``p``'s vertices (plus ``shift``) along each direction,
            # vertex by vertex: (E, K) slabs instead of a strided reduction over (E, v, K)
            out: FloatArray | None = None
            for v in range(p.shape[1]):
                d = p[:, v, 0, None] * cx + p[:, v, 1, None] * sy
                if shift is not None:
                    d = d + shift[:, v]
                out = d if out is None else pick(out, d)
            assert out is not None
            return out

        hinge_b = extreme(bh, np.minimum) - clearance
        hinge_a = -extreme(a_hinge, np.maximum) - clearance
        other = extreme(bo, np.minimum, -lo_b) - extreme(a_other, np.maximum, lo_a)
        return np.asarray(np.minimum(np.minimum(hinge_b, hinge_a), 0.5 * other))

    start = np.arctan2(bh[:, 2, 1], bh[:, 2, 0])  # b's side leaving H
    stop = np.arctan2(a_hinge[:, 0, 1], a_hinge[:, 0, 0])  # a's side arriving at H
    width = np.mod(stop - start, 2.0 * np.pi)  # the void's opening, counter-clockwise
    frac = np.linspace(0.0, 1.0, _WEDGE_SAMPLES)
    # the line's normal points to b's side: the line direction turned by -90 deg
    az = start[:, None] + width[:, None] * frac[None, :] - 0.5 * np.pi
    m = margins(az)
    best = az[np.arange(len(az)), np.argmax(m, axis=1)]
    step = width / (_WEDGE_SAMPLES - 1)
    fine = np.linspace(-1.0, 1.0, _FINE_SAMPLES)
    refined = margins(best[:, None] + step[:, None] * fine[None, :])
    return np.asarray(np.maximum(m.max(axis=1), refined.max(axis=1)) >= 0.0)


def free_openings(
    linkage: Linkage,
    tiles: ArrayLike,
    bottom: ArrayLike,
    *,
    clearance: float,
    touch: float,
) -> tuple[FloatArray, FloatArray]:
    """Collision-free openings ``[lo, hi]`` at every slit end, on its hinge face, rad.

    Parameters
    ----------
    linkage : Linkage
    tiles : (T, 8, 3) float, mm
        Tiles in any flat pose (top faces horizontal, e.g. ``extrude_flat`` of a flat layout);
        only each tile's own shape matters, not where it lies.
    bottom : (H,) bool
        Hinge side of every hinge (True: bottom face).
    clearance, touch : float, mm
        Distance required between a pair's separating plane and its vertices; the corners
        above or below the hinge may cross it by ``touch``.

    Returns
    -------
    lo, hi : (E,) float, rad
        In the order of :func:`~drawstring.geometry.tiling.linkage.slit_ends`: the first interval of
        separable openings within ``[0, pi / 2]`` (``lo > hi`` where there is none).  A low
        ``hi`` means the tiles meet on the hinge's far side when the gap opens wide.
    """
    pairs = _slit_end_pairs(linkage, tiles, bottom, clearance, touch)
    if pairs is None:
        return np.zeros(0), np.zeros(0)
    n_ends = len(pairs.current)
    ok = pairs.separable

    # Every end is checked on its own (row by row), so all the openings on the grid are
    # checked in one batch, split into blocks of at most _CHECK_BLOCK_ROWS spread over the
    # cores (:func:`map_blocks`); a bisection's lower and upper midpoints, too few to pay for
    # a thread, go in one batch.
    grid = np.radians(np.linspace(0.0, 90.0, _GRID + 1))
    batch_end = np.tile(np.arange(n_ends), len(grid))
    batch_opening = np.repeat(grid, n_ends)
    blocks = max(thread_count(), -(-len(batch_end) // _CHECK_BLOCK_ROWS))
    spans = np.array_split(np.arange(len(batch_end)), blocks)
    on_grid = (
        np.concatenate(map_blocks(lambda rows: ok(batch_opening[rows], batch_end[rows]), spans))
        .reshape(len(grid), n_ends)
        .T
    )  # (E, G)
    anywhere = on_grid.any(axis=1)
    first = np.argmax(on_grid, axis=1)
    # end of the first separable run
    after = np.where(np.arange(len(grid))[None, :] > first[:, None], ~on_grid, False)
    stop = np.where(after.any(axis=1), np.argmax(after, axis=1) - 1, len(grid) - 1)
    lo_out, lo_in = grid[np.maximum(first - 1, 0)], grid[first]
    hi_in, hi_out = grid[stop], grid[np.minimum(stop + 1, len(grid) - 1)]
    # only the ends whose separable run starts or stops inside [0, 90] deg are refined
    lo_sel = np.flatnonzero(anywhere & (first > 0))
    hi_sel = np.flatnonzero(anywhere & (stop < len(grid) - 1))
    for _ in range(_BISECTIONS):
        lo_mid = 0.5 * (lo_out[lo_sel] + lo_in[lo_sel])
        hi_mid = 0.5 * (hi_in[hi_sel] + hi_out[hi_sel])
        good = ok(np.concatenate([lo_mid, hi_mid]), np.concatenate([lo_sel, hi_sel]))
        lo_good, hi_good = good[: len(lo_sel)], good[len(lo_sel) :]
        lo_in[lo_sel] = np.where(lo_good, lo_mid, lo_in[lo_sel])
        lo_out[lo_sel] = np.where(lo_good, lo_out[lo_sel], lo_mid)
        hi_in[hi_sel] = np.where(hi_good, hi_mid, hi_in[hi_sel])
        hi_out[hi_sel] = np.where(hi_good, hi_out[hi_sel], hi_mid)
    lo = np.where(first == 0, 0.0, lo_in)
    hi = np.where(stop == len(grid) - 1, 0.5 * np.pi, hi_in)
    return np.where(anywhere, lo, 0.5 * np.pi), np.where(anywhere, hi, 0.0)


@dataclass(frozen=True)
class _SlitEndPairs:
    """The two tiles at every slit end seen from above, relative to the hinge vertex: tile
    ``a``'s (``t0``) and tile ``b``'s (``t1``) hinge-face vertices other than the hinge
    ``(E, 3, 2)`` and their other faces ``(E, 4, 2)``, the distances each other-face vertex
    must keep from the separating line ``(E, 4)`` (``-touch`` at the hinge corner), and the
    openings of the pose the tiles were given in ``current`` ``(E,)``, rad."""

    a_hinge: FloatArray
    b_hinge: FloatArray
    a_other: FloatArray
    b_other: FloatArray
    need_a: FloatArray
    need_b: FloatArray
    clearance: float
    current: FloatArray

    def separable(self, opening: FloatArray, sel: IntArray | slice = slice(None)) -> BoolArray:
        """Whether the pairs of the ends ``sel`` are separable at ``opening`` (rad)."""
        # turning t1 about the hinge by d lowers the opening by d (ends ``sel`` only)
        return _separable(
            self.a_hinge[sel], self.b_hinge[sel], self.a_other[sel], self.b_other[sel],
            self.need_a[sel], self.need_b[sel], self.clearance, self.current[sel] - opening,
        )  # fmt: skip


def _slit_end_pairs(
    linkage: Linkage, tiles: ArrayLike, bottom: ArrayLike, clearance: float, touch: float
) -> _SlitEndPairs | None:
    """The :class:`_SlitEndPairs` of :func:`free_openings`' arguments (None: no slit end)."""
    t = np.asarray(tiles, dtype=np.float64)[..., :2]
    side = np.asarray(bottom, dtype=bool)
    ends = slit_ends(linkage)
    n_ends = len(ends.hinge)
    if n_ends == 0:
        return None
    h = linkage.hinges[ends.hinge]
    t0, t1 = ends.tiles[:, 0], ends.tiles[:, 1]
    # the hinge corner of each tile of the end (hinge rows are (tile_a, corner_a, tile_b, ...))
    c0 = np.where(h[:, 0] == t0, h[:, 1], h[:, 3])
    c1 = np.where(h[:, 0] == t1, h[:, 1], h[:, 3])
    face = np.where(side[ends.hinge], 4, 0)
    e = np.arange(n_ends)

    def pick(tile: IntArray, corner: IntArray) -> tuple[FloatArray, FloatArray]:
        """Hinge-face vertices other than the hinge (E, 3, 2) and the other face (E, 4, 2),
        relative to the hinge vertex."""
        apex = t[tile, face + corner]
        rest = (corner[:, None] + np.arange(1, 4)[None, :]) % 4
        hinge_face = t[tile[:, None], face[:, None] + rest] - apex[:, None]
        other_face = t[tile[:, None], (4 - face)[:, None] + np.arange(4)[None, :]] - apex[:, None]
        return hinge_face, other_face

    a_hinge, a_other = pick(t0, c0)
    b_hinge, b_other = pick(t1, c1)
    need_a = np.full((n_ends, 4), clearance)
    need_b = np.full((n_ends, 4), clearance)
    need_a[e, c0] = -touch
    need_b[e, c1] = -touch
    current = ends.angles(np.asarray(tiles, dtype=np.float64), face)
    return _SlitEndPairs(a_hinge, b_hinge, a_other, b_other, need_a, need_b, clearance, current)
