"""Sparse row operators and batched small linear algebra shared by the constraint groups.

The operators build the constant matrices ``A`` of the groups (selecting, differencing and
centring vertices); the batched routines work on many small point sets at once: covariances,
smallest eigenvectors of 3x3 matrices in closed form, least-variance normals and plane fits, and
closest points on triangles.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import scipy.sparse as sp

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray

# --------------------------------------------------------------------------------------------
# Sparse operators shared by the groups
# --------------------------------------------------------------------------------------------


def selection_matrix(indices: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows that pick vertices: ``(A X)[r] = X[indices[r]]``.

    Parameters
    ----------
    indices : (k,) int
    n_vertices : int

    Returns
    -------
    A : (k, n_vertices) sparse
    """
    k = len(indices)
    return sp.csr_matrix(
        (np.ones(k), (np.arange(k), np.asarray(indices, dtype=np.int64))), shape=(k, n_vertices)
    )


def difference_matrix(edges: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows ``(A X)[r] = X[edges[r, 1]] - X[edges[r, 0]]``.

    Parameters
    ----------
    edges : (k, 2) int
    n_vertices : int

    Returns
    -------
    A : (k, n_vertices) sparse
    """
    k = len(edges)
    rows = np.repeat(np.arange(k), 2)
    cols = np.asarray(edges, dtype=np.int64).reshape(-1)
    vals = np.tile([-1.0, 1.0], k)
    return sp.csr_matrix((vals, (rows, cols)), shape=(k, n_vertices))


def centering_matrix(elements: IntArray, n_vertices: int) -> sp.csr_matrix:
    """Rows that give each element's vertices minus the element's centroid.

    Parameters
    ----------
    elements : (k, s) int
        Vertex indices of ``k`` elements of ``s`` vertices each.
    n_vertices : int

    Returns
    -------
    A : (k * s, n_vertices) sparse
        Row ``e * s + a`` is ``X[elements[e, a]] - mean_b X[elements[e, b]]``.
    """
    elements = np.asarray(elements, dtype=np.int64)
    k, s = elements.shape
    rows = np.repeat(np.arange(k * s), s)
    cols = np.repeat(elements, s, axis=0).reshape(-1)
    block = np.eye(s) - 1.0 / s
    vals = np.tile(block.reshape(-1), k)
    return sp.csr_matrix((vals, (rows, cols)), shape=(k * s, n_vertices))


def cross3(a: FloatArray, b: FloatArray) -> FloatArray:
    """Row-wise cross products of (..., 3) arrays (cheaper than ``np.cross`` on small batches)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[..., 0] = a[..., 1] * b[..., 2] - a[..., 2] * b[..., 1]
    out[..., 1] = a[..., 2] * b[..., 0] - a[..., 0] * b[..., 2]
    out[..., 2] = a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]
    return out


def covariances(points: FloatArray) -> FloatArray:
    """Scatter matrices ``sum_s p p^T`` of many point sets (points already centred).

    Parameters
    ----------
    points : (k, s, dim) float

    Returns
    -------
    scatter : (k, dim, dim) float
    """
    return np.matmul(points.transpose(0, 2, 1), points)


def smallest_eigenvectors(matrices: FloatArray) -> FloatArray:
    """Unit eigenvectors of the smallest eigenvalue of many symmetric matrices.

    3x3 matrices use the closed-form trigonometric eigenvalue and a cross product of two rows
    of ``M - lambda I`` (about 3x faster than batched ``eigh``); matrices where that is ill
    conditioned (two smallest eigenvalues nearly equal) and other sizes fall back to ``eigh``.

    Parameters
    ----------
    matrices : (k, d, d) float, symmetric

    Returns
    -------
    vectors : (k, d) float
    """
    k, d, _ = matrices.shape
    if d != 3 or k == 0:
        return np.asarray(np.linalg.eigh(matrices)[1][:, :, 0])
    return _smallest_eigenvectors_3(
        matrices[:, 0, 0],
        matrices[:, 1, 1],
        matrices[:, 2, 2],
        matrices[:, 0, 1],
        matrices[:, 0, 2],
        matrices[:, 1, 2],
        lambda bad: matrices[bad],
    )


