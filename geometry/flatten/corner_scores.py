"""Automatic corner choice of the rectangle flattening: boundary vertices sampled as corner
candidates, quadruples of them scored by the area-weighted variance of the log scale factor
(exactly, from precomputed responses), and low-variance quadruples of different orientation
picked for the principal-alignment score.
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flatten.bff import BffSystem, neumann_solve, solve_interior

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


def _turning_peaks(system: BffSystem, arc: FloatArray, window: float) -> IntArray:
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


def corner_allowed(system: BffSystem) -> BoolArray:
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


def corner_samples(system: BffSystem) -> IntArray:
    """Sorted loop positions sampled as corner candidates (equal arc length + turning peaks).

    Short boundaries use every vertex. Turning is summed over windows of half-width
    ``perimeter * CORNER_MIN_ARC_FRACTION / 2``, so two peaks are at least one minimum arc apart.
    Positions :func:`corner_allowed` rules out are left out (an even sample moves to the
    nearest allowed one).
    """
    k = len(system.boundary)
    allowed = corner_allowed(system)
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


def quadruples(samples: IntArray, arc: FloatArray, perimeter: float) -> IntArray:
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


def corner_responses(
    system: BffSystem, samples: IntArray, schur: FloatArray
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
    schur : (k, k) float, the system's Schur complement
        (:func:`~drawstring.geometry.flatten.bff.schur_complement`, computed once per map).

    Returns
    -------
    a : (n,) float, u for target turning 0 everywhere (defined up to a constant).
    Y : (n, d) float, response of u to target turning 1 rad at each sample.
    """
    w0 = solve_interior(system, -system.omega)
    unit = np.zeros((len(system.boundary), len(samples)))
    unit[samples, np.arange(len(samples))] = 1.0
    responses = neumann_solve(
        schur,
        np.column_stack([-system.turning - system.A_IB.T @ w0, unit]),
    )
    a_boundary, Y_boundary = responses[:, 0], responses[:, 1:]
    interior = solve_interior(system, system.A_IB @ np.column_stack([a_boundary, Y_boundary]))
    a = np.empty(system.n)
    a[system.boundary] = a_boundary
    a[system.interior] = w0 - interior[:, 0]
    Y = np.empty((system.n, len(samples)))
    Y[system.boundary] = Y_boundary
    Y[system.interior] = -interior[:, 1:]
    return a, Y


def corner_scores(
    system: BffSystem,
    a: FloatArray,
    Y: FloatArray,
    corner_sets: IntArray,
) -> FloatArray:
    """(q,) float: area-weighted variance of ``u`` over the surface for each corner quadruple.

    ``u = a + (pi/2) Y x`` with ``x`` the indicator of the quadruple, so the variance is a
    quadratic form in ``x`` evaluated for all quadruples at once.
    """
    return variances(variance_terms(system, a, Y), corner_sets)


def variance_terms(
    system: BffSystem, a: FloatArray, Y: FloatArray
) -> tuple[float, FloatArray, FloatArray]:
    """The constant, linear (d,) and quadratic (d, d) terms of :func:`corner_scores`."""
    weight = system.mass / system.mass.sum()
    a_c = a - weight @ a
    Y_c = Y - weight @ Y
    g = (Y_c * weight[:, None]).T @ a_c
    Q = (Y_c * weight[:, None]).T @ Y_c
    return float(weight @ a_c**2), g, Q


def variances(terms: tuple[float, FloatArray, FloatArray], corner_sets: IntArray) -> FloatArray:
    """(q,) variance of ``u`` for each quadruple of sample columns, from :func:`variance_terms`."""
    constant, g, Q = terms
    c = corner_sets
    h = 0.5 * math.pi
    quad = Q[c[:, :, None], c[:, None, :]].sum(axis=(1, 2))
    return np.asarray(constant + 2.0 * h * g[c].sum(axis=1) + h * h * quad)


def diverse_candidates(
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
