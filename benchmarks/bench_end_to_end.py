"""``drawstring design saddle`` end to end (issue 47): time, memory and the weight of its files.

The command runs as a user runs it (default options: fdm-dual, about 200 tiles, CAD and every
file) in a child process; the row holds its wall time, the CPU seconds of its process tree
(workers included) and its peak resident memory, the size of each STEP file, the triangles of
``print.3mf`` (all, and the most in one part), and, where ``prusa-slicer`` is on PATH, the wall
and CPU time of slicing ``print.3mf`` with the CLI: with the command line of the issue (the
slicer's own defaults for everything it does not set) and with the shipped ``print.ini``
(``--load``; the settings the design assumes).
Targets (2 cores): end to end <= 20 s; each STEP file <= 20 MB; slicing <= 60 s.
The machine's load averages (1, 5 and 15 minutes) when the design is written go into the row
as ``load_avg``: on a shared machine they tell how many cores the run had.
``python benchmarks/bench_end_to_end.py [--no-slice]`` prints the row and writes it to
``benchmarks/results.json`` as ``bench_end_to_end`` (with ``--no-slice``, the slicing fields
of the row there are kept, marked ``slice_from_earlier_row``); ``run.py --stages`` runs it
with the other stage benchmarks.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import shutil
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
TARGET = "saddle"
TARGET_S = 20.0
STEP_TARGET_MB = 20.0
SLICE_TARGET_S = 60.0
SLICE_ARGS = (
    "--export-gcode --bed-shape 0x0,330x0,330x240,0x240 --nozzle-diameter 0.4,0.4 "
    "--filament-diameter 1.75,1.75 --temperature 210,230 --first-layer-temperature 210,230 "
    "--center 165,120"
).split()


def _timed(command: list[str]) -> tuple[int, float, float, float]:
    """Exit status, wall seconds, CPU seconds of the process tree and peak RSS (MB) of a
    child process (its workers are its own children, reaped by it, so counted)."""
    start = time.perf_counter()
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return done.returncode, wall, cpu, after.ru_maxrss / 1024.0


def _triangles(path: Path) -> tuple[int, int]:
    """All triangles of a 3MF and the most in one part (PrusaSlicer's volume ranges)."""
    with zipfile.ZipFile(path) as archive:
        config = ET.fromstring(archive.read("Metadata/Slic3r_PE_model.config"))
    sizes = [int(v.get("lastid", 0)) - int(v.get("firstid", 0)) + 1 for v in config.iter("volume")]
    return sum(sizes), max(sizes, default=0)


def run(slice_print: bool = True) -> list[dict[str, Any]]:
    with tempfile.TemporaryDirectory(prefix="drawstring-bench-") as scratch:
        out = Path(scratch) / TARGET
        status, wall, cpu, rss = _timed(
            [sys.executable, "-m", "drawstring.app.cli", "design", TARGET, "--out", str(out)]
        )
        fabrication = out / "fabrication"
        design = json.loads((out / "design.json").read_text())
        triangles, part_max = _triangles(fabrication / "print.3mf")
        row: dict[str, Any] = {
            "case": TARGET,
            "tiles": design["metrics"]["cad"]["tiles"],
            "hinge_parts": design["metrics"]["cad"]["hinge_parts"],
            "exit": status,
            "wall_s": round(wall, 1),
            "cpu_s": round(cpu, 1),
            "peak_rss_mb": round(rss),
            "target_s": TARGET_S,
            "stages_s": design["timings_s"],
            "flat_step_mb": round((fabrication / "flat.step").stat().st_size / 1e6, 1),
            "assembled_step_mb": round((fabrication / "assembled.step").stat().st_size / 1e6, 1),
            "step_target_mb": STEP_TARGET_MB,
            "print_3mf_mb": round((fabrication / "print.3mf").stat().st_size / 1e6, 2),
            "print_3mf_triangles": triangles,
            "print_3mf_part_triangles_max": part_max,
            "slice_wall_s": None,
            "slice_cpu_s": None,
            "slice_ini_wall_s": None,
            "slice_ini_cpu_s": None,
            "slice_target_s": SLICE_TARGET_S,
            "load_avg": [round(v, 2) for v in os.getloadavg()],
        }
        slicer = shutil.which("prusa-slicer")
        if slicer and slice_print:
            gcode = Path(scratch) / "print.gcode"
            command = [slicer, *SLICE_ARGS, str(fabrication / "print.3mf"), "-o", str(gcode)]
            status, wall, cpu, _ = _timed(command)
            row.update(slice_wall_s=round(wall, 1), slice_cpu_s=round(cpu, 1))
            row["slice_exit"] = status
            ini = ["--export-gcode", "--load", str(fabrication / "print.ini")]
            status, wall, cpu, _ = _timed(
                [slicer, *ini, str(fabrication / "print.3mf"), "-o", str(gcode)]
            )
            row.update(slice_ini_wall_s=round(wall, 1), slice_ini_cpu_s=round(cpu, 1))
            row["slice_ini_exit"] = status
    return [row]


def main() -> None:
    sliced = "--no-slice" not in sys.argv[1:]
    rows = run(slice_print=sliced)
    path = HERE / "results.json"
    results: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    earlier = (results.get("bench_end_to_end") or [{}])[0]
    if not sliced and earlier.get("slice_wall_s") is not None:
        # --no-slice: the slicing numbers stay those of the row measured with slicing (the
        # slicer's time depends on print.3mf, which the design's timing does not change)
        for key, value in earlier.items():
            if key.startswith("slice_"):
                rows[0][key] = value
        rows[0]["slice_from_earlier_row"] = True
    for key, value in rows[0].items():
        print(f"{key:30} {value}")
    results["bench_end_to_end"] = rows
    results.setdefault("machine", {"cores": os.cpu_count(), "python": platform.python_version()})
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
