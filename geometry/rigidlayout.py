"""Rigid planar layout of the flat tiles with their hinge pairs brought together (paper 4.4).

The ``dual`` strategy's ``w_rigid E_rigid + w_collision E_collision + w_conn E_conn`` with the
rigidity exact: every flat tile keeps its T2D shape and only turns about the vertical axis and
translates in the plane (3 degrees of freedom).  Close tile pairs are kept apart by separating
planes attached to one tile of each pair (through the hinge for hinged pairs, or on the hinge
face only for pairs whose overlap is trimmed), gap angles are held in ``[theta_min, 90]``, and
the squared distance of every hinge pair is minimized by an augmented Lagrangian with
Levenberg-Marquardt subproblems.  Then every pair is merged into one point where that keeps the
layout valid.  :func:`~drawstring.geometry.hinges.layout_hinges` decides the hinge sides and
the trims and calls :func:`rigid_layout`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray
from scipy.spatial import cKDTree

from drawstring.geometry import parallel
from drawstring.geometry.errors import InputError
from drawstring.geometry.linkage import Linkage, SlitEnds, slit_ends
from drawstring.geometry.spd import SpdSolver
from drawstring.geometry.tolerances import (
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_FEASIBLE_MM,
    HINGE_LAYOUT_TOUCH_MM,
)
from drawstring.geometry.verify import convex_pieces, hinge_gaps

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
HingeStrategy = Literal["dual", "top"]

__all__ = ["HingeStrategy", "RigidLayoutResult", "rigid_layout"]


@dataclass(frozen=True)
class _Planes:
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
    trim: NDArray[np.bool_]  # (H,) the hinges treated as trimmed when choosing them


#: Most rows searched at once for separating planes, and fewest worth a block of their own on
#: another core.  Their (rows, 8, 120, 5) heights, 4.9 MB at 128 rows, stay in the caches
#: between the passes over them: 1600-tile hinge layout 2.18 s in blocks of 512 rows, 1.76 s
#: in blocks of 128 (bitwise the same; 64 gains no more).
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


def _perp(v: FloatArray) -> FloatArray:
    """Vectors ``(k, 2)`` turned by +90 degrees."""
    return np.stack([-v[..., 1], v[..., 0]], axis=-1)


def _rotate2(v: FloatArray, angle: FloatArray) -> FloatArray:
    """Rotate vectors ``(..., 2)`` counter-clockwise by ``angle`` (broadcast)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([c * v[..., 0] - s * v[..., 1], s * v[..., 0] + c * v[..., 1]], axis=-1)


class _RigidLayout:
    """Rigid, still-flat tiles (3 DOF each: turn about z, translate in x, y).

    Minimizes the squared horizontal distance of paired hinge vertices subject to gap opening
    angle bounds and separating planes between close tile pairs, by an augmented Lagrangian
    whose subproblems are solved by Levenberg-Marquardt (sparse normal equations).
    """

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
        xy = _rotate2(self.local, phi[:, None]) + (self.centre + trans)[:, None]
        return np.concatenate([xy, self.z[..., None]], axis=-1)

    def origin(self, trans: FloatArray | None = None) -> FloatArray:
        return self.centre + (self.trans if trans is None else trans)


def _close_pairs(x: FloatArray, reach: float) -> IntArray:
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


