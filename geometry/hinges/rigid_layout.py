"""Rigid planar layout of the flat tiles with their hinge pairs brought together (paper 4.4).

The ``dual`` strategy's ``w_rigid E_rigid + w_collision E_collision + w_conn E_conn`` with the
rigidity exact: every flat tile keeps its T2D shape and only turns about the vertical axis and
translates in the plane (3 degrees of freedom).  Close tile pairs are kept apart by separating
planes attached to one tile of each pair (through the hinge for hinged pairs, or on the hinge
face only for pairs whose overlap is trimmed), gap angles are held in ``[theta_min, 90]``, and
the squared distance of every hinge pair is minimized by an augmented Lagrangian with
Levenberg-Marquardt subproblems.  Then every pair is merged into one point where that keeps the
layout valid.  :func:`~drawstring.geometry.hinges.placement.layout_hinges` decides the hinge
sides and the trims and calls :func:`rigid_layout`; the planes are found and measured in
:mod:`~drawstring.geometry.hinges.separating_planes`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import (
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_FEASIBLE_MM,
)
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.verify import hinge_gaps
from drawstring.geometry.hinges.separating_planes import (
    RigidPose,
    SeparatingPlanes,
    perp,
    plane_values,
    rotate2,
    select_planes,
)
from drawstring.geometry.solve.spd import SpdSolver
from drawstring.geometry.tiling.linkage import Linkage, SlitEnds, slit_ends

logger = logging.getLogger(__name__)

HingeStrategy = Literal["dual", "top"]

__all__ = ["HingeStrategy", "RigidLayoutResult", "rigid_layout"]


@dataclass
class _Constraints:
    """Current inequality set ``g(pose) >= 0`` of the layout (planes and angle bounds)."""

    planes: SeparatingPlanes
    ends: SlitEnds
    faces: IntArray  # (F,) faces whose angles are bounded (0 top, 4 bottom)
    angle0: FloatArray  # (F, E) rad at zero pose
    lo: FloatArray  # (F, E) rad
    hi: FloatArray  # (F, E) rad
    scale: float  # mm per rad (mean tile side)


def _constraint_values(
    layout: RigidPose,
    con: _Constraints,
    phi: FloatArray,
    trans: FloatArray,
    rows: IntArray | None = None,
) -> tuple[FloatArray, sp.csr_matrix | None]:
    """All inequality values ``(m,)`` (mm) at a pose, and the Jacobian ``(len(rows), 3T)`` of
    the selected ones (plane rows first, then lower and upper angle bounds per face)."""
    x = layout.positions(phi, trans)
    planes = con.planes
    gb, _, w = plane_values(layout, planes, x, phi, trans, carrier=False)
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
            np.einsum("ki,ki->k", wp, perp(xb - origin[b])),
            wp[:, 0],
            wp[:, 1],
            np.einsum("ki,ki->k", perp(wp), xb - origin[a]),
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
    layout: RigidPose,
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
    ra = rotate2(layout.local[ta, va], phi[ta])  # hinge vertices relative to tile origins
    rb = rotate2(layout.local[tb, vb], phi[tb])
    origin = layout.centre + trans
    xa, xb = origin[ta] + ra, origin[tb] + rb
    sw = np.sqrt(weight)
    res = (sw[:, None] * (xa - xb)).ravel()
    if not jacobian:
        return res, None
    h = len(ids)
    pa, pb = perp(ra), perp(rb)
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
    layout: RigidPose,
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
    first_planes : SeparatingPlanes
        The separating planes chosen at the start layout (``shapes``), before any round.
    """

    tiles: FloatArray
    merged: FloatArray
    points: FloatArray
    is_merged: BoolArray
    gap_mm: FloatArray
    violation_mm: float
    iterations: int
    first_planes: SeparatingPlanes


def _merge_points(
    layout: RigidPose, planes: SeparatingPlanes, ids: IntArray, x: FloatArray
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
    w = rotate2(planes.normal[p, :2], layout.phi[a])
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
      two convex pieces, :func:`~drawstring.geometry.flat.verify.convex_pieces`, each separated on
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
        raise InternalError(f"trim has shape {cut.shape}; pass one flag per hinge")
    layout = RigidPose(t2)
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

    def constraints(planes: SeparatingPlanes) -> _Constraints:
        return _Constraints(
            planes, ends, faces, angle0, np.radians(lo_deg), np.radians(hi_deg), scale
        )

    state: dict[str, Any] = {"lam": None, "rho": 10.0}
    # One solver for the whole layout, its pattern reserved for all the constraints a set of
    # planes can make active: a symbolic analysis per set of planes rather than one whenever the
    # active set grows (62 of them, 9 ms each, in the 1600-tile wave's hinge layout).
    factor = SpdSolver()

    def solve(
        planes: SeparatingPlanes, rounds: int, reselect: int
    ) -> tuple[SeparatingPlanes, float]:
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
                planes = select_planes(
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
    first_planes = select_planes(layout, linkage, ids, cut, clearance_mm, reach, known=known)
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


def _normal_pattern(
    n: int, ids: IntArray, planes: SeparatingPlanes, ends: SlitEnds
) -> sp.csr_matrix:
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
    x: FloatArray, ids: IntArray, points: FloatArray, is_merged: BoolArray
) -> FloatArray:
    """Tiles ``(T, 8, 3)`` with both vertices of every merged hinge moved to its point."""
    flat = x.reshape(-1, 3).copy()
    flat[ids[is_merged, 0]] = points[is_merged]
    flat[ids[is_merged, 1]] = points[is_merged]
    return flat.reshape(x.shape)


def _hinges_of_ends(ends: SlitEnds, bad: BoolArray, ids: IntArray, faces: IntArray) -> BoolArray:
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
    layout: RigidPose,
    linkage: Linkage,
    trim: BoolArray,
    planes: SeparatingPlanes,
    ends: SlitEnds,
    faces: IntArray,
    merged: FloatArray,
    ids: IntArray,
    is_merged: BoolArray,
    min_gap_angle_deg: float,
) -> BoolArray:
    """Merged hinges to undo: those whose moved vertices leave two tiles without a separating
    plane, or a gap angle out of its bounds (checked on the merged tiles)."""
    tol = 1e-9
    gb, ga, _ = plane_values(layout, planes, merged, layout.phi, layout.trans)
    assert ga is not None
    # Separation only (the clearance is a target of the layout, not a validity condition).
    gb = gb + np.where(np.isfinite(planes.delta_b), planes.delta_b, 0.0)
    ga = ga + np.where(np.isfinite(planes.delta_a), planes.delta_a, 0.0)
    suspect = np.flatnonzero(np.any(gb < -tol, axis=1) | np.any(ga < -tol, axis=1))
    undo = np.zeros(len(ids), dtype=bool)
    if suspect.size:
        pairs = np.stack([planes.a[suspect], planes.b[suspect]], axis=1)
        again = select_planes(layout, linkage, ids, trim, 0.0, 0.0, x=merged, pairs=pairs)
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
