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

import itertools
import logging
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flatten.alignment import (
    _Curvature,
    _face_curvature,
    _grid_torsion_integral,
)
from drawstring.geometry.flatten.alignment import principal_misalignment as principal_misalignment
from drawstring.geometry.flatten.bff import SCHUR_DENSE_MAX_ENTRIES as SCHUR_DENSE_MAX_ENTRIES
from drawstring.geometry.flatten.bff import SOLVE_BLOCK_COLUMNS as SOLVE_BLOCK_COLUMNS
from drawstring.geometry.flatten.bff import (
    _boundary_loop,
    _build_system,
    _check_lengths,
    _close_lengths,
    _harmonic_extension,
    _neumann_solve,
    _order_corners,
    _scaled_lengths,
    _schur_complement,
    _solve_interior,
    _System,
)

log = logging.getLogger(__name__)

Mode = Literal["free", "rectangle"]

#: Boundary vertices sampled at equal arc length as corner candidates in automatic corner choice.
CORNER_EVEN_SAMPLES = 24
#: At most this many boundary turning peaks are added to the corner candidates.
CORNER_TURNING_PEAKS = 8
#: Each of the four rectangle sides spans at least this fraction of the boundary length.
CORNER_MIN_ARC_FRACTION = 1.0 / 48.0
#: Best-scoring corner quadruples tried, in order, until one flattens without flipped triangles.
CORNER_MAX_TRIES = 8
#: Lowest-variance corner quadruples whose grid alignment with the principal curvature directions
#: is measured (each costs one boundary curve and one harmonic extension).
CORNER_ALIGN_CANDIDATES = 24
#: Weight of the grid's squared geodesic torsion ``int tau^2 dA`` (dimensionless) against the
#: area-weighted variance of ``u`` in the automatic corner score. Measured on the built-ins: large
#: enough to prefer the principal-aligned corners of the seashell (torsion 4.6 -> 3.3 for a
#: variance 0.073 -> 0.083), small enough to keep the lowest-variance corners where the
#: alternatives buy little alignment for much more size variation (cloud).
CORNER_ALIGN_WEIGHT = 0.1
#: Below this total anisotropy ``int ((k1 - k2) / 2)^2 dA`` (dimensionless) the surface is nearly
#: umbilic (sphere, plane): every direction is principal and alignment is not scored.
CORNER_ALIGN_MIN_ANISOTROPY = 0.05
#: An alternative to the lowest-variance corners must lower ``int tau^2 dA`` by at least this
#: fraction of the total anisotropy: small gains are within the noise of the curvature estimate
#: and not worth more size variation (measured: seashell 11 %, a rotated saddle 80 %; cloud, wave
#: and strongly curved scanned meshes 1-2 %).
CORNER_ALIGN_MIN_GAIN = 0.05
#: Shifting the chosen corners along the boundary must lower ``int tau^2 dA`` by at least this
#: fraction of the total anisotropy.  Measured: a rotated saddle whose samples missed its axes by
#: 7 degrees gains 3.2-3.7 %; one-vertex shifts on the seashell and the wave gain 0.2-0.5 % (noise,
#: and they would break the seashell's mirror symmetry).
CORNER_SHIFT_MIN_GAIN = 0.01


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
        If the mesh is not a valid disk, ``mode`` is unknown, or ``corners`` are not four distinct
        boundary vertices (or are given in free mode).
    """
    t0 = time.perf_counter()
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if mode not in ("free", "rectangle"):
        raise InputError(f"unknown flattening mode {mode!r}; use 'free' or 'rectangle'")
    if mode == "free" and corners is not None:
        raise InputError("corners only apply to mode='rectangle'; drop corners or change mode")
    boundary = _boundary_loop(V, F)
    system = _build_system(V, F.astype(np.int64), boundary)
    t1 = time.perf_counter()
    if mode == "free":
        uv, u, loop, corner_ids = _flatten_free(system)
    else:
        named = None if corners is None else _order_corners(system.boundary, corners)
        curvature = _face_curvature(V, system.faces) if named is None and align_principal else None
        uv, u, loop, corner_ids = _flatten_rectangle(system, named, curvature)
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


# --------------------------------------------------------------------------------------------
# free mode


def _flatten_free(
    system: _System,
) -> tuple[FloatArray, FloatArray, IntArray, None]:
    """Free boundary: ``u = 0`` on the boundary, turning angles from Dirichlet-to-Neumann."""
    u = np.zeros(system.n)
    u_interior = _solve_interior(system, -system.omega)
    u[system.interior] = u_interior
    target_turning = system.turning + system.A_IB.T @ u_interior
    angle = np.concatenate([[0.0], np.cumsum(target_turning[1:])])
    tangents = np.column_stack([np.cos(angle), np.sin(angle)])
    lengths = system.edge_length
    closed = _close_lengths(lengths, tangents, system.edge_length)
    if not _check_lengths(closed, lengths):
        log.warning("free-boundary curve needed a large closing correction")
    steps = closed[:, None] * tangents
    boundary_uv = np.concatenate([np.zeros((1, 2)), np.cumsum(steps[:-1], axis=0)])
    uv = _harmonic_extension(system, boundary_uv)
    uv -= uv.min(axis=0)
    return uv, u, system.boundary.copy(), None


# --------------------------------------------------------------------------------------------
# principal curvature alignment


# --------------------------------------------------------------------------------------------
# rectangle mode


_SIDE_DIRECTIONS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def _rectangle_curve(
    system: _System, u_boundary: FloatArray, corner_pos: IntArray
) -> tuple[FloatArray, bool]:
    """Rectangle through the scaled boundary lengths, starting at ``corner_pos[0]``.

    Returns the (k, 2) boundary positions in loop order and whether the length closing kept every
    edge at a positive length.
    """
    k = len(system.boundary)
    side = np.zeros(k, dtype=np.int64)  # side index of edge b[i] -> b[i+1]
    side[corner_pos[1:]] = 1
    side = np.roll(np.cumsum(np.roll(side, -corner_pos[0])), corner_pos[0])
    target = _scaled_lengths(system, u_boundary)
    closed = _close_lengths(target, _SIDE_DIRECTIONS[side], system.edge_length)
    ok = _check_lengths(closed, target)
    width = float(closed[side == 0].sum())
    height = float(closed[side == 1].sum())
    # Place each side exactly on the rectangle by its cumulative length fraction.
    points = np.empty((k, 2), dtype=np.float64)
    starts = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    extents = np.array([width, height, width, height])
    for s in range(4):
        a, b = corner_pos[s], corner_pos[(s + 1) % 4]
        edges = np.arange(a, a + (b - a) % k) % k
        total = closed[edges].sum()
        frac = np.cumsum(closed[edges])[:-1] / total if total > 0 else np.zeros(len(edges) - 1)
        points[edges[0]] = starts[s]
        points[edges[1:]] = starts[s] + (frac * extents[s])[:, None] * _SIDE_DIRECTIONS[s]
    return points, ok


def _turning_peaks(system: _System, arc: FloatArray, window: float) -> IntArray:
    """Loop positions of up to ``CORNER_TURNING_PEAKS`` well-separated peaks of boundary turning.

    The turning angle is summed over an arc-length window of half-width ``window``; ties go to
    the vertex that turns most itself.
    """
    perimeter = float(arc[-1] + system.edge_length[-1])
    cum = np.concatenate([[0.0], np.cumsum(np.tile(system.turning, 3))])
    positions = np.concatenate([arc - perimeter, arc, arc + perimeter])
    lo = np.searchsorted(positions, arc - window, side="left")
    hi = np.searchsorted(positions, arc + window, side="right")
    smooth = cum[hi] - cum[lo]
    chosen: list[int] = []
    for i in np.lexsort((-system.turning, -np.round(smooth, 9))):
        if smooth[i] <= 0.0 or len(chosen) == CORNER_TURNING_PEAKS:
            break
        gap = np.abs(arc[chosen] - arc[i])
        if np.all(np.minimum(gap, perimeter - gap) > 2.0 * window):
            chosen.append(int(i))
    return np.asarray(chosen, dtype=np.int64)


def _corner_allowed(system: _System) -> BoolArray:
    """(k,) bool per loop position: may be a corner.

    A boundary vertex in one triangle only (an ear) has its two loop neighbours in that same
    triangle; a corner at either neighbour puts all three on one side of the rectangle, and the
    triangle collapses to a segment (zero area, counted as flipped).
    """
    k = len(system.boundary)
    ear = np.bincount(system.faces.ravel(), minlength=system.n)[system.boundary] == 1
    allowed = np.ones(k, dtype=bool)
    at = np.flatnonzero(ear)
    allowed[(at - 1) % k] = False
    allowed[(at + 1) % k] = False
    allowed[at] = True  # the ear itself: its triangle gets the right angle
    return allowed


def _corner_samples(system: _System) -> IntArray:
    """Sorted loop positions sampled as corner candidates (equal arc length + turning peaks).

    Short boundaries use every vertex. Turning is summed over windows of half-width
    ``perimeter * CORNER_MIN_ARC_FRACTION / 2``, so two peaks are at least one minimum arc apart.
    Positions :func:`_corner_allowed` rules out are left out (an even sample moves to the
    nearest allowed one).
    """
    k = len(system.boundary)
    allowed = _corner_allowed(system)
    if k <= CORNER_EVEN_SAMPLES + CORNER_TURNING_PEAKS:
        return np.flatnonzero(allowed).astype(np.int64)
    arc = np.concatenate([[0.0], np.cumsum(system.edge_length[:-1])])
    perimeter = float(system.edge_length.sum())
    targets = np.arange(CORNER_EVEN_SAMPLES) * perimeter / CORNER_EVEN_SAMPLES
    even = np.clip(np.searchsorted(arc, targets), 0, k - 1)
    before = np.clip(even - 1, 0, k - 1)
    even = np.where(np.abs(arc[before] - targets) < np.abs(arc[even] - targets), before, even)
    ok = np.flatnonzero(allowed)
    gap = np.abs(ok[None, :] - even[:, None])
    even = ok[np.argmin(np.minimum(gap, k - gap), axis=1)]
    peaks = _turning_peaks(system, arc, 0.5 * CORNER_MIN_ARC_FRACTION * perimeter)
    return np.unique(np.concatenate([even, peaks[allowed[peaks]]]))


def _quadruples(samples: IntArray, arc: FloatArray, perimeter: float) -> IntArray:
    """(q, 4) indices into ``samples`` of increasing quadruples with every arc long enough."""
    d = len(samples)
    combos = np.fromiter(
        itertools.chain.from_iterable(itertools.combinations(range(d), 4)),
        dtype=np.int64,
        count=4 * math.comb(d, 4),
    ).reshape(-1, 4)
    s = arc[samples[combos]]
    arcs = np.diff(np.column_stack([s, s[:, 0] + perimeter]), axis=1)
    good = np.all(arcs >= CORNER_MIN_ARC_FRACTION * perimeter, axis=1)
    return combos[good] if np.any(good) else combos


def _landscape_start(system: _System, u_boundary: FloatArray, corner_pos: IntArray) -> IntArray:
    """Rotate increasing corner positions so the side ``corners[0] -> corners[1]`` is the longer."""
    lengths = _scaled_lengths(system, u_boundary)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    at = cum[corner_pos]  # corner_pos is increasing here
    side = np.diff(np.append(at, at[0] + cum[-1]))
    if side[1] + side[3] > side[0] + side[2]:
        return np.roll(corner_pos, -1)
    return corner_pos


def _log_scale_offset(system: _System, u: FloatArray, uv: FloatArray) -> float:
    """Constant ``c`` fitting ``exp(u + c)`` to the flat map's area scale (least squares).

    Minimizes ``sum_f A_f (log(A~_f / A_f) / 2 - mean_f(u) - c)^2`` over unflipped faces, with
    ``A_f`` the 3D and ``A~_f`` the flat face area. It absorbs both the global scale and the
    part of the boundary length that the discrete corner singularities miss.
    """
    F = system.faces
    d1 = uv[F[:, 1]] - uv[F[:, 0]]
    d2 = uv[F[:, 2]] - uv[F[:, 0]]
    flat = 0.5 * (d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0])
    good = flat > 0.0
    weight = system.face_area[good]
    misfit = 0.5 * np.log(flat[good] / weight) - u[F[good]].mean(axis=1)
    return float(weight @ misfit / weight.sum())


def _corner_responses(
    system: _System, samples: IntArray, schur: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Log scale factor as an affine function of which sampled boundary vertices are corners.

    With target turning ``pi/2`` at the corners and 0 elsewhere, the Neumann-to-Dirichlet solve
    gives ``u = a + (pi/2) * Y[:, corners].sum(axis=1)``: ``S u_B = k~ - k - A_BI A_II^-1 f_I``
    with ``f_I = -omega``, and ``u_I = A_II^-1 (f_I - A_IB u_B)``. All columns come from one
    multi-right-hand-side solve with the factorization of ``A_II``.

    Parameters
    ----------
    system : the mesh's BFF system.
    samples : (d,) int, loop positions of candidate corner vertices.
    schur : (k, k) float, the system's :func:`~.bff._schur_complement` (computed once per map).

    Returns
    -------
    a : (n,) float, u for target turning 0 everywhere (defined up to a constant).
    Y : (n, d) float, response of u to target turning 1 rad at each sample.
    """
    w0 = _solve_interior(system, -system.omega)
    unit = np.zeros((len(system.boundary), len(samples)))
    unit[samples, np.arange(len(samples))] = 1.0
    responses = _neumann_solve(
        schur,
        np.column_stack([-system.turning - system.A_IB.T @ w0, unit]),
    )
    a_boundary, Y_boundary = responses[:, 0], responses[:, 1:]
    interior = _solve_interior(system, system.A_IB @ np.column_stack([a_boundary, Y_boundary]))
    a = np.empty(system.n)
    a[system.boundary] = a_boundary
    a[system.interior] = w0 - interior[:, 0]
    Y = np.empty((system.n, len(samples)))
    Y[system.boundary] = Y_boundary
    Y[system.interior] = -interior[:, 1:]
    return a, Y


