"""A sweep's scaling with the local cluster's worker processes (issue 49).

Target: a 12-variant sweep of the saddle without CAD (two profiles x three tile counts x both
hinge strategies, with the simulation) finishes at least 1.6x faster on 2 local workers than
on 1, on a 2-core machine.  Each run is ``drawstring sweep ... --workers N`` in a process of its
own, timed from its start to its exit (cluster start and stop included).  The machine's load
average before each run is recorded beside it: other work on the machine takes cores from the
workers.  The two runs' folders are compared: the same files, byte for byte, timings aside.

``python benchmarks/bench_sweep.py`` prints the rows and stores them under ``sweep`` in
``benchmarks/results.json`` (``run.py --sweep`` does the same).
"""

from __future__ import annotations

import csv
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
TARGET_SPEEDUP = 1.6
SWEEP = [
    "saddle", "--profile", "fdm-dual,laser-epdm", "--tiles", "60,100,140", "--hinges",
    "dual,top", "--no-cad", "--quiet",
]  # fmt: skip


def _sweep(out: Path, workers: int) -> float:
    """Wall seconds of one ``drawstring sweep`` run with ``workers`` local workers."""
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "drawstring.app.cli", "sweep", *SWEEP, "--workers", str(workers)]
        + ["--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    seconds = time.perf_counter() - start
    if done.returncode not in (0, 3):
        raise RuntimeError(f"the sweep failed ({done.returncode}): {done.stderr}")
    return seconds


#: report.html's cell of design.json's size, which its timings change.
DESIGN_JSON_SIZE = re.compile(rb"(<a href='design.json'>design.json</a></td><td class=num>)[^<]*")


def _same(a: Path, b: Path) -> bool:
    """Whether two sweeps wrote the same variant folders (design.json's timings aside, and
    with them its size shown in report.html)."""
    for folder in sorted(p for p in a.iterdir() if p.is_dir()):
        for path in sorted(p for p in folder.rglob("*") if p.is_file()):
            other = b / path.relative_to(a)
            if path.name == "design.json":
                docs = [json.loads(p.read_text()) for p in (path, other)]
                for doc in docs:
                    doc.pop("timings_s")
                if docs[0] != docs[1]:
                    return False
            elif path.name == "report.html":
                pages = [DESIGN_JSON_SIZE.sub(rb"\1", p.read_bytes()) for p in (path, other)]
                if pages[0] != pages[1]:
                    return False
            elif path.read_bytes() != other.read_bytes():
                return False
    return True


def sweep_rows() -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    with tempfile.TemporaryDirectory(prefix="bench-sweep-") as tmp:
        outs = {}
        for workers in (1, 2):
            out = Path(tmp) / f"w{workers}"
            load = os.getloadavg()[0]
            seconds = _sweep(out, workers)
            with (out / "sweep.csv").open(newline="") as f:
                table = list(csv.DictReader(f))
            outs[workers] = out
            rows.append(
                {
                    "case": "saddle, 2 profiles x 3 tile counts x 2 hinges, no CAD",
                    "variants": len(table),
                    "workers": workers,
                    "wall_s": round(seconds, 1),
                    "variants_s": round(sum(float(r["design_s"]) for r in table), 1),
                    "exit_0": sum(r["status"] == "0" for r in table),
                    "load_before": round(load, 2),
                    "load_after": round(os.getloadavg()[0], 2),
                    "cores": os.cpu_count(),
                }
            )
        speedup = rows[0]["wall_s"] / rows[1]["wall_s"]
        rows[1]["speedup"] = round(speedup, 2)
        rows[1]["target_speedup"] = TARGET_SPEEDUP
        rows[1]["same_folders"] = _same(outs[1], outs[2])
    return rows


def store(rows: list[dict[str, Any]]) -> None:
    """Put the rows under ``sweep`` in ``results.json``, keeping every other row."""
    path = HERE / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    results["sweep"] = rows
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    found = sweep_rows()
    for row in found:
        print(row)
    store(found)
