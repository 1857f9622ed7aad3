"""Boundary First Flattening (Sawhney & Crane 2017, "Boundary First Flattening", ACM TOG 37(1)).

A disk-topology surface is mapped conformally to the plane. Write ``A`` for the positive
semi-definite cotangent Laplacian (``-igl.cotmatrix``), ``Omega`` for the angle defect at interior
vertices and ``k`` for the exterior (turning) angle ``pi - sum of corner angles`` at boundary
vertices. A log conformal scale factor ``u`` changes these curvatures to

    Omega~ = Omega + (A u)_I        (interior),
    k~     = k     + (A u)_B        (boundary),

the discrete Cherrier problem. A flat metric needs ``Omega~ = 0``. Prescribing ``u`` on the
boundary and solving for the interior gives ``k~`` (Dirichlet-to-Neumann); prescribing ``k~`` and
solving for ``u`` uses the Schur complement of ``A`` on the boundary (Neumann-to-Dirichlet). The
boundary curve is then integrated from the turning angles ``k~`` and the scaled edge lengths
``exp((u_i + u_j) / 2) l_ij``, closed by the smallest weighted change of those lengths, and
extended into the interior harmonically (both coordinates, so the curve is met exactly).

Every solve reuses one sparse LU factorization of the interior block ``A_II``. The Schur complement
``S = A_BB - A_BI A_II^-1 A_IB`` is formed from the same factors: with the symmetric ordering and
diagonal pivoting used here ``P A_II P^T = L D L^T``, so ``A_BI A_II^-1 A_IB = Z^T D^-1 Z`` with
``Z = L^-1 P A_IB``. Because ``A_IB`` touches only the interior vertices next to the boundary,
``Z`` is nonzero only on their ancestors in the elimination tree, a small triangular solve.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flatten.alignment import face_curvature
from drawstring.geometry.flatten.bff import (
    BffSystem,
    boundary_loop,
    build_system,
    check_lengths,
    close_lengths,
    harmonic_extension,
    order_corners,
    solve_interior,
)
from drawstring.geometry.flatten.distortion import flipped_faces
from drawstring.geometry.flatten.rectangle import flatten_rectangle

log = logging.getLogger(__name__)

Mode = Literal["free", "rectangle"]


@dataclass(frozen=True)
class Flattening:
    """A conformal flattening of a disk-topology surface.

    Attributes
    ----------
    uv : (n, 2) float, mm, flat vertex positions. In ``"rectangle"`` mode the domain is the
        axis-aligned rectangle ``[0, width] x [0, height]`` with ``corners[0]`` at ``(0, 0)``,
        ``corners[1]`` at ``(width, 0)``, ``corners[2]`` at ``(width, height)`` and ``corners[3]``
        at ``(0, height)``; its area equals the 3D surface area. In ``"free"`` mode the first
        boundary edge points along +x and the bounding box starts at the origin.
    log_scale : (n,) float, per-vertex log conformal scale factor ``u``: a flat edge is about
        ``exp((u_i + u_j) / 2)`` times as long as the 3D edge. Exactly 0 on the boundary in
        ``"free"`` mode; in ``"rectangle"`` mode its additive constant is fitted to the flat face
        areas (area-weighted least squares of ``log(flat area / 3D area) / 2``).
    boundary : (k,) int, the boundary loop, counter-clockwise in uv (starts at ``corners[0]`` in
        ``"rectangle"`` mode).
    corners : (4,) int or None, vertex ids of the rectangle corners in boundary order; None in
        ``"free"`` mode.
    mode : which domain was produced.
    flipped : how many triangles the map turns over (0 for a fine mesh; the pipeline reports
        any as a note).
    """

    uv: FloatArray
    log_scale: FloatArray
    boundary: IntArray
    corners: IntArray | None
    mode: Mode
    flipped: int = 0

    @property
    def width(self) -> float:
        """Extent of ``uv`` along x, mm (the rectangle width in ``"rectangle"`` mode)."""
        return float(np.ptp(self.uv[:, 0]))

    @property
    def height(self) -> float:
        """Extent of ``uv`` along y, mm (the rectangle height in ``"rectangle"`` mode)."""
        return float(np.ptp(self.uv[:, 1]))


def flatten(
    vertices: ArrayLike,
    faces: ArrayLike,
    mode: Mode = "rectangle",
    corners: Sequence[int] | None = None,
    align_principal: bool = True,
) -> Flattening:
    """Flatten a disk-topology mesh conformally with Boundary First Flattening.

    Parameters
    ----------
    vertices : (n, 3) float, mm, vertex positions.
    faces : (m, 3) int, triangles, consistently oriented (outward normal by the right-hand rule),
        one boundary loop, every vertex used.
    mode : ``"free"`` keeps the boundary scale factor at zero (``u = 0`` on the boundary) and
        lets the boundary take its natural shape; among all conformal flattenings this one has
        the least area distortion in the sense of the smallest Dirichlet energy of ``u``.
        ``"rectangle"`` maps to an axis-aligned rectangle: four boundary corners get exterior angle
        pi/2 and all other boundary vertices zero; the result is scaled so that its area equals the
        3D surface area.
    corners : 4 boundary vertex ids, rectangle mode only, in any order; ``corners[0]`` goes to the
        origin and the others follow counter-clockwise along the boundary. If None, the corners
        are chosen automatically: boundary vertices are sampled (``CORNER_EVEN_SAMPLES`` at equal
        arc length plus up to ``CORNER_TURNING_PEAKS`` peaks of the boundary turning angle), every
        quadruple of samples whose four arcs each span at least ``CORNER_MIN_ARC_FRACTION`` of the
        boundary is scored by the area-weighted variance of the resulting log scale factor
        ``u`` over the whole surface (exact, from precomputed responses), and the lowest-variance
        quadruple that flattens without flipped triangles is used (up to ``CORNER_MAX_TRIES``
        tried). ``corners[0]`` is then chosen so that width >= height.
    align_principal : rectangle mode with automatic corners only. If True (default), up to
        ``CORNER_ALIGN_CANDIDATES`` low-variance quadruples of different orientation are
        flattened and scored by ``variance + CORNER_ALIGN_WEIGHT * int tau^2 dA``, with ``tau``
        the geodesic torsion of the grid lines (from ``igl.principal_curvature``): a grid along
        the principal curvature directions has planar, near-conical quads (paper 4.1-4.2). The
        lowest-variance choice is kept unless an alternative lowers ``int tau^2 dA`` by at least
        ``CORNER_ALIGN_MIN_GAIN`` of the surface's anisotropy ``int ((k1 - k2) / 2)^2 dA``.
        Nearly umbilic surfaces, a failed curvature estimate or flips in every aligned candidate
        fall back to the variance-only choice (``align_principal=False``).

    Returns
    -------
    Flattening
        uv (mm), log scale factor, boundary loop and corners.

    Raises
    ------
    InputError
        If ``corners`` are not four distinct boundary vertices or give no closed rectangle
        boundary, or the mesh is too coarse or distorted for automatic corners.
    InternalError
        If the mesh is not a valid disk (the target stage refuses those), ``mode`` is unknown, or
        ``corners`` are given in free mode.
    """
    t0 = time.perf_counter()
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if mode not in ("free", "rectangle"):
        raise InternalError(f"unknown flattening mode {mode!r}; use 'free' or 'rectangle'")
    if mode == "free" and corners is not None:
        raise InternalError("corners only apply to mode='rectangle'; drop corners or change mode")
    boundary = boundary_loop(V, F)
    system = build_system(V, F.astype(np.int64), boundary)
    t1 = time.perf_counter()
    if mode == "free":
        uv, u, loop, corner_ids = _flatten_free(system)
    else:
        named = None if corners is None else order_corners(system.boundary, corners)
        curvature = face_curvature(V, system.faces) if named is None and align_principal else None
        uv, u, loop, corner_ids = flatten_rectangle(system, named, curvature)
    t2 = time.perf_counter()
    log.debug(
        "flatten %s: %d vertices, setup+factor %.3f s, solve %.3f s", mode, len(V), t1 - t0, t2 - t1
    )
    flips = int(np.count_nonzero(flipped_faces(F, uv)))
    for array in (uv, u, loop):
        array.flags.writeable = False
    if corner_ids is not None:
        corner_ids.flags.writeable = False
    return Flattening(
        uv=uv, log_scale=u, boundary=loop, corners=corner_ids, mode=mode, flipped=flips
    )


def _flatten_free(
    system: BffSystem,
) -> tuple[FloatArray, FloatArray, IntArray, None]:
    """Free boundary: ``u = 0`` on the boundary, turning angles from Dirichlet-to-Neumann."""
    u = np.zeros(system.n)
    u_interior = solve_interior(system, -system.omega)
    u[system.interior] = u_interior
    target_turning = system.turning + system.A_IB.T @ u_interior
    angle = np.concatenate([[0.0], np.cumsum(target_turning[1:])])
    tangents = np.column_stack([np.cos(angle), np.sin(angle)])
    lengths = system.edge_length
    closed = close_lengths(lengths, tangents, system.edge_length)
    if not check_lengths(closed, lengths):
        log.warning("free-boundary curve needed a large closing correction")
    steps = closed[:, None] * tangents
    boundary_uv = np.concatenate([np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)])
    uv = harmonic_extension(system, boundary_uv)
    uv -= uv.min(axis=0)
    return uv, u, system.boundary.copy(), None