def _smallest_eigenvectors_3(
    a00: FloatArray,
    a11: FloatArray,
    a22: FloatArray,
    a01: FloatArray,
    a02: FloatArray,
    a12: FloatArray,
    matrices_of: Callable[[BoolArray], FloatArray],
) -> FloatArray:
    """:func:`smallest_eigenvectors` of 3x3 symmetric matrices given by their six entries.

    ``matrices_of(mask)`` returns the full ``(j, 3, 3)`` matrices of the rows in ``mask`` (for
    the ``eigh`` fallback of ill-conditioned rows).
    """
    mean = (a00 + a11 + a22) / 3.0
    b00, b11, b22 = a00 - mean, a11 - mean, a22 - mean
    spread = np.sqrt((b00**2 + b11**2 + b22**2 + 2.0 * (a01**2 + a02**2 + a12**2)) / 6.0)
    safe = np.where(spread > 0, spread, 1.0)
    det = (
        b00 * (b11 * b22 - a12 * a12)
        - a01 * (a01 * b22 - a12 * a02)
        + a02 * (a01 * a12 - b11 * a02)
    ) / safe**3
    angle = np.arccos(np.clip(0.5 * det, -1.0, 1.0)) / 3.0
    lam = mean + 2.0 * spread * np.cos(angle + 2.0 * np.pi / 3.0)
    s00, s11, s22 = a00 - lam, a11 - lam, a22 - lam
    # cross products of the rows (0, 1), (0, 2), (1, 2) of M - lam I
    crosses = np.empty((3, 3, len(lam)))
    crosses[0] = (a01 * a12 - a02 * s11, a02 * a01 - s00 * a12, s00 * s11 - a01 * a01)
    crosses[1] = (a01 * s22 - a02 * a12, a02 * a02 - s00 * s22, s00 * a12 - a01 * a02)
    crosses[2] = (s11 * s22 - a12 * a12, a12 * a02 - a01 * s22, a01 * a12 - s11 * a02)
    norms2 = np.einsum("cik,cik->ck", crosses, crosses)
    best = np.argmax(norms2, axis=0)
    rows = np.arange(len(lam))
    best_norm2 = norms2[best, rows]
    out = crosses[best, :, rows] / np.sqrt(np.where(best_norm2 > 0, best_norm2, 1.0))[:, None]
    # well conditioned when |cross| ~ (gap between the two larger eigenvalues and lam)^2 is large
    bad = best_norm2 <= (1e-6 * spread**2) ** 2
    if np.any(bad):
        out[bad] = np.linalg.eigh(matrices_of(bad))[1][:, :, 0]
    return np.asarray(out)


class _NormalMemo:
    """The last batch of centred point sets given to :func:`centred_normals` and its result.

    In one local step of the K3D solve, :class:`~drawstring.geometry.solve.groups.Plane` and the
    oriented :class:`~drawstring.geometry.solve.shape_groups.SimilarityToSquare` receive bitwise
    identical rows (both groups centre the same quads), so the second one reuses the first one's
    eigenvectors instead of recomputing them.
    """

    points: FloatArray | None = None
    normals: FloatArray | None = None
    hits = 0


