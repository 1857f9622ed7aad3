"""Fabrication exports (issue 8): every file of each profile for a 200-tile design.

Target: all exports for 200 tiles <= 30 s on 2 cores (the CAD build is timed by bench_cad.py
and is not included).  ``run()`` builds the synthetic cylinder design
(:func:`cad_sample.cylinder_design`, 10 x 20 cells) once per profile, then times
:func:`drawstring.fabrication.exports.write_fabrication`: wall time, CPU time of the process tree,
files and bytes written.  ``python benchmarks/bench_exports.py`` prints the rows.
"""

from __future__ import annotations

import dataclasses
import os
import resource
import sys
import tempfile
import time
from pathlib import Path
from pathlib import Path as _Path
from typing import Any

import numpy as np

# the synthetic scenes and designs the tests use live beside them
sys.path.insert(0, str(_Path(__file__).resolve().parents[1] / "tests"))

from cad_sample import cylinder_design  # noqa: E402

from drawstring.cad.design import build_design_solids
from drawstring.cad.tiles import move_solid
from drawstring.fabrication.exports import write_fabrication
from drawstring.fabrication.profiles import load_profile
from drawstring.output.assembly_guide import write_guide

TARGET_S = 30.0
CELLS = (10, 20)
PROFILES = ("fdm-dual", "laser-epdm", "plywood-cnc")


def _cpu_seconds() -> float:
    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def run(
    cells: tuple[int, int] = CELLS,
    profiles: tuple[str, ...] = PROFILES,
    workers: int | None = None,
) -> list[dict]:
    """One row per profile: CAD build time (not part of the target) and export time."""
    rows: list[dict[str, Any]] = []
    for name in profiles:
        if name == "plywood-cnc":
            design = cylinder_design(cells, side=300.0, thickness=60.0, radius=600.0 * cells[0])
            profile = load_profile(name)
        else:
            design = cylinder_design(cells, radius=30.0 * cells[0])
            profile = dataclasses.replace(
                load_profile(name), magnet_diameter_mm=3.0, magnet_height_mm=1.5
            )
        start = time.perf_counter()
        flat = build_design_solids(
            *design.solid_inputs(),
            profile,
            workers=workers,
        )
        assembled = dataclasses.replace(
            flat,
            pose="assembled",
            tiles=tuple(move_solid(s, m) for s, m in zip(flat.tiles, flat.transforms, strict=True)),
            pads=(),
            pad_hinge=np.zeros(0, dtype=np.int64),
        )
        cad_s = time.perf_counter() - start
        with tempfile.TemporaryDirectory(prefix="drawstring-bench-") as folder:
            cpu_start, wall_start = _cpu_seconds(), time.perf_counter()
            files = write_fabrication(
                Path(folder),
                profile=profile,
                linkage=design.linkage,
                tiles_flat=design.tiles_2d,
                tiles_assembled=design.tiles_3d,
                hinge_side=design.hinge_side,
                route_steps=design.route_steps,
                lift_tiles=design.lift_tiles,
                magnet_pairs=design.magnet_pairs,
                trims=design.trims,
                cad_flat=flat,
                cad_assembled=assembled,
                design_name="bench",
                guide=write_guide,
                workers=workers,
            )
            wall = time.perf_counter() - wall_start
            cpu = _cpu_seconds() - cpu_start
            size = sum((Path(folder) / f).stat().st_size for f in files)
        rows.append(
            {
                "profile": name,
                "tiles": len(flat.tiles),
                "hinge_parts": len(flat.pads),
                "workers": workers or os.cpu_count(),
                "cad_s_not_counted": round(cad_s, 2),
                "export_wall_s": round(wall, 2),
                "export_cpu_s": round(cpu, 2),
                "target_s": TARGET_S,
                "files": len(files),
                "megabytes": round(size / 1e6, 2),
            }
        )
    return rows


if __name__ == "__main__":
    for row in run():
        print(row)
