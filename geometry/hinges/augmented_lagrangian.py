"""The rigid hinge layout's solver terms (:mod:`~drawstring.geometry.hinges.rigid_layout`): the
inequality constraints (separating planes and gap-angle bounds) and the hinge residuals with their
Jacobians in the tiles' pose (a turn and a translation each), the sparsity pattern of the normal
equations, and one augmented-Lagrangian subproblem solved by damped Gauss-Newton.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.hinges.separating_planes import (
    RigidPose,
    SeparatingPlanes,
    perp,
    plane_values,
    rotate2,
)
from drawstring.geometry.solve.spd import SpdSolver
from drawstring.geometry.tiling.linkage import SlitEnds

__all__ = [
    "LayoutConstraints",
    "augmented_lagrangian",
    "constraint_values",
    "hinge_residuals",
    "normal_pattern",
]


@dataclass
class LayoutConstraints:
    """Current inequality set ``g(pose) >= 0`` of the layout (planes and angle bounds)."""

    planes: SeparatingPlanes
    ends: SlitEnds
    faces: IntArray  # (F,) faces whose angles are bounded (0 top, 4 bottom)
    angle0: FloatArray  # (F, E) rad at zero pose
    lo: FloatArray  # (F, E) rad
    hi: FloatArray  # (F, E) rad
    scale: float  # mm per rad (mean tile side)


def constraint_values(
    layout: RigidPose,
    con: LayoutConstraints,
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


def hinge_residuals(
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


def augmented_lagrangian(
    layout: RigidPose,
    con: LayoutConstraints,
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
        rh, _ = hinge_residuals(layout, ids, phi, trans, weight, jacobian=False)
        g, _ = constraint_values(layout, con, phi, trans)
        slack = np.maximum(lam / rho - g, 0.0)
        return float(rh @ rh + rho * (slack @ slack)), rh, g

    def jacobian(phi: FloatArray, trans: FloatArray, g: FloatArray, rh: FloatArray):
        _, jh = hinge_residuals(layout, ids, phi, trans, weight)
        assert jh is not None
        slack = lam / rho - g
        act = np.flatnonzero(slack > 0)
        _, jg = constraint_values(layout, con, phi, trans, act)
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


def normal_pattern(
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
