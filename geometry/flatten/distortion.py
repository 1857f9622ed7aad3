"""Measures of a piecewise-linear map of a triangle mesh to the plane: quasi-conformal
distortion per face and the faces it turns over.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.types import BoolArray, FloatArray


def quasi_conformal_distortion(vertices: ArrayLike, faces: ArrayLike, uv: ArrayLike) -> FloatArray:
    """Per-face quasi-conformal distortion of a piecewise-linear map to the plane.

    Parameters
    ----------
    vertices : (n, 3) float, mm, 3D vertex positions.
    faces : (m, 3) int, triangles.
    uv : (n, 2) float, mm, flat vertex positions.

    Returns
    -------
    (m,) float, ratio ``sigma_max / sigma_min >= 1`` of the singular values of each face's
    Jacobian (1 for a similarity); ``inf`` where the flat triangle has zero area.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    W = np.asarray(uv, dtype=np.float64)
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    len1 = np.linalg.norm(e1, axis=1)
    x_axis = e1 / len1[:, None]
    a = np.einsum("ij,ij->i", e2, x_axis)
    b = np.linalg.norm(e2 - a[:, None] * x_axis, axis=1)
    # 3D triangle in a local frame: p1 = (len1, 0), p2 = (a, b); J = Q P^-1.
    q1 = W[F[:, 1]] - W[F[:, 0]]
    q2 = W[F[:, 2]] - W[F[:, 0]]
    j_col0 = q1 / len1[:, None]
    j_col1 = (q2 - a[:, None] * j_col0) / b[:, None]
    # J = [[p, q], [r, s]] splits into a similarity part (|f_z|) and an anti-similarity part
    # (|f_zbar|); the singular values are their sum and difference.
    p, r = j_col0[:, 0], j_col0[:, 1]
    q, s = j_col1[:, 0], j_col1[:, 1]
    f_z = np.hypot(p + s, r - q)
    f_zbar = np.hypot(p - s, r + q)
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = (f_z + f_zbar) / np.abs(f_z - f_zbar)
    ratio[f_z == f_zbar] = np.inf
    return np.asarray(np.maximum(ratio, 1.0), dtype=np.float64)


def flipped_faces(faces: ArrayLike, uv: ArrayLike) -> BoolArray:
    """Faces whose flat image has non-positive signed area.

    Parameters
    ----------
    faces : (m, 3) int, triangles.
    uv : (n, 2) float, mm, flat vertex positions.

    Returns
    -------
    (m,) bool, True where the triangle is flipped or degenerate in uv.
    """
    F = np.asarray(faces, dtype=np.int64)
    W = np.asarray(uv, dtype=np.float64)
    d1 = W[F[:, 1]] - W[F[:, 0]]
    d2 = W[F[:, 2]] - W[F[:, 0]]
    return np.asarray(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] <= 0.0)
