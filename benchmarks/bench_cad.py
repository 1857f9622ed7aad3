"""CAD stage: B-rep tiles with every feature (issue 7).

Target: 200 tiles with channels, lift bores, TPU hinge pads with pins, a magnet pair, trims and
labels in <= 30 s on 2 cores, growing linearly.  ``run()`` builds the synthetic cylinder design
(:func:`cad_sample.cylinder_design`) at 50 and 200 tiles and reports wall time, the
CPU time of the whole process tree (so the numbers mean something on a busy machine), seconds per
tile and counts, then the same for the solid checks (validity, interference tiles-tiles and
tiles-pads on one shared tessellation per solid).  ``python benchmarks/bench_cad.py`` prints
the rows.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import sys
import time
from pathlib import Path as _Path
from typing import Any

# the synthetic scenes and designs the tests use live beside them
sys.path.insert(0, str(_Path(__file__).resolve().parents[1] / "tests"))

from cad_sample import cylinder_design  # noqa: E402

from drawstring.cad import checks
from drawstring.cad.design import build_design_solids
from drawstring.fabrication.profiles import load_profile, print_clearance_mm

TARGET_S = 30.0
CASES = ((5, 10), (10, 20))


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def run(cases: tuple[tuple[int, int], ...] = CASES, workers: int | None = None) -> list[dict]:
    """One row per grid size: wall and CPU seconds of ``build_design_solids``."""
    # 3 mm magnets: the shipped 6 mm ones do not fit the 6 mm thick tiles' side faces.
    profile = dataclasses.replace(
        load_profile("fdm-dual"), magnet_diameter_mm=3.0, magnet_height_mm=1.5
    )
    rows: list[dict[str, Any]] = []
    for cells in cases:
        design = cylinder_design(cells, radius=30.0 * cells[0])
        cpu_start, wall_start = _cpu_seconds(), time.perf_counter()
        result = build_design_solids(
            *design.solid_inputs(),
            profile,
            workers=workers,
            print_clearance_mm=print_clearance_mm(profile),  # hinge reliefs, as designs run
        )
        wall = time.perf_counter() - wall_start
        cpu = _cpu_seconds() - cpu_start
        tiles = len(result.tiles)
        # The checks measure_cad runs on the flat solids (one tessellation per solid, reused).
        check_cpu, check_wall = _cpu_seconds(), time.perf_counter()
        all_valid = bool(
            checks.check_valid(result.tiles).all() and checks.check_valid(result.pads).all()
        )
        meshes = [checks.to_manifold(solid) for solid in result.tiles]
        overlap = max(
            checks.interference(meshes).max_volume,
            checks.interference(meshes, result.pads).max_volume,
        )
        check_wall = time.perf_counter() - check_wall
        check_cpu = _cpu_seconds() - check_cpu
        rows.append(
            {
                "case": f"cylinder {cells[0]}x{cells[1]}",
                "tiles": tiles,
                "pads": len(result.pads),
                "route_steps": len(design.route_steps),
                "trims": len(design.trims),
                "workers": workers or os.cpu_count(),
                "wall_s": round(wall, 2),
                "cpu_s": round(cpu, 2),
                "cpu_s_per_tile": round(cpu / tiles, 4),
                "target_s": TARGET_S if tiles >= 200 else None,
                "checks_wall_s": round(check_wall, 2),
                "checks_cpu_s": round(check_cpu, 2),
                "interference_max_mm3": round(overlap, 6),
                "all_valid": all_valid,
                "notes": len(result.notes),
            }
        )
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
