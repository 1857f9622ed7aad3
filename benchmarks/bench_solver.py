"""Benchmark of the local-global solver and the assembled stage, with and without Anderson.

``run(cores_note)`` returns one row per (stage, case, tile count, Anderson setting); the lead's
``benchmarks/run.py`` records them. Cases are self-contained (no files read):

- ``solver / warped-grid``: a 40 x 40 (1600-quad) regular grid over 200 mm warped by a smooth
  height field, solved for planarity (w = 1e4) plus closeness to its start (w = 1), the setting
  of the libigl ``planarize_quad_mesh`` comparison in issue 3; then the exact planarity polish.
- ``assembled / saddle, dome, wave``: a regular grid lifted onto a height field over a 200 mm
  patch (14 x 14 = 196 and 40 x 40 = 1600 tiles), target = a finer triangulation of the same
  field, default (paper) weights, tile thickness 3 mm (1.5 mm at 1600 tiles).

``time_s`` is wall time; ``cpu_s`` is this process's CPU time, which is less disturbed when
other work shares the machine. Run ``python benchmarks/bench_solver.py`` to print the rows as
JSON.
"""

from __future__ import annotations

import json
import os
import time
from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.assembled import optimize_assembled
from drawstring.geometry.solver import (
    ClosenessToPoints,
    LocalGlobalSolver,
    Plane,
    planarize_quads,
    quad_planarity,
)

Field = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]

PATCH_MM = 200.0

FIELDS: dict[str, Field] = {
    "saddle": lambda x, y: x * y / 250.0,
    "dome": lambda x, y: np.sqrt(180.0**2 - x**2 - y**2),
    "wave": lambda x, y: 12.0 * np.sin(2 * np.pi * x / 160.0) * np.cos(2 * np.pi * y / 220.0),
}


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


def height_field_case(
    field: Field, n: int
) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64], NDArray[np.int64]]:
    """Lifted grid (n x n quads) and a finer target triangulation of the same height field."""
    uv, quads = grid(n, PATCH_MM / 2)
    fine_uv, fine_quads = grid(120, 0.55 * PATCH_MM)
    triangles = np.vstack([fine_quads[:, [0, 1, 2]], fine_quads[:, [0, 2, 3]]])
    vertices = np.c_[uv, field(uv[:, 0], uv[:, 1])]
    target = np.c_[fine_uv, field(fine_uv[:, 0], fine_uv[:, 1])]
    return vertices, quads, target, triangles


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


def assembled_row(name: str, n: int, anderson: int, cores_note: str) -> dict[str, object]:
    """The assembled stage (K3D + extrusion) on one lifted height field."""
    vertices, quads, target, triangles = height_field_case(FIELDS[name], n)
    thickness = 3.0 if n <= 20 else 1.5
    cpu_start = time.process_time()
    result = optimize_assembled(
        vertices, quads, target, triangles, thickness=thickness, anderson=anderson
    )
    cpu = time.process_time() - cpu_start
    m = result.metrics
    top, ext = result.top_solve, result.extrusion_solve
    iterations = top.iterations + ext.iterations
    side = m["tile_side_mean_mm"]
    return {
        "stage": "assembled",
        "case": name,
        "tiles": len(quads),
        "anderson": anderson,
        "iterations": iterations,
        "top_iterations": top.iterations,
        "extrusion_iterations": ext.iterations,
        "converged": bool(top.converged and ext.converged),
        "time_s": round(result.time_s, 3),
        "cpu_s": round(cpu, 3),
        "per_iter_ms": round(1e3 * (top.time_s + ext.time_s) / max(iterations, 1), 3),
        "accelerated_accepted": top.accelerated_accepted + ext.accelerated_accepted,
        "accelerated_rejected": top.accelerated_rejected + ext.accelerated_rejected,
        "planarity_max_mm": m["planarity_max_mm"],
        "planarity_max_before_mm": m["planarity_max_before_mm"],
        "planarity_limit_mm": 1e-6 * m["bbox_diagonal_mm"],
        "contact_gap_max_mm": m["contact_gap_max_mm"],
        "contact_gap_limit_mm": 1e-3 * side,
        "contact_angle_max_deg": m["contact_angle_max_deg"],
        "surface_distance_mean_mm": m["surface_distance_mean_mm"],
        "surface_distance_max_mm": m["surface_distance_max_mm"],
        "surface_distance_limit_mm": 0.02 * side,
        "tile_side_spread": m["tile_side_spread"],
        "flipped_tiles": m["flipped_tiles"],
        "polish_move_max_mm": m["polish_move_max_mm"],
        "cores_note": cores_note,
    }


def run(cores_note: str = "") -> list[dict[str, object]]:
    """All benchmark rows (a few minutes on 2 cores; the plain runs dominate).

    Parameters
    ----------
    cores_note : str
        Free text recorded with each row (e.g. "2 cores, idle").

    Returns
    -------
    rows : list of dict
        ``stage, case, tiles, anderson, iterations, time_s, per_iter_ms`` and quality numbers.
    """
    rows: list[dict[str, object]] = []
    for anderson in (0, 5):
        rows.append(warped_grid_row(anderson, cores_note))
    for n in (14, 40):
        for name in FIELDS:
            for anderson in (0, 5):
                rows.append(assembled_row(name, n, anderson, cores_note))
    return rows


if __name__ == "__main__":
    note = f"{os.cpu_count()} cores"
    for row in run(note):
        print(json.dumps(row))