def centred_normals(points: FloatArray) -> FloatArray:
    """Least-variance unit directions of many centred point sets (sign arbitrary).

    The same as ``smallest_eigenvectors(covariances(points))``; a repeated call with an equal
    array returns the previous result (read-only) without recomputing it.

    Parameters
    ----------
    points : (k, s, dim) float, each set centred on its centroid

    Returns
    -------
    normals : (k, dim) float, read-only
    """
    memo_points = _NormalMemo.points
    if (
        memo_points is not None
        and _NormalMemo.normals is not None
        and memo_points.shape == points.shape
        and np.array_equal(memo_points, points)
    ):
        _NormalMemo.hits += 1
        return _NormalMemo.normals
    if points.ndim == 3 and points.shape[2] == 3 and len(points):
        x, y, z = points[:, :, 0], points[:, :, 1], points[:, :, 2]
        normals = _smallest_eigenvectors_3(
            np.einsum("ks,ks->k", x, x),
            np.einsum("ks,ks->k", y, y),
            np.einsum("ks,ks->k", z, z),
            np.einsum("ks,ks->k", x, y),
            np.einsum("ks,ks->k", x, z),
            np.einsum("ks,ks->k", y, z),
            lambda bad: covariances(points[bad]),
        )
    else:
        normals = smallest_eigenvectors(covariances(points))
    normals.flags.writeable = False
    _NormalMemo.points = np.array(points, dtype=np.float64)
    _NormalMemo.normals = normals
    return normals


def plane_fit(points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Least-squares planes (hyperplanes in 2D: lines) of many point sets at once.

    Parameters
    ----------
    points : (k, s, dim) float
        ``k`` sets of ``s`` points.

    Returns
    -------
    centroids : (k, dim) float
    normals : (k, dim) float
        Unit normals (direction of least variance; sign arbitrary).
    """
    centroids = points.mean(axis=1)
    centred = points - centroids[:, None, :]
    return centroids, smallest_eigenvectors(covariances(centred))


def closest_points_on_triangles(
    points: FloatArray, a: FloatArray, b: FloatArray, c: FloatArray
) -> tuple[FloatArray, IntArray]:
    """Closest point of each triangle ``(a, b, c)`` to each point, and the feature it lies on.

    Ericson, "Real-Time Collision Detection" (2005), 5.1.5, batched.

    Parameters
    ----------
    points, a, b, c : (k, 3) float

    Returns
    -------
    closest : (k, 3) float
    feature : (k,) int
        0, 1, 2: corner ``a``, ``b``, ``c``; 3, 4, 5: edge ``ab``, ``ac``, ``bc`` (inside it);
        6: the interior of the triangle.
    """
    ab, ac = b - a, c - a
    ap, bp, cp = points - a, points - b, points - c
    d1 = np.einsum("ki,ki->k", ab, ap)
    d2 = np.einsum("ki,ki->k", ac, ap)
    d3 = np.einsum("ki,ki->k", ab, bp)
    d4 = np.einsum("ki,ki->k", ac, bp)
    d5 = np.einsum("ki,ki->k", ab, cp)
    d6 = np.einsum("ki,ki->k", ac, cp)
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    feature = np.select(
        [
            (d1 <= 0) & (d2 <= 0),
            (d3 >= 0) & (d4 <= d3),
            (d6 >= 0) & (d5 <= d6),
            (vc <= 0) & (d1 >= 0) & (d3 <= 0),
            (vb <= 0) & (d2 >= 0) & (d6 <= 0),
            (va <= 0) & (d4 >= d3) & (d5 >= d6),
        ],
        [0, 1, 2, 3, 4, 5],
        6,
    )
    # barycentric weights (of b and c) of the closest point, feature by feature
    with np.errstate(divide="ignore", invalid="ignore"):
        edge_ab = d1 / (d1 - d3)
        edge_ac = d2 / (d2 - d6)
        edge_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        total = va + vb + vc
        inner_v, inner_w = vb / total, vc / total
    zero = np.zeros(len(points))
    one = np.ones(len(points))
    v = np.choose(feature, [zero, one, zero, edge_ab, zero, 1.0 - edge_bc, inner_v])
    w = np.choose(feature, [zero, zero, one, zero, edge_ac, edge_bc, inner_w])
    closest = a + v[:, None] * ab + w[:, None] * ac
    return closest, np.asarray(feature, dtype=np.int64)