def _corner_scores(
    system: _System,
    a: FloatArray,
    Y: FloatArray,
    corner_sets: IntArray,
) -> FloatArray:
    """(q,) float: area-weighted variance of ``u`` over the surface for each corner quadruple.

    ``u = a + (pi/2) Y x`` with ``x`` the indicator of the quadruple, so the variance is a
    quadratic form in ``x`` evaluated for all quadruples at once.
    """
    return _variances(_variance_terms(system, a, Y), corner_sets)


def _variance_terms(
    system: _System, a: FloatArray, Y: FloatArray
) -> tuple[float, FloatArray, FloatArray]:
    """The constant, linear (d,) and quadratic (d, d) terms of :func:`_corner_scores`."""
    weight = system.mass / system.mass.sum()
    a_c = a - weight @ a
    Y_c = Y - weight @ Y
    g = (Y_c * weight[:, None]).T @ a_c
    Q = (Y_c * weight[:, None]).T @ Y_c
    return float(weight @ a_c**2), g, Q


def _variances(terms: tuple[float, FloatArray, FloatArray], corner_sets: IntArray) -> FloatArray:
    """(q,) variance of ``u`` for each quadruple of sample columns, from :func:`_variance_terms`."""
    constant, g, Q = terms
    c = corner_sets
    h = 0.5 * math.pi
    quad = Q[c[:, :, None], c[:, None, :]].sum(axis=(1, 2))
    return np.asarray(constant + 2.0 * h * g[c].sum(axis=1) + h * h * quad)


