"""Benchmark of the flat layout and hinge stages (issue 4): time and verified metrics.

Fixture: a square grid over a 200 mm patch lifted onto an analytic height field (saddle, dome)
or wrapped on a cylinder from inside, tiles 4 mm thick (``verify.heightfield_tiles``).
Run ``python benchmarks/bench_flat.py`` to print one row per case.  Timings are wall clock
(``*_s``) and process CPU time (``*_cpu_s``); on a shared machine the CPU time is the steadier
one.  Set ``OPENBLAS_NUM_THREADS=1`` for comparable numbers.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from drawstring.geometry.flat.layout import extrude_flat, optimize_flat
from drawstring.geometry.flat.verify import (
    flat_edge_errors,
    flat_overlap,
    gap_opening_angles_deg,
    heightfield_tiles,
    hinge_gaps,
    interpenetration,
)
from drawstring.geometry.hinges.placement import layout_hinges
from drawstring.geometry.tiling.linkage import build_linkage

CASES: tuple[tuple[str, float], ...] = (
    ("saddle", 0.002),
    ("dome", 0.002),
    ("cylinder_inside", 150.0),
)


def run(sizes: tuple[int, ...] = (14, 40), min_gap_angle_deg: float = 10.0) -> list[dict[str, Any]]:
    """One row per (surface, grid size): timings (s) and independently verified metrics."""
    rows: list[dict[str, Any]] = []
    for n in sizes:
        linkage = build_linkage(np.ones((n, n), dtype=bool))
        uv = linkage.vertex_ij * (200.0 / n) - 100.0
        for surface, parameter in CASES:
            top, t3 = heightfield_tiles(uv, linkage.tile_corners, surface, 4.0, parameter)
            start, cpu = time.perf_counter(), time.process_time()
            flat = optimize_flat(
                linkage, top, uv=uv, min_gap_angle_deg=min_gap_angle_deg, tiles_3d=t3
            )
            t_flat = time.perf_counter() - start
            c_flat = time.process_time() - cpu
            start, cpu = time.perf_counter(), time.process_time()
            t2 = extrude_flat(flat, t3)
            layout = layout_hinges(linkage, flat, t2, t3, strategy="dual")
            t_hinges = time.perf_counter() - start
            c_hinges = time.process_time() - cpu
            angles = gap_opening_angles_deg(linkage, flat.corners)
            rows.append(
                {
                    "surface": surface,
                    "tiles": linkage.n_tiles,
                    "flat_s": round(t_flat, 3),
                    "hinges_s": round(t_hinges, 3),
                    "flat_cpu_s": round(c_flat, 3),
                    "hinges_cpu_s": round(c_hinges, 3),
                    "flat_overlap_area_mm2": flat_overlap(flat.corners)[0],
                    "flat_edge_error_max_mm": float(flat_edge_errors(flat.corners, top).max()),
                    "flat_gap_angle_min_deg": float(angles.min()),
                    "flat_gap_angle_max_deg": float(angles.max()),
                    "bottom_hinges": int(layout.bottom.sum()),
                    "hinge_gap_max_mm": layout.hinge_gap_max_mm,
                    "hinge_gap_after_merge_mm": float(
                        hinge_gaps(layout.tiles, layout.hinge_vertices).max()
                    ),
                    "interpenetration_mm3": interpenetration(layout.tiles)[0],
                    "problems": len(flat.problems) + len(layout.problems),
                }
            )
    return rows


if __name__ == "__main__":
    for row in run():
        print(
            " ".join(f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items())
        )
