"""``--fit``'s rows of ``benchmarks/run.py --fit``: how close each built-in's assembled tiles sit
to the target, close against paper, and the fit frontier.

* ``pipeline_200_fit_160mm``: every built-in at about 200 tiles and the command's default size
  (the default profile's 160 mm; each row says ``size_mm``), with the simulation, once with
  ``--fit close`` (the default) and once with ``--fit paper``: the surface distance over
  the top faces (mean as % of the mean tile side, largest as % of the target's diagonal),
  whether it meets the fit level (mean <= 2 %, largest <= 1 %), the 1e-3 mm layout levels,
  overlap, deployment, and the layout time of close against paper.
* ``fit_frontier``: per built-in, the close shape's eq. 1 tried at several surface weights
  (face samples at the same weight; the gate on the conical defect off, so every shape is laid
  out, with dual hinges): its surface distance after the rigid fit against its accuracy (the
  larger of flat edge error and hinge gap), with the paper's shape as the first point
  (percentages of the paper design's mean tile side and the target's diagonal), at the same
  default size as ``pipeline_200_fit_160mm`` (160 mm), without the simulation.

Each row has ``load_avg``, the machine's one-minute load average as the row was started: the
times are wall clock, and on a shared machine they vary with it.

Run with ``nice -n 10 .venv/bin/python benchmarks/fit_rows.py [NAME ...] [--frontier]
[--repeat N]`` (all built-ins by default; ``--repeat``: each close and paper row the fastest
layout of N designs, the designs themselves identical); it writes its rows into
``benchmarks/results.json``.  The two rows of all eight take about 15 min on a two-core
machine at load 6 (per repeat), the frontier about 3 min per built-in.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

# Single-threaded BLAS, as ``drawstring design`` runs (see run.py).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

#: The fit level of issue 46: mean distance over the mean tile side, largest over the
#: target's bounding-box diagonal.
FIT_MEAN_REL = 0.02
FIT_MAX_REL = 0.01
#: The layout levels: flat edge error and hinge gap, mm.
LAYOUT_TOL_MM = 1e-3
#: The row kind of the close/paper rows: about 200 tiles at the command's default size.
FIT_ROWS = "pipeline_200_fit_160mm"
#: That size (the default profile's ``default_size_mm``), checked against each design's.
DEFAULT_SIZE_MM = 160.0
#: Surface (and face-sample) weights of the frontier's eq. 1, planar 1e4 and square 10.
FRONTIER_SURFACE_WEIGHTS = (1.0, 10.0, 100.0)


def _layout_s(result: Any) -> float:
    return float(sum(result.timings_s.get(k, 0.0) for k in ("flat", "co-optimize", "hinges")))


def _fit_figures(mean_mm: float, max_mm: float, side_mm: float, diagonal_mm: float) -> dict:
    mean_pct = 100 * mean_mm / side_mm
    max_pct = 100 * max_mm / diagonal_mm
    return {
        "surface_mean_mm": round(mean_mm, 4),
        "surface_max_mm": round(max_mm, 4),
        "surface_mean_pct_side": round(mean_pct, 2),
        "surface_max_pct_diagonal": round(max_pct, 2),
        "meets_fit": mean_pct <= 100 * FIT_MEAN_REL and max_pct <= 100 * FIT_MAX_REL,
    }


def fit_row(name: str, fit: str, tiles: int, simulate: bool = True) -> dict[str, Any]:
    """One built-in designed with ``--fit fit`` at the default size, as ``FIT_ROWS`` records
    it."""
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    options = DesignOptions(tiles=tiles, cad=False, simulate=simulate, fit=fit)  # type: ignore[arg-type]
    load = os.getloadavg()[0]
    cpu = time.process_time()
    result = design(name, options)
    cpu = time.process_time() - cpu
    if result.options.size_mm != DEFAULT_SIZE_MM:
        raise SystemExit(f"the default size is {result.options.size_mm:g} mm: rename {FIT_ROWS}")
    m = result.metrics()
    edge, hinge = m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"]
    overlap = m["flat_overlap_area_mm2"]
    deployed = m.get("simulation", {}).get("deployed")
    meets_layout = edge <= LAYOUT_TOL_MM and hinge <= LAYOUT_TOL_MM and overlap == 0
    figures = _fit_figures(
        m["surface_distance_mean_mm"],
        m["surface_distance_max_mm"],
        m["tile_side_mean_mm"],
        result.target.bbox_diagonal_mm,
    )
    return {
        "case": name,
        "fit": fit,
        "size_mm": result.options.size_mm,
        "fit_used": m["fit"]["used"],
        "hinges": str(result.options.hinges),
        "tiles": result.tiling.linkage.n_tiles,
        "parts": result.tiling.linkage.n_components,
        **figures,
        "flat_edge_error_mm": edge,
        "hinge_gap_mm": hinge,
        "overlap_mm2": overlap,
        "meets_layout": bool(meets_layout and not result.problems),
        "deployed": deployed,
        "conical_defect_deg": m["fit"].get("close", {}).get("conical_defect_deg"),
        "refused": m["fit"].get("close", {}).get("refused"),
        "refused_top": m["fit"].get("close_top", {}).get("refused"),
        "layout_s": round(_layout_s(result), 3),
        "assembled_s": round(result.timings_s.get("assembled", 0.0), 3),
        "cpu_s": round(cpu, 2),
        "load_avg": round(load, 2),
    }


def _fastest(name: str, fit: str, tiles: int, repeat: int) -> dict[str, Any]:
    """:func:`fit_row` with the shortest layout of ``repeat`` designs (the same design each
    time; only the times vary), which says how many in ``repeat``."""
    rows = [fit_row(name, fit, tiles) for _ in range(repeat)]
    return {**min(rows, key=lambda r: r["layout_s"]), "repeat": repeat}


def pipeline_fit_rows(names: list[str], tiles: int = 200, repeat: int = 1) -> list[dict[str, Any]]:
    """``FIT_ROWS``: close then paper per built-in, each the fastest layout of ``repeat``;
    the close row's ``layout_vs_paper`` is its layout time over the paper row's."""
    rows: list[dict[str, Any]] = []
    for name in names:
        close = _fastest(name, "close", tiles, repeat)
        paper = _fastest(name, "paper", tiles, repeat)
        close["layout_vs_paper"] = round(close["layout_s"] / max(paper["layout_s"], 1e-9), 2)
        close["no_worse_than_paper"] = (
            close["surface_mean_mm"] <= paper["surface_mean_mm"] + 1e-9
            and close["surface_max_mm"] <= paper["surface_max_mm"] + 1e-9
        )
        rows += [close, paper]
    return rows


def frontier_rows(names: list[str], tiles: int = 200) -> list[dict[str, Any]]:
    """``fit_frontier``: per built-in, the paper's shape, then the close shape at each of
    :data:`FRONTIER_SURFACE_WEIGHTS` laid out whatever its conical defect, at
    :data:`DEFAULT_SIZE_MM` (no simulation)."""
    from drawstring.geometry.assembled.top import Eq1Weights
    from drawstring.pipeline.policy import DEFAULT_POLICY
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    rows: list[dict[str, Any]] = []
    for name in names:
        # dual hinges throughout: left unset, a layout over the fabrication tolerance would be
        # laid out again with top hinges, another curve
        base = DesignOptions(
            tiles=tiles, size_mm=DEFAULT_SIZE_MM, cad=False, simulate=False, hinges="dual"
        )
        load = os.getloadavg()[0]
        paper = design(name, replace(base, fit="paper"))
        m = paper.metrics()
        side, diagonal = m["tile_side_mean_mm"], paper.target.bbox_diagonal_mm
        accuracy = max(m["flat_edge_error_max_mm"], m["hinge_gap_max_mm"])
        rows.append(
            {
                "case": name,
                "size_mm": DEFAULT_SIZE_MM,
                "eq1": m["fit"]["eq1"],
                **_fit_figures(
                    m["surface_distance_mean_mm"], m["surface_distance_max_mm"], side, diagonal
                ),  # fmt: skip
                "accuracy_mm": accuracy,
                "meets_layout": accuracy <= LAYOUT_TOL_MM,
                "conical_defect_deg": None,
                "load_avg": round(load, 2),
            }
        )
        for w in FRONTIER_SURFACE_WEIGHTS:
            policy = replace(
                DEFAULT_POLICY,
                close_fit=Eq1Weights(1e4, 10.0, w, w),
                close_conical_defect_max_deg=math.inf,
            )
            load = os.getloadavg()[0]
            tried = design(name, base, policy=policy).metrics()["fit"]["close"]
            accuracy = tried["accuracy_mm"]
            rows.append(
                {
                    "case": name,
                    "size_mm": DEFAULT_SIZE_MM,
                    "eq1": tried["eq1"],
                    **_fit_figures(
                        tried["surface_distance_mean_mm"],
                        tried["surface_distance_max_mm"],
                        side,
                        diagonal,
                    ),  # fmt: skip
                    "accuracy_mm": accuracy,
                    "meets_layout": accuracy <= LAYOUT_TOL_MM,
                    "conical_defect_deg": tried["conical_defect_deg"],
                    "load_avg": round(load, 2),
                }
            )
    return rows


def main() -> None:
    from drawstring.geometry.target.builtins import BUILTIN_TARGETS

    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("names", nargs="*", help="built-ins (all by default)")
    parser.add_argument("--frontier", action="store_true", help="also the fit frontier")
    parser.add_argument("--frontier-only", action="store_true", help="only the fit frontier")
    parser.add_argument(
        "--repeat", type=int, default=1, help="keep the fastest layout of N designs per row"
    )
    parser.add_argument("--out", type=Path, default=Path(__file__).with_name("results.json"))
    args = parser.parse_args()
    names = args.names or list(BUILTIN_TARGETS)
    found: dict[str, Any] = {} if args.frontier_only else {FIT_ROWS: []}
    if args.frontier or args.frontier_only:
        found["fit_frontier"] = []
    for name in names:  # one built-in at a time, each written as it is done
        if FIT_ROWS in found:
            found[FIT_ROWS] += pipeline_fit_rows([name], repeat=args.repeat)
        if "fit_frontier" in found:
            found["fit_frontier"] += frontier_rows([name])
        results = json.loads(args.out.read_text()) if args.out.exists() else {}
        for key, rows in found.items():  # the rows of built-ins not run this time are kept
            run = {r["case"] for r in rows}
            results[key] = [r for r in results.get(key, []) if r["case"] not in run] + rows
        args.out.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")
        print(json.dumps({k: v[-2:] for k, v in found.items()}), flush=True)


if __name__ == "__main__":
    main()
