"""Rectangle mode of the flattening: target turning pi/2 at four boundary corners and 0
elsewhere (Neumann-to-Dirichlet), the boundary laid on an axis-aligned rectangle through the
scaled lengths, and the corners chosen automatically when none are named
(:mod:`drawstring.geometry.flatten.corner_scores`).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flatten.alignment import Curvature, grid_torsion_integral
from drawstring.geometry.flatten.bff import (
    BffSystem,
    check_lengths,
    close_lengths,
    harmonic_extension,
    scaled_lengths,
    schur_complement,
)
from drawstring.geometry.flatten.corner_scores import (
    CORNER_ALIGN_MIN_ANISOTROPY,
    CORNER_ALIGN_MIN_GAIN,
    CORNER_ALIGN_WEIGHT,
    CORNER_EVEN_SAMPLES,
    CORNER_MAX_TRIES,
    CORNER_SHIFT_MIN_GAIN,
    corner_allowed,
    corner_responses,
    corner_samples,
    corner_scores,
    diverse_candidates,
    quadruples,
    variance_terms,
    variances,
)
from drawstring.geometry.flatten.distortion import flipped_faces

log = logging.getLogger(__name__)


_SIDE_DIRECTIONS = np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0], [0.0, -1.0]])


def _rectangle_curve(
    system: BffSystem, u_boundary: FloatArray, corner_pos: IntArray
) -> tuple[FloatArray, bool]:
    """Rectangle through the scaled boundary lengths, starting at ``corner_pos[0]``.

    Returns the (k, 2) boundary positions in loop order and whether the length closing kept every
    edge at a positive length.
    """
    k = len(system.boundary)
    side = np.zeros(k, dtype=np.int64)  # side index of edge b[i] -> b[i+1]
    side[corner_pos[1:]] = 1
    side = np.roll(np.cumsum(np.roll(side, -corner_pos[0])), corner_pos[0])
    target = scaled_lengths(system, u_boundary)
    closed = close_lengths(target, _SIDE_DIRECTIONS[side], system.edge_length)
    ok = check_lengths(closed, target)
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


def _landscape_start(system: BffSystem, u_boundary: FloatArray, corner_pos: IntArray) -> IntArray:
    """Rotate increasing corner positions so the side ``corners[0] -> corners[1]`` is the longer."""
    lengths = scaled_lengths(system, u_boundary)
    cum = np.concatenate([[0.0], np.cumsum(lengths)])
    at = cum[corner_pos]  # corner_pos is increasing here
    side = np.diff(np.append(at, at[0] + cum[-1]))
    if side[1] + side[3] > side[0] + side[2]:
        return np.roll(corner_pos, -1)
    return corner_pos


def _log_scale_offset(system: BffSystem, u: FloatArray, uv: FloatArray) -> float:
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


def _rectangle_candidate(
    system: BffSystem,
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
    uv = harmonic_extension(system, scale * points)
    return uv, (u + _log_scale_offset(system, u, uv) if fit else u)


def _shift_corners(
    system: BffSystem,
    curvature: Curvature,
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
    allowed = corner_allowed(system)
    shifts = np.array(
        [s for s in range(-reach, reach + 1) if s and allowed[(start + s) % k].all()],
        dtype=np.int64,
    )
    if not len(shifts):
        return best
    positions = np.unique((start[None, :] + shifts[:, None]) % k)
    _, Y = corner_responses(system, positions, schur)
    terms = variance_terms(system, a, Y)
    unshifted_torsion = grid_torsion_integral(system, curvature, best[0])
    for shift in shifts:
        columns = np.searchsorted(positions, (start + shift) % k)
        variance = float(variances(terms, columns[None, :])[0])
        if variance >= best_score:
            continue  # the torsion term cannot bring it back
        u = a + 0.5 * math.pi * Y[:, columns].sum(axis=1)
        corner_pos = _landscape_start(system, u[system.boundary], np.sort(positions[columns]))
        candidate = _rectangle_candidate(system, u, corner_pos, fit=False)
        if candidate is None or np.any(flipped_faces(system.faces, candidate[0])):
            continue
        torsion = grid_torsion_integral(system, curvature, candidate[0])
        score = variance + CORNER_ALIGN_WEIGHT * torsion
        log.debug("corners shifted by %d: variance %.4f, torsion %.4f", shift, variance, torsion)
        if (
            score < best_score
            and reference_torsion - torsion >= CORNER_ALIGN_MIN_GAIN * curvature.anisotropy
            and unshifted_torsion - torsion >= CORNER_SHIFT_MIN_GAIN * curvature.anisotropy
        ):
            best, best_score = (candidate[0], candidate[1], corner_pos), score
    return best


def flatten_rectangle(
    system: BffSystem,
    named: IntArray | None,
    curvature: Curvature | None = None,
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
        raise InternalError(f"the boundary has only {k} vertices; a rectangle needs at least 4")
    align = (
        named is None
        and curvature is not None
        and curvature.anisotropy >= CORNER_ALIGN_MIN_ANISOTROPY
    )
    samples, corner_sets = _corner_sets(system, named)
    schur = schur_complement(system) if schur is None else schur
    a, Y = corner_responses(system, samples, schur)
    scores, order = _ranked(system, named, align, curvature, a, Y, samples, corner_sets)
    fallback, best, best_score, reference_torsion = _chosen(
        system, named, align, curvature, (a, Y), samples, corner_sets, (scores, order)
    )
    if best is None and align:
        log.debug("no aligned corner candidate without flipped triangles; variance-only choice")
        return flatten_rectangle(system, None, None, schur)
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
        final = flatten_rectangle(system, corner_pos, None, schur)
        if not np.any(flipped_faces(system.faces, final[0])) or np.any(
            flipped_faces(system.faces, uv)
        ):
            return final
        u = u + _log_scale_offset(system, u, uv)
    return uv, u, np.roll(system.boundary, -corner_pos[0]), system.boundary[corner_pos]


def _corner_sets(system: BffSystem, named: IntArray | None) -> tuple[IntArray, IntArray]:
    """The boundary loop positions whose responses are computed and the quadruples of them
    (indices into those positions) to try: the named corners alone, or the sampled candidates
    and every quadruple of them with long enough arcs."""
    if named is not None:
        return named, np.arange(4, dtype=np.int64)[None, :]
    k = len(system.boundary)
    samples = corner_samples(system)
    arc = np.concatenate([[0.0], np.cumsum(system.edge_length[:-1])])
    corner_sets = quadruples(samples, arc, float(system.edge_length.sum()))
    if not len(corner_sets):
        raise InputError(
            f"the mesh is too coarse for rectangle corners: {len(samples)} of its {k} "
            "boundary vertices can take one (a corner may not sit beside a triangle with "
            "two boundary edges); subdivide the mesh, or name four --corners"
        )
    return samples, corner_sets


def _ranked(
    system: BffSystem,
    named: IntArray | None,
    align: bool,
    curvature: Curvature | None,
    a: FloatArray,
    Y: FloatArray,
    samples: IntArray,
    corner_sets: IntArray,
) -> tuple[FloatArray, IntArray]:
    """The variance of ``u`` of every quadruple and the quadruples to try, in order: the
    ``CORNER_MAX_TRIES`` lowest, or with ``align`` the diverse low-variance candidates (the
    named corners: the one quadruple)."""
    if named is not None:
        return np.zeros(1), np.zeros(1, dtype=np.int64)
    scores = corner_scores(system, a, Y, corner_sets)
    order = np.argsort(scores, kind="stable")
    if align:
        assert curvature is not None
        arc = np.concatenate([[0.0], np.cumsum(system.edge_length[:-1])])
        order = diverse_candidates(
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
    return scores, order


_Candidate = tuple[FloatArray, FloatArray, IntArray]


def _chosen(
    system: BffSystem,
    named: IntArray | None,
    align: bool,
    curvature: Curvature | None,
    responses: tuple[FloatArray, FloatArray],
    samples: IntArray,
    corner_sets: IntArray,
    ranking: tuple[FloatArray, IntArray],
) -> tuple[_Candidate | None, _Candidate | None, float, float]:
    """The candidates flattened in ranking order: the first whose boundary closes (the
    fallback), and the chosen one with its score and the reference torsion of the
    lowest-variance candidate without flips.

    The chosen one is the first candidate without flipped triangles, or with ``align`` the
    best-scoring such one (``variance + CORNER_ALIGN_WEIGHT * torsion``) among those that lower
    the torsion by ``CORNER_ALIGN_MIN_GAIN`` of the anisotropy; named corners are taken as
    they close.  ``responses``: ``(a, Y)`` of :func:`corner_responses`; ``ranking``: the
    quadruples' scores and the order to try them in.
    """
    a, Y = responses
    scores, order = ranking
    fallback: _Candidate | None = None
    best: _Candidate | None = None
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
        torsion = grid_torsion_integral(system, curvature, candidate[0])
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
    return fallback, best, best_score, reference_torsion
