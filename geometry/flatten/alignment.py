"""How well a flat map's grid lines follow the target's principal curvature directions.

A quad grid along the principal directions has planar, near-conical quads (paper 4.1-4.2); the
automatic rectangle corners (:mod:`drawstring.geometry.flatten.rectangle`) are scored by the
grid's geodesic torsion, which is zero there.  Per-face shape operators come from
``igl.principal_curvature``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import igl
import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flatten.bff import BffSystem

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Curvature:
    """Per-face second fundamental form, for scoring grid alignment (internal)."""

    tensor: FloatArray  # (m, 3, 3) mean of the vertices' shape operators, 1/mm
    normal: FloatArray  # (m, 3) unit face normals
    area: FloatArray  # (m,) face areas, mm^2
    anisotropy: float  # int ((k1 - k2) / 2)^2 dA over the surface, dimensionless
    # For d = a e1 + b e2 (e1, e2 the face's edges from its first corner): the torsion's
    # numerator d^T S (n x d) and |d|^2 as quadratic forms in (a, b), (m, 3) each:
    # coefficients of a^2, a b, b^2.
    torsion_form: FloatArray
    length_form: FloatArray


def face_curvature(V: FloatArray, F: IntArray) -> Curvature | None:
    """Shape operators from ``igl.principal_curvature``, averaged to faces; None if it fails.

    Each vertex's operator ``k1 d1 d1^T + k2 d2 d2^T`` is averaged over the face's corners (no
    sign ambiguity of the directions) and restricted to the face plane.
    """
    try:
        d1, d2, k1, k2, _ = igl.principal_curvature(V, F)
    except Exception as exc:  # igl raises plain RuntimeErrors on meshes it cannot fit
        log.debug("principal curvature failed (%s); corners chosen without alignment", exc)
        return None
    d1, d2 = np.asarray(d1), np.asarray(d2)
    k1, k2 = np.asarray(k1), np.asarray(k2)
    if not (np.all(np.isfinite(d1)) and np.all(np.isfinite(k1)) and np.all(np.isfinite(k2))):
        return None
    shape_op = k1[:, None, None] * d1[:, :, None] * d1[:, None, :]
    shape_op += k2[:, None, None] * d2[:, :, None] * d2[:, None, :]
    tensor = shape_op[F].mean(axis=1)
    cross = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    double_area = np.linalg.norm(cross, axis=1)
    normal = cross / double_area[:, None]
    project = np.eye(3) - normal[:, :, None] * normal[:, None, :]
    tensor = project @ tensor @ project
    # (k1 - k2)^2 / 4 of the tangential 2x2 part: |S|_F^2 / 2 - (tr S)^2 / 4
    frob = np.einsum("fij,fij->f", tensor, tensor)
    trace = np.einsum("fii->f", tensor)
    half_gap_sq = np.maximum(0.5 * frob - 0.25 * trace**2, 0.0)
    area = 0.5 * double_area
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    s1 = np.einsum("fij,fj->fi", tensor, np.cross(normal, e1))
    s2 = np.einsum("fij,fj->fi", tensor, np.cross(normal, e2))
    torsion_form = np.column_stack(
        [
            np.einsum("fi,fi->f", e1, s1),
            np.einsum("fi,fi->f", e1, s2) + np.einsum("fi,fi->f", e2, s1),
            np.einsum("fi,fi->f", e2, s2),
        ]
    )
    length_form = np.column_stack(
        [
            np.einsum("fi,fi->f", e1, e1),
            2.0 * np.einsum("fi,fi->f", e1, e2),
            np.einsum("fi,fi->f", e2, e2),
        ]
    )
    return Curvature(
        tensor=tensor,
        normal=normal,
        area=area,
        anisotropy=float(area @ half_gap_sq),
        torsion_form=torsion_form,
        length_form=length_form,
    )


def _grid_directions(V: FloatArray, F: IntArray, uv: FloatArray) -> tuple[FloatArray, BoolArray]:
    """(m, 3) unit 3D direction mapped to the uv x-axis in each face, and which faces are valid."""
    e1 = V[F[:, 1]] - V[F[:, 0]]
    e2 = V[F[:, 2]] - V[F[:, 0]]
    q1 = uv[F[:, 1]] - uv[F[:, 0]]
    q2 = uv[F[:, 2]] - uv[F[:, 0]]
    det = q1[:, 0] * q2[:, 1] - q1[:, 1] * q2[:, 0]
    valid = det > 0.0
    safe = np.where(valid, det, 1.0)
    # d = alpha e1 + beta e2 has flat image (1, 0): [q1 q2] (alpha, beta)^T = (1, 0)^T
    direction = (q2[:, 1] / safe)[:, None] * e1 - (q1[:, 1] / safe)[:, None] * e2
    length = np.linalg.norm(direction, axis=1)
    valid &= length > 0.0
    return direction / np.where(valid, length, 1.0)[:, None], valid


def _grid_torsion(curvature: Curvature, direction: FloatArray, valid: BoolArray) -> FloatArray:
    """(m,) 1/mm, geodesic torsion ``II(d, n x d)`` of the grid line along ``direction``.

    Zero when the grid follows principal directions; both grid families have the same value
    (up to sign) because the map is conformal. Invalid faces get 0.
    """
    tangent = direction - np.einsum("fi,fi->f", direction, curvature.normal)[:, None] * (
        curvature.normal
    )
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1), 1e-300)[:, None]
    across = np.cross(curvature.normal, tangent)
    tau = np.einsum("fi,fij,fj->f", tangent, curvature.tensor, across)
    return np.asarray(np.where(valid, tau, 0.0), dtype=np.float64)


def grid_torsion_integral(system: BffSystem, curvature: Curvature, uv: FloatArray) -> float:
    """Dimensionless ``int tau^2 dA`` of the uv grid lines (see ``_grid_torsion``).

    The grid direction of a face is ``d = a e1 + b e2`` with ``(a, b)`` from the uv edges
    (:func:`_grid_directions`), so ``tau`` is a ratio of two quadratic forms in ``(a, b)``
    precomputed per face (``Curvature.torsion_form`` / ``length_form``): a few flops per face
    for each candidate map.  Faces with a flipped or degenerate flat image count 0.
    """
    F = system.faces
    q1 = uv[F[:, 1]] - uv[F[:, 0]]
    q2 = uv[F[:, 2]] - uv[F[:, 0]]
    det = q1[:, 0] * q2[:, 1] - q1[:, 1] * q2[:, 0]
    # (a, b) = (q2y, -q1y) / det; tau is homogeneous of degree 0, so det cancels (sign too)
    a, b = q2[:, 1], -q1[:, 1]
    basis = np.column_stack([a * a, a * b, b * b])
    top = np.einsum("fk,fk->f", curvature.torsion_form, basis)
    bottom = np.einsum("fk,fk->f", curvature.length_form, basis)
    valid = (det > 0.0) & (bottom > 0.0)
    tau = np.where(valid, top / np.where(valid, bottom, 1.0), 0.0)
    return float(curvature.area @ tau**2)


def principal_misalignment(
    vertices: ArrayLike, faces: ArrayLike, uv: ArrayLike
) -> tuple[FloatArray, FloatArray]:
    """How far the grid lines of a flat map are from the principal curvature directions.

    Parameters
    ----------
    vertices : (n, 3) float, mm, 3D vertex positions.
    faces : (m, 3) int, triangles.
    uv : (n, 2) float, mm, a conformal flat map (e.g. :attr:`Flattening.uv`); its grid lines are
        the preimages of the x and y axes.

    Returns
    -------
    angle_deg : (m,) float, per face, angle in [0, 45] degrees between the grid lines and the
        nearest principal direction (``nan`` where the surface is umbilic or the flat face is
        flipped).
    torsion : (m,) float, 1/mm, geodesic torsion of the grid lines, ``(k1 - k2) / 2 *
        sin(2 angle)`` up to sign (0 on flipped faces).

    Raises
    ------
    InternalError
        If igl cannot compute principal curvatures on this mesh.
    """
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces, dtype=np.int64)
    W = np.asarray(uv, dtype=np.float64)
    curvature = face_curvature(V, F)
    if curvature is None:
        raise InternalError("principal curvatures could not be computed; check the mesh")
    direction, valid = _grid_directions(V, F, W)
    tau = _grid_torsion(curvature, direction, valid)
    frob = np.einsum("fij,fij->f", curvature.tensor, curvature.tensor)
    trace = np.einsum("fii->f", curvature.tensor)
    half_gap = np.sqrt(np.maximum(0.5 * frob - 0.25 * trace**2, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.clip(np.abs(tau) / half_gap, 0.0, 1.0)
    angle = 0.5 * np.degrees(np.arcsin(ratio))
    angle[~valid | (half_gap <= 1e-12 * max(float(half_gap.max(initial=0.0)), 1e-300))] = np.nan
    return np.asarray(angle), tau
