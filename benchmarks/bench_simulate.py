"""Deployment simulation benchmark (issue 6 section 4).

Targets on 2 cores: 200 tiles deploy in <= 20 s, 1600 tiles in <= 180 s (the paper reports
5.5-6 min).  Scenes are exact frustum linkages on a cylinder patch
(:func:`sim_scene.cylinder_scene`) with the boundary loop as the route and
the centre gap as the lift point.  Each row records deployed, steps, wall time, per-step cost,
local-global iterations and factorizations.

Run ``.venv/bin/python benchmarks/bench_simulate.py [--sizes 4x4 8x8 10x20 40x40]``.
Wall time on a shared machine is noisy; ``cpu_s`` is the process CPU time.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path as _Path
from typing import Any

import numpy as np

# the synthetic scenes and designs the tests use live beside them
sys.path.insert(0, str(_Path(__file__).resolve().parents[1] / "tests"))

from sim_scene import cylinder_scene  # noqa: E402

from drawstring.geometry.simulate import deploy as S
from drawstring.geometry.simulate.inputs import lift_targets_for_gaps, route_snap_pairs
from drawstring.geometry.simulate.result import SimulationSettings

SIZES: tuple[tuple[int, int], ...] = ((4, 4), (8, 8), (10, 20), (40, 40))
TARGET_S = {200: 20.0, 1600: 180.0}


def run_one(n_i: int, n_j: int, settings: SimulationSettings | None = None) -> dict[str, Any]:
    """Simulate one cylinder scene and return its benchmark row (wall and CPU seconds)."""
    scene = cylinder_scene(n_i, n_j)
    link = scene.linkage
    pairs, gaps = route_snap_pairs(scene.route)
    centre = np.array(link.grid_shape) / 2.0
    lift_gap = int(np.argmin(np.linalg.norm(link.vertex_ij[link.gap_vertex] - centre, axis=1)))
    verts, targets = lift_targets_for_gaps(link, scene.tiles_assembled, [lift_gap])
    cpu = time.process_time()
    res = S.simulate_deployment(
        link,
        scene.tiles_flat,
        scene.tiles_assembled,
        scene.hinge_vertices,
        pairs,
        verts,
        targets,
        snap_gaps=gaps,
        thickness=scene.thickness,
        settings=settings,
        frame_every=20,
    )
    tiles = link.n_tiles
    return {
        "name": f"simulate_{n_i}x{n_j}",
        "tiles": tiles,
        "deployed": res.deployed,
        "steps": res.steps,
        "time_s": round(res.time_s, 3),
        "cpu_s": round(time.process_time() - cpu, 3),
        "per_step_ms": round(res.per_step_ms, 2),
        "cpu_per_step_ms": round(1e3 * (time.process_time() - cpu) / max(res.steps, 1), 2),
        "iterations_per_step": round(res.iterations / max(res.steps, 1), 2),
        "iterations": res.iterations,
        "factorizations": res.factorizations,
        "final_max_deviation_mm": round(res.final_max_deviation_mm, 5),
        "max_penetration_mm": round(res.max_penetration_mm, 5),
        "max_edge_error_mm": round(res.max_edge_error_mm, 5),
        "open_gaps": len(res.open_gaps),
        "reasons": list(res.reasons),
        "target_s": TARGET_S.get(tiles),
        "cores": os.cpu_count(),
    }


def run(sizes: tuple[tuple[int, int], ...] = SIZES) -> list[dict[str, Any]]:
    """Benchmark rows for every scene size."""
    return [run_one(n_i, n_j) for n_i, n_j in sizes]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", nargs="*", default=[f"{a}x{b}" for a, b in SIZES])
    args = parser.parse_args()
    sizes = tuple(tuple(int(v) for v in s.split("x")) for s in args.sizes)
    for row in run(sizes):  # type: ignore[arg-type]
        print(json.dumps(row))


if __name__ == "__main__":
    main()
