"""What the report reads from a design folder: the files it finds (any may be missing or
damaged: each problem is named, and the page is made of what is left) and the data of its 3D view.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.core.tolerances import SURFACE_MEAN_REL
from drawstring.geometry.core.types import FloatArray
from drawstring.output.design_folder import (
    DESIGN_JSON_TYPES,
    Route,
    design_json_faults,
    hinges_from_flat,
    neighbour_lists,
    read_deploy_frames,
    read_obj_quads,
    read_obj_tiles,
    read_route,
    read_tile_fit,
    subsample_frames,
    touching_tiles,
)

#: Decimals kept for inlined coordinates (mm): 0.01 mm is far below what the eye sees.
GEOMETRY_DECIMALS = 2


@dataclass(frozen=True)
class FolderContents:
    """What the report found in the output folder."""

    folder: Path
    design: dict[str, Any]
    assembled: FloatArray | None
    flat: FloatArray | None
    frames: FloatArray | None
    route: Route | None
    problems: tuple[str, ...]
    assembled_source: str = "assembled.obj"
    #: (T, 2) per tile the mean and largest distance of its top face from the target, mm
    fit: FloatArray | None = None


def read_folder(folder: Path) -> FolderContents:
    """Read the folder's files; each missing one is None, each damaged one a problem."""
    problems: list[str] = []
    design: dict[str, Any] = {}
    path = folder / "design.json"
    if path.is_file():
        try:
            design = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as err:
            problems.append(f"design.json is not valid JSON ({err})")
        faults = design_json_faults(design)
        if faults:  # the page is made of what is left
            problems += faults
            design = {} if not isinstance(design, dict) else design
            design = {k: v for k, v in design.items() if k not in DESIGN_JSON_TYPES
                      or isinstance(v, DESIGN_JSON_TYPES[k])}  # fmt: skip

    def attempt(name: str, reader: Callable[[Path], Any]) -> Any:
        if not (folder / name).is_file():
            return None
        try:
            return reader(folder / name)
        except (InputError, OSError, ValueError) as err:
            problems.append(f"{name} could not be read: {err}")
            return None

    assembled = attempt("assembled.obj", read_obj_tiles)
    assembled_source = "assembled.obj"
    if assembled is None and not (folder / "assembled.obj").exists():
        quads = attempt("lifted.obj", read_obj_quads)
        if quads is not None:  # the lifted grid stands in, as tiles without thickness
            assembled = np.concatenate([quads, quads], axis=1)
            assembled_source = "lifted.obj"
    flat = attempt("flat.obj", read_obj_tiles)
    frames = attempt("deploy.npz", read_deploy_frames)
    route = attempt("route.json", read_route)
    fit = attempt("tiles.npz", read_tile_fit)
    counts = {len(x) for x in (assembled, flat) if x is not None}
    if frames is not None:
        counts.add(frames.shape[1])
    if len(counts) > 1:
        problems.append(
            f"the files disagree on the number of tiles ({sorted(counts)}); the 3D view shows "
            "the assembled and flat poses only"
        )
        frames = None
    if fit is not None and counts and len(fit) not in counts:
        problems.append("tiles.npz's surface distances do not match the tiles; not shown")
        fit = None
    return FolderContents(
        folder, design, assembled, flat, frames, route, tuple(problems), assembled_source, fit
    )


def _neighbours(
    found: FolderContents, n_tiles: int
) -> tuple[list[list[int]], list[list[int]], str]:
    """Hinges (with side) and neighbour lists, from the best source the folder has."""
    design_hinges = found.design.get("linkage", {}).get("hinges")
    if isinstance(design_hinges, list) and design_hinges:
        hinges = np.asarray(design_hinges, dtype=np.int64).reshape(-1, 4)
        sides_raw = found.design.get("linkage", {}).get("hinge_side") or []
        side = [1 if s == HingeSide.BOTTOM else 0 if s == HingeSide.TOP else 2 for s in sides_raw]
        side += [2] * (len(hinges) - len(side))
        rule = "sharing a hinge"
    elif found.flat is not None:
        hinges, side_arr = hinges_from_flat(found.flat)
        side = side_arr.tolist()
        rule = "sharing a hinge"
    elif found.assembled is not None:
        pairs = touching_tiles(found.assembled)
        return [], neighbour_lists(n_tiles, pairs), "touching along an edge"
    else:
        return [], [[] for _ in range(n_tiles)], "none known"
    rows = [
        [int(a), int(ca), int(b), int(cb), int(s)]
        for (a, ca, b, cb), s in zip(hinges, side, strict=True)
    ]
    return rows, neighbour_lists(n_tiles, hinges[:, [0, 2]]), rule


def view_data(found: FolderContents) -> dict[str, Any]:
    """The 3D view's data: both poses, deployment frames, hinges, neighbours and route."""
    n_tiles = next(
        (len(x) for x in (found.assembled, found.flat) if x is not None),
        found.frames.shape[1] if found.frames is not None else 0,
    )
    hinges, neighbours, rule = _neighbours(found, n_tiles)
    frames = None if found.frames is None else subsample_frames(found.frames)
    route = None
    if found.route is not None and len(found.route.steps):
        steps = found.route.steps
        ok = (steps[:, 1] >= 0) & (steps[:, 1] < n_tiles)
        ok &= (steps[:, 2:] >= 0).all(axis=1) & (steps[:, 2:] < 4).all(axis=1)
        lift = found.route.lift[(found.route.lift[:, 1] >= 0) & (found.route.lift[:, 1] < n_tiles)]
        route = {"steps": steps[ok].tolist(), "lift": lift.tolist()}
    return {
        "tiles": int(n_tiles),
        "poses": {
            "flat": None if found.flat is None else _rounded(found.flat),
            "assembled": None if found.assembled is None else _rounded(found.assembled),
        },
        "frames": None if frames is None else [_rounded(f) for f in frames],
        "frames_in_file": None if found.frames is None else int(len(found.frames)),
        "hinges": hinges,
        "neighbours": neighbours,
        "neighbour_rule": rule,
        "route": route,
        "assembled_source": found.assembled_source,
        "fit": None if found.fit is None else _fit_view(found),
    }


def _fit_view(found: FolderContents) -> dict[str, Any]:
    """The 3D view's distance colouring: per tile the mean and largest distance of its top
    face from the target (mm), and the quality level of the mean (mm; 0 where unknown)."""
    assert found.fit is not None
    side = found.design.get("metrics", {}).get("tile_side_mean_mm")
    level = SURFACE_MEAN_REL * float(side) if isinstance(side, int | float) else 0.0
    return {
        "mean": np.round(found.fit[:, 0], 3).tolist(),
        "max": np.round(found.fit[:, 1], 3).tolist(),
        "level": round(level, 3),
        "level_pct": round(100 * SURFACE_MEAN_REL, 3),
    }


def _rounded(array: FloatArray) -> list[Any]:
    """A flat list of coordinates rounded to :data:`GEOMETRY_DECIMALS`."""
    return np.round(np.asarray(array, dtype=float), GEOMETRY_DECIMALS).reshape(-1).tolist()