def _rectangle_candidate(
    system: _System,
    u: FloatArray,
    corner_pos: IntArray,
    fit: bool = True,
) -> tuple[FloatArray, FloatArray] | None:
    """Rectangle flattening for given corners and log scale ``u``: (uv, fitted u) or None.

    None when the boundary length closing fails for these corners.  Without ``fit`` the
    returned ``u`` is ``u`` as given (:func:`_log_scale_offset` not yet added: candidates are
    scored on ``uv`` alone).
    """
    points, closed_ok = _rectangle_curve(system, u[system.boundary], corner_pos)
    if not closed_ok:
        return None
    scale = math.sqrt(system.area / float(np.prod(points[corner_pos[2]])))
    uv = _harmonic_extension(system, scale * points)
    return uv, (u + _log_scale_offset(system, u, uv) if fit else u)


def _diverse_candidates(
    order: IntArray,
    scores: FloatArray,
    positions: FloatArray,
    slack: float,
) -> IntArray:
    """Up to ``CORNER_ALIGN_CANDIDATES`` quadruples worth scoring for alignment.

    Walks the quadruples by increasing variance and keeps one if its corners differ from every
    kept one (each corner moves by at least one sample spacing along the boundary), until the
    variance exceeds the best by ``slack``: the largest torsion term, ``CORNER_ALIGN_WEIGHT``
    times the total anisotropy, so no skipped quadruple could win. Near-duplicates of a kept
    quadruple (the same grid shifted by a vertex or two) are skipped, so that grids of different
    orientation compete. The lowest-variance quadruple is always kept.

    Parameters
    ----------
    order : (q,) int, quadruple indices by increasing score.
    scores : (q,) float, variance of ``u`` per quadruple.
    positions : (q, 4) float, corner positions as fractions of the boundary length, increasing.
    slack : float, largest possible alignment term.
    """
    limit = float(scores[order[0]]) + slack
    min_shift = 1.0 / CORNER_EVEN_SAMPLES
    within = order[scores[order] <= limit]
    pos = positions[within]
    alive = np.ones(len(within), dtype=bool)
    kept: list[int] = []
    while len(kept) < CORNER_ALIGN_CANDIDATES:
        remaining = np.flatnonzero(alive)
        if not len(remaining):
            break
        first = int(remaining[0])
        kept.append(int(within[first]))
        delta = np.abs(pos - pos[first])
        alive &= np.minimum(delta, 1.0 - delta).mean(axis=1) >= min_shift
    return np.asarray(kept, dtype=np.int64)


