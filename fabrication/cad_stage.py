"""Glue between the geometry stages and the CAD layer: what each tile's solid needs.

The geometry pipeline speaks in linkages, routes and hinge layouts; :mod:`drawstring.cad` takes
plain arrays.  This module translates one into the other and runs the CAD build in both poses.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.linkage import SIDE_BOTTOM, SIDE_LEFT, SIDE_RIGHT, SIDE_TOP, Linkage
from drawstring.geometry.route import Route

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult

    from .exports import Measures
    from .pipeline import Design


@dataclass(frozen=True)
class CadInputs:
    """Arrays :func:`drawstring.cad.design.build_design_solids` takes, derived from a design.

    Attributes
    ----------
    route_steps : (S, 4) int, ``(gap, tile, enter_side, leave_side)`` in route order.
    lift_tiles : (L, 2) int, ``(tile, side)``: the string leaves ``tile`` through side ``side``
        into a lift gap; a bore from that side up through the top face lets it out.
    magnet_pairs : (M, 4) int, ``(tile_a, side_a, tile_b, side_b)`` touching across a split.
    trims : tile -> convex polyhedra (vertex arrays, flat pose) to subtract (top hinges only).
    """

    route_steps: NDArray[np.int64]
    lift_tiles: NDArray[np.int64]
    magnet_pairs: NDArray[np.int64]
    trims: dict[int, Sequence[NDArray[np.float64]]]


def route_steps(route: Route) -> NDArray[np.int64]:
    """(S, 4) int rows ``(gap, tile, enter_side, leave_side)`` of a route."""
    return np.stack([route.gaps, route.tiles, route.enter_side, route.leave_side], axis=1).astype(
        np.int64
    )


def lift_exits(route: Route, lift_gaps: NDArray[np.int64]) -> NDArray[np.int64]:
    """(L, 2) ``(tile, side)`` for the string to leave and re-enter through the top faces.

    At a lift gap the route arrives from the previous step's tile (through its leaving side) and
    departs into this step's tile (through its entering side); both tiles get a bore from that
    side up through the top face, so the pulled loop runs out of one and back into the other.
    """
    rows: list[tuple[int, int]] = []
    count = len(route.gaps)
    for gap in np.asarray(lift_gaps, dtype=np.int64).tolist():
        hits = np.flatnonzero(route.gaps == gap)
        for k in hits.tolist():
            before = (k - 1) % count
            rows.append((int(route.tiles[before]), int(route.leave_side[before])))
            rows.append((int(route.tiles[k]), int(route.enter_side[k])))
    return np.array(sorted(set(rows)), dtype=np.int64).reshape(-1, 2)


def split_contacts(linkage: Linkage) -> NDArray[np.int64]:
    """(M, 4) ``(tile_a, side_a, tile_b, side_b)``: neighbours across every split line."""
    tile_at = {(int(i), int(j)): t for t, (i, j) in enumerate(linkage.tile_cells)}
    rows: list[tuple[int, int, int, int]] = []
    for split in linkage.splits:
        for k in range(split.lo, split.hi):
            if split.axis == "x":
                a = tile_at.get((split.line - 1, k))
                b = tile_at.get((split.line, k))
                sides = (SIDE_RIGHT, SIDE_LEFT)
            else:
                a = tile_at.get((k, split.line - 1))
                b = tile_at.get((k, split.line))
                sides = (SIDE_TOP, SIDE_BOTTOM)
            if a is not None and b is not None:
                rows.append((a, sides[0], b, sides[1]))
    return np.array(sorted(set(rows)), dtype=np.int64).reshape(-1, 4)


def cad_inputs(result: Design) -> CadInputs:
    """Collect the CAD layer's inputs from a finished geometry design."""
    pieces: dict[int, list[NDArray[np.float64]]] = {}
    for trim in result.hinge_layout.trims:
        pieces.setdefault(int(trim.tile), []).append(np.asarray(trim.vertices, dtype=np.float64))
    trims: dict[int, Sequence[NDArray[np.float64]]] = dict(pieces)
    return CadInputs(
        route_steps=route_steps(result.route),
        lift_tiles=lift_exits(result.route, result.lift.lift_gaps),
        magnet_pairs=split_contacts(result.tiling.linkage),
        trims=trims,
    )


def print_tiles(result: Design) -> NDArray[np.float64]:
    """(T, 8, 3) flat tiles to fabricate (see :func:`~drawstring.fabrication.pipeline.
    fabricated_tiles`): congruent to the assembled ones, placed by the hinge layout."""
    from .pipeline import fabricated_tiles

    return fabricated_tiles(result.hinge_layout, result.tiles_assembled)


def route_lengths(result: Design) -> tuple[float, float]:
    """(flat, assembled) string route length of a design, mm: along the channels of the tiles
    as printed and as assembled (:func:`~.exports_parts.route_lengths`, the value every output
    reports; it needs no solids)."""
    from .exports_parts import route_lengths as measured

    return measured(print_tiles(result), result.tiles_assembled, route_steps(result.route))


