"""Reading a design's output folder, and the geometry the report measures on it.

Readers for the folder's files (``assembled.obj``, ``flat.obj``, ``lifted.obj``,
``deploy.npz``, ``route.json``, the print jobs of ``fabrication/manifest.json``) and the
measurements the report derives from the tiles: hinges of the flat layout, touching tiles of the
assembled pose, neighbour lists, tile volumes and the subsampling of deployment frames.  Used by
the report (:mod:`drawstring.output.report`) and the command line.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import TILE_FACES
from drawstring.geometry.core.types import FloatArray, IntArray

#: At most this many coordinates of deployment frames are inlined (F * T * 24); more frames are
#: subsampled evenly, keeping the first (flat) and the last (assembled).
MAX_FRAME_VALUES = 1_000_000
#: Tile corners of different tiles closer than this fraction of the median tile edge coincide
#: (a hinge in the flat pose, a shared corner in the assembled pose).
COINCIDENT_CORNER_REL = 0.02


# ----------------------------------------------------------------------------------------------
# Reading the output folder
# ----------------------------------------------------------------------------------------------

#: The type of every top-level entry of ``design.json`` (see the output contract in README).
DESIGN_JSON_TYPES: dict[str, type] = {
    "drawstring_version": str,
    "target": dict,
    "options": dict,
    "profile": str,
    "linkage": dict,
    "metrics": dict,
    "quality": dict,
    "notes": list,
    "problems": list,
    "warnings": list,
    "timings_s": dict,
    "files": list,
}


def _json_kind(value: Any) -> str:
    """The JSON name of a parsed value's type."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    names = {dict: "an object", list: "an array", str: "a string", int: "a number"}
    return names.get(type(value), "a number" if isinstance(value, float) else type(value).__name__)


def design_json_faults(doc: Any) -> list[str]:
    """What is wrong with the shape of a parsed ``design.json`` (empty: nothing): not an
    object, or a top-level entry of another type than the output contract's.  Entries that
    are missing are not faults here (a reader asks for those it needs)."""
    if not isinstance(doc, dict):
        return [f"design.json holds {_json_kind(doc)}, not an object"]
    return [
        f"design.json's '{key}' is {_json_kind(doc[key])}, not {_json_kind(kind())}"
        for key, kind in DESIGN_JSON_TYPES.items()
        if key in doc and not isinstance(doc[key], kind)
    ]


def read_obj_tiles(path: Path) -> FloatArray:
    """Tiles of an output OBJ (``assembled.obj``, ``flat.obj``).

    Parameters
    ----------
    path : OBJ written by the pipeline: 8 vertices per tile in tile order, top corners 0..3
        then bottom corners 4..7.

    Returns
    -------
    tiles : (T, 8, 3) float, mm.

    Raises
    ------
    InputError
        If the file holds no vertices or a vertex count that is not a multiple of 8.
    """
    rows = [
        line.split()[1:4]
        for line in path.read_text(encoding="utf-8").splitlines()
        if line.startswith("v ")
    ]
    vertices = np.asarray(rows, dtype=float).reshape(-1, 3)
    if len(vertices) == 0 or len(vertices) % 8:
        raise InputError(
            f"{path.name} has {len(vertices)} vertices, not 8 per tile; rerun drawstring design"
        )
    return vertices.reshape(-1, 8, 3)


def read_obj_quads(path: Path) -> FloatArray:
    """Quads of ``lifted.obj`` (one quad per tile, tile order), as (T, 4, 3) float, mm.

    Raises
    ------
    InputError
        If a face is not a quad or refers to a missing vertex.
    """
    vertices: list[list[str]] = []
    faces: list[list[int]] = []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.startswith("v "):
            vertices.append(line.split()[1:4])
        elif line.startswith("f "):
            faces.append([int(item.split("/")[0]) - 1 for item in line.split()[1:]])
    points = np.asarray(vertices, dtype=float).reshape(-1, 3)
    if not faces or any(len(f) != 4 for f in faces) or np.max(faces) >= len(points):
        raise InputError(f"{path.name} does not hold one quad per tile; rerun drawstring design")
    return points[np.asarray(faces, dtype=np.int64)]


def read_deploy_frames(path: Path) -> FloatArray:
    """Deployment frames of ``deploy.npz``: key ``frames``, (F, T, 8, 3) float, mm."""
    with np.load(path) as npz:
        if "frames" not in npz.files:
            raise InputError(f"{path.name} has no 'frames' array; rerun drawstring design")
        frames = np.asarray(npz["frames"], dtype=float)
    if frames.ndim != 4 or frames.shape[2:] != (8, 3) or frames.shape[0] < 1:
        raise InputError(
            f"{path.name} frames have shape {frames.shape}, not (F, T, 8, 3); "
            "rerun drawstring design"
        )
    return frames


