"""Separating planes between close flat tiles, and the rigid pose they move with.

The rigid hinge layout (:mod:`~drawstring.geometry.hinges.rigid_layout`) keeps close tile pairs
apart by planes attached to one tile of each pair: through the hinge for hinged pairs, on the hinge
face only for pairs whose overlap is trimmed, and with a clearance elsewhere.
:func:`select_planes` finds the best plane of every pair of convex pieces by a sampled search
refined around its best sample (warm-started from earlier planes, or taking known ones as they
are); :func:`plane_values` measures every vertex against them.  :class:`RigidPose` is the
tiles' pose (a turn and a translation each) that the planes move with.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from drawstring.geometry.core import parallel
from drawstring.geometry.core.tolerances import HINGE_LAYOUT_TOUCH_MM
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.polygons import convex_pieces
from drawstring.geometry.tiling.linkage import Linkage

__all__ = [
    "RigidPose",
    "SeparatingPlanes",
    "close_pairs",
    "perp",
    "plane_values",
    "rotate2",
    "select_planes",
]


@dataclass(frozen=True)
class SeparatingPlanes:
    """Separating planes of close tile pairs; each plane is attached rigidly to its tile ``a``.

    In world coordinates the plane of pair ``p`` is ``w . (x_xy - o_a) + nz * x_z = offset``
    with ``w = R(phi_a) normal[p, :2]``, ``nz = normal[p, 2]`` and ``o_a`` tile ``a``'s
    origin.  Vertex ``v`` of ``b`` must satisfy ``value - offset >= delta_b[p, v]`` and vertex
    ``u`` of ``a`` ``offset - value >= delta_a[p, u]`` (``inf``: not constrained, e.g. not in
    the convex piece ``piece_a`` / ``piece_b`` of a non-convex tile that the row separates).
    """

    a: IntArray
    b: IntArray
    hinge: IntArray
    normal: FloatArray
    offset: FloatArray
    delta_a: FloatArray
    delta_b: FloatArray
    score: FloatArray
    piece_a: IntArray
    piece_b: IntArray
    trim: BoolArray  # (H,) the hinges treated as trimmed when choosing them
    #: digest of what else the search saw (the vertices, clearance, touch, unhinged pairs on
    #: their top faces only): ``known`` planes are taken only from a search of the same
    made_with: bytes = b""


#: Most rows searched at once for separating planes, and fewest worth a block of their own on
#: another core.  Their (rows, 8, 120, 5) heights, 4.9 MB at 128 rows, stay in the caches
#: between the passes over them; the planes found do not depend on the block size.
_SEARCH_BLOCK_ROWS = 128
_SEARCH_MIN_BLOCK_ROWS = 64

#: Weight of a violation on the side of the tile that carries a plane (the layout cannot repair
#: it: the plane moves with that tile) against one on the other side when choosing planes.
_CARRIER_VIOLATION_WEIGHT = 1e3


def _plane_scores(
    sa: FloatArray,
    sb: FloatArray,
    anchor: IntArray,
    delta_a: FloatArray,
    delta_b: FloatArray,
    clearance: float,
) -> tuple[FloatArray, FloatArray]:
    """Score and offset ``(P, C)`` of candidate planes from vertex heights ``(P, 8, C)``.

    ``sa``, ``sb``: the vertices of ``a`` and ``b`` projected on each candidate normal.
    ``anchor[p] >= 0``: the plane passes through that vertex of ``a`` (hinged pair); otherwise
    it lies ``clearance`` beyond ``a``'s farthest vertex.  The score is the smallest margin
    beyond the required ones; a violation on ``a``'s side (which the layout cannot repair, the
    plane moving with ``a``) counts ``_CARRIER_VIOLATION_WEIGHT`` times.
    """
    ka = np.isfinite(delta_a)
    p = np.arange(len(anchor))
    # the minima and maxima over the 8 vertices run vertex by vertex on contiguous (P, C) slabs
    # (a strided reduction over axis 1 of (P, 8, C) is several times slower)
    nv = sa.shape[1]
    far = _over_vertices(
        np.maximum, [np.where(ka[:, v, None], sa[:, v], -np.inf) for v in range(nv)]
    )
    far = far + clearance
    offset = np.where((anchor >= 0)[:, None], sa[p, np.maximum(anchor, 0)], far)
    # unconstrained vertices get -inf / +inf requirements and so drop out of the minima
    da = np.where(ka, delta_a, -np.inf)[:, :, None]
    margin_a = _over_vertices(np.minimum, [offset - sa[:, v] - da[:, v] for v in range(nv)])
    db = np.where(np.isfinite(delta_b), delta_b, -np.inf)[:, :, None]
    margin_b = _over_vertices(np.minimum, [sb[:, v] - offset - db[:, v] for v in range(nv)])
    margin_a = np.where(margin_a < 0, _CARRIER_VIOLATION_WEIGHT * margin_a, margin_a)
    return np.minimum(margin_a, margin_b), offset


def _over_vertices(pick: np.ufunc, slabs: list[FloatArray]) -> FloatArray:
    """``pick`` (``np.minimum`` or ``np.maximum``) folded over equal-shaped arrays."""
    out = slabs[0]
    for slab in slabs[1:]:
        out = pick(out, slab)
    return out


def perp(v: FloatArray) -> FloatArray:
    """Vectors ``(k, 2)`` turned by +90 degrees."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def rotate2(v: FloatArray, angle: FloatArray) -> FloatArray:
    """Rotate vectors ``(..., 2)`` counter-clockwise by ``angle`` (broadcast)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


class RigidPose:
    """Rigid, still-flat tiles (3 DOF each: turn ``phi`` about z, translate ``trans`` in x, y)
    and their convex pieces; the pose the rigid hinge layout solves for."""

    def __init__(self, shapes: FloatArray) -> None:
        self.shapes = shapes
        self.n = len(shapes)
        self.centre = shapes[:, :, :2].mean(axis=1)
        self.local = shapes[:, :, :2] - self.centre[:, None]
        self.z = shapes[:, :, 2]
        self.phi = np.zeros(self.n)
        self.trans = np.zeros((self.n, 2))
        self.pieces = convex_pieces(shapes)  # (T, 2, 8): collision bodies of every tile
        #: Unhinged pairs are separated on their top faces only (their 3D overlap is trimmed,
        #: as ``top`` hinged pairs' is), not by planes through the whole tiles.
        self.unhinged_top_only = False

    def positions(
        self, phi: FloatArray | None = None, trans: FloatArray | None = None
    ) -> FloatArray:
        """World ``(T, 8, 3)`` vertices for a pose (default: the current one)."""
        phi = self.phi if phi is None else phi
        trans = self.trans if trans is None else trans
        xy = rotate2(self.local, phi[:, None]) + (self.centre + trans)[:, None]
        return np.concatenate([xy, self.z[..., None]], axis=-1)

    def origin(self, trans: FloatArray | None = None) -> FloatArray:
        return self.centre + (self.trans if trans is None else trans)


def close_pairs(x: FloatArray, reach: float) -> IntArray:
    """Tile pairs ``(P, 2)``, ``i < j``, whose vertex sets (x, y) may come within ``reach``."""
    centres = x[:, :, :2].mean(axis=1)
    radius = np.linalg.norm(x[:, :, :2] - centres[:, None], axis=2).max(axis=1)
    tree = cKDTree(centres)
    pairs = np.asarray(
        tree.query_pairs(2.0 * float(radius.max(initial=0.0)) + reach, output_type="ndarray"),
        dtype=np.int64,
    ).reshape(-1, 2)
    dist = np.linalg.norm(centres[pairs[:, 0]] - centres[pairs[:, 1]], axis=1)
    pairs = pairs[dist <= radius[pairs[:, 0]] + radius[pairs[:, 1]] + reach]
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def _hinge_of_pairs(linkage: Linkage, n: int, pairs: IntArray) -> tuple[IntArray, ...]:
    """Pairs oriented as ``(a, b)`` with ``a`` the first tile of their hinge, and the hinge
    index of every pair (-1: not hinged)."""
    h = linkage.hinges
    keys = h[:, 0] * n + h[:, 2]
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]

    def lookup(k: IntArray) -> IntArray:
        if not len(sorted_keys):
            return np.full(len(k), -1, dtype=np.int64)
        pos = np.minimum(np.searchsorted(sorted_keys, k), len(sorted_keys) - 1)
        return np.asarray(np.where(sorted_keys[pos] == k, order[pos], -1), dtype=np.int64)

    fwd = lookup(pairs[:, 0] * n + pairs[:, 1])
    bwd = lookup(pairs[:, 1] * n + pairs[:, 0])
    swap = (fwd < 0) & (bwd >= 0)
    a = np.where(swap, pairs[:, 1], pairs[:, 0])
    b = np.where(swap, pairs[:, 0], pairs[:, 1])
    return a, b, np.where(fwd >= 0, fwd, bwd)


def select_planes(
    layout: RigidPose,
    linkage: Linkage,
    hinge_ids: IntArray,
    trim: BoolArray,
    clearance: float,
    reach: float,
    *,
    touch: float = HINGE_LAYOUT_TOUCH_MM,
    x: FloatArray | None = None,
    pairs: IntArray | None = None,
    previous: SeparatingPlanes | None = None,
    known: SeparatingPlanes | None = None,
) -> SeparatingPlanes:
    """Best separating plane of every close pair of convex pieces (sampled, then refined).

    ``x`` defaults to the current pose's vertices (pass merged vertices to re-check them);
    ``pairs`` defaults to all tile pairs within ``reach`` (plus twice the clearance); every
    tile pair gives one row per pair of convex pieces (one piece for a convex tile).  ``trim``
    ``(H,)`` marks hinges whose pair is separated on the hinge face only (its overlap in the
    other face's half is trimmed away).  ``touch``
    is the separation required where a hinged pair may touch.  With
    ``previous`` planes, a row found there is only searched near its previous plane, unless
    that leaves it violated.  ``known`` planes, chosen earlier by a search of these vertices
    ``x`` with the same clearance and touch (``known.made_with``; otherwise they are not
    used), are taken as they are for every row found there whose hinge is not treated
    differently now (``known.trim``): the search is row by row, so this gives the same planes.
    The returned score of each plane is its smallest margin beyond the required ones.
    """
    x = layout.positions() if x is None else x
    if pairs is None:
        pairs = close_pairs(x, reach + 2.0 * clearance)
    rows = _plane_rows(layout, linkage, hinge_ids, trim, clearance, touch, x, pairs)
    a, b, hinge, piece_a, piece_b = rows.a, rows.b, rows.hinge, rows.piece_a, rows.piece_b
    best = _BestPlanes.empty(len(a))
    todo = np.arange(len(a))
    new = _row_key(layout.n, a, b, piece_a, piece_b)
    if previous is not None and len(previous.a):
        # warm start: rows also present before are searched near their previous plane
        found, src = _match(layout.n, new, previous)
        world = np.concatenate(
            [rotate2(previous.normal[src, :2], layout.phi[a[found]]), previous.normal[src, 2:]],
            axis=1,
        )
        warm = np.flatnonzero(found)
        best.run(rows, warm, world)
        todo = np.concatenate([np.flatnonzero(~found), warm[best.score[warm] < 0]])
    reused = np.zeros(0, dtype=np.int64)
    made_with = hashlib.sha1(
        np.ascontiguousarray(x).tobytes()
        + repr((clearance, touch, layout.unhinged_top_only)).encode()
    ).digest()
    if known is not None and len(known.a) and known.made_with == made_with:
        found, src = _match(layout.n, new, known)
        same = ~np.isin(hinge[found], np.flatnonzero(known.trim != trim))
        reused, src = np.flatnonzero(found)[same], src[same]
        todo = np.setdiff1d(todo, reused)
    best.run(rows, np.sort(todo), None)
    normal, score, offset = best.normal, best.score, best.offset
    body = np.concatenate([rotate2(normal[:, :2], -layout.phi[a]), normal[:, 2:]], axis=1)
    if len(reused):
        assert known is not None
        body[reused], offset[reused], score[reused] = (
            known.normal[src],
            known.offset[src],
            known.score[src],
        )
    return SeparatingPlanes(
        a,
        b,
        hinge,
        body,
        offset,
        rows.delta_a,
        rows.delta_b,
        score,
        piece_a,
        piece_b,
        trim.copy(),
        made_with,
    )


def _row_key(n: int, pa: IntArray, pb: IntArray, ia: IntArray, ib: IntArray) -> IntArray:
    """One integer per row: its tile pair and pair of convex pieces (``n`` tiles)."""
    return ((pa * n + pb) * 2 + ia) * 2 + ib


def _match(n: int, new: IntArray, old_planes: SeparatingPlanes) -> tuple[BoolArray, IntArray]:
    """Rows (keys ``new``) also in ``old_planes``, and where they are there."""
    old = _row_key(n, old_planes.a, old_planes.b, old_planes.piece_a, old_planes.piece_b)
    order = np.argsort(old, kind="stable")
    pos = np.minimum(np.searchsorted(old[order], new), len(old) - 1)
    found = old[order][pos] == new
    return found, order[pos[found]]


@dataclass
class _PlaneRows:
    """The rows of a plane search, one per pair of convex pieces of a close tile pair: the
    tiles (``a`` carries the plane), the hinge (-1: none), the pieces, the margins required of
    every vertex (``inf``: not constrained), and the vertices relative to ``a``'s origin.

    ``anchor >= 0``: the plane passes through that vertex of ``a`` (hinged rows); ``level``: the
    plane is vertical (rows separated on one face only); ``dual_hinged``: hinged rows whose
    tight vertices are the corners of the other face at the hinge, ``d_pa`` and ``d_pb`` ``(P,
    3)`` those corners of ``a`` and ``b`` relative to ``a``'s hinge vertex."""

    a: IntArray
    b: IntArray
    hinge: IntArray
    piece_a: IntArray
    piece_b: IntArray
    delta_a: FloatArray
    delta_b: FloatArray
    anchor: IntArray
    level: BoolArray
    dual_hinged: BoolArray
    rel_a: FloatArray
    rel_b: FloatArray
    d_pa: FloatArray
    d_pb: FloatArray
    clearance: float

    def search(
        self, sel: IntArray, az: FloatArray, spread: FloatArray, base: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Best of azimuths ``(p, K)`` x slopes for rows ``sel``: normals ``(p, 3)``, scores
        and offsets ``(p,)``.

        For a hinged row the tight vertices are the corners of the other face at the hinge: for
        a horizontal direction e their margins are linear in the plane's vertical slope t, so
        the best slope is found exactly (a's margin kept >= 0 since the plane moves with a)."""
        c, s = np.cos(az), np.sin(az)
        pa_, pb_ = self.d_pa[sel], self.d_pb[sel]
        al1 = -(c * pa_[:, 0:1] + s * pa_[:, 1:2])
        be1 = -pa_[:, 2:3]
        al2 = c * pb_[:, 0:1] + s * pb_[:, 1:2]
        be2 = pb_[:, 2:3]
        den = be2 - be1
        t = np.where(np.abs(den) > 1e-12, (al1 - al2) / np.where(den == 0, 1.0, den), 0.0)
        low = al1 + be1 * t < 0
        t = np.where(low & (np.abs(be1) > 1e-12), -al1 / np.where(be1 == 0, 1.0, be1), t)
        exact = np.clip(t, -0.8, 0.8)[:, :, None] + 0.1 * spread
        tilt = np.where(
            self.dual_hinged[sel, None, None],
            exact,
            base[:, None, None] + spread + 0.0 * c[:, :, None],
        )
        tilt = np.where(self.level[sel, None, None], 0.0, tilt)  # (p, K, S)
        norm = np.sqrt(1.0 + tilt * tilt)
        ra, rb = self.rel_a[sel], self.rel_b[sel]

        def heights(r: FloatArray) -> FloatArray:
            flat_part = r[:, :, 0:1] * c[:, None] + r[:, :, 1:2] * s[:, None]  # (p, 8, K)
            h = flat_part[..., None] + r[:, :, 2, None, None] * tilt[:, None]
            return np.asarray((h / norm[:, None]).reshape(len(sel), 8, -1))

        score, offset = _plane_scores(
            heights(ra),
            heights(rb),
            self.anchor[sel],
            self.delta_a[sel],
            self.delta_b[sel],
            self.clearance,
        )
        pick = np.argmax(score, axis=1)
        kk, ss = np.unravel_index(pick, tilt.shape[1:])
        q = np.arange(len(sel))
        t_best = tilt[q, kk, ss]
        nrm = np.sqrt(1.0 + t_best * t_best)
        normal = np.stack([c[q, kk] / nrm, s[q, kk] / nrm, t_best / nrm], axis=1)
        return normal, score[q, pick], offset[q, pick]

    def refine(self, sel: IntArray, guess: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Azimuth +-3 deg by 0.25 deg, slope +-0.05 around ``guess`` normals ``(p, 3)``."""
        az = np.arctan2(guess[:, 1], guess[:, 0])[:, None] + np.radians(np.arange(-3.0, 3.01, 0.25))
        base = guess[:, 2] / np.sqrt(np.maximum(1.0 - guess[:, 2] ** 2, 1e-12))
        return self.search(sel, az, np.array([0.0, 0.025, -0.025, 0.05, -0.05]), base)


@dataclass
class _BestPlanes:
    """The best plane found so far for every row: world normal, score, offset."""

    normal: FloatArray
    score: FloatArray
    offset: FloatArray

    @classmethod
    def empty(cls, n_rows: int) -> _BestPlanes:
        return cls(np.zeros((n_rows, 3)), np.full(n_rows, -np.inf), np.zeros(n_rows))

    def run(self, rows: _PlaneRows, sel: IntArray, guess: FloatArray | None) -> None:
        """Search rows ``sel`` (near ``guess`` normals, or over all directions first) and keep
        every plane that scores better than the one held."""
        # Rows are searched independently, in blocks of at most _SEARCH_BLOCK_ROWS (caches)
        # spread over the cores (:func:`map_blocks`; the result does not depend on the blocks).
        count = -(-len(sel) // _SEARCH_BLOCK_ROWS)
        count = max(count, min(parallel.thread_count(), -(-len(sel) // _SEARCH_MIN_BLOCK_ROWS)))
        bounds = [int(v) for v in np.linspace(0, len(sel), count + 1)] if len(sel) else [0]
        spans = list(zip(bounds[:-1], bounds[1:], strict=True))

        def block(span: tuple[int, int]) -> tuple[FloatArray, FloatArray, FloatArray]:
            part = sel[span[0] : span[1]]
            if guess is None:
                az = np.broadcast_to(np.radians(np.arange(0.0, 360.0, 3.0)), (len(part), 120))
                spread = np.array([0.0, 0.15, -0.15, 0.35, -0.35])
                g, _, _ = rows.search(part, az, spread, np.zeros(len(part)))
            else:
                g = guess[span[0] : span[1]]
            return rows.refine(part, g)

        for span, (n_new, s_new, o_new) in zip(
            spans, parallel.map_blocks(block, spans), strict=True
        ):
            part = sel[span[0] : span[1]]
            better = s_new > self.score[part]
            part = part[better]
            self.normal[part] = n_new[better]
            self.score[part] = s_new[better]
            self.offset[part] = o_new[better]


def _plane_rows(
    layout: RigidPose,
    linkage: Linkage,
    hinge_ids: IntArray,
    trim: BoolArray,
    clearance: float,
    touch: float,
    x: FloatArray,
    pairs: IntArray,
) -> _PlaneRows:
    """The search rows of tile ``pairs`` at vertices ``x`` (see :func:`select_planes`)."""
    pairs = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    a, b, hinge = _hinge_of_pairs(linkage, layout.n, pairs)
    # one row per pair of convex pieces
    n_pieces = 1 + layout.pieces[:, 1].any(axis=1).astype(np.int64)
    na, nb = n_pieces[a], n_pieces[b]
    count = na * nb
    row_pair = np.repeat(np.arange(len(a)), count)
    local = np.arange(int(count.sum())) - np.repeat(np.cumsum(count) - count, count)
    piece_a = local // nb[row_pair]
    piece_b = local % nb[row_pair]
    a, b, hinge = a[row_pair], b[row_pair], hinge[row_pair]
    mask_a = layout.pieces[a, piece_a]
    mask_b = layout.pieces[b, piece_b]
    k_all = np.arange(len(a))
    hk = np.maximum(hinge, 0)
    va = hinge_ids[hk, 0] % 8  # a's hinge vertex (tile a is hinges[:, 0])
    vb = hinge_ids[hk, 1] % 8
    # a row treats the hinge only if both its pieces hold the hinge vertices
    hinged = (hinge >= 0) & mask_a[k_all, va] & mask_b[k_all, vb]
    hinge = np.where(hinged, hinge, -1)
    delta_a = np.where(mask_a, clearance, np.inf)
    delta_b = np.where(mask_b, clearance, np.inf)
    rows = np.flatnonzero(hinged)
    face_only = hinged & trim[hk]  # separated on the hinge face only
    # unhinged neighbours in one part: separated on the top face only (their 3D overlap is
    # trimmed); tiles of different parts keep whole-tile planes (they are never trimmed)
    same_part = linkage.tile_component[a] == linkage.tile_component[b]
    loose = ~hinged & same_part & layout.unhinged_top_only
    delta_a[np.ix_(np.flatnonzero(loose), np.arange(4, 8))] = np.inf
    delta_b[np.ix_(np.flatnonzero(loose), np.arange(4, 8))] = np.inf
    level = face_only | loose  # rows whose plane is vertical
    dual_hinged = hinged & ~trim[hk]
    cut = np.flatnonzero(face_only)
    other = np.arange(4)
    delta_a[cut[:, None], 4 * (1 - va[cut, None] // 4) + other] = np.inf
    delta_b[cut[:, None], 4 * (1 - vb[cut, None] // 4) + other] = np.inf
    # elsewhere the other face's corner under/over the hinge may touch the plane
    both = np.flatnonzero(dual_hinged)
    delta_a[both, (va[both] + 4) % 8] = touch
    delta_b[both, (vb[both] + 4) % 8] = touch
    delta_a[rows, va[rows]] = np.inf  # the plane passes through it
    delta_b[rows, vb[rows]] = 0.0  # b's hinge vertex meets the plane when merged
    anchor = np.where(hinged, va, -1)
    origin = layout.origin()
    o3 = np.concatenate([origin, np.zeros((layout.n, 1))], axis=1)
    rel_a = x[a] - o3[a][:, None]
    rel_b = x[b] - o3[a][:, None]
    d_pa = rel_a[k_all, (va + 4) % 8] - rel_a[k_all, va]
    d_pb = rel_b[k_all, (vb + 4) % 8] - rel_a[k_all, va]
    return _PlaneRows(
        a, b, hinge, piece_a, piece_b, delta_a, delta_b, anchor, level, dual_hinged,
        rel_a, rel_b, d_pa, d_pb, clearance,
    )  # fmt: skip


def plane_values(
    layout: RigidPose,
    planes: SeparatingPlanes,
    x: FloatArray,
    phi: FloatArray,
    trans: FloatArray,
    *,
    carrier: bool = True,
) -> tuple[FloatArray, FloatArray | None, FloatArray]:
    """Signed distances ``(P, 8)`` of ``b``'s and (if ``carrier``) ``a``'s vertices beyond their
    required margins, and the world plane normals ``(P, 2)`` (x, y part)."""
    origin = (layout.centre + trans)[planes.a]
    w = rotate2(planes.normal[:, :2], phi[planes.a])
    nz = planes.normal[:, 2]

    def value(t: IntArray) -> FloatArray:
        xt = x[t]
        return np.asarray(
            (xt[:, :, 0] - origin[:, 0:1]) * w[:, 0:1]
            + (xt[:, :, 1] - origin[:, 1:2]) * w[:, 1:2]
            + nz[:, None] * xt[:, :, 2]
            - planes.offset[:, None]
        )

    gb = value(planes.b) - np.where(np.isfinite(planes.delta_b), planes.delta_b, -np.inf)
    if not carrier:
        return gb, None, w
    ga = -value(planes.a) - np.where(np.isfinite(planes.delta_a), planes.delta_a, -np.inf)
    return gb, ga, w
