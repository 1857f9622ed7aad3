"""Hinges on the flat tiles T2D (paper section 4.4): each hinge's face
(:mod:`~drawstring.geometry.hinges.sides`), the rigid layout that brings every hinge pair together
(:mod:`~drawstring.geometry.hinges.rigid_layout`), and the trims of the overlaps left
(:mod:`~drawstring.geometry.hinges.trims`).

Strategies
----------
``top``: all hinges at the top.  The region where two hinged tiles overlap in the flat pose is
computed exactly (convex hulls intersected with manifold3d); it is to be removed from the tile
with the larger id, and the side-face (contact) area it takes away is reported.  Unhinged
neighbours are kept apart on their top faces only and any 3D overlap left (bottoms reaching
past the top faces on thick, strongly curved tiles) is trimmed the same way.
``dual``: each hinge on the face :mod:`.sides` chooses (decided once, on the eq.-1 tiles, and
passed through the flat layout, which makes the hinge points meet), then the rigid-tile layout
``w_rigid E_rigid + w_collision E_collision + w_conn E_conn`` (tiles exactly rigid; separating
planes between close pairs, through the hinge for hinged ones; paired hinge vertices to their
midpoint), then every hinge pair is merged into one vertex.  A pair that, on the final tiles,
collides on its hinge face at every opening within the gap-angle bounds is laid out as a ``top``
pair is (separated on the hinge face only) and its overlap trimmed; without that, the layout
would have to hold it apart and its hinge would not meet.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import TILE_FACES, HingeSide, HingeStrategy
from drawstring.geometry.core.tolerances import (
    HINGE_ANGLE_MARGIN_DEG,
    HINGE_GAP_TOL_MM,
    HINGE_LAYOUT_CLEARANCE_MM,
    HINGE_LAYOUT_FEASIBLE_MM,
)
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flat.layout import FlatResult
from drawstring.geometry.flat.pose import hinge_faces
from drawstring.geometry.flat.verify import hinge_gaps
from drawstring.geometry.hinges.rigid_layout import RigidLayoutResult, rigid_layout
from drawstring.geometry.hinges.sides import hinge_sides
from drawstring.geometry.hinges.trims import (
    HingeTrim,
    hinge_trims,
    pair_count,
    pair_trims,
    unhinged_close_pairs,
)
from drawstring.geometry.tiling.linkage import Linkage, slit_ends

logger = logging.getLogger(__name__)


__all__ = [
    "HingeLayout",
    "hinge_vertex_json",
    "layout_hinges",
    "write_flat_obj",
]


@dataclass(frozen=True)
class HingeLayout:
    """Flat tiles with their hinges.

    Attributes
    ----------
    strategy : "dual" | "top"
    tiles : (T, 8, 3) float, mm
        Final flat tiles (hinge pairs merged for ``dual``).
    bottom : (H,) bool
        Hinge side (True: bottom).
    hinge_vertices : (H, 2) int
        ``8 * tile + vertex`` of both tiles' hinge vertex.
    hinge_points : (H, 3) float, mm
        Hinge positions (after merging).
    hinge_gap_max_mm : float
        Max paired-vertex distance before merging.
    trims : tuple of HingeTrim
        Flat-pose overlaps to cut: every overlapping ``top`` hinged pair, ``dual`` pairs laid
        out on their hinge face only, and (``top``) unhinged neighbours (``hinge == -1``).
    contact_area_lost_mm2 : float
    iterations : int
    time_s : float
    problems : tuple of str
    rigid_tiles : (T, 8, 3) float, mm, or None
        The tiles before merging: congruent to T3D, separated by the layout's clearance
        except at their hinge points.  These are what gets fabricated; the hinge parts bridge
        the residual hinge mismatch.
    """

    strategy: HingeStrategy
    tiles: FloatArray
    bottom: BoolArray
    hinge_vertices: IntArray
    hinge_points: FloatArray
    hinge_gap_max_mm: float
    trims: tuple[HingeTrim, ...] = field(default=())
    contact_area_lost_mm2: float = 0.0
    iterations: int = 0
    time_s: float = 0.0
    problems: tuple[str, ...] = field(default=())
    rigid_tiles: FloatArray | None = None

    @property
    def sides(self) -> tuple[HingeSide, ...]:
        return tuple(HingeSide.BOTTOM if b else HingeSide.TOP for b in self.bottom)


def _hinge_vertex_ids(linkage: Linkage, bottom: BoolArray) -> IntArray:
    h = linkage.hinges
    off = np.where(bottom, 4, 0)
    return np.stack([8 * h[:, 0] + h[:, 1] + off, 8 * h[:, 2] + h[:, 3] + off], axis=1)


def layout_hinges(
    linkage: Linkage,
    flat: FlatResult,
    tiles_2d: ArrayLike,
    tiles_3d: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    min_gap_angle_deg: float | None = None,
    clearance_mm: float = HINGE_LAYOUT_CLEARANCE_MM,
    max_rounds: int = 40,
    bottom: ArrayLike | None = None,
) -> HingeLayout:
    """Place hinges and lay the rigid tiles out so paired hinge vertices meet.

    ``dual``: each hinge goes to the top or the bottom (:func:`hinge_sides`); ``top``: all on
    top.  Then :func:`rigid_layout` moves the rigid T2D tiles in the plane (this is the paper's
    ``E_Hinge`` with ``w_rigid -> infinity``: tiles exactly rigid; ``E_Collision`` as hard
    separating planes; ``E_Conn`` minimized) keeping every gap angle within
    ``[theta_min, 90]`` deg, and merges every hinge pair into one point where that keeps the
    layout valid.  For ``top`` the 3D overlap of each hinged pair, and of each pair of unhinged
    neighbours in one part (kept apart on their top faces only), is then computed and recorded
    as a trim of the tile with the larger id (``dual``: of the pairs laid out on their hinge
    face only).

    Parameters
    ----------
    linkage : Linkage
    flat : FlatResult
        K2D (gives ``theta_min`` unless ``min_gap_angle_deg`` is passed).
    tiles_2d : (T, 8, 3) float, mm
        T2D from :func:`~drawstring.geometry.flat.layout.extrude_flat`.
    tiles_3d : (T, 8, 3) float, mm
        T3D (hinge sides).
    strategy : "dual" | "top"
    min_gap_angle_deg : float, deg, optional
    clearance_mm : float, mm
        Least distance between tiles away from their shared hinge point.
    max_rounds : int
        Augmented Lagrangian rounds.
    bottom : (H,) bool, optional
        ``dual`` hinge sides; default the faces the flat layout was made for (``flat.hinges``,
        whose clear openings, computed on ``tiles_3d``, are then reused), else
        :func:`hinge_sides` of ``tiles_3d``.

    Returns
    -------
    HingeLayout
    """
    start = time.perf_counter()
    t2 = np.asarray(tiles_2d, dtype=np.float64)
    t3 = np.asarray(tiles_3d, dtype=np.float64)
    if t2.shape != t3.shape or t2.shape[1:] != (8, 3) or len(t2) != linkage.n_tiles:
        raise InternalError("tiles_2d and tiles_3d must both be (T, 8, 3) for the linkage's tiles")
    if strategy not in tuple(HingeStrategy):
        raise InternalError(f"hinge strategy {strategy!r} is not dual or top")
    theta = flat.min_gap_angle_deg if min_gap_angle_deg is None else float(min_gap_angle_deg)
    problems: list[str] = []
    sides = _hinge_bottoms(linkage, flat, t3, strategy, bottom)
    ids = _hinge_vertex_ids(linkage, sides)
    trim, released = _trimmed_pairs(linkage, flat, t3, sides, strategy, theta)
    never_clear = int(np.count_nonzero(trim & ~released))
    result = rigid_layout(
        linkage, t2, ids, strategy=strategy, min_gap_angle_deg=theta,
        clearance_mm=clearance_mm, max_rounds=max_rounds, trim=trim,
    )  # fmt: skip
    result, trim = _relayout_held_apart(
        linkage, t2, ids, result, trim, strategy, theta, clearance_mm, max_rounds, problems
    )
    gap_max = float(result.gap_mm.max(initial=0.0))
    problems += _layout_problems(result, theta)
    trims, unhinged = _flat_pose_trims(
        linkage, result, trim, strategy, theta, never_clear, released, problems
    )
    lost = float(sum(tr.contact_area_lost_mm2 for tr in trims + unhinged))
    return HingeLayout(
        strategy, result.merged, sides, ids, result.points, gap_max, trims + unhinged, lost,
        result.iterations, time.perf_counter() - start, tuple(problems), result.tiles,
    )  # fmt: skip


def _hinge_bottoms(
    linkage: Linkage,
    flat: FlatResult,
    tiles_3d: FloatArray,
    strategy: HingeStrategy,
    bottom: ArrayLike | None,
) -> BoolArray:
    """Which hinges go to the bottom (see :func:`layout_hinges`'s ``bottom``)."""
    if strategy == HingeStrategy.TOP:
        return np.zeros(linkage.n_hinges, dtype=bool)
    if bottom is None:
        return hinge_sides(linkage, tiles_3d) if flat.hinges is None else flat.hinges.bottom
    sides = np.asarray(bottom, dtype=bool)
    if sides.shape != (linkage.n_hinges,):
        raise InternalError(f"bottom has shape {sides.shape}; pass one flag per hinge")
    return sides


def _trimmed_pairs(
    linkage: Linkage,
    flat: FlatResult,
    tiles_3d: FloatArray,
    sides: BoolArray,
    strategy: HingeStrategy,
    theta: float,
) -> tuple[BoolArray, BoolArray]:
    """Hinges ``(H,)`` whose pairs are separated on the hinge face only and trimmed (every one
    for ``top``), and those the flat layout released from their clear openings."""
    released = np.zeros(linkage.n_hinges, dtype=bool)
    if strategy == HingeStrategy.TOP:
        return np.ones(linkage.n_hinges, dtype=bool), released
    # pairs that collide on their hinge face at every opening within the gap-angle bounds
    # are laid out like top hinges: separated on the hinge face, their overlap trimmed
    ends = slit_ends(linkage)
    bounds = np.radians([theta + HINGE_ANGLE_MARGIN_DEG, 90.0 - HINGE_ANGLE_MARGIN_DEG])
    made_for = flat.hinges
    if made_for is None or not np.array_equal(made_for.bottom, sides):
        made_for = hinge_faces(linkage, tiles_3d, sides)
    _, _, fits = made_for.window(*bounds)
    trim = np.zeros(linkage.n_hinges, dtype=bool)
    trim[ends.hinge[~fits]] = True
    if made_for.released is not None:
        released[ends.hinge[made_for.released]] = True
    return trim, released


def _relayout_held_apart(
    linkage: Linkage,
    tiles_2d: FloatArray,
    ids: IntArray,
    result: RigidLayoutResult,
    trim: BoolArray,
    strategy: HingeStrategy,
    theta: float,
    clearance_mm: float,
    max_rounds: int,
    problems: list[str],
) -> tuple[RigidLayoutResult, BoolArray]:
    """The layout again with the pairs that planes through the hinge held apart laid out like
    trimmed ones, kept when it is as feasible and its hinges meet closer; else ``result``.

    A plane through the hinge that separates the two whole tiles is stricter than keeping them
    apart; where it holds a pair apart, that pair is laid out like a trimmed one: separated on
    its hinge face, with whatever 3D overlap is left trimmed (often none)."""
    apart = _held_apart(hinge_gaps(result.tiles, ids, in_plane=True), tiles_2d, ids, ~trim)
    logger.info("hinge layout: %d of %d pairs apart", apart.sum(), len(apart))
    if not 0 < apart.sum() <= HINGE_RELAYOUT_MAX_SHARE * len(apart):
        return result, trim
    retry = rigid_layout(
        linkage, tiles_2d, ids, strategy=strategy, min_gap_angle_deg=theta,
        clearance_mm=clearance_mm, max_rounds=max_rounds, trim=trim | apart, like=result,
    )  # fmt: skip
    if retry.violation_mm <= max(result.violation_mm, HINGE_LAYOUT_FEASIBLE_MM) and _in_plane_max(
        retry, ids
    ) < _in_plane_max(result, ids):
        problems.append(
            f"dual hinges: laid out {_pairs(int(apart.sum()))} again that planes through "
            "the hinge held apart, separated on their hinge face only"
        )
        return retry, trim | apart
    return result, trim


def _layout_problems(result: RigidLayoutResult, theta: float) -> list[str]:
    """What the rigid layout could not do: separate the tiles within the angle bounds, merge
    every hinge pair."""
    problems = []
    if result.violation_mm > HINGE_LAYOUT_FEASIBLE_MM:
        problems.append(
            f"hinge layout: tiles could not be separated with every gap angle in [{theta:g}, 90] "
            f"deg (constraint violation {result.violation_mm:.3g} mm)"
        )
    n_apart = int(np.count_nonzero(~result.is_merged))
    if n_apart:
        problems.append(
            f"{_pairs(n_apart, 'hinge ')} left unmerged (up to "
            f"{float(result.gap_mm[~result.is_merged].max()):.3g} mm apart): merging them would "
            "overlap tiles or break a gap-angle bound"
        )
    return problems


def _flat_pose_trims(
    linkage: Linkage,
    result: RigidLayoutResult,
    trim: BoolArray,
    strategy: HingeStrategy,
    theta: float,
    never_clear: int,
    released: BoolArray,
    problems: list[str],
) -> tuple[tuple[HingeTrim, ...], tuple[HingeTrim, ...]]:
    """The trims of the ``trim`` hinges' pairs and (``top``) of the unhinged neighbours that
    overlap on the merged tiles, each kind reported in ``problems``."""
    trims = hinge_trims(linkage, result.merged, np.flatnonzero(trim))
    unhinged: tuple[HingeTrim, ...] = ()
    if strategy == HingeStrategy.TOP:
        # the layout kept unhinged pairs apart on their top faces only
        unhinged = pair_trims(result.merged, unhinged_close_pairs(linkage, result.merged))
        if unhinged:
            problems.append(
                f"top hinges: {_pairs(pair_count(unhinged), 'unhinged ', 'overlap')} in the "
                "flat pose "
                f"(bottoms reaching past the top faces); trimmed "
                f"{sum(tr.volume_mm3 for tr in unhinged):.3g} mm^3, losing "
                f"{sum(tr.contact_area_lost_mm2 for tr in unhinged):.3g} mm^2 of contact"
            )
    hinged_lost = float(sum(tr.contact_area_lost_mm2 for tr in trims))
    if trims:
        which = f"{strategy} hinges: "
        if never_clear and strategy == HingeStrategy.DUAL:
            which += (
                f"{_pairs(never_clear, verb='collide')} on their hinge face at every opening in "
                f"[{theta:g}, 90] deg; "
            )
        if released.any():
            which += (
                f"{_pairs(int(released.sum()))} laid out free of their clear openings on the "
                "hinge face, to keep the tiles' assembled shapes; "
            )
        problems.append(
            f"{which}{_pairs(pair_count(trims), 'hinged ', 'overlap')} in the flat pose; trimmed "
            f"{sum(tr.volume_mm3 for tr in trims):.3g} mm^3, losing {hinged_lost:.3g} mm^2 of "
            "contact"
        )
    return trims, unhinged


#: The second layout (pairs held apart laid out on their hinge face only) runs only when at
#: most this share of the pairs is apart: planes through the hinge hold pairs apart locally (a
#: few per cent of them, at split-line ends for instance); when most pairs are apart, the flat
#: tiles themselves are not congruent and a second layout only doubles the stage's time.
HINGE_RELAYOUT_MAX_SHARE = 0.1


def _pairs(count: int, kind: str = "", verb: str = "") -> str:
    """``"1 hinged pair overlaps"``, ``"2 hinged pairs overlap"``."""
    if count == 1:
        return f"1 {kind}pair" + (f" {verb}s" if verb else "")
    return f"{count} {kind}pairs" + (f" {verb}" if verb else "")


#: A hinge pair of the rigid layout counts as held apart by its separating plane when it is
#: more than the tolerance apart, or more than this share of it and :data:`HELD_APART_RATIO`
#: times as far apart as its two tiles were in T2D (where the flat layout left them), provided
#: no pair below the tolerance is wider (:func:`_held_apart`).  A pair held just inside the
#: tolerance, far wider than the flat layout left it, is laid out again too: otherwise a change
#: in the last bit elsewhere could push it past the tolerance.
HELD_APART_SHARE = 0.5
HELD_APART_RATIO = 3.0


def _held_apart(
    gaps: FloatArray, tiles_2d: FloatArray, ids: IntArray, free: BoolArray
) -> BoolArray:
    """Hinge pairs ``(H,)`` among ``free`` ones whose rigid-layout ``gaps`` (in-plane, mm) a
    separating plane holds open: those above the tolerance, and those near it
    (:data:`HELD_APART_SHARE`) and much wider than in T2D (:data:`HELD_APART_RATIO`) where no
    pair outside these is wider.  (A pair that only matches the flat layout's own misfit elsewhere
    gains nothing from another layout: the 200-tile peanut's largest gaps, 6e-4 mm, are its
    flat layout's.)"""
    over = free & (gaps > HINGE_GAP_TOL_MM)
    start = hinge_gaps(tiles_2d, ids, in_plane=True)
    near = free & ~over & (gaps > HELD_APART_SHARE * HINGE_GAP_TOL_MM)
    near &= gaps > HELD_APART_RATIO * start
    if near.any() and gaps[near].max() >= gaps[~(over | near)].max(initial=0.0):
        return np.asarray(over | near)
    return np.asarray(over)


def _in_plane_max(result: RigidLayoutResult, ids: IntArray) -> float:
    """Largest in-plane distance of a hinge pair of a rigid layout, before merging, mm."""
    return float(hinge_gaps(result.tiles, ids, in_plane=True).max(initial=0.0))


def write_flat_obj(path: str | Path, tiles: ArrayLike) -> None:
    """Write tiles as closed outward-oriented quad meshes (8 vertices, 6 faces each).

    Vertex order per tile: top BL, BR, TR, TL, then the bottom vertices under them (same as
    ``assembled.obj``); tile ``t`` uses OBJ vertices ``8 t + 1 .. 8 t + 8`` and group ``tile_t``.

    Parameters
    ----------
    path : output file
    tiles : (T, 8, 3) float, mm
    """
    t = np.asarray(tiles, dtype=np.float64)
    lines = ["# drawstring flat configuration (T2D), mm"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in t.reshape(-1, 3)]
    for k in range(len(t)):
        lines.append(f"g tile_{k}")
        for face in TILE_FACES:
            lines.append("f " + " ".join(str(8 * k + int(i) + 1) for i in face))
    Path(path).write_text("\n".join(lines) + "\n")


def hinge_vertex_json(layout: HingeLayout, linkage: Linkage) -> dict[str, Any]:
    """Hinge list for design.json: tiles, corners, side, 0-based OBJ vertex ids, position."""
    rows = []
    for k, (ta, ca, tb, cb) in enumerate(linkage.hinges):
        rows.append(
            {
                "tiles": [int(ta), int(tb)],
                "corners": [int(ca), int(cb)],
                "side": HingeSide.BOTTOM if layout.bottom[k] else HingeSide.TOP,
                "vertices": [int(layout.hinge_vertices[k, 0]), int(layout.hinge_vertices[k, 1])],
                "point_mm": [float(v) for v in layout.hinge_points[k]],
            }
        )
    out: dict[str, Any] = {"strategy": layout.strategy, "hinges": rows}
    if layout.trims:
        out["trims"] = [
            {
                "hinge": tr.hinge,
                "tile": tr.tile,
                "other": tr.other,
                "volume_mm3": tr.volume_mm3,
                "contact_area_lost_mm2": tr.contact_area_lost_mm2,
                "vertices_mm": tr.vertices.tolist(),
            }
            for tr in layout.trims
        ]
    json.dumps(out)  # fail early on anything not serializable
    return out