def read_tile_fit(path: Path) -> FloatArray | None:
    """Per tile, the mean and the largest distance of its top face from the target (mm),
    ``tiles.npz``'s ``surface_distance_mean_mm`` and ``surface_distance_max_mm`` as (T, 2);
    None for a ``tiles.npz`` without them."""
    with np.load(path) as npz:
        if "surface_distance_mean_mm" not in npz.files:
            return None
        mean = np.asarray(npz["surface_distance_mean_mm"], dtype=float).reshape(-1)
        if "surface_distance_max_mm" in npz.files:
            largest = np.asarray(npz["surface_distance_max_mm"], dtype=float).reshape(-1)
        else:
            largest = mean
    if len(largest) != len(mean) or not np.all(np.isfinite(mean) & np.isfinite(largest)):
        raise InputError(f"{path.name} has malformed surface distances; rerun drawstring design")
    return np.stack([mean, largest], axis=1)


@dataclass(frozen=True)
class Route:
    """The string route of ``route.json``.

    Attributes
    ----------
    steps : (S, 4) int, ``(gap or -1, tile, enter_side, leave_side)`` in pulling order (closed).
    lift : (L, 2) int, ``(gap, tile)`` of every lift point; the string leaves through the top
        face of ``tile`` (``-1`` where the file does not say).
    length_mm : string length when the file gives it, else ``None``.
    """

    steps: IntArray
    lift: IntArray
    length_mm: float | None


def _step_row(item: Any) -> list[int]:
    if isinstance(item, dict):
        keys = (("gap",), ("tile",), ("enter_side", "enter"), ("leave_side", "leave"))
        values = [next((item[k] for k in names if k in item), None) for names in keys]
        if values[1] is None or values[2] is None or values[3] is None:
            raise ValueError(f"route step {item} lacks tile, enter_side or leave_side")
        return [int(v) if v is not None else -1 for v in values]
    row = [int(v) for v in item]
    if len(row) != 4:
        raise ValueError(f"route step {item} is not (gap, tile, enter_side, leave_side)")
    return row


def _lift_row(item: Any) -> list[int]:
    if isinstance(item, dict):
        return [int(item.get("gap", -1)), int(item.get("tile", -1))]
    if isinstance(item, int | float):
        return [int(item), -1]
    row = [int(v) for v in item]
    return row if len(row) == 2 else [row[0], -1]


def read_route(path: Path) -> Route:
    """Parse ``route.json`` (steps as 4-lists or dicts; lift points as dicts or pairs).

    Raises
    ------
    InputError
        If the file is not valid JSON or its steps cannot be read.
    """
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        steps_raw = raw if isinstance(raw, list) else raw.get("steps", raw.get("route", []))
        steps = [_step_row(s) for s in steps_raw]
        lift_raw = [] if isinstance(raw, list) else _first(raw, "lift", "lift_points", "lifts")
        lift = [_lift_row(x) for x in lift_raw or []]
        length = None if isinstance(raw, list) else _first(raw, "length_mm", "string_length_mm")
    except (ValueError, TypeError, AttributeError) as err:
        raise InputError(f"{path.name} cannot be read ({err}); rerun drawstring design") from err
    # A lift point given by its gap only: take the tile the route passes at that gap.
    step_arr = np.asarray(steps, dtype=np.int64).reshape(-1, 4)
    for row in lift:
        if row[1] < 0:
            at_gap = step_arr[step_arr[:, 0] == row[0], 1]
            row[1] = int(at_gap[0]) if len(at_gap) else -1
    return Route(
        steps=step_arr,
        lift=np.asarray(lift, dtype=np.int64).reshape(-1, 2),
        length_mm=float(length) if isinstance(length, int | float) else None,
    )


def _first(mapping: dict[str, Any], *keys: str) -> Any:
    return next((mapping[k] for k in keys if k in mapping), None)


def print_job_counts(folder: Path) -> tuple[int, int]:
    """Print jobs and beds listed in a design folder's ``fabrication/manifest.json`` (0, 0
    without one)."""
    try:
        manifest = json.loads((folder / "fabrication" / "manifest.json").read_text())
        jobs = [job for job in manifest.get("print_jobs", []) if isinstance(job, dict)]
    except (OSError, ValueError, AttributeError):
        return 0, 0
    return len(jobs), len({job.get("bed", 1) for job in jobs})


# ----------------------------------------------------------------------------------------------
# Geometry measured for the page
# ----------------------------------------------------------------------------------------------


def median_edge_length(tiles: FloatArray) -> float:
    """Median length (mm) of the top-face edges of (T, 8, 3) tiles."""
    top = tiles[:, :4]
    return float(np.median(np.linalg.norm(np.roll(top, -1, axis=1) - top, axis=2)))


