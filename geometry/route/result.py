"""A planned string route and its measures: the :class:`Route` record, its checks (contact
partners, crossings) measured from the route alone, its metrics for ``design.json`` and its
``route.json``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.tile import Side
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.route.milp import segments_cross, turn_angle
from drawstring.geometry.route.rules import check_positions
from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)

__all__ = [
    "Route",
    "channel_partner_faults",
    "channel_partners_ok",
    "count_crossings",
    "route_metrics",
    "route_to_json",
]


@dataclass(frozen=True)
class Route:
    """A closed string route.

    Attributes
    ----------
    gaps : (r,) int, the cyclic sequence of gaps (the route closes from the last to the first).
    labels : (r,) int, node label of each gap (0, 1, -1 entrance, -2 split).
    tiles : (r,) int, tile the string passes from ``gaps[k]`` to ``gaps[(k + 1) % r]``.
    enter_side : (r,) int, side (0 bottom, 1 right, 2 top, 3 left) of ``tiles[k]`` by which the
        string enters it from ``gaps[k]``: the segment it shares with ``tiles[k - 1]``.
    leave_side : (r,) int, side of ``tiles[k]`` by which it leaves into ``gaps[k + 1]``: the
        segment it shares with ``tiles[k + 1]``.
    turn_angle_total_rad : float, sum of the turn angles at all nodes (flat centroids).
    method : ``"exact"`` or ``"heuristic: <name>"``.
    lower_bound_rad : float or None, a proven lower bound on the optimum total turn.
    crossings : int, gaps visited twice plus pairs of route segments that intersect.
    boundary_tiles_covered : bool, measured: every boundary tile is some ``tiles[k]``.
    length_flat_mm : float, polyline length through the flat gap centroids.
    channel_partners_ok : bool, measured: every consecutive tile pair are contact partners at
        their gap (:func:`channel_partners_ok`).
    tiles_passed_once : bool, measured: no tile appears twice in ``tiles``.
    lifts_missed : (m,) int, lift gaps the route could not pass (reasons in ``notes``).
    notes : what the solver had to give up or work around.
    """

    gaps: IntArray
    labels: IntArray
    tiles: IntArray
    enter_side: IntArray
    leave_side: IntArray
    turn_angle_total_rad: float
    method: str
    lower_bound_rad: float | None
    crossings: int
    boundary_tiles_covered: bool
    length_flat_mm: float
    channel_partners_ok: bool = True
    tiles_passed_once: bool = True
    lifts_missed: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    notes: tuple[str, ...] = field(default=())


def channel_partner_faults(route: Route, linkage: Linkage) -> IntArray:
    """Steps ``k`` where the string does not pass straight between contact partners.

    Measured from the route alone: step ``k`` is fine when ``tiles[k - 1] != tiles[k]``, the
    leave side of ``tiles[k - 1]`` and the enter side of ``tiles[k]`` are the same grid segment
    (same two grid vertices, read from ``linkage.tile_corners``), and the gap ``gaps[k]`` sits at
    one end of that segment.

    Returns
    -------
    (f,) int, the faulty step indices (empty when every crossing is a contact-partner crossing).
    """
    r = len(route.gaps)
    if r == 0:
        return np.zeros(0, dtype=np.int64)
    corners = linkage.tile_corners
    prev_t, here_t = np.roll(route.tiles, 1), route.tiles
    out_s, in_s = np.roll(route.leave_side, 1), route.enter_side
    bad_side = (out_s < 0) | (out_s > 3) | (in_s < 0) | (in_s > 3)
    out_s, in_s = np.clip(out_s, 0, 3), np.clip(in_s, 0, 3)
    a0, a1 = corners[prev_t, out_s], corners[prev_t, (out_s + 1) % 4]
    b0, b1 = corners[here_t, in_s], corners[here_t, (in_s + 1) % 4]
    same = ((a0 == b0) & (a1 == b1)) | ((a0 == b1) & (a1 == b0))
    vertex = linkage.gap_vertex[route.gaps]
    at_end = (vertex == a0) | (vertex == a1)
    ok = same & at_end & (prev_t != here_t) & ~bad_side
    return np.asarray(np.nonzero(~ok)[0], dtype=np.int64)


def channel_partners_ok(route: Route, linkage: Linkage) -> bool:
    """Whether every consecutive tile pair of the route are contact partners at their gap."""
    return not channel_partner_faults(route, linkage).size


def count_crossings(gaps: IntArray, pos: FloatArray, parts: IntArray | None = None) -> int:
    """Gaps visited more than once plus pairs of non-adjacent route segments that cross.

    ``parts`` (r,): the split part of each segment (segment ``k`` runs from gap ``k`` to gap
    ``k + 1`` through the route's tile ``k``).  Segments in different parts are not compared:
    the parts are cut apart in the flat layout and lie in different places assembled, while
    the positions here are the parts moved rigidly together (``parts_in_place``), where two
    parts whose own flat layouts bend different ways overlap at their ends, and segments of
    the two would seem to cross there."""
    r = len(gaps)
    repeats = int(r - len(np.unique(gaps)))
    if r < 4:
        return repeats
    a = pos[gaps]
    b = pos[np.roll(gaps, -1)]
    i, j = np.triu_indices(r, k=2)
    keep = ~((i == 0) & (j == r - 1))
    if parts is not None:
        part = np.asarray(parts)
        keep &= part[i] == part[j]
    i, j = i[keep], j[keep]
    return repeats + int(segments_cross(a[i], b[i], a[j], b[j]).sum())


def route_metrics(
    route: Route,
    linkage: Linkage,
    positions_flat: ArrayLike,
    positions_assembled: ArrayLike | None,
    mu: float,
) -> dict[str, Any]:
    """Measured route metrics for ``design.json``.

    Parameters
    ----------
    route : the route.
    linkage : topology (boundary tiles, components).
    positions_flat : (G, 2) float, mm, flat gap centroids.
    positions_assembled : (G, 3) float, mm, assembled gap positions, or None.
    mu : channel friction coefficient of the profile.

    Returns
    -------
    dict with ``tiles`` (distinct tiles passed), ``boundary_tiles_covered``,
    ``turn_angle_total_rad`` (recomputed), ``crossings`` (recounted), ``capstan_factor``
    ``= exp(mu * total turn)``, ``length_mm {flat, assembled}``, ``components_visited``,
    ``channel_partners_ok`` (every consecutive tile pair are contact partners at their gap,
    measured by :func:`channel_partner_faults`), ``tiles_passed_once``, ``lift_gaps_missed``,
    ``method`` and ``lower_bound_rad``.
    """
    pos = check_positions(linkage, positions_flat)
    p = pos[route.gaps]
    total = float(turn_angle(np.roll(p, 1, axis=0), p, np.roll(p, -1, axis=0)).sum())
    tiles = set(route.tiles.tolist())
    boundary = set(np.nonzero(linkage.boundary_tile)[0].tolist())
    lengths: dict[str, float | None] = {
        "flat": float(np.linalg.norm(np.roll(p, -1, axis=0) - p, axis=1).sum())
    }
    if positions_assembled is not None:
        q = np.asarray(positions_assembled, dtype=np.float64)[route.gaps]
        lengths["assembled"] = float(np.linalg.norm(np.roll(q, -1, axis=0) - q, axis=1).sum())
    comps = set(linkage.tile_component[route.tiles].tolist())
    faults = channel_partner_faults(route, linkage)
    return {
        "tiles": len(tiles),
        "gaps": int(len(route.gaps)),
        "boundary_tiles_covered": bool(boundary <= tiles),
        "turn_angle_total_rad": total,
        "crossings": count_crossings(route.gaps, pos, linkage.tile_component[route.tiles]),
        "capstan_factor": float(math.exp(mu * total)),
        "length_mm": lengths,
        "components_visited": len(comps),
        "components": linkage.n_components,
        "channel_partners_ok": not faults.size,
        "channel_partner_faults": int(faults.size),
        "tiles_passed_once": bool(len(tiles) == len(route.tiles)),
        "lift_gaps_missed": [int(g) for g in route.lifts_missed],
        "method": route.method,
        "lower_bound_rad": route.lower_bound_rad,
    }


def route_to_json(
    route: Route,
    linkage: Linkage,
    positions_flat: ArrayLike,
    positions_assembled: ArrayLike | None = None,
    lift_gaps: ArrayLike = (),
) -> dict[str, Any]:
    """The ordered route for ``route.json``.

    Every step lists the gap the string is in, its label, the tile it passes next, the side
    faces of that tile it enters and leaves by (0 bottom, 1 right, 2 top, 3 left), and the gap
    position flat (mm) and assembled (mm, when given).  Every lift point lists its gap, its step
    index, the tile and side the string arrives from and the tile and side it departs into; the
    string exits the structure there out of the gap on the top side.
    """
    pos = check_positions(linkage, positions_flat)
    asm = None if positions_assembled is None else np.asarray(positions_assembled, float)
    r = len(route.gaps)
    steps = []
    for k in range(r):
        g = int(route.gaps[k])
        step: dict[str, Any] = {
            "gap": g,
            "label": int(route.labels[k]),
            "tile": int(route.tiles[k]),
            "enter_side": int(route.enter_side[k]),
            "leave_side": int(route.leave_side[k]),
            "position_flat_mm": [float(c) for c in pos[g]],
        }
        if asm is not None:
            step["position_assembled_mm"] = [float(c) for c in asm[g]]
        steps.append(step)
    lifts: list[dict[str, Any]] = []
    where = {int(g): k for k, g in enumerate(route.gaps)}
    for g in np.asarray(lift_gaps, dtype=np.int64).tolist():
        if int(g) not in where:
            lifts.append({"gap": int(g), "on_route": False})
            continue
        k = where[int(g)]
        lifts.append(
            {
                "gap": int(g),
                "on_route": True,
                "step": k,
                "arrive_tile": int(route.tiles[k - 1]),
                "arrive_side": int(route.leave_side[k - 1]),
                "depart_tile": int(route.tiles[k]),
                "depart_side": int(route.enter_side[k]),
                "exit": "top",
            }
        )
    return {
        # Measured: the wrap from the last step back to the first is a contact-partner crossing.
        "closed": bool(r > 2 and 0 not in channel_partner_faults(route, linkage)),
        "method": route.method,
        "turn_angle_total_rad": route.turn_angle_total_rad,
        "lower_bound_rad": route.lower_bound_rad,
        "crossings": route.crossings,
        "boundary_tiles_covered": route.boundary_tiles_covered,
        "length_flat_mm": route.length_flat_mm,
        "side_names": [side.label for side in Side],
        "steps": steps,
        "lift_points": lifts,
        "notes": list(route.notes),
    }
