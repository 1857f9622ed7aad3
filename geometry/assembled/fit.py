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
RIGID_FIT_ITERATIONS: int = 30
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
    to a triangle mesh: iterated closest points, point to plane (each step the small rotation
    and shift, by Gauss-Newton, that bring points spread over every top face, a
    ``RIGID_FIT_SAMPLES_PER_SIDE`` grid, onto the planes of their closest target triangles),
    until a step moves no point more than ``RIGID_FIT_STOP_MM``.  A rigid motion keeps every
    tile's shape and every distance between tiles.

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
    points = np.einsum("sk,tki->tsi", basis, quads).reshape(-1, 3)
    target = np.ascontiguousarray(target_vertices, dtype=np.float64)
    faces = np.ascontiguousarray(target_faces, dtype=np.int64)
    corners = target[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    normals /= np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-300)
    rotation, shift = np.eye(3), np.zeros(3)
    for _ in range(iterations):
        _, face, closest = igl.point_mesh_squared_distance(points, target, faces)
        n = normals[np.asarray(face, dtype=np.int64)]
        offset = np.einsum("pi,pi->p", points - np.asarray(closest, dtype=np.float64), n)
        # rows d/d(omega, delta) of (omega x p + delta) . n, omega a small rotation vector
        rows = np.concatenate([np.cross(points, n), n], axis=1)
        normal_matrix = rows.T @ rows
        # damped: a target that lets the points slide (a plane, a cylinder) keeps them still
        damping = 1e-9 * float(np.trace(normal_matrix)) + 1e-300
        step = np.linalg.solve(normal_matrix + damping * np.eye(6), -rows.T @ offset)
        omega, delta = step[:3], step[3:]
        angle = float(np.linalg.norm(omega))
        turn = np.eye(3)
        if angle > 0:
            k = (
                np.array(
                    [[0, -omega[2], omega[1]], [omega[2], 0, -omega[0]], [-omega[1], omega[0], 0]]
                )
                / angle
            )
            turn += np.sin(angle) * k + (1 - np.cos(angle)) * k @ k
        moved = points @ turn.T + delta
        rotation, shift = turn @ rotation, turn @ shift + delta
        moved_by = float(np.linalg.norm(moved - points, axis=1).max())
        points = moved
        if moved_by < RIGID_FIT_STOP_MM:
            break
    return rotation, shift
