"""The real-mesh corpus: every mesh of ``../shared/meshes/corpus/`` designed at the defaults
as a new user would (``drawstring design FILE``), following a refusal's ``retry with:`` once.

Run through ``benchmarks/run.py --corpus`` (rows in ``benchmarks/results.json`` under
``corpus``, merged by mesh so that a run over some meshes keeps the others' rows).  Each row:
the exit status, the retried options and the exit status after the retry, the values the tool
chose itself (``metrics.chosen_values``), tiles, parts,
whether the simulation deploys it, the flat edge error and hinge gap, the fit to the target
(mean and largest surface distance) and the design time.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

RETRY = re.compile(r"retry with: (.+)$")


def _run(mesh: Path, args: list[str], out: Path) -> tuple[int, str, float]:
    """``drawstring design`` on ``mesh``: exit status, last line of standard error, seconds."""
    start = time.perf_counter()
    done = subprocess.run(
        [sys.executable, "-m", "drawstring.app.cli", "design", str(mesh), *args, "--quiet"]
        + ["--out", str(out)],
        capture_output=True,
        text=True,
        check=False,
    )
    seconds = time.perf_counter() - start
    lines = done.stderr.strip().splitlines()
    return done.returncode, lines[-1] if lines else "", seconds


def _percent(metrics: dict[str, Any], key: str, of: float | None) -> float | None:
    value = metrics.get(key)
    if value is None or not of:
        return None
    return round(100.0 * float(value) / float(of), 2)


def _design_facts(folder: Path) -> dict[str, Any]:
    """What a written design's design.json says, for the row."""
    path = folder / "design.json"
    if not path.is_file():
        return {}
    doc = json.loads(path.read_text(encoding="utf-8"))
    metrics = doc.get("metrics", {})
    simulation = metrics.get("simulation") or {}
    levels = doc.get("quality", {}).get("measures", {})
    fit_levels = [levels.get(f"surface_distance_{k}_mm", {}).get("level") for k in ("mean", "max")]
    chosen = metrics.get("chosen_values") or {}
    return {
        # the values the tool chose itself where the defaults were refused or missed the
        # fabrication tolerance (none given), as options
        "chosen_options": [
            word
            for key, value in (chosen.get("used") or {}).items()
            for word in (f"--{key.removesuffix('_mm')}", f"{value:g}")
        ],
        "chosen_reason": chosen.get("reason"),
        "hinges": doc.get("options", {}).get("hinges"),
        "fit_used": (metrics.get("fit") or {}).get("used"),
        "tiles": doc.get("linkage", {}).get("tiles"),
        "parts": doc.get("linkage", {}).get("components"),
        "deployed": simulation.get("deployed"),
        "flat_edge_error_max_mm": metrics.get("flat_edge_error_max_mm"),
        "hinge_gap_max_mm": metrics.get("hinge_gap_max_mm"),
        "hinge_gap_in_plane_max_mm": metrics.get("hinge_gap_in_plane_max_mm"),
        "fit_mean_mm": metrics.get("surface_distance_mean_mm"),
        "fit_max_mm": metrics.get("surface_distance_max_mm"),
        "fit_mean_pct_side": _percent(
            metrics, "surface_distance_mean_mm", metrics.get("tile_side_mean_mm")
        ),
        "fit_max_pct_diagonal": _percent(
            metrics, "surface_distance_max_mm", doc.get("target", {}).get("bbox_diagonal_mm")
        ),
        # #46's fit levels: mean within 2 % of the mean tile side, largest within 1 % of the
        # target's diagonal
        "fit_met": fit_levels == ["target", "target"],
        "problems": doc.get("problems", []),
    }


def corpus_row(mesh: Path, args: list[str]) -> dict[str, Any]:
    """One mesh at the defaults (plus ``args``), its ``retry with:`` followed once."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "design"
        status, line, seconds = _run(mesh, args, out)
        row: dict[str, Any] = {"mesh": mesh.name, "options": args, "exit": status}
        row["design_time_s"] = round(seconds, 1)
        retry = RETRY.search(line) if status == 2 else None
        if status == 2:
            row["refusal"] = line
        if retry is not None:
            retried = retry.group(1).split()
            status, line, seconds = _run(mesh, [*args, *retried], out)
            row.update(
                retried_options=retried,
                exit_after_retry=status,
                retry_time_s=round(seconds, 1),
            )
            if status == 2:
                row["refusal_after_retry"] = line
        row.update(_design_facts(out))
    row["success"] = row.get("exit_after_retry", row["exit"]) == 0 and row.get("deployed") in (
        True,
        None,
    )
    return row


def corpus_rows(folder: Path, args: list[str], only: list[str]) -> list[dict[str, Any]]:
    """Rows for every mesh of ``folder`` (or those named in ``only``), printed as they come."""
    rows = []
    for mesh in sorted(folder.glob("*.obj")):
        if only and mesh.stem not in only and mesh.name not in only:
            continue
        row = corpus_row(mesh, args)
        shown = {k: row.get(k) for k in ("exit", "retried_options", "exit_after_retry")}
        print(f"{mesh.name}: {shown} deployed={row.get('deployed')} {row['design_time_s']} s")
        rows.append(row)
    return rows
