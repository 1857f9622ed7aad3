"""Best rigid motions between corresponding point sets, batched (Kabsch, no reflection)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.types import FloatArray


def rigid_fit(source: ArrayLike, target: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Rotation and translation taking each source set onto its target set (least squares).

    Parameters
    ----------
    source, target : (T, k, d) float, corresponding points (e.g. tiles, k = 8, d = 3).

    Returns
    -------
    rotation : (T, 3, 3) float, proper rotations (det +1).
    translation : (T, 3) float, so that ``target ~ rotation @ source + translation``.
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    src_mean = src.mean(axis=1)
    dst_mean = dst.mean(axis=1)
    covariance = np.matmul((src - src_mean[:, None]).transpose(0, 2, 1), dst - dst_mean[:, None])
    u, _, vt = np.linalg.svd(covariance)
    u[np.linalg.det(np.matmul(u, vt)) < 0, :, -1] *= -1.0  # no reflections
    rotation = np.matmul(u, vt).transpose(0, 2, 1)  # V U^T
    translation = dst_mean - np.einsum("tij,tj->ti", rotation, src_mean)
    return rotation, translation


def apply_rigid(rotation: FloatArray, translation: FloatArray, points: ArrayLike) -> FloatArray:
    """(T, k, 3) ``points`` moved by each set's rotation and translation."""
    pts = np.asarray(points, dtype=np.float64)
    return np.asarray(np.matmul(pts, rotation.transpose(0, 2, 1)) + translation[:, None])


def rigid_copies(rest: ArrayLike, points: ArrayLike) -> FloatArray:
    """(T, k, 3) the rigid copies of each ``rest`` set closest to ``points`` (least squares)."""
    rotation, translation = rigid_fit(rest, points)
    return apply_rigid(rotation, translation, rest)
