"""One design's CAD on a local Dask cluster against the same design on this machine's processes.

Runs ``drawstring design saddle --tiles N --size S --no-simulate`` (S keeps the default tile
side) three ways, each in a process of its own: on this machine (the CAD stage's own process
pool), then with ``--scheduler`` pointing at a local cluster of 1 and of 2 single-threaded
worker processes.  Each row has the wall time of
the run, the CAD stage's time from design.json, the machine's load average before
the run, and whether every file is the one the local run wrote, byte for byte (design.json's
timings aside, and with them its size shown in report.html).

``python benchmarks/bench_cad_cluster.py --tiles 200`` prints the rows and stores them under
``cad_cluster`` in ``benchmarks/results.json`` (rows of other tile counts are kept).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent

#: report.html's cell of design.json's size, which its timings change.
DESIGN_JSON_SIZE = re.compile(rb"(<a href='design.json'>design.json</a></td><td class=num>)[^<]*")


def size_for(tiles: int) -> float:
    """The saddle's size for ``tiles``: fdm-dual's 160 mm at its 200 tiles, scaled to keep
    the tile side (so the string channel fits), to 10 mm."""
    return float(max(160, round(160 * math.sqrt(tiles / 200) / 10) * 10))


def _design(tiles: int, out: Path, scheduler: str | None) -> dict[str, Any]:
    """One run: its wall time, stage times and load average before it."""
    command = [sys.executable, "-m", "drawstring.app.cli", "design", "saddle"]
    command += ["--tiles", str(tiles), "--size", f"{size_for(tiles):g}"]
    command += ["--no-simulate", "--quiet", "--out", str(out)]
    if scheduler is not None:
        command += ["--scheduler", scheduler]
    load = os.getloadavg()[0]
    start = time.perf_counter()
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    seconds = time.perf_counter() - start
    if done.returncode not in (0, 3, 4):
        raise RuntimeError(f"the design failed ({done.returncode}): {done.stderr}")
    timings = json.loads((out / "design.json").read_text())["timings_s"]
    return {
        "tiles": tiles,
        "size_mm": size_for(tiles),
        "wall_s": round(seconds, 1),
        "cad_s": round(float(timings.get("cad", 0.0)), 1),
        "exit": done.returncode,
        "load_before": round(load, 2),
        "load_after": round(os.getloadavg()[0], 2),
        "cores": os.cpu_count(),
    }


def same_files(a: Path, b: Path) -> bool:
    """Whether two design folders hold the same files, byte for byte (timings aside)."""
    names_a = sorted(p.relative_to(a).as_posix() for p in a.rglob("*") if p.is_file())
    names_b = sorted(p.relative_to(b).as_posix() for p in b.rglob("*") if p.is_file())
    if names_a != names_b:
        return False
    for name in names_a:
        data_a, data_b = (a / name).read_bytes(), (b / name).read_bytes()
        if name == "design.json":
            docs = [json.loads(data) for data in (data_a, data_b)]
            for doc in docs:
                doc.pop("timings_s")
            if docs[0] != docs[1]:
                return False
        elif name == "report.html":
            if DESIGN_JSON_SIZE.sub(rb"\1", data_a) != DESIGN_JSON_SIZE.sub(rb"\1", data_b):
                return False
        elif data_a != data_b:
            return False
    return True


def cluster_rows(tiles: int, workers: tuple[int, ...] = (1, 2)) -> list[dict[str, Any]]:
    from drawstring.app.executor import DaskExecutor

    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-cad-cluster-") as tmp:
        local = Path(tmp) / "local"
        rows.append({"where": "this machine's processes", **_design(tiles, local, None)})
        for count in workers:
            with DaskExecutor(workers=count) as executor:
                address = executor.client.scheduler.address
                out = Path(tmp) / f"cluster{count}"
                row = _design(tiles, out, address)
            row["where"] = f"local Dask cluster, {count} worker{'s' if count > 1 else ''}"
            row["same_files"] = same_files(local, out)
            rows.append(row)
    return rows


def store(rows: list[dict[str, Any]]) -> None:
    path = HERE / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    kept = [r for r in results.get("cad_cluster", []) if r["tiles"] != rows[0]["tiles"]]
    results["cad_cluster"] = kept + rows
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tiles", type=int, default=200)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    args = parser.parse_args()
    found = cluster_rows(args.tiles, tuple(args.workers))
    for row in found:
        print(row, flush=True)
    store(found)
