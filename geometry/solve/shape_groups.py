"""Constraint groups that fit a shape to each element: the closest square to a quad
(:class:`SimilarityToSquare`) and the frustum slab of a tile (:class:`Slab`), with the batched
closed-form fits they project with.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.solve.groups import ConstraintGroup
from drawstring.geometry.solve.linalg import centering_matrix, centred_normals, cross3


def _square_template(dim: int) -> FloatArray:
    """Corners of a centred square of side 2, counter-clockwise, padded to ``dim`` columns."""
    template = np.zeros((4, dim))
    template[:, :2] = [[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]
    return template


def _closest_squares_planar_template(pts: FloatArray) -> FloatArray:
    """Closed-form batched Umeyama fit of a square to centred quads in 2D or 3D.

    With the template ``T`` in the first two coordinates, ``Sigma = Q^T T`` has two non-zero
    columns ``c1, c2``; the optimal rotated template axes are the orthonormal polar factor
    ``[u1 u2] = [c1 c2] S^(-1/2)`` with ``S = [c1 c2]^T [c1 c2]`` (2x2, closed-form square root),
    which in 3D can always be completed to a proper rotation. In 2D the rotation angle is
    ``atan2(c1_y - c2_x, c1_x + c2_y)`` (no reflection). Scale is ``trace(S^(1/2)) / |T|^2``.
    Degenerate quads (collapsed to a segment or point) fall back to the SVD route.

    Parameters
    ----------
    pts : (k, 4, dim) float, centred quads, dim in {2, 3}

    Returns
    -------
    squares : (k, 4, dim) float
    """
    k, _, dim = pts.shape
    tx = np.array([-1.0, 1.0, 1.0, -1.0])
    ty = np.array([-1.0, -1.0, 1.0, 1.0])
    norm_t = 8.0
    c1 = np.einsum("ksi,s->ki", pts, tx)
    c2 = np.einsum("ksi,s->ki", pts, ty)
    if dim == 2:
        a = c1[:, 0] + c2[:, 1]
        b = c1[:, 1] - c2[:, 0]
        r = np.hypot(a, b)
        cos = np.where(r > 0, a / np.where(r > 0, r, 1.0), 1.0)
        sin = np.where(r > 0, b / np.where(r > 0, r, 1.0), 0.0)
        scale = r / norm_t
        u1 = np.stack([cos, sin], axis=1) * scale[:, None]
        u2 = np.stack([-sin, cos], axis=1) * scale[:, None]
    else:
        s11 = np.einsum("ki,ki->k", c1, c1)
        s12 = np.einsum("ki,ki->k", c1, c2)
        s22 = np.einsum("ki,ki->k", c2, c2)
        det = s11 * s22 - s12 * s12
        root_det = np.sqrt(np.maximum(det, 0.0))
        trace_root = np.sqrt(np.maximum(s11 + s22 + 2.0 * root_det, 0.0))  # trace of S^(1/2)
        ok = root_det > 1e-12 * np.maximum(s11 + s22, 1e-300)
        # S^(1/2) = (S + sqrt(det) I) / trace_root ; its inverse in closed form (2x2)
        safe_tr = np.where(ok, trace_root, 1.0)
        r11 = (s11 + root_det) / safe_tr
        r22 = (s22 + root_det) / safe_tr
        r12 = s12 / safe_tr
        root_det2 = r11 * r22 - r12 * r12
        inv_det = np.where(ok, 1.0 / np.where(ok, root_det2, 1.0), 0.0)
        i11, i22, i12 = r22 * inv_det, r11 * inv_det, -r12 * inv_det
        scale = trace_root / norm_t
        u1 = (c1 * i11[:, None] + c2 * i12[:, None]) * scale[:, None]
        u2 = (c1 * i12[:, None] + c2 * i22[:, None]) * scale[:, None]
        if not np.all(ok):
            bad = ~ok
            fallback = _closest_squares_svd(pts[bad])
            out = tx[None, :, None] * u1[:, None, :] + ty[None, :, None] * u2[:, None, :]
            out[bad] = fallback
            return np.asarray(out)
    return np.asarray(tx[None, :, None] * u1[:, None, :] + ty[None, :, None] * u2[:, None, :])


def _closest_squares_svd(pts: FloatArray) -> FloatArray:
    """Batched Umeyama closest square through an SVD (any dimension).

    Parameters
    ----------
    pts : (k, 4, dim) float, centred quads

    Returns
    -------
    squares : (k, 4, dim) float
    """
    dim = pts.shape[2]
    template = _square_template(dim)
    cross = np.einsum("ksi,sj->kij", pts, template)  # Sigma = Q^T T
    u, sing, vt = np.linalg.svd(cross)
    sign = np.sign(np.linalg.det(u) * np.linalg.det(vt))
    sign[sign == 0] = 1.0
    u[:, :, -1] *= sign[:, None]
    rot = u @ vt
    sing[:, -1] *= sign
    scale = sing.sum(axis=1) / np.sum(template * template)
    return np.asarray(scale[:, None, None] * np.einsum("sj,kij->ksi", template, rot))


class SimilarityToSquare(ConstraintGroup):
    """Each quad projected onto the closest similarity transform of a square.

    Without ``reference_normals`` (and always in 2D): batched Umeyama (1991) closest similarity
    (rotation with ``det R = +1``, uniform scale) of a square template to the centred quad, the
    exact closest square. In 3D a rotation can turn the square over, so a quad that folded over
    still counts as a perfect square.

    With ``reference_normals`` (3D): the square lies in the quad's best-fit plane, whose normal
    is oriented to agree with the quad's reference normal, and runs counter-clockwise about it
    (no reflection within the plane). A quad that turned over relative to its reference then
    projects onto a far-away square, which keeps tiles from folding over; the projection is the
    closest square in that oriented plane (for a planar quad, the closest oriented square).

    Parameters
    ----------
    quads : (k, 4) int
        Corners in cyclic order.
    reference_normals : (k, 3) float, optional
        Outward direction of each quad (e.g. its initial normal).
    """

    def __init__(
        self,
        quads: ArrayLike,
        weight: float = 1.0,
        name: str = "square_shape",
        reference_normals: ArrayLike | None = None,
    ) -> None:
        super().__init__(name, weight)
        arr = np.asarray(quads, dtype=np.int64)
        if arr.ndim != 2 or arr.shape[1] != 4:
            raise InternalError("SimilarityToSquare needs quads of shape (k, 4)")
        self.quads = arr
        self.reference_normals: FloatArray | None = None
        if reference_normals is not None:
            ref = np.asarray(reference_normals, dtype=np.float64)
            if ref.shape != (len(arr), 3):
                raise InternalError("reference_normals must have shape (k, 3), one per quad")
            self.reference_normals = ref

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(self.quads, n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        dim = ax.shape[1]
        pts = ax.reshape(-1, 4, dim)
        if dim == 3 and self.reference_normals is not None:
            return _closest_oriented_squares(pts, self.reference_normals).reshape(ax.shape)
        if dim in (2, 3):
            return _closest_squares_planar_template(pts).reshape(ax.shape)
        return _closest_squares_svd(pts).reshape(ax.shape)


def _closest_oriented_squares(pts: FloatArray, reference: FloatArray) -> FloatArray:
    """Closest counter-clockwise squares in each quad's best-fit plane, oriented by ``reference``.

    In an in-plane frame ``(e1, e2, n)`` the 2D Umeyama fit (see
    :func:`_closest_squares_planar_template`) puts the square's first axis along ``(a, b)``
    with ``a = c1.e1 + c2.e2`` and ``b = c1.e2 - c2.e1`` (``c1, c2`` the template-weighted sums
    of the corners) and scales it by ``|(a, b)| / 8``; that axis is the in-plane vector
    ``q = c1 - (c1.n) n - n x c2``, so the square is ``tx q / 8 + ty (n x q) / 8`` without any
    frame.

    Parameters
    ----------
    pts : (k, 4, 3) float, centred quads
    reference : (k, 3) float

    Returns
    -------
    squares : (k, 4, 3) float
    """
    normal = centred_normals(pts)
    n = normal * np.where(np.einsum("ki,ki->k", normal, reference) < 0, -1.0, 1.0)[:, None]
    c1 = pts[:, 1] + pts[:, 2] - pts[:, 0] - pts[:, 3]  # template x: -1, 1, 1, -1
    c2 = pts[:, 2] + pts[:, 3] - pts[:, 0] - pts[:, 1]  # template y: -1, -1, 1, 1
    u1 = 0.125 * (c1 - np.einsum("ki,ki->k", c1, n)[:, None] * n - cross3(n, c2))
    u2 = cross3(n, u1)
    out = np.empty_like(pts)
    out[:, 0] = -u1 - u2
    out[:, 1] = u1 - u2
    out[:, 2] = u1 + u2
    out[:, 3] = u2 - u1
    return out


def _unit_normal_with_offset(matrix: FloatArray, linear: FloatArray) -> FloatArray:
    """Minimize ``n^T M n - 2 g^T n`` over unit vectors ``n``, for many (M, g) at once.

    The minimizer is ``n = (M - lam I)^{-1} g`` with ``lam <= lambda_min(M)`` and ``|n| = 1``
    (the trust-region boundary problem); ``lam`` is found by Newton's method on
    ``1 / |n(lam)| - 1`` in the eigenbasis of ``M``, which converges monotonically from the left.

    Parameters
    ----------
    matrix : (k, d, d) float, symmetric
    linear : (k, d) float

    Returns
    -------
    n : (k, d) float, unit
    """
    mu, vecs = np.linalg.eigh(matrix)
    gam = np.einsum("kji,kj->ki", vecs, linear)
    gnorm = np.linalg.norm(gam, axis=1)
    hard = np.abs(gam[:, 0]) <= 1e-12 * np.maximum(gnorm, 1e-300)
    # shift t = mu_0 - lam > 0; Newton on phi(t) = 1/|p(t)| - 1 with p_i = gam_i / (mu_i - mu_0 + t)
    # from the left of the root: |p(t)| >= |gam_i| / (gap_i + t) = 1 at t = |gam_i| - gap_i, so
    # the largest of those (and |gam_0|) is a lower bound; for a slab the offset runs along the
    # largest eigenvector and that bound is within a few Newton steps of the root
    gap = mu - mu[:, :1]
    t = np.where(hard, 1.0, np.maximum(np.abs(gam[:, 0]), np.max(np.abs(gam) - gap, axis=1)))
    round_off = 4.0 * np.finfo(np.float64).eps
    for _ in range(60):
        denom = gap + t[:, None]
        p = gam / denom
        pn = np.linalg.norm(p, axis=1)
        dpn = -np.sum(gam * gam / denom**3, axis=1) / pn  # d|p|/dt
        phi = 1.0 / pn - 1.0
        dphi = -dpn / pn**2
        step = phi / dphi
        t_new = np.maximum(t - step, 0.5 * t)
        # converged: no more progress from the left, or |p| = 1 to round-off (where the step
        # would only flip by an ulp)
        done = (t_new - t <= 1e-15 * np.maximum(t, 1e-300)) | (np.abs(phi) <= round_off)
        t = t_new
        if np.all(done | hard):
            break
    p = gam / (gap + t[:, None])
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    if np.any(hard):
        p[hard] = 0.0
        p[hard, 0] = 1.0
    return np.einsum("kij,kj->ki", vecs, p)


class Slab(ConstraintGroup):
    """Tile top and bottom on two parallel planes a given distance apart (frustum extrusion).

    Each tile's top vertices are projected onto one plane and its bottom vertices onto the
    parallel plane ``thickness`` below it (along the common normal, which points from bottom to
    top). The common normal solves the exact closest-point problem, a unit-sphere quadratic
    ``n^T (C + s/2 d d^T) n - s h d^T n`` (``C`` the summed covariances of top and bottom, ``d``
    the top-minus-bottom centroid offset, ``s`` the vertices per face), batched over all tiles.

    Parameters
    ----------
    top : (k, s) int
        Top face vertex indices of each tile.
    bottom : (k, s) int
        Bottom face vertex indices, ``bottom[t, a]`` under ``top[t, a]``.
    thickness : (k,) float or float, mm
    """

    def __init__(
        self,
        top: ArrayLike,
        bottom: ArrayLike,
        thickness: ArrayLike,
        weight: float = 1.0,
        name: str = "slab",
    ) -> None:
        super().__init__(name, weight)
        top_arr = np.asarray(top, dtype=np.int64)
        bottom_arr = np.asarray(bottom, dtype=np.int64)
        if top_arr.ndim != 2 or top_arr.shape != bottom_arr.shape or top_arr.shape[1] < 3:
            raise InternalError("Slab top and bottom must both be (k, s) index arrays with s >= 3")
        self.top = top_arr
        self.bottom = bottom_arr
        thick = np.broadcast_to(np.asarray(thickness, dtype=np.float64), (len(top_arr),)).copy()
        if np.any(thick < 0) or not np.all(np.isfinite(thick)):
            raise InternalError("Slab thickness must be finite and >= 0")
        self.thickness = thick

    def matrix(self, n_vertices: int) -> sp.csr_matrix:
        return centering_matrix(np.hstack([self.top, self.bottom]), n_vertices)

    def project(self, ax: FloatArray, x: FloatArray) -> FloatArray:
        k, s = self.top.shape
        dim = ax.shape[1]
        pts = ax.reshape(k, 2 * s, dim)
        top, bottom = pts[:, :s], pts[:, s:]
        top_c, bottom_c = top.mean(axis=1), bottom.mean(axis=1)
        dt, db = top - top_c[:, None], bottom - bottom_c[:, None]
        cov = np.einsum("ksi,ksj->kij", dt, dt) + np.einsum("ksi,ksj->kij", db, db)
        offset = top_c - bottom_c
        half = 0.5 * s
        quad = cov + half * np.einsum("ki,kj->kij", offset, offset)
        lin = half * self.thickness[:, None] * offset
        normal = _unit_normal_with_offset(quad, lin)
        a = np.einsum("ki,ki->k", normal, top_c)
        b = np.einsum("ki,ki->k", normal, bottom_c)
        level_top = 0.5 * (a + b + self.thickness)
        level_bottom = level_top - self.thickness
        h_top = np.einsum("ksi,ki->ks", top, normal) - level_top[:, None]
        h_bottom = np.einsum("ksi,ki->ks", bottom, normal) - level_bottom[:, None]
        out = np.empty_like(pts)
        out[:, :s] = top - h_top[:, :, None] * normal[:, None, :]
        out[:, s:] = bottom - h_bottom[:, :, None] * normal[:, None, :]
        return out.reshape(ax.shape)
