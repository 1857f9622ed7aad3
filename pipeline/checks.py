"""Checks on a loaded target and its flattening that refuse before the costly stages: the
grid a tile count gives (:func:`check_grid`) and ``--corners`` as ids of the loaded target
(:func:`mesh_corners`).  The pipeline (:mod:`.run`) and the retry search (:mod:`.retry`) share
them."""

from __future__ import annotations

import igl
import numpy as np

from drawstring.fabrication.profiles import MAX_TILES, MIN_GRID_SIDE
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.flatten.conformal import Flattening
from drawstring.geometry.target.surface import Target
from drawstring.geometry.tiling.grid import grid_shape_for
from drawstring.pipeline.record import ResolvedOptions


def check_grid(options: ResolvedOptions, flat_map: Flattening, *, from_profile: bool) -> None:
    """Refuse a tile count that gives this target's flattening a grid too narrow for a string
    route (fewer than :data:`MIN_GRID_SIDE` cells one way), before the costly stages."""
    if options.tiles is None:
        return
    width, height = np.ptp(flat_map.uv, axis=0).tolist()
    n_i, n_j = grid_shape_for(width, height, options.tiles)
    if min(n_i, n_j) >= MIN_GRID_SIDE:
        return
    need = options.tiles
    while need < MAX_TILES and min(grid_shape_for(width, height, need)) < MIN_GRID_SIDE:
        need += 1
    asked = f"the profile's {options.tiles} tiles" if from_profile else f"--tiles {options.tiles}"
    grid = f"--grid {MIN_GRID_SIDE} {MIN_GRID_SIDE}"
    fix = (
        f"use --tiles {need} or more, or {grid}"
        if min(grid_shape_for(width, height, need)) >= MIN_GRID_SIDE
        else f"use {grid} or more (no tile count up to {MAX_TILES} gives such a grid)"
    )
    raise InputError(
        f"with {asked} this target gets a {n_i} x {n_j} grid, but the string route needs at least "
        f"{MIN_GRID_SIDE} tiles each way: {fix}"
    )


def mesh_corners(target: Target, options: ResolvedOptions) -> tuple[int, ...] | None:
    """``--corners`` (vertex ids of the mesh as read, counting from 0) as ids of the loaded
    target, whose repairs may have dropped or merged vertices."""
    if options.corners is None:
        return None
    ids = [int(v) for v in options.corners]
    where = target.vertex_of_input
    if where is None:
        return tuple(ids)
    outside = [v for v in ids if not 0 <= v < len(where)]
    if outside:
        raise InputError(
            f"--corners {outside[0]} is not a vertex of the mesh, which has {len(where)} "
            f"(ids 0 to {len(where) - 1}, in the file's order)"
        )
    if len(set(ids)) != len(ids):
        raise InputError(
            f"--corners {' '.join(map(str, ids))} repeat a vertex; name four distinct boundary "
            "vertices"
        )
    dropped = [v for v in ids if where[v] < 0]
    if dropped:
        raise InputError(
            f"--corners {dropped[0]} names a vertex that no face of the mesh uses (or only "
            "faces that loading removed, zero-area or duplicated); pick four boundary vertices "
            "of the surface"
        )
    mapped = [int(where[v]) for v in ids]
    boundary = set(igl.boundary_loop(np.asarray(target.faces)).tolist())
    inside = [v for v, m in zip(ids, mapped, strict=True) if m not in boundary]
    if inside:
        raise InputError(
            f"--corners vertices {inside} are not on the mesh boundary; pick four boundary "
            "vertex ids (counting from 0, in the file's order)"
        )
    if len(set(mapped)) < len(set(ids)):
        raise InputError(
            f"--corners {' '.join(map(str, ids))} name coincident vertices, which loading "
            "merged into one; pick four distinct corners"
        )
    return tuple(mapped)
