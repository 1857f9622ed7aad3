"""Benchmark of the local-global solver and the assembled stage, with and without Anderson.

``run(cores_note)`` returns one row per (stage, case, tile count, Anderson setting); the lead's
``benchmarks/run.py`` records them.

- ``solver / warped-grid``: a 40 x 40 (1600-quad) regular grid over 200 mm warped by a smooth
  height field, solved for planarity (w = 1e4) plus closeness to its start (w = 1), the setting
  of the libigl ``planarize_quad_mesh`` comparison in issue 3; then the exact planarity polish.
- ``assembled / <built-in>``: the real front of the pipeline on every built-in target: load at the
  default profile's size and resolution, rectangle BFF flattening (automatic corners with
  principal-direction alignment), tiling with splits at about 200 tiles (and 1600 tiles for
  saddle, dome and wave), then :func:`optimize_assembled` with the default (paper) weights and
  the profile's thickness. Each row records time, per-iteration cost, planarity, contact gap and
  the mean surface distance of K3D as a percentage of the mean tile side, next to the issue 3
  targets (``*_limit`` fields and ``meets_*`` flags). Iterations, per-iteration cost and Anderson
  counts cover every solve of the stage, including a plain K3D solve discarded for the
  convexity re-solve (``convex_resolve``; ``top_solve_iterations`` lists the K3D solves).
- ``weights / <built-in>``: K3D at ~200 tiles with the paper's weights and with the close-fit
  weights, both scored on the paper's eq. 1 energy (:func:`weights_row`): whether the paper's
  weights themselves keep K3D off the target (issue 3's 2 % surface-distance target).

``time_s`` is wall time of the assembled stage; ``cpu_s`` is this process's CPU time for it,
which is less disturbed when other work shares the machine. Run
``python benchmarks/bench_solver.py [--quick]`` to print the rows as JSON.
"""

from __future__ import annotations

import json
import os
import sys
import time

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.assembled.shape import ANDERSON_HISTORY, optimize_assembled
from drawstring.geometry.assembled.top import CLOSE_FIT_WEIGHTS, PAPER_WEIGHTS, eq1_energy
from drawstring.geometry.flatten.alignment import principal_misalignment
from drawstring.geometry.flatten.conformal import Flattening, flatten
from drawstring.geometry.solve.groups import ClosenessToPoints, Plane
from drawstring.geometry.solve.planarity import planarize_quads, quad_planarity
from drawstring.geometry.solve.solver import LocalGlobalSolver
from drawstring.geometry.target.builtins import BUILTIN_TARGETS
from drawstring.geometry.target.surface import Target, load_target
from drawstring.geometry.tiling.grid import Tiling, tile_surface
from drawstring.pipeline.layout_stage import split_bound
from drawstring.pipeline.record import DesignOptions, ResolvedOptions
from drawstring.pipeline.run import resolve_options

PATCH_MM = 200.0

#: Issue 3 targets: seconds for the assembled stage on 2 cores, by tile count.
TIME_LIMIT_S = {200: 2.0, 1600: 10.0}
#: Issue 3 quality targets (relative).
PLANARITY_LIMIT_REL_BBOX = 1e-6
CONTACT_GAP_LIMIT_REL_SIDE = 1e-3
SURFACE_DISTANCE_LIMIT_REL_SIDE = 0.02

#: Built-ins also run at 1600 tiles.
FINE_CASES = ("saddle", "dome", "wave")


