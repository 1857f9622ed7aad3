"""Benchmark every stage: built-in targets and the scanned face mesh at three resolutions.

Run with ``.venv/bin/python benchmarks/run.py`` (``--quick`` for a smaller sweep).  Prints a table
and writes ``benchmarks/results.json`` with the machine's core count (``--fine`` adds the whole
pipeline at 1600 tiles on three built-ins: the 1600-tile deployment target of issue 6;
``--fine-layout`` the same without the simulation, for issue 4's 1600-tile layout target, in a
few minutes; ``--corpus`` runs only the real-mesh corpus of ``../shared/meshes/corpus/``, see
``bench_corpus.py``).
Targets (2 cores): flattening the 34k-triangle face under 1 s; tiling under 0.5 s at 1600 tiles;
the per-stage targets of the other issues are listed next to their rows.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import platform
import sys
import time
from pathlib import Path
from typing import Any

# Single-threaded BLAS, as ``drawstring design`` runs: threading changes the order of floating
# point sums, and with it a near tie (a hinge side, say), so rows would not match the CLI's.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from drawstring.geometry.assembled.top import CLOSE_FIT_WEIGHTS  # noqa: E402
from drawstring.geometry.flatten.conformal import flatten  # noqa: E402
from drawstring.geometry.target.builtins import BUILTIN_TARGETS  # noqa: E402
from drawstring.geometry.target.surface import load_target  # noqa: E402
from drawstring.geometry.tiling.grid import tile_surface  # noqa: E402

FACE = HERE / "data" / "face.obj"
#: The real-mesh corpus, beside the repository (``--corpus``).
CORPUS = HERE.parent.parent / "shared" / "meshes" / "corpus"
TARGETS_S = {"flatten_face": 1.0, "tiling_1600": 0.5}
#: Flat layout, co-optimization and hinge layout together, by tile count (issue 4), seconds.
LAYOUT_TARGET_S = {200: 2.0, 1600: 10.0}
#: Built-ins whose whole pipeline also runs at 1600 tiles with ``--fine``.
FINE_CASES = ("saddle", "dome", "wave")


def timed(fn: Any, *args: Any, repeat: int = 3, **kwargs: Any) -> tuple[Any, float]:
    """Best wall time of ``repeat`` calls (seconds) and the last result."""
    best = float("inf")
    result = None
    for _ in range(repeat):
        start = time.perf_counter()
        result = fn(*args, **kwargs)
        best = min(best, time.perf_counter() - start)
    return result, best


def foundation_rows(tile_counts: tuple[int, ...], names: list[str]) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = []
    cases = [(n, n) for n in names] + [("face", str(FACE))]
    for name, spec in cases:
        target, t_load = timed(load_target, spec, size_mm=200.0, repeat=1)
        flat, t_flat = timed(flatten, target.vertices, target.faces, repeat=3)
        for tiles in tile_counts:
            tiling, t_tile = timed(
                tile_surface, target.vertices, target.faces, flat.uv, tiles=tiles, repeat=3
            )
            rows.append(
                {
                    "case": name,
                    "triangles": int(len(target.faces)),
                    "tiles": tiling.linkage.n_tiles,
                    "load_s": round(t_load, 4),
                    "flatten_s": round(t_flat, 4),
                    "tiling_s": round(t_tile, 4),
                    "splits": len(tiling.linkage.splits),
                    "scale_factor_max": round(tiling.scale_factor_max, 3),
                }
            )
    return rows


def pipeline_rows(
    names: list[str],
    tiles: int,
    hinges: str = "dual",
    simulate: bool = True,
    weights: tuple[float, float, float] | None = None,
    repeat: int = 1,
) -> list[dict[str, Any]]:
    """Every stage of ``design`` on each built-in at about ``tiles`` tiles, with its quality
    (``weights``: paper eq. 1 weights other than the default).  With ``repeat``, each design
    runs that many times and the row holds the run with the least layout time (the designs
    are the same; the machine's speed is not)."""
    from drawstring.pipeline.record import DesignOptions
    from drawstring.pipeline.run import design

    def layout_s(result: Any) -> float:
        return float(sum(result.timings_s.get(k, 0.0) for k in ("flat", "co-optimize", "hinges")))

    rows: list[dict[str, Any]] = []
    for name in names:
        options = DesignOptions(
            tiles=tiles,
            size_mm=200.0,
            cad=False,
            hinges=hinges,
            simulate=simulate,  # type: ignore[arg-type]
            **({"weights": weights} if weights else {}),
        )
        best: tuple[float, float, Any] | None = None
        for _ in range(max(repeat, 1)):
            cpu = time.process_time()
            run = design(name, options)
            if best is None or layout_s(run) < best[0]:
                best = (layout_s(run), time.process_time() - cpu, run)
        assert best is not None
        _, cpu, result = best
        m = result.metrics()
        sim = m.get("simulation", {})
        rows.append(
            {
                "case": name,
                "tiles": result.tiling.linkage.n_tiles,
                "parts": result.tiling.linkage.n_components,
                "split_bound": m.get("split_bound"),
                "hinges": hinges,
                **{f"{k}_s": round(v, 3) for k, v in result.timings_s.items()},
                # issue 4's flat-layout time: the flat layout, its co-optimization with the
                # assembled shape (which the 1e-3 mm targets need) and the hinge layout
                "layout_s": round(layout_s(result), 3),
                "runs": max(repeat, 1),
                "layout_target_s": LAYOUT_TARGET_S.get(tiles),
                "planarity_mm": m.get("planarity_max_mm"),
                "overlap_mm2": m.get("flat_overlap_area_mm2"),
                "gap_deg": f"{m.get('flat_gap_angle_min_deg', 0):.1f}-"
                f"{m.get('flat_gap_angle_max_deg', 0):.1f}",
                "hinge_gap_mm": m.get("hinge_gap_max_mm"),
                "hinge_gap_in_plane_mm": m.get("hinge_gap_in_plane_max_mm"),
                "flat_edge_error_mm": m.get("flat_edge_error_max_mm"),
                "co_optimized": m.get("co_optimization", {}).get("accepted"),
                "co_steps": m.get("co_optimization", {}).get("steps"),
                "co_per_step_ms": round(
                    1e3
                    * result.timings_s.get("co-optimize", 0.0)
                    / max(m.get("co_optimization", {}).get("steps", 0) or 1, 1),
                    2,
                ),
                "surface_mean_pct": round(
                    100 * m["surface_distance_mean_mm"] / m["tile_side_mean_mm"], 2
                ),
                "lift": m["lift_points"]["count"],
                "deployed": sim.get("deployed"),
                "sim_steps": sim.get("steps"),
                "sim_runs": sim.get("runs"),
                "rigidity_null_dim": m["rigidity"]["null_dimension"],
                "cpu_s": round(cpu, 2),
                "problems": len(result.problems),
            }
        )
    return rows


def extra_rows() -> dict[str, list[dict[str, Any]]]:
    """Rows from the per-stage benchmark modules that exist (``bench_*.py`` with ``run()``)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for path in sorted(HERE.glob("bench_*.py")):
        module = importlib.import_module(path.stem)
        if hasattr(module, "run"):
            out[path.stem] = module.run()
    return out


def print_table(rows: list[dict[str, Any]]) -> None:
    if not rows:
        return
    keys = list(rows[0])
    widths = {k: max(len(k), *(len(str(r.get(k, ""))) for r in rows)) for k in keys}
    print("  ".join(k.ljust(widths[k]) for k in keys))
    for r in rows:
        print("  ".join(str(r.get(k, "")).ljust(widths[k]) for k in keys))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--quick", action="store_true", help="two targets, two resolutions")
    parser.add_argument(
        "--stages",
        action="store_true",
        help="also run every per-stage benchmark (benchmarks/bench_*.py; several minutes)",
    )
    parser.add_argument(
        "--close-fit",
        action="store_true",
        help="also the 200-tile pipeline with the close-fit eq. 1 weights (issue 3's surface "
        "distance against issue 4's flat layout; about 8 min)",
    )
    parser.add_argument(
        "--fine-layout",
        action="store_true",
        help="also the pipeline without the simulation at 1600 tiles on saddle, dome and wave "
        "(issue 4's layout time; about 1 min each)",
    )
    parser.add_argument(
        "--fine",
        action="store_true",
        help="also the whole pipeline at 1600 tiles on saddle, dome and wave (about 2 min each)",
    )
    parser.add_argument(
        "--sweep",
        action="store_true",
        help="also a 12-variant sweep without CAD on 1 and 2 local Dask workers "
        "(bench_sweep.py; a few minutes)",
    )
    parser.add_argument(
        "--repeat",
        type=int,
        default=1,
        help="run every pipeline row this many times and keep the fastest layout "
        "(the machine's speed varies by 10-20 percent from run to run)",
    )
    parser.add_argument(
        "--corpus",
        action="store_true",
        help="run only the real-mesh corpus (../shared/meshes/corpus/, skipped when absent): "
        "every mesh at the defaults, its 'retry with:' followed once (minutes per mesh)",
    )
    parser.add_argument(
        "--corpus-dir", type=Path, default=CORPUS, help=f"the corpus folder (default {CORPUS})"
    )
    parser.add_argument(
        "--corpus-args",
        default="",
        help="options added to every corpus design, e.g. '--no-cad'",
    )
    parser.add_argument("--corpus-only", nargs="*", default=[], help="these corpus meshes only")
    args = parser.parse_args()
    if args.corpus:
        run_corpus(args.corpus_dir, args.corpus_args.split(), args.corpus_only)
        return
    names = list(BUILTIN_TARGETS)[:2] if args.quick else list(BUILTIN_TARGETS)
    counts = (100, 400) if args.quick else (100, 400, 1600)
    rows = foundation_rows(counts, names)
    print_table(rows)
    stages = pipeline_rows(names, 200, repeat=args.repeat)
    print("\npipeline at about 200 tiles, 200 mm")
    print_table(stages)
    top_rows = pipeline_rows(names, 200, hinges="top", simulate=False, repeat=args.repeat)
    print("\npipeline at about 200 tiles, 200 mm, --hinges top (no simulation)")
    print_table(top_rows)
    fine = pipeline_rows(list(FINE_CASES), 1600, repeat=args.repeat) if args.fine else []
    if fine:
        print("\npipeline at about 1600 tiles, 200 mm")
        print_table(fine)
    fine_layout = (
        pipeline_rows(list(FINE_CASES), 1600, simulate=False, repeat=args.repeat)
        if args.fine_layout
        else []
    )
    if fine_layout:
        print("\npipeline at about 1600 tiles, 200 mm, no simulation")
        print_table(fine_layout)
    close_fit = pipeline_rows(names, 200, weights=CLOSE_FIT_WEIGHTS) if args.close_fit else []
    if close_fit:
        print(f"\npipeline at about 200 tiles, 200 mm, --weights {CLOSE_FIT_WEIGHTS}")
        print_table(close_fit)
    sweep = importlib.import_module("bench_sweep").sweep_rows() if args.sweep else []
    if sweep:
        print("\nsweep of 12 variants on 1 and 2 local workers")
        print_table(sweep)
    extras = extra_rows() if args.stages else {}
    for name, stage_rows in extras.items():
        print(f"\n{name}")
        print_table(stage_rows)
    # Rows this run did not compute (e.g. --fine or --stages left out) are kept from the last run.
    path = HERE / "results.json"
    results: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    results.update(
        {
            "machine": {
                "cores": os.cpu_count(),
                "python": platform.python_version(),
                "platform": platform.platform(),
            },
            "targets_s": TARGETS_S,
            "foundation": rows,
            "pipeline_200": stages,
            "pipeline_200_top": top_rows,
            **({"pipeline_1600": fine} if fine else {}),
            **({"pipeline_1600_layout": fine_layout} if fine_layout else {}),
            **({"pipeline_200_close_fit": close_fit} if close_fit else {}),
            **({"sweep": sweep} if sweep else {}),
            **extras,
        }
    )
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


def run_corpus(folder: Path, extra: list[str], only: list[str]) -> None:
    """The corpus rows, merged by mesh into ``results.json``'s ``corpus`` (designed with
    ``--no-cad``) or ``corpus_cad`` (with CAD, the solids and print files built and checked),
    with the success count (exit 0 and deploying, directly or through the retry)."""
    if not folder.is_dir():
        print(f"no corpus at {folder}: skipped (give --corpus-dir)")
        return
    from bench_corpus import corpus_rows

    rows = corpus_rows(folder, extra, only)
    path = HERE / "results.json"
    results: dict[str, Any] = json.loads(path.read_text()) if path.exists() else {}
    key = "corpus" if "--no-cad" in extra else "corpus_cad"
    kept = {row["mesh"]: row for row in results.get(key, {}).get("rows", [])}
    kept.update({row["mesh"]: row for row in rows})
    merged = [kept[name] for name in sorted(kept)]
    succeeded = sum(1 for row in merged if row.get("success"))
    results[key] = {
        "meshes": len(sorted(folder.glob("*.obj"))),
        "run": len(merged),
        "succeeded": succeeded,
        "rows": merged,
    }
    print(f"{key}: {succeeded} of {len(merged)} meshes run end in exit 0 and deploy")
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


if __name__ == "__main__":
    main()