def _shift_corners(
    system: _System,
    curvature: _Curvature,
    a: FloatArray,
    best: tuple[FloatArray, FloatArray, IntArray],
    best_score: float,
    reference_torsion: float,
    schur: FloatArray,
) -> tuple[FloatArray, FloatArray, IntArray]:
    """The aligned choice moved along the boundary, all four corners by the same number of
    vertices, up to a sample spacing either way, if that scores lower.

    The samples are spaced from wherever the boundary loop starts, so without this step how well
    the grid can follow the principal directions depends on that start (a rotated saddle: 1 to 17
    degrees off its axes).  A shift is kept only if it lowers the score, its torsion is
    ``CORNER_ALIGN_MIN_GAIN`` of the anisotropy below the lowest-variance candidate's (the rule
    for the candidates) and ``CORNER_SHIFT_MIN_GAIN`` below the unshifted choice's (so a
    symmetric shape keeps its symmetric corners unless a shift buys real alignment).
    """
    k = len(system.boundary)
    reach = k // CORNER_EVEN_SAMPLES
    start = best[2]
    allowed = _corner_allowed(system)
    shifts = np.array(
        [s for s in range(-reach, reach + 1) if s and allowed[(start + s) % k].all()],
        dtype=np.int64,
    )
    if not len(shifts):
        return best
    positions = np.unique((start[None, :] + shifts[:, None]) % k)
    _, Y = _corner_responses(system, positions, schur)
    terms = _variance_terms(system, a, Y)
    unshifted_torsion = _grid_torsion_integral(system, curvature, best[0])
    for shift in shifts:
        columns = np.searchsorted(positions, (start + shift) % k)
        variance = float(_variances(terms, columns[None, :])[0])
        if variance >= best_score:
            continue  # the torsion term cannot bring it back
        u = a + 0.5 * math.pi * Y[:, columns].sum(axis=1)
        corner_pos = _landscape_start(system, u[system.boundary], np.sort(positions[columns]))
        candidate = _rectangle_candidate(system, u, corner_pos, fit=False)
        if candidate is None or np.any(flipped_faces(system.faces, candidate[0])):
            continue
        torsion = _grid_torsion_integral(system, curvature, candidate[0])
        score = variance + CORNER_ALIGN_WEIGHT * torsion
        log.debug("corners shifted by %d: variance %.4f, torsion %.4f", shift, variance, torsion)
        if (
            score < best_score
            and reference_torsion - torsion >= CORNER_ALIGN_MIN_GAIN * curvature.anisotropy
            and unshifted_torsion - torsion >= CORNER_SHIFT_MIN_GAIN * curvature.anisotropy
        ):
            best, best_score = (candidate[0], candidate[1], corner_pos), score
    return best


