"""How far the assembled tiles' top faces sit from the target surface, over each whole face.

A planar quad whose corners lie on a curved target is off it inside by its sagitta, so the
distance is measured on points spread over each top face, not only on its corners
(:func:`top_face_distances`).
"""

from __future__ import annotations

from dataclasses import dataclass

import igl
import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray

#: Points per side of the grid each top face is sampled on (corners and edges included), 289
#: points per face.  The trapezoid rule reads the mean high where the distance has a kink
#: (where a face crosses the target): on the 64-tile saddle a grid of 65 gives a mean 1.1 %
#: below this one's, one of 9 reads it 4 % high.
FIT_SAMPLES_PER_SIDE: int = 17


@dataclass(frozen=True)
class TopFaceDistances:
    """Distances (mm) of the tiles' top faces from the target.

    Attributes
    ----------
    tile_mean : (T,) float
        Per tile, the mean distance over its top face (weighted by area).
    tile_max : (T,) float
        Per tile, the largest distance of a sample of its top face.
    mean : float
        Over every top face, weighted by area.
    max : float
    """

    tile_mean: FloatArray
    tile_max: FloatArray
    mean: float
    max: float


def top_face_distances(
    tiles: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    samples: int = FIT_SAMPLES_PER_SIDE,
) -> TopFaceDistances:
    """Distances of the tiles' top faces (corners 0..3 of each tile) from a triangle mesh.

    Each top face is sampled on a ``samples`` x ``samples`` grid of its bilinear patch (the
    face itself where it is planar, as assembled tiles are), corners and edges included; the
    means integrate the distance over the face (trapezoid rule weighted by the patch's area
    element), the largest is the largest sample's.

    Parameters
    ----------
    tiles : (T, 8, 3) or (T, 4, 3) float, mm
    target_vertices : (p, 3) float, mm
    target_faces : (f, 3) int
    samples : int
        At least 2 (the corners alone).
    """
    quads = np.asarray(tiles, dtype=np.float64)
    if quads.ndim != 3 or quads.shape[1] not in (4, 8) or quads.shape[2] != 3:
        raise InternalError(f"tiles have shape {quads.shape}; pass (T, 8, 3) or (T, 4, 3)")
    if samples < 2:
        raise InternalError(f"samples is {samples}; use at least 2")
    if len(quads) == 0:
        empty = np.zeros(0)
        return TopFaceDistances(empty, empty, 0.0, 0.0)
    p = quads[:, :4]
    t = np.linspace(0.0, 1.0, samples)
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    basis = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=1)  # (S, 4)
    points = np.einsum("sk,tki->tsi", basis, p)  # (T, S, 3)
    du = np.einsum("s,ti->tsi", 1 - v, p[:, 1] - p[:, 0]) + np.einsum(
        "s,ti->tsi", v, p[:, 2] - p[:, 3]
    )
    dv = np.einsum("s,ti->tsi", 1 - u, p[:, 3] - p[:, 0]) + np.einsum(
        "s,ti->tsi", u, p[:, 2] - p[:, 1]
    )
    trapezoid = np.ones(samples)
    trapezoid[[0, -1]] = 0.5
    weights = np.outer(trapezoid, trapezoid).ravel()[None, :] * np.linalg.norm(
        np.cross(du, dv), axis=2
    )  # (T, S)
    sqd, _, _ = igl.point_mesh_squared_distance(
        np.ascontiguousarray(points.reshape(-1, 3)),
        np.ascontiguousarray(target_vertices, dtype=np.float64),
        np.ascontiguousarray(target_faces, dtype=np.int64),
    )
    dist = np.sqrt(np.maximum(np.asarray(sqd, dtype=np.float64), 0.0)).reshape(len(p), -1)
    area = weights.sum(axis=1)
    safe = np.where(area > 0, area, 1.0)
    tile_mean = np.where(area > 0, (weights * dist).sum(axis=1) / safe, dist.mean(axis=1))
    total = float(area.sum())
    mean = float((weights * dist).sum() / total) if total > 0 else float(dist.mean())
    return TopFaceDistances(tile_mean, dist.max(axis=1), mean, float(dist.max()))


#: Iterations of :func:`rigid_fit` at most, and the move (mm) of its sample points below which
#: it stops.
RIGID_FIT_ITERATIONS: int = 50
RIGID_FIT_STOP_MM: float = 1e-6
#: Points per side of the grid each top face is sampled on for :func:`rigid_fit`.
RIGID_FIT_SAMPLES_PER_SIDE: int = 5


def rigid_fit(
    tiles: ArrayLike,
    target_vertices: ArrayLike,
    target_faces: ArrayLike,
    iterations: int = RIGID_FIT_ITERATIONS,
) -> tuple[FloatArray, FloatArray]:
    """The rigid motion ``x -> rotation @ x + shift`` that brings the tiles' top faces closest
    to a triangle mesh in the least-squares sense: iterated closest points, each step the
    best rotation and shift (Kabsch) of points spread over every top face (a
    ``RIGID_FIT_SAMPLES_PER_SIDE`` grid) onto their closest target points.  A rigid motion
    keeps every tile's shape and every distance between tiles.

    Parameters
    ----------
    tiles : (T, 8, 3) or (T, 4, 3) float, mm
    target_vertices : (p, 3) float, mm
    target_faces : (f, 3) int

    Returns
    -------
    rotation : (3, 3) float
    shift : (3,) float, mm
    """
    quads = np.asarray(tiles, dtype=np.float64)[:, :4]
    t = np.linspace(0.0, 1.0, RIGID_FIT_SAMPLES_PER_SIDE)
    u, v = (a.ravel() for a in np.meshgrid(t, t, indexing="ij"))
    basis = np.stack([(1 - u) * (1 - v), u * (1 - v), u * v, (1 - u) * v], axis=1)
    start = np.einsum("sk,tki->tsi", basis, quads).reshape(-1, 3)
    target = np.ascontiguousarray(target_vertices, dtype=np.float64)
    faces = np.ascontiguousarray(target_faces, dtype=np.int64)
    rotation, shift = np.eye(3), np.zeros(3)
    points = start
    for _ in range(iterations):
        _, _, closest = igl.point_mesh_squared_distance(points, target, faces)
        closest = np.asarray(closest, dtype=np.float64)
        # the best rigid motion of the start points onto the closest points (Kabsch)
        p_mean, q_mean = start.mean(axis=0), closest.mean(axis=0)
        u_, _, vt = np.linalg.svd((start - p_mean).T @ (closest - q_mean))
        flip = np.diag([1.0, 1.0, float(np.sign(np.linalg.det(vt.T @ u_.T)))])
        rotation = vt.T @ flip @ u_.T
        shift = q_mean - rotation @ p_mean
        moved = start @ rotation.T + shift
        step = float(np.linalg.norm(moved - points, axis=1).max())
        points = moved
        if step < RIGID_FIT_STOP_MM:
            break
    return rotation, shift