def grid(n: int, half: float) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Square grid of n x n cells over [-half, half]^2: (p, 2) points, (n*n, 4) ccw quads."""
    ticks = np.linspace(-half, half, n + 1)
    x, y = np.meshgrid(ticks, ticks, indexing="ij")
    col, row = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a, b = col.ravel(), row.ravel()
    quads = np.stack(
        [a * (n + 1) + b, (a + 1) * (n + 1) + b, (a + 1) * (n + 1) + b + 1, a * (n + 1) + b + 1],
        axis=1,
    )
    return np.c_[x.ravel(), y.ravel()], quads


def warped_grid_row(anderson: int, cores_note: str) -> dict[str, object]:
    """Planarity + closeness on a smoothly warped 1600-quad grid."""
    uv, quads = grid(40, PATCH_MM / 2)
    x, y = uv[:, 0], uv[:, 1]
    z = 20.0 * np.sin(x / 30.0) * np.cos(y / 40.0) + 0.002 * x * y
    vertices = np.c_[uv, z]
    solver = LocalGlobalSolver(
        len(vertices),
        [Plane(quads, 1e4), ClosenessToPoints(np.arange(len(vertices)), vertices, 1.0)],
    )
    start, cpu_start = time.perf_counter(), time.process_time()
    result = solver.solve(vertices, rel_tol=1e-6, max_iter=5000, anderson=anderson)
    polish = planarize_quads(result.X, quads, tol_mm=1e-7)
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    return {
        "stage": "solver",
        "case": "warped-grid planarity+closeness",
        "tiles": len(quads),
        "anderson": anderson,
        "iterations": result.iterations,
        "converged": result.converged,
        "time_s": round(elapsed, 3),
        "cpu_s": round(cpu, 3),
        "solver_time_s": round(result.time_s, 3),
        "per_iter_ms": round(result.per_iteration_ms, 3),
        "accelerated_accepted": result.accelerated_accepted,
        "accelerated_rejected": result.accelerated_rejected,
        "planarity_before_mm": float(quad_planarity(vertices, quads).max()),
        "planarity_solver_mm": float(quad_planarity(result.X, quads).max()),
        "planarity_max_mm": polish.planarity_after_mm,
        "polish_iterations": polish.iterations,
        "polish_max_move_mm": polish.max_move_mm,
        "drift_max_mm": float(np.linalg.norm(polish.X - vertices, axis=1).max()),
        "cores_note": cores_note,
    }


def _front(name: str, tiles: int) -> tuple[ResolvedOptions, Target, Flattening, Tiling, float]:
    """The real front of the pipeline for a built-in at the default profile: its options, the
    loaded target, the rectangle flattening, the tiling, and the seconds flattening and tiling
    took."""
    options = DesignOptions(tiles=tiles)
    resolved = resolve_options(options, load_profile(options.profile))
    loaded = load_target(name, size_mm=resolved.size_mm, resolution=resolved.resolution)
    start = time.perf_counter()
    flat = flatten(loaded.vertices, loaded.faces, mode="rectangle", corners=resolved.corners)
    tiling = tile_surface(
        loaded.vertices,
        loaded.faces,
        flat.uv,
        tiles=tiles,
        grid=resolved.grid,
        max_scale_factor=split_bound(resolved),
    )
    return resolved, loaded, flat, tiling, time.perf_counter() - start


def assembled_row(name: str, tiles: int, anderson: int, cores_note: str) -> dict[str, object]:
    """The assembled stage (K3D + extrusion) of a built-in through the real flatten and tiling."""
    resolved, loaded, flat, tiling, front = _front(name, tiles)
    angle, _ = principal_misalignment(loaded.vertices, loaded.faces, flat.uv)
    cpu_start = time.process_time()
    result = optimize_assembled(
        tiling.vertices,
        tiling.quads,
        loaded.vertices,
        loaded.faces,
        thickness=resolved.thickness_mm,
        anderson=anderson,
    )
    cpu = time.process_time() - cpu_start
    m = result.metrics
    # every solve of the stage counts, including a plain K3D solve discarded for the convexity
    # re-solve (result.top_solve is only the last K3D solve)
    tops, ext = result.top_solves, result.extrusion_solve
    solves = (*tops, ext)
    top_iterations = sum(s.iterations for s in tops)
    iterations = top_iterations + ext.iterations
    side = m["tile_side_mean_mm"]
    n_tiles = len(tiling.quads)
    time_limit = TIME_LIMIT_S[200] if n_tiles <= 600 else TIME_LIMIT_S[1600]
    planarity_limit = PLANARITY_LIMIT_REL_BBOX * m["bbox_diagonal_mm"]
    gap_limit = CONTACT_GAP_LIMIT_REL_SIDE * side
    distance_pct = 100.0 * m["surface_distance_mean_mm"] / side
    return {
        "stage": "assembled",
        "case": name,
        "tiles": n_tiles,
        "components": tiling.linkage.n_components,
        "anderson": anderson,
        "corners": [int(c) for c in flat.corners] if flat.corners is not None else None,
        "grid_principal_angle_median_deg": float(np.nanmedian(angle)),
        "flatten_tiling_s": round(front, 3),
        "iterations": iterations,
        "top_iterations": top_iterations,
        "top_solve_iterations": [s.iterations for s in tops],
        "extrusion_iterations": ext.iterations,
        "convex_resolve": bool(m["convex_resolve"]),
        "converged": bool(tops[-1].converged and ext.converged),
        "time_s": round(result.time_s, 3),
        "cpu_s": round(cpu, 3),
        "time_limit_s": time_limit,
        "per_iter_ms": round(1e3 * sum(s.time_s for s in solves) / max(iterations, 1), 3),
        "accelerated_accepted": sum(s.accelerated_accepted for s in solves),
        "accelerated_rejected": sum(s.accelerated_rejected for s in solves),
        "planarity_max_mm": m["planarity_max_mm"],
        "planarity_max_before_mm": m["planarity_max_before_mm"],
        "planarity_limit_mm": planarity_limit,
        "contact_gap_max_mm": m["contact_gap_max_mm"],
        "contact_gap_limit_mm": gap_limit,
        "contact_angle_max_deg": m["contact_angle_max_deg"],
        "surface_distance_mean_mm": m["surface_distance_mean_mm"],
        "surface_distance_max_mm": m["surface_distance_max_mm"],
        "surface_distance_mean_pct_side": round(distance_pct, 2),
        "surface_distance_limit_pct_side": 100.0 * SURFACE_DISTANCE_LIMIT_REL_SIDE,
        "tile_side_mean_mm": side,
        "tile_side_spread": m["tile_side_spread"],
        "flipped_tiles": m["flipped_tiles"],
        "polish_move_max_mm": m["polish_move_max_mm"],
        "meets_time": bool(cpu <= time_limit),
        "meets_planarity": bool(m["planarity_max_mm"] <= planarity_limit),
        "meets_contact_gap": bool(m["contact_gap_max_mm"] <= gap_limit),
        "meets_surface_distance": bool(distance_pct <= 100.0 * SURFACE_DISTANCE_LIMIT_REL_SIDE),
        "cores_note": cores_note,
    }


def weights_row(name: str, tiles: int = 200) -> dict[str, object]:
    """Why the paper's weights leave K3D off the target (issue 3's 2 % target).

    K3D of one built-in is solved with the paper's weights and with the close-fit weights from
    the same tiling, and both results are scored on the paper's eq. 1 energy. When the close fit
    scores higher, no better solve of eq. 1 with the paper's weights brings K3D closer: the
    weights, not the solver, set the distance.
    """
    resolved, loaded, _, tiling, _ = _front(name, tiles)
    row: dict[str, object] = {"stage": "weights", "case": name, "tiles": len(tiling.quads)}
    for label, weights in (("paper", PAPER_WEIGHTS), ("close_fit", CLOSE_FIT_WEIGHTS)):
        result = optimize_assembled(
            tiling.vertices,
            tiling.quads,
            loaded.vertices,
            loaded.faces,
            thickness=resolved.thickness_mm,
            w_planar=weights[0],
            w_square=weights[1],
            w_surface=weights[2],
        )
        m = result.metrics
        energy = eq1_energy(
            tiling.vertices, result.quads, loaded.vertices, loaded.faces, result.top
        )
        row[f"{label}_surface_distance_mean_pct_side"] = round(
            100.0 * m["surface_distance_mean_mm"] / m["tile_side_mean_mm"], 2
        )
        row[f"{label}_tile_side_spread"] = round(m["tile_side_spread"], 3)
        row[f"{label}_paper_energy"] = {k: float(f"{v:.4g}") for k, v in energy.items()}
    paper = row["paper_paper_energy"]
    close = row["close_fit_paper_energy"]
    assert isinstance(paper, dict) and isinstance(close, dict)
    row["close_fit_scores_higher"] = bool(close["total"] > paper["total"])
    return row


def run(cores_note: str = "", quick: bool = False) -> list[dict[str, object]]:
    """All benchmark rows (a few minutes on 2 cores).

    The assembled rows run with the stage's default Anderson history
    (:data:`~drawstring.geometry.assembled.shape.ANDERSON_HISTORY`) and with ``anderson=0``.

    Parameters
    ----------
    cores_note : str
        Free text recorded with each row (e.g. "2 cores, idle").
    quick : bool
        Only the Anderson (default) setting and no 1600-tile rows.

    Returns
    -------
    rows : list of dict
        ``stage, case, tiles, anderson, iterations, time_s, cpu_s, per_iter_ms`` and quality
        numbers with their limits.
    """
    # the solver's default Anderson history for the warped grid, the assembled stage's own
    # default (ANDERSON_HISTORY) for its rows; and each without acceleration
    settings = (5,) if quick else (0, 5)
    stage_settings = (ANDERSON_HISTORY,) if quick else (0, ANDERSON_HISTORY)
    rows: list[dict[str, object]] = []
    for anderson in settings:
        rows.append(warped_grid_row(anderson, cores_note))
    for name in BUILTIN_TARGETS:
        for anderson in stage_settings:
            rows.append(assembled_row(name, 200, anderson, cores_note))
    if not quick:
        for name in FINE_CASES:
            for anderson in stage_settings:
                rows.append(assembled_row(name, 1600, anderson, cores_note))
        rows += [weights_row(name) for name in BUILTIN_TARGETS]
    return rows


def _summary(row: dict[str, object]) -> str:
    if row["stage"] == "weights":
        return (
            f"{row['case']:12s} weights: dist paper {row['paper_surface_distance_mean_pct_side']} "
            f"% / close fit {row['close_fit_surface_distance_mean_pct_side']} %, "
            f"close fit scores higher on eq. 1: {row['close_fit_scores_higher']}"
        )
    if row["stage"] != "assembled":
        return json.dumps(row)
    return (
        f"{row['case']:12s} tiles {row['tiles']:5d} AA {row['anderson']} "
        f"it {row['iterations']:5d} cpu {row['cpu_s']:6.2f} s ({row['per_iter_ms']:.2f} ms/it) "
        f"dist {row['surface_distance_mean_pct_side']:5.1f} % "
        f"plan {row['planarity_max_mm']:.1e} gap {row['contact_gap_max_mm']:.1e} "
        f"angle {row['grid_principal_angle_median_deg']:.1f} deg"
    )


if __name__ == "__main__":
    note = f"{os.cpu_count()} cores"
    for row in run(note, quick="--quick" in sys.argv):
        print(_summary(row) if "--table" in sys.argv else json.dumps(row))