def fabrication_measures(result: Design, cad_flat: CadResult) -> Measures:
    """Route, string and mass measured on a design's solids (:func:`~.exports.
    measure_fabrication` with the design's print tiles, route and lift bores)."""
    from .exports import measure_fabrication

    inputs = cad_inputs(result)
    return measure_fabrication(
        result.profile,
        print_tiles(result),
        result.tiles_assembled,
        inputs.route_steps,
        inputs.lift_tiles,
        cad_flat,
    )


def build_cad(result: Design) -> tuple[CadResult, CadResult]:
    """Solids of every tile and hinge part, in the flat (print) and the assembled pose."""
    from drawstring.cad.design import build_design_solids
    from drawstring.cad.tiles import move_solid

    inputs = cad_inputs(result)
    flat = build_design_solids(
        print_tiles(result),
        result.tiles_assembled,
        result.tiling.linkage.hinges,
        result.hinge_layout.sides,
        inputs.route_steps,
        inputs.lift_tiles,
        inputs.magnet_pairs,
        inputs.trims,
        result.profile,
        pose="flat",
    )
    # The assembled pose is the same solids moved rigidly (hinge parts bend, so they stay out).
    moved = tuple(
        move_solid(solid, motion) for solid, motion in zip(flat.tiles, flat.transforms, strict=True)
    )
    assembled = replace(
        flat, pose="assembled", tiles=moved, pads=(), pad_hinge=np.zeros(0, dtype=np.int64)
    )
    return flat, assembled


def _sunk_fraction(found: Any, pads: Sequence[Any]) -> float:
    """Largest share of a hinge part's volume inside a tile (0 without hinge parts)."""
    if found is None or not np.any(found.volumes > 0):
        return 0.0
    hit = np.flatnonzero(found.volumes > 0)
    volumes = np.array([pads[int(j)].volume for j in found.pairs[hit, 1]])
    return float(np.max(found.volumes[hit] / np.maximum(volumes, 1e-300)))


def measure_cad(result: Design, cad_flat: CadResult) -> dict[str, Any]:
    """Checks measured on the solids (issue 7 section 3), for design.json ``metrics.cad``.

    Validity (BRepCheck, closed, positive volume) of every tile and hinge part; interference
    volumes between tiles and between tiles and hinge parts in the flat print pose (manifold3d);
    channel continuity (distance between each channel exit and the next tile's entry in the
    assembled pose); magnet pockets paired (distance apart and facing) in the assembled pose.
    Mass, route and string length as the fabrication files state them
    (:func:`fabrication_measures`).
    """
    from drawstring.cad.checks import (
        channel_continuity,
        check_valid,
        interference,
        pockets_paired,
        to_manifold,
    )

    inputs = cad_inputs(result)
    flat_tiles = print_tiles(result)
    valid_tiles = check_valid(cad_flat.tiles)
    valid_pads = check_valid(cad_flat.pads)
    # One tessellation of each tile serves both interference checks.
    tile_meshes = [to_manifold(solid) for solid in cad_flat.tiles]
    tiles_vs_tiles = interference(tile_meshes)
    tiles_vs_pads = interference(tile_meshes, cad_flat.pads) if cad_flat.pads else None
    channels = channel_continuity(
        cad_flat.tiles, flat_tiles, cad_flat.transforms, inputs.route_steps, result.profile
    )
    pockets, facing = pockets_paired(
        cad_flat.tiles, flat_tiles, cad_flat.transforms, cad_flat.magnets
    )
    return {
        "solids_valid": bool(valid_tiles.all() and valid_pads.all()),
        "tiles": len(cad_flat.tiles),
        "hinge_parts": len(cad_flat.pads),
        "interference_tiles_max_mm3": round(tiles_vs_tiles.max_volume, 6),
        "interference_tiles_pads_max_mm3": round(
            tiles_vs_pads.max_volume if tiles_vs_pads is not None else 0.0, 6
        ),
        "interference_tiles_pads_max_rel": round(_sunk_fraction(tiles_vs_pads, cad_flat.pads), 6),
        "channel_opening_distance_max_mm": round(_max(channels.distances), 6),
        "channel_openings_missing": int(np.count_nonzero(~np.isfinite(channels.distances))),
        "magnet_pairs": len(cad_flat.magnets),
        "magnet_pocket_distance_max_mm": round(_max(pockets.distances), 6),
        "magnet_pockets_missing": int(np.count_nonzero(~np.isfinite(pockets.distances))),
        "magnet_pockets_facing": bool(np.all(facing < -0.999)) if len(facing) else True,
        **fabrication_measures(result, cad_flat).to_json(),
        "notes": list(cad_flat.notes),
    }


def _max(values: NDArray[np.float64]) -> float:
    finite = np.asarray(values, dtype=np.float64)
    finite = finite[np.isfinite(finite)]
    return float(finite.max()) if finite.size else 0.0