def _flatten_rectangle(
    system: _System,
    named: IntArray | None,
    curvature: _Curvature | None = None,
    schur: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, IntArray, IntArray]:
    """Rectangle mode: target turning pi/2 at four corners, 0 elsewhere (Neumann-to-Dirichlet).

    Named corners are used as given. Otherwise quadruples of sampled boundary vertices are ranked
    by the area-weighted variance of ``u``. Without ``curvature`` (or on a nearly umbilic
    surface) the first of them without flipped triangles is used. With it, the
    ``CORNER_ALIGN_CANDIDATES`` best of different orientation are flattened and the one without
    flipped triangles that minimizes ``variance + CORNER_ALIGN_WEIGHT * int tau^2 dA`` (``tau``
    the geodesic torsion of the grid lines, zero when they follow principal curvature
    directions) is used, provided it lowers the torsion term by at least
    ``CORNER_ALIGN_MIN_GAIN`` of the anisotropy; otherwise the lowest-variance one.
    """
    k = len(system.boundary)
    if k < 4:
        raise InputError(f"the boundary has only {k} vertices; a rectangle needs at least 4")
    align = (
        named is None
        and curvature is not None
        and curvature.anisotropy >= CORNER_ALIGN_MIN_ANISOTROPY
    )
    if named is not None:
        samples = named
        corner_sets = np.arange(4, dtype=np.int64)[None, :]
        order = np.zeros(1, dtype=np.int64)
        scores = np.zeros(1)
    else:
        samples = _corner_samples(system)
        arc = np.concatenate([[0.0], np.cumsum(system.edge_length[:-1])])
        corner_sets = _quadruples(samples, arc, float(system.edge_length.sum()))
        if not len(corner_sets):
            raise InputError(
                f"the mesh is too coarse for rectangle corners: {len(samples)} of its {k} "
                "boundary vertices can take one (a corner may not sit beside a triangle with "
                "two boundary edges); subdivide the mesh, or name four --corners"
            )
    schur = _schur_complement(system) if schur is None else schur
    a, Y = _corner_responses(system, samples, schur)
    if named is None:
        scores = _corner_scores(system, a, Y, corner_sets)
        order = np.argsort(scores, kind="stable")
        if align:
            assert curvature is not None
            arc = np.concatenate([[0.0], np.cumsum(system.edge_length[:-1])])
            order = _diverse_candidates(
                order,
                scores,
                arc[samples[corner_sets]] / float(system.edge_length.sum()),
                CORNER_ALIGN_WEIGHT * curvature.anisotropy,
            )
        else:
            order = order[:CORNER_MAX_TRIES]
        log.debug(
            "corner choice: %d samples, %d quadruples, best std of u %.4f",
            len(samples),
            len(corner_sets),
            math.sqrt(max(float(scores[order[0]]), 0.0)),
        )
    # The first closed candidate is the fallback; a candidate without flipped triangles replaces
    # it (the first such one, or with alignment the best-scoring such one).
    fallback: tuple[FloatArray, FloatArray, IntArray] | None = None
    best: tuple[FloatArray, FloatArray, IntArray] | None = None
    best_score = math.inf
    reference_torsion = math.inf
    for attempt, index in enumerate(order):
        u = a + 0.5 * math.pi * Y[:, corner_sets[index]].sum(axis=1)
        corner_pos = samples[corner_sets[index]]
        if named is None:
            corner_pos = _landscape_start(system, u[system.boundary], np.sort(corner_pos))
        candidate = _rectangle_candidate(system, u, corner_pos, fit=named is not None)
        if candidate is None:
            log.debug("corner candidate %d: the length closing failed", attempt)
            continue
        result = (candidate[0], candidate[1], corner_pos)
        if fallback is None:
            fallback = result
        if named is not None:
            best = result
            break
        if np.any(flipped_faces(system.faces, candidate[0])):
            log.debug("corner candidate %d: flipped triangles, trying the next", attempt)
            continue
        if not align:
            best = result
            break
        assert curvature is not None
        torsion = _grid_torsion_integral(system, curvature, candidate[0])
        score = float(scores[index]) + CORNER_ALIGN_WEIGHT * torsion
        log.debug(
            "corner candidate %d %s: variance %.4f, torsion %.4f",
            attempt,
            corner_pos,
            scores[index],
            torsion,
        )
        if best is None:
            # the lowest-variance candidate without flips: what the variance alone would pick
            best, best_score, reference_torsion = result, score, torsion
        elif score < best_score and (
            reference_torsion - torsion >= CORNER_ALIGN_MIN_GAIN * curvature.anisotropy
        ):
            best, best_score = result, score
    if best is None and align:
        log.debug("no aligned corner candidate without flipped triangles; variance-only choice")
        return _flatten_rectangle(system, None, None, schur)
    if align and best is not None:
        assert curvature is not None
        best = _shift_corners(system, curvature, a, best, best_score, reference_torsion, schur)
    chosen = best if best is not None else fallback
    if chosen is None:
        if named is not None:
            raise InputError(
                "these corners give no closed rectangle boundary; pick corners farther apart"
            )
        raise InputError(
            f"none of the {len(order)} sets of rectangle corners tried gives a closed boundary: "
            "the mesh is likely folded or badly distorted; check it (--repair mends small "
            "defects) or name four --corners"
        )
    uv, u, corner_pos = chosen
    if named is None:
        # The map of the chosen corners computed as named corners are (their four responses
        # alone), so that --corners with the recorded corners gives the same map to the bit;
        # kept unless that rounding flips a triangle the chosen map did not.
        final = _flatten_rectangle(system, corner_pos, None, schur)
        if not np.any(flipped_faces(system.faces, final[0])) or np.any(
            flipped_faces(system.faces, uv)
        ):
            return final
        u = u + _log_scale_offset(system, u, uv)
    return uv, u, np.roll(system.boundary, -corner_pos[0]), system.boundary[corner_pos]