def _select_planes(
    layout: _RigidLayout,
    linkage: Linkage,
    hinge_ids: IntArray,
    trim: NDArray[np.bool_],
    clearance: float,
    reach: float,
    *,
    touch: float = HINGE_LAYOUT_TOUCH_MM,
    x: FloatArray | None = None,
    pairs: IntArray | None = None,
    previous: _Planes | None = None,
    known: _Planes | None = None,
) -> _Planes:
    """Best separating plane of every close pair of convex pieces (sampled, then refined).

    ``x`` defaults to the current pose's vertices (pass merged vertices to re-check them);
    ``pairs`` defaults to all tile pairs within ``reach`` (plus twice the clearance); every
    tile pair gives one row per pair of convex pieces (one piece for a convex tile).  ``trim``
    ``(H,)`` marks hinges whose pair is separated on the hinge face only (its overlap in the
    other face's half is trimmed away).  ``touch``
    is the separation required where a hinged pair may touch.  With
    ``previous`` planes, a row found there is only searched near its previous plane, unless
    that leaves it violated.  ``known`` planes, chosen earlier at this very pose (vertices
    ``x``), are taken as they are for every row found there whose hinge is not treated
    differently now (``known.trim``): the search is row by row, so this gives the same planes.
    The returned score of each plane is its smallest margin beyond the required ones.
    """
    x = layout.positions() if x is None else x
    if pairs is None:
        pairs = _close_pairs(x, reach + 2.0 * clearance)
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
    n_p = len(a)
    k_all = np.arange(n_p)
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
    # For a hinged pair the tight vertices are the corners of the other face at the hinge: for a
    # horizontal direction e their margins are linear in the plane's vertical slope t, so the
    # best slope is found exactly (a's margin kept >= 0 since the plane moves with a).
    d_pa = rel_a[k_all, (va + 4) % 8] - rel_a[k_all, va]
    d_pb = rel_b[k_all, (vb + 4) % 8] - rel_a[k_all, va]

    def search(
        sel: IntArray, az: FloatArray, spread: FloatArray, base: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Best of azimuths ``(p, K)`` x slopes for rows ``sel``: normals ``(p, 3)``, scores
        and offsets ``(p,)``."""
        c, s = np.cos(az), np.sin(az)
        pa_, pb_ = d_pa[sel], d_pb[sel]
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
            dual_hinged[sel, None, None], exact, base[:, None, None] + spread + 0.0 * c[:, :, None]
        )
        tilt = np.where(level[sel, None, None], 0.0, tilt)  # (p, K, S)
        norm = np.sqrt(1.0 + tilt * tilt)
        ra, rb = rel_a[sel], rel_b[sel]

        def heights(r: FloatArray) -> FloatArray:
            flat_part = r[:, :, 0:1] * c[:, None] + r[:, :, 1:2] * s[:, None]  # (p, 8, K)
            h = flat_part[..., None] + r[:, :, 2, None, None] * tilt[:, None]
            return np.asarray((h / norm[:, None]).reshape(len(sel), 8, -1))

        score, offset = _plane_scores(
            heights(ra), heights(rb), anchor[sel], delta_a[sel], delta_b[sel], clearance
        )
        pick = np.argmax(score, axis=1)
        kk, ss = np.unravel_index(pick, tilt.shape[1:])
        q = np.arange(len(sel))
        t_best = tilt[q, kk, ss]
        nrm = np.sqrt(1.0 + t_best * t_best)
        normal = np.stack([c[q, kk] / nrm, s[q, kk] / nrm, t_best / nrm], axis=1)
        return normal, score[q, pick], offset[q, pick]

    def refine(sel: IntArray, guess: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Azimuth +-3 deg by 0.25 deg, slope +-0.05 around ``guess`` normals ``(p, 3)``."""
        az = np.arctan2(guess[:, 1], guess[:, 0])[:, None] + np.radians(np.arange(-3.0, 3.01, 0.25))
        base = guess[:, 2] / np.sqrt(np.maximum(1.0 - guess[:, 2] ** 2, 1e-12))
        return search(sel, az, np.array([0.0, 0.025, -0.025, 0.05, -0.05]), base)

    normal = np.zeros((n_p, 3))
    score = np.full(n_p, -np.inf)
    offset = np.zeros(n_p)

    def run(sel: IntArray, guess: FloatArray | None) -> None:
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
                g, _, _ = search(part, az, spread, np.zeros(len(part)))
            else:
                g = guess[span[0] : span[1]]
            return refine(part, g)

        for span, (n_new, s_new, o_new) in zip(
            spans, parallel.map_blocks(block, spans), strict=True
        ):
            part = sel[span[0] : span[1]]
            better = s_new > score[part]
            part = part[better]
            normal[part], score[part], offset[part] = n_new[better], s_new[better], o_new[better]

    def row_key(pa: IntArray, pb: IntArray, ia: IntArray, ib: IntArray) -> IntArray:
        return ((pa * layout.n + pb) * 2 + ia) * 2 + ib

    new = row_key(a, b, piece_a, piece_b)

    def match(old_planes: _Planes) -> tuple[NDArray[np.bool_], IntArray]:
        """Rows of this selection also in ``old_planes``, and where they are there."""
        old = row_key(old_planes.a, old_planes.b, old_planes.piece_a, old_planes.piece_b)
        order = np.argsort(old, kind="stable")
        pos = np.minimum(np.searchsorted(old[order], new), len(old) - 1)
        found = old[order][pos] == new
        return found, order[pos[found]]

    todo = k_all
    if previous is not None and len(previous.a):
        # warm start: rows also present before are searched near their previous plane
        found, src = match(previous)
        world = np.concatenate(
            [_rotate2(previous.normal[src, :2], layout.phi[a[found]]), previous.normal[src, 2:]],
            axis=1,
        )
        warm = np.flatnonzero(found)
        run(warm, world)
        todo = np.concatenate([np.flatnonzero(~found), warm[score[warm] < 0]])
    reused = np.zeros(0, dtype=np.int64)
    if known is not None and len(known.a):
        found, src = match(known)
        same = ~np.isin(hinge[found], np.flatnonzero(known.trim != trim))
        reused, src = np.flatnonzero(found)[same], src[same]
        todo = np.setdiff1d(todo, reused)
    run(np.sort(todo), None)
    body = np.concatenate([_rotate2(normal[:, :2], -layout.phi[a]), normal[:, 2:]], axis=1)
    if len(reused):
        assert known is not None
        body[reused], offset[reused], score[reused] = (
            known.normal[src],
            known.offset[src],
            known.score[src],
        )
    return _Planes(
        a, b, hinge, body, offset, delta_a, delta_b, score, piece_a, piece_b, trim.copy()
    )


def _plane_values(
    layout: _RigidLayout,
    planes: _Planes,
    x: FloatArray,
    phi: FloatArray,
    trans: FloatArray,
    *,
    carrier: bool = True,
) -> tuple[FloatArray, FloatArray | None, FloatArray]:
    """Signed distances ``(P, 8)`` of ``b``'s and (if ``carrier``) ``a``'s vertices beyond their
    required margins, and the world plane normals ``(P, 2)`` (x, y part)."""
    origin = (layout.centre + trans)[planes.a]
    w = _rotate2(planes.normal[:, :2], phi[planes.a])
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


@dataclass
class _Constraints:
    """Current inequality set ``g(pose) >= 0`` of the layout (planes and angle bounds)."""

    planes: _Planes
    ends: SlitEnds
    faces: IntArray  # (F,) faces whose angles are bounded (0 top, 4 bottom)
    angle0: FloatArray  # (F, E) rad at zero pose
    lo: FloatArray  # (F, E) rad
    hi: FloatArray  # (F, E) rad
    scale: float  # mm per rad (mean tile side)


def _constraint_values(
    layout: _RigidLayout,
    con: _Constraints,
    phi: FloatArray,
    trans: FloatArray,
    rows: IntArray | None = None,
) -> tuple[FloatArray, sp.csr_matrix | None]:
    """All inequality values ``(m,)`` (mm) at a pose, and the Jacobian ``(len(rows), 3T)`` of
    the selected ones (plane rows first, then lower and upper angle bounds per face)."""
    x = layout.positions(phi, trans)
    planes = con.planes
    gb, _, w = _plane_values(layout, planes, x, phi, trans, carrier=False)
    mask = np.isfinite(gb)
    g_planes = gb[mask]
    t0, t1 = con.ends.tiles[:, 0], con.ends.tiles[:, 1]
    ang = con.angle0 + (phi[t0] - phi[t1])[None, :]
    g_lo = ((ang - con.lo) * con.scale).ravel()
    g_hi = ((con.hi - ang) * con.scale).ravel()
    g = np.concatenate([g_planes, g_lo, g_hi])
    if rows is None:
        return g, None
    m_p = len(g_planes)
    pr = rows[rows < m_p]
    ar = rows[rows >= m_p] - m_p
    p_idx, v_idx = np.nonzero(mask)
    p_idx, v_idx = p_idx[pr], v_idx[pr]
    a, b = planes.a[p_idx], planes.b[p_idx]
    wp = w[p_idx]
    origin = layout.centre + trans
    xb = x[b, v_idx, :2]
    cols = np.stack([3 * b, 3 * b + 1, 3 * b + 2, 3 * a, 3 * a + 1, 3 * a + 2], axis=1)
    vals = np.stack(
        [
            np.einsum("ki,ki->k", wp, _perp(xb - origin[b])),
            wp[:, 0],
            wp[:, 1],
            np.einsum("ki,ki->k", _perp(wp), xb - origin[a]),
            -wp[:, 0],
            -wp[:, 1],
        ],
        axis=1,
    )
    # Angle bounds, linear in phi: angle = angle0 + phi[t0] - phi[t1].
    end = ar % len(t0)
    sign = np.where(ar < g_lo.size, 1.0, -1.0) * con.scale
    cols_a = np.stack([3 * t0[end], 3 * t1[end]], axis=1)
    vals_a = np.stack([sign, -sign], axis=1)
    n_pr = len(pr)
    row_ids = np.concatenate(
        [np.repeat(np.arange(n_pr), 6), n_pr + np.repeat(np.arange(len(ar)), 2)]
    )
    jac = sp.csr_matrix(
        (
            np.concatenate([vals.ravel(), vals_a.ravel()]),
            (row_ids, np.concatenate([cols.ravel(), cols_a.ravel()])),
        ),
        shape=(len(rows), 3 * layout.n),
    )
    return g, jac


def _hinge_residuals(
    layout: _RigidLayout,
    ids: IntArray,
    phi: FloatArray,
    trans: FloatArray,
    weight: FloatArray,
    *,
    jacobian: bool = True,
) -> tuple[FloatArray, sp.csr_matrix | None]:
    """Horizontal hinge mismatch ``(2H,)`` (mm, weighted) and (if asked) its Jacobian
    ``(2H, 3T)``."""
    ta, va = ids[:, 0] // 8, ids[:, 0] % 8
    tb, vb = ids[:, 1] // 8, ids[:, 1] % 8
    ra = _rotate2(layout.local[ta, va], phi[ta])  # hinge vertices relative to tile origins
    rb = _rotate2(layout.local[tb, vb], phi[tb])
    origin = layout.centre + trans
    xa, xb = origin[ta] + ra, origin[tb] + rb
    sw = np.sqrt(weight)
    res = (sw[:, None] * (xa - xb)).ravel()
    if not jacobian:
        return res, None
    h = len(ids)
    pa, pb = _perp(ra), _perp(rb)
    rows = np.repeat(np.arange(2 * h), 4)
    cols = np.stack(
        [
            np.stack([3 * ta, 3 * ta + 1, 3 * tb, 3 * tb + 1], axis=1),
            np.stack([3 * ta, 3 * ta + 2, 3 * tb, 3 * tb + 2], axis=1),
        ],
        axis=1,
    ).ravel()
    one = np.ones(h)
    vals = (
        np.stack(
            [
                np.stack([pa[:, 0], one, -pb[:, 0], -one], axis=1),
                np.stack([pa[:, 1], one, -pb[:, 1], -one], axis=1),
            ],
            axis=1,
        )
        * sw[:, None, None]
    )
    jac = sp.csr_matrix((vals.ravel(), (rows, cols)), shape=(2 * h, 3 * layout.n))
    return res, jac


def _augmented_lagrangian(
    layout: _RigidLayout,
    con: _Constraints,
    ids: IntArray,
    lam: FloatArray,
    rho: float,
    inner: int,
    weight: FloatArray,
    pin: FloatArray,
    factor: SpdSolver,
) -> tuple[FloatArray, int]:
    """Minimize ``|hinge mismatch|^2 + rho * sum max(0, lam / rho - g)^2`` over the pose.

    ``pin`` ``(3T,)`` is 1 on the pose variables held fixed; ``factor`` solves the normal
    equations (its pattern reserved for every constraint the planes can make active).

    Damped Gauss-Newton (the objective is piecewise quadratic up to the small rotations); the
    layout's pose is updated in place.  Returns the constraint values at the end and the number
    of accepted steps.
    """
    sr = np.sqrt(rho)

    def evaluate(phi: FloatArray, trans: FloatArray) -> tuple[float, FloatArray, FloatArray]:
        rh, _ = _hinge_residuals(layout, ids, phi, trans, weight, jacobian=False)
        g, _ = _constraint_values(layout, con, phi, trans)
        slack = np.maximum(lam / rho - g, 0.0)
        return float(rh @ rh + rho * (slack @ slack)), rh, g

    def jacobian(phi: FloatArray, trans: FloatArray, g: FloatArray, rh: FloatArray):
        _, jh = _hinge_residuals(layout, ids, phi, trans, weight)
        assert jh is not None
        slack = lam / rho - g
        act = np.flatnonzero(slack > 0)
        _, jg = _constraint_values(layout, con, phi, trans, act)
        assert jg is not None
        res = np.concatenate([rh, sr * slack[act]])
        return res, sp.vstack([jh, -sr * jg], format="csr")

    cost, rh, g = evaluate(layout.phi, layout.trans)
    steps = 0
    for _ in range(inner):
        res, jac = jacobian(layout.phi, layout.trans, g, rh)
        jtj = (jac.T @ jac).tocsc()
        grad = jac.T @ res
        diag = jtj.diagonal()
        top = max(float(diag.max(initial=0.0)), 1e-12)
        # Every component's free rigid motion is fixed by pinning one of its tiles (``pin``);
        # a tiny Levenberg term keeps the system regular.
        damp = sp.diags(1e-9 * np.maximum(diag, 1e-6 * top) + pin * 1e6 * top)
        step = factor.solve(jtj + damp, -grad).reshape(layout.n, 3)
        accepted = False
        alpha = 1.0
        for _ls in range(12):
            phi_new = layout.phi + alpha * step[:, 0]
            trans_new = layout.trans + alpha * step[:, 1:]
            cost_new, rh_new, g_new = evaluate(phi_new, trans_new)
            if cost_new < cost:
                accepted = True
                break
            alpha *= 0.3
        if not accepted:
            break
        improvement = cost - cost_new
        layout.phi, layout.trans = phi_new, trans_new
        cost, rh, g = cost_new, rh_new, g_new
        steps += 1
        if improvement <= 1e-7 * cost or alpha * float(np.abs(step).max()) < 1e-11:
            break
    return g, steps


@dataclass(frozen=True)
class RigidLayoutResult:
    """Outcome of :func:`rigid_layout`.

    Attributes
    ----------
    tiles : (T, 8, 3) float, mm
        Rigid tiles (congruent to the input shapes) before merging.
    merged : (T, 8, 3) float, mm
        Tiles with every merged hinge pair moved to its shared point.
    points : (H, 3) float, mm
        Hinge points (shared point, or the midpoint of an unmerged pair).
    is_merged : (H,) bool
    gap_mm : (H,) float
        3D distance of each hinge pair before merging.
    violation_mm : float
        Largest remaining violation of a separating plane or angle bound (angle bounds in rad
        times the mean tile side), rigid tiles.
    iterations : int
        Accepted Levenberg-Marquardt steps over all rounds.
    first_planes : _Planes
        The separating planes chosen at the start layout (``shapes``), before any round.
    """

    tiles: FloatArray
    merged: FloatArray
    points: FloatArray
    is_merged: NDArray[np.bool_]
    gap_mm: FloatArray
    violation_mm: float
    iterations: int
    first_planes: _Planes


def _merge_points(
    layout: _RigidLayout, planes: _Planes, ids: IntArray, x: FloatArray
) -> FloatArray:
    """Shared point ``(H, 3)`` of every hinge pair: the midpoint moved horizontally onto the
    pair's separating plane (so both tiles stay on their own side after merging)."""
    flat = x.reshape(-1, 3)
    mid = 0.5 * (flat[ids[:, 0]] + flat[ids[:, 1]])
    pair_of = -np.ones(len(ids), dtype=np.int64)
    hinged = np.flatnonzero(planes.hinge >= 0)
    pair_of[planes.hinge[hinged]] = hinged
    out = mid.copy()
    ok = pair_of >= 0
    p = pair_of[ok]
    a = planes.a[p]
    w = _rotate2(planes.normal[p, :2], layout.phi[a])
    nz = planes.normal[p, 2]
    origin = layout.origin()[a]
    value = np.einsum("ki,ki->k", mid[ok, :2] - origin, w) + nz * mid[ok, 2] - planes.offset[p]
    out[ok, :2] -= (value / np.maximum(np.einsum("ki,ki->k", w, w), 1e-300))[:, None] * w
    return out


def rigid_layout(
    linkage: Linkage,
    shapes: ArrayLike,
    hinge_ids: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    min_gap_angle_deg: float = 12.0,
    clearance_mm: float = HINGE_LAYOUT_CLEARANCE_MM,
    max_rounds: int = 40,
    inner_steps: int = 60,
    trim: ArrayLike | None = None,
    like: RigidLayoutResult | None = None,
) -> RigidLayoutResult:
    """Lay rigid flat tiles out so paired hinge vertices meet as closely as possible.

    Every tile keeps its shape (``shapes``, the T2D pose: top face horizontal) and may only
    turn about the vertical axis and translate in the plane (3 DOF).  Minimized: the squared
    horizontal distance of every hinge pair.  Subject to

    * every slit end's opening angle in ``[min_gap_angle_deg, 90]`` on the top faces and, for
      ``dual``, on the bottom faces (linear in the rotations);
    * every close pair of tiles separated by a plane attached to one of them (exact
      non-interpenetration for convex tiles; a non-convex, dart-shaped tile takes part as its
      two convex pieces, :func:`~drawstring.geometry.verify.convex_pieces`, each separated on
      its own, since its hull would fill the notch): with ``clearance_mm`` to spare, except that a
      hinged pair's plane passes through the hinge, which with the corner of the other face at
      the hinge may touch it; for ``top`` hinged pairs, and ``trim`` ones, only the hinge faces
      are separated (their 3D overlap is trimmed), and for ``top`` also unhinged pairs only
      on their top faces (the paper's ``top`` strategy trims whatever two tiles overlap in the
      flat pose; planes through whole wedge-shaped tiles pulled the 300-tile wave's hinges
      6.7e-3 mm apart over overlaps of 0.04 mm^3).  Planes are re-chosen (sampled max-margin,
      never accepting a violation on the carrying tile's side when avoidable) in the first
      rounds, warm-started from the previous planes.

    The solver is an augmented Lagrangian whose subproblems are solved by Levenberg-Marquardt.
    Hinge pairs are then merged at their midpoint moved horizontally onto the pair's plane; a
    merge that would break an angle bound (after raising that bound's margin and re-solving) or
    a plane is undone, leaving that pair rigid and apart.

    Parameters
    ----------
    linkage : Linkage
    shapes : (T, 8, 3) float, mm
        T2D tiles (start layout and rigid shapes).
    hinge_ids : (H, 2) int
        ``8 * tile + vertex`` of both vertices of every hinge (tile order of ``linkage.hinges``).
    strategy : "dual" | "top"
    min_gap_angle_deg : float, deg
    clearance_mm : float, mm
    max_rounds, inner_steps : solver limits (augmented Lagrangian rounds, LM steps per round).
    trim : (H,) bool, optional
        ``dual`` hinges whose pairs are separated on the hinge face only (default none; every
        hinge for ``top``).
    like : RigidLayoutResult, optional
        An earlier layout of these ``shapes`` (with other ``trim`` flags, say): its first
        planes are taken as they are for the pairs whose flags agree, instead of being searched
        for again (the same planes, found once).

    Returns
    -------
    RigidLayoutResult
    """
    t2 = np.asarray(shapes, dtype=np.float64)
    ids = np.asarray(hinge_ids, dtype=np.int64).reshape(-1, 2)
    cut = np.full(len(ids), strategy == "top") if trim is None else np.asarray(trim, dtype=bool)
    if cut.shape != (len(ids),):
        raise InputError(f"trim has shape {cut.shape}; pass one flag per hinge")
    layout = _RigidLayout(t2)
    layout.unhinged_top_only = strategy == "top"
    ends = slit_ends(linkage)
    faces = np.array([0, 4] if strategy == "dual" else [0], dtype=np.int64)
    angle0 = np.stack([ends.angles(t2, int(f)) for f in faces])
    lo_deg = np.full(angle0.shape, float(min_gap_angle_deg) + HINGE_ANGLE_MARGIN_DEG)
    hi_deg = np.full(angle0.shape, 90.0 - HINGE_ANGLE_MARGIN_DEG)
    side = np.linalg.norm(t2[:, [1, 2, 3, 0], :2] - t2[:, :4, :2], axis=2)
    scale = float(side.mean()) if side.size else 1.0
    weight = np.ones(len(ids))
    reach = 0.5 * scale
    pin = np.zeros(3 * layout.n)
    comp = linkage.tile_component
    first = np.unique(comp, return_index=True)[1]
    pin[(3 * first[:, None] + np.arange(3)).ravel()] = 1.0
    total_steps = 0

    def constraints(planes: _Planes) -> _Constraints:
        return _Constraints(
            planes, ends, faces, angle0, np.radians(lo_deg), np.radians(hi_deg), scale
        )

    state: dict[str, Any] = {"lam": None, "rho": 10.0}
    # One solver for the whole layout, its pattern reserved for all the constraints a set of
    # planes can make active: a symbolic analysis per set of planes rather than one whenever the
    # active set grows (62 of them, 9 ms each, in the 1600-tile wave's hinge layout).
    factor = SpdSolver()

    def solve(planes: _Planes, rounds: int, reselect: int) -> tuple[_Planes, float]:
        """Augmented Lagrangian rounds; multipliers carry over between calls."""
        nonlocal total_steps
        con = constraints(planes)
        factor.reserve(_normal_pattern(layout.n, ids, planes, ends))
        g, _ = _constraint_values(layout, con, layout.phi, layout.trans)
        lam = state["lam"] if state["lam"] is not None and len(state["lam"]) == len(g) else None
        lam = np.zeros(len(g)) if lam is None else lam
        rho = float(state["rho"])
        prev = np.inf
        viol = float(np.max(-g, initial=0.0))
        for r in range(rounds):
            if 0 < r <= reselect:
                planes = _select_planes(
                    layout, linkage, ids, cut, clearance_mm, reach, previous=planes
                )
                n_old = len(lam)
                con = constraints(planes)
                factor.reserve(_normal_pattern(layout.n, ids, planes, ends))
                g, _ = _constraint_values(layout, con, layout.phi, layout.trans)
                n_ang = 2 * angle0.size
                lam = np.concatenate([np.zeros(len(g) - n_ang), lam[n_old - n_ang :]])
            g, steps = _augmented_lagrangian(
                layout, con, ids, lam, rho, inner_steps, weight, pin, factor
            )
            total_steps += steps
            viol = float(np.max(-g, initial=0.0))
            lam = np.maximum(0.0, lam - rho * g)
            logger.debug("rigid layout round %d: violation %.3g mm, rho %.3g", r, viol, rho)
            if viol <= HINGE_LAYOUT_FEASIBLE_MM and r >= reselect:
                break
            if viol > 0.25 * prev:
                rho = min(rho * 5.0, 1e5)
            prev = viol
        state["lam"] = lam
        return planes, viol

    known = None if like is None else like.first_planes
    first_planes = _select_planes(layout, linkage, ids, cut, clearance_mm, reach, known=known)
    planes, violation = solve(first_planes, max_rounds, 2)
    is_merged = np.ones(len(ids), dtype=bool)
    for attempt in range(4):
        x = layout.positions()
        points = _merge_points(layout, planes, ids, x)
        merged = _merged_tiles(x, ids, points, is_merged)
        ang = np.stack([np.degrees(ends.angles(merged, int(f))) for f in faces])
        lo_def = min_gap_angle_deg - ang
        hi_def = ang - 90.0
        need_lo = lo_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        need_hi = hi_def > -0.25 * HINGE_ANGLE_MARGIN_DEG
        bad_ends = (need_lo | need_hi).any(axis=0)
        logger.debug(
            "merge angles attempt %d: %d bad ends, deficit %.3g",
            attempt,
            int(bad_ends.sum()),
            float(max(np.max(lo_def, initial=-np.inf), np.max(hi_def, initial=-np.inf))),
        )
        if not bad_ends.any():
            break
        if attempt == 3:
            is_merged &= ~_hinges_of_ends(ends, bad_ends, ids, faces)
            break
        lo_deg[need_lo] += 2.0 * np.maximum(lo_def[need_lo], 0.0) + HINGE_ANGLE_MARGIN_DEG
        hi_deg[need_hi] -= 2.0 * np.maximum(hi_def[need_hi], 0.0) + HINGE_ANGLE_MARGIN_DEG
        planes, violation = solve(planes, max_rounds, 0)
    x = layout.positions()
    points = _merge_points(layout, planes, ids, x)
    gap = hinge_gaps(x, ids)
    for _ in range(len(ids) + 1):
        merged = _merged_tiles(x, ids, points, is_merged)
        undo = _broken_merges(
            layout,
            linkage,
            cut,
            planes,
            ends,
            faces,
            merged,
            ids,
            is_merged,
            min_gap_angle_deg,
        )
        if not undo.any():
            break
        is_merged &= ~undo
    points = np.where(
        is_merged[:, None],
        points,
        0.5 * (x.reshape(-1, 3)[ids[:, 0]] + x.reshape(-1, 3)[ids[:, 1]]),
    )
    return RigidLayoutResult(
        x, merged, points, is_merged, gap, violation, total_steps, first_planes
    )


def _normal_pattern(n: int, ids: IntArray, planes: _Planes, ends: SlitEnds) -> sp.csr_matrix:
    """Every entry the layout's Gauss-Newton matrix ``(3T, 3T)`` can hold with ``planes``,
    whichever constraints are active: a 3 x 3 block for every tile and for every tile pair that
    a hinge, a plane or a slit end's angle couples."""
    tiles = np.arange(n)
    pairs = np.concatenate(
        [
            ids // 8,
            np.column_stack([planes.a, planes.b]),
            ends.tiles,
            np.column_stack([tiles, tiles]),
        ]
    )
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    d = np.arange(3)
    rows = np.broadcast_to(3 * pairs[:, 0, None, None] + d[:, None], (len(pairs), 3, 3))
    cols = np.broadcast_to(3 * pairs[:, 1, None, None] + d[None, :], (len(pairs), 3, 3))
    return sp.csr_matrix((np.ones(rows.size), (rows.ravel(), cols.ravel())), shape=(3 * n, 3 * n))


def _merged_tiles(
    x: FloatArray, ids: IntArray, points: FloatArray, is_merged: NDArray[np.bool_]
) -> FloatArray:
    """Tiles ``(T, 8, 3)`` with both vertices of every merged hinge moved to its point."""
    flat = x.reshape(-1, 3).copy()
    flat[ids[is_merged, 0]] = points[is_merged]
    flat[ids[is_merged, 1]] = points[is_merged]
    return flat.reshape(x.shape)


def _hinges_of_ends(
    ends: SlitEnds, bad: NDArray[np.bool_], ids: IntArray, faces: IntArray
) -> NDArray[np.bool_]:
    """Hinges whose merged vertices enter the angle of any ``bad`` slit end."""
    t0, t1 = ends.tiles[bad, 0], ends.tiles[bad, 1]
    s0, s1 = ends.sides[bad, 0], ends.sides[bad, 1]
    verts = []
    for f in faces:
        verts += [
            8 * t1 + f + s1,
            8 * t1 + f + (s1 + 1) % 4,
            8 * t0 + f + s0,
            8 * t0 + f + (s0 + 1) % 4,
        ]
    used = np.unique(np.concatenate(verts)) if verts else np.zeros(0, dtype=np.int64)
    return np.asarray(np.isin(ids[:, 0], used) | np.isin(ids[:, 1], used))


def _broken_merges(
    layout: _RigidLayout,
    linkage: Linkage,
    trim: NDArray[np.bool_],
    planes: _Planes,
    ends: SlitEnds,
    faces: IntArray,
    merged: FloatArray,
    ids: IntArray,
    is_merged: NDArray[np.bool_],
    min_gap_angle_deg: float,
) -> NDArray[np.bool_]:
    """Merged hinges to undo: those whose moved vertices leave two tiles without a separating
    plane, or a gap angle out of its bounds (checked on the merged tiles)."""
    tol = 1e-9
    gb, ga, _ = _plane_values(layout, planes, merged, layout.phi, layout.trans)
    assert ga is not None
    # Separation only (the clearance is a target of the layout, not a validity condition).
    gb = gb + np.where(np.isfinite(planes.delta_b), planes.delta_b, 0.0)
    ga = ga + np.where(np.isfinite(planes.delta_a), planes.delta_a, 0.0)
    suspect = np.flatnonzero(np.any(gb < -tol, axis=1) | np.any(ga < -tol, axis=1))
    undo = np.zeros(len(ids), dtype=bool)
    if suspect.size:
        pairs = np.stack([planes.a[suspect], planes.b[suspect]], axis=1)
        again = _select_planes(layout, linkage, ids, trim, 0.0, 0.0, x=merged, pairs=pairs)
        broken = again.score < -tol
        tiles = np.concatenate([again.a[broken], again.b[broken]])
        undo |= is_merged & (np.isin(ids[:, 0] // 8, tiles) | np.isin(ids[:, 1] // 8, tiles))
        # only hinges that moved a vertex of a broken pair matter; undo them pairwise
        if broken.any():
            pair_tiles = np.stack([again.a[broken], again.b[broken]], axis=1)
            mine = np.zeros(len(ids), dtype=bool)
            for ta, tb in pair_tiles:
                mine |= np.isin(ids[:, 0] // 8, (ta, tb)) | np.isin(ids[:, 1] // 8, (ta, tb))
            undo &= mine
    bad = np.zeros(len(ends.hinge), dtype=bool)
    for f in faces:
        ang = np.degrees(ends.angles(merged, int(f)))
        bad |= (ang < min_gap_angle_deg) | (ang > 90.0)
    logger.debug(
        "merge check: %d suspect pairs, %d undone for separation, %d bad angles",
        suspect.size,
        int(undo.sum()),
        int(bad.sum()),
    )
    if bad.any():
        undo |= is_merged & _hinges_of_ends(ends, bad, ids, faces)
    return undo