def coincident_corners(tiles: FloatArray, rel_tol: float = COINCIDENT_CORNER_REL) -> IntArray:
    """Pairs of corners of different tiles that coincide.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm.
    rel_tol : distance below which two corners coincide, as a fraction of the median edge.

    Returns
    -------
    pairs : (P, 4) int, rows ``(tile_a, vertex_a, tile_b, vertex_b)`` with ``tile_a < tile_b``
        and vertex ids 0..7.
    """
    points = tiles.reshape(-1, 3)
    tol = rel_tol * median_edge_length(tiles)
    found = cKDTree(points).query_pairs(max(tol, 1e-9), output_type="ndarray")
    found = found[found[:, 0] // 8 != found[:, 1] // 8]
    a, b = found.min(axis=1), found.max(axis=1)
    rows = np.stack([a // 8, a % 8, b // 8, b % 8], axis=1).astype(np.int64)
    order = np.lexsort(rows.T[::-1])
    return rows[order].reshape(-1, 4)


def hinges_from_flat(tiles_flat: FloatArray) -> tuple[IntArray, IntArray]:
    """Hinges of a flat layout: tile corners of two tiles at the same place.

    In the flat pose hinged corners coincide and every other pair of corners is apart (gaps
    are open), so coincidence finds the hinges.

    Returns
    -------
    hinges : (H, 4) int, ``(tile_a, corner_a, tile_b, corner_b)``, corners 0..3.
    side : (H,) int, 0 the top corners coincide, 1 the bottom ones, 2 both.
    """
    pairs = coincident_corners(tiles_flat)
    if len(pairs) == 0:
        return np.zeros((0, 4), np.int64), np.zeros(0, np.int64)
    key = np.stack([pairs[:, 0], pairs[:, 1] % 4, pairs[:, 2], pairs[:, 3] % 4], axis=1)
    is_bottom = (pairs[:, 1] >= 4) & (pairs[:, 3] >= 4)
    is_top = (pairs[:, 1] < 4) & (pairs[:, 3] < 4)
    keep = is_top | is_bottom
    key, is_bottom = key[keep], is_bottom[keep]
    hinges, inverse = np.unique(key, axis=0, return_inverse=True)
    inverse = inverse.reshape(-1)
    bottom = np.zeros(len(hinges), bool)
    top = np.zeros(len(hinges), bool)
    np.logical_or.at(bottom, inverse, is_bottom)
    np.logical_or.at(top, inverse, ~is_bottom)
    side = np.where(top & bottom, 2, np.where(bottom, 1, 0)).astype(np.int64)
    return hinges.astype(np.int64), side


def touching_tiles(tiles_assembled: FloatArray) -> IntArray:
    """Pairs of tiles sharing a top edge (two top corners) in the assembled pose.

    Returns
    -------
    pairs : (P, 2) int, ``tile_a < tile_b``.
    """
    pairs = coincident_corners(tiles_assembled)
    pairs = pairs[(pairs[:, 1] < 4) & (pairs[:, 3] < 4)]
    tile_pairs, counts = np.unique(pairs[:, [0, 2]], axis=0, return_counts=True)
    return tile_pairs[counts >= 2].reshape(-1, 2).astype(np.int64)


def neighbour_lists(n_tiles: int, pairs: IntArray) -> list[list[int]]:
    """Sorted neighbour ids of every tile from (P, 2) tile pairs."""
    out: list[set[int]] = [set() for _ in range(n_tiles)]
    for a, b in np.asarray(pairs, dtype=np.int64).reshape(-1, 2):
        if 0 <= a < n_tiles and 0 <= b < n_tiles and a != b:
            out[a].add(int(b))
            out[b].add(int(a))
    return [sorted(s) for s in out]


def tile_volumes(tiles: FloatArray) -> FloatArray:
    """Volume (mm^3) of every closed (T, 8, 3) tile, by the divergence theorem."""
    quads = tiles[:, TILE_FACES]  # (T, 6, 4, 3)
    a, b, c, d = (quads[:, :, k] for k in range(4))
    signed = np.einsum("tfi,tfi->t", a, np.cross(b, c)) + np.einsum("tfi,tfi->t", a, np.cross(c, d))
    return np.abs(signed) / 6.0


def subsample_frames(frames: FloatArray, max_values: int = MAX_FRAME_VALUES) -> FloatArray:
    """At most ``max_values`` coordinates of (F, T, 8, 3) frames; first and last kept."""
    per_frame = max(1, int(np.prod(frames.shape[1:])))
    keep = max(2, max_values // per_frame)
    if len(frames) <= keep:
        return frames
    return frames[np.unique(np.linspace(0, len(frames) - 1, keep).round().astype(int))]
