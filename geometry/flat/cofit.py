"""The joint solve's rows for a shape pulled to the target at its quads' face samples.

:func:`~drawstring.geometry.flat.coflat.co_optimize_top` pulls its vertices to the target; with
face samples (``w_samples``) it also pulls the quads' centres and edge midpoints
(:func:`face_sample_matrix`: a planar quad with its corners on a curved target is off it
inside by its sagitta), and keeps every quad's corners convex (:func:`convex_corner_rows`): a
shape pulled to the target while its tiles are made to fold flat can fold a small quad into
a dart (the 200-tile cloud's did, at face-sample weight 30).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from drawstring.geometry.core.types import FloatArray, IntArray

#: Smallest corner margin (:func:`convex_corner_rows`) a joint solve with face samples keeps:
#: a corner's height over the diagonal joining its two neighbours, over that diagonal's
#: length (0.5 at a square's corners, 0 at a straight angle; eq. 1 keeps 0.2).
CO_CONVEX_MARGIN = 0.05
#: Weight of those rows relative to planarity: soft, so that they stop a fold without
#: holding the tiles against their congruence (at 1, or at margin 0.1, the 200-tile cloud
#: and three-shell missed 1e-3 mm; at 1e-5 the cloud still folded).
CO_CONVEX_WEIGHT_REL = 1e-3


def face_sample_matrix(quads: IntArray, n_vertices: int) -> sp.csr_matrix:
    """The quads' centres and their unique edges' midpoints as rows of vertex weights
    (the points :class:`~drawstring.geometry.solve.groups.FaceSamplesToSurface` pulls)."""
    q = np.asarray(quads, dtype=np.int64)
    pairs = np.stack([q, np.roll(q, -1, axis=1)], axis=2).reshape(-1, 2)
    edges = np.unique(np.sort(pairs, axis=1), axis=0)
    m, k = len(q), len(edges)
    rows = np.concatenate([np.repeat(np.arange(m), 4), m + np.repeat(np.arange(k), 2)])
    cols = np.concatenate([q.ravel(), edges.ravel()])
    vals = np.concatenate([np.full(4 * m, 0.25), np.full(2 * k, 0.5)])
    return sp.csr_matrix((vals, (rows, cols)), shape=(m + k, n_vertices))


def quad_normals(top: FloatArray, quads: IntArray) -> FloatArray:
    """Unit normals of the quads, from their diagonals' cross product."""
    p = top[quads]
    n = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    return np.asarray(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))


def convex_corner_rows(
    top: FloatArray, quads: IntArray, reference: FloatArray, side: float
) -> tuple[FloatArray, IntArray, FloatArray]:
    """Residuals of the quad corners whose margin is under :data:`CO_CONVEX_MARGIN`, as a
    length, ``side * (margin - CO_CONVEX_MARGIN)``, 0 at the others; the three vertices of
    each (``(4 m, 3)``: the corner's two neighbours and the corner) and the residual's
    gradients there (``(4 m, 3, 3)``).  The margin of corner ``b`` between ``a`` and ``c`` is
    ``(b - a) . ((c - a) x n) / |c - a|^2``, ``n`` its quad's normal turned to agree with
    ``reference`` (the normals where the solve started); the gradient holds ``n`` and
    ``|c - a|`` fixed."""
    n = quad_normals(top, quads)
    n *= np.where(np.einsum("ki,ki->k", n, reference) < 0, -1.0, 1.0)[:, None]
    a_i, b_i, c_i = np.roll(quads, 1, axis=1), quads, np.roll(quads, -1, axis=1)
    d, u = top[c_i] - top[a_i], top[b_i] - top[a_i]
    nn = np.broadcast_to(n[:, None, :], d.shape)
    scale = side / np.maximum(np.einsum("kci,kci->kc", d, d), 1e-300)
    g_u = np.cross(d, nn)  # gradient of u . (d x n) in u, and below in d
    g_d = np.cross(nn, u)
    margin = np.einsum("kci,kci->kc", u, g_u) * scale / side
    active = margin < CO_CONVEX_MARGIN
    res = np.where(active, side * (margin - CO_CONVEX_MARGIN), 0.0)
    grads = np.stack([-g_u - g_d, g_u, g_d], axis=2) * (scale * active)[..., None, None]
    vertices = np.stack([a_i, b_i, c_i], axis=2)
    return res.ravel(), vertices.reshape(-1, 3), grads.reshape(-1, 3, 3)
