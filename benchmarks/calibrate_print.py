"""Fit the print estimate to PrusaSlicer, and compare the two on every built-in.

``--fit`` designs a set of small designs (several targets, tile counts, printers, both
printed profiles), two test coupons and every built-in as ``--builtins`` does, slices every
bed with PrusaSlicer and the shipped settings, reads each bed's parts back from its 3MF, and
fits the weights of
:mod:`drawstring.fabrication.print_estimate` to PrusaSlicer's times and filament by
non-negative least squares; it prints the weights (to copy into that module) and keeps the
samples in ``benchmarks/data/print_samples.json`` (``--refit`` fits again from them without
slicing).  ``--builtins`` designs every built-in at 200 tiles with CAD, slices it and writes
the estimate next to PrusaSlicer's into ``benchmarks/results.json`` (key ``print_estimate``).

Needs ``prusa-slicer`` on PATH; a 200-tile built-in takes a few minutes to slice.  The
STEP files are left out (placeholders), and slicing is given up only after six hours.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import tempfile
import xml.etree.ElementTree as ET
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from scipy.optimize import nnls

HERE = Path(__file__).resolve().parent
SAMPLES = HERE / "data" / "print_samples.json"

from drawstring.fabrication import exports, slicer  # noqa: E402
from drawstring.fabrication import print_estimate as pe  # noqa: E402
from drawstring.fabrication.beside import Beside  # noqa: E402
from drawstring.fabrication.mesh3mf import PartMesh  # noqa: E402
from drawstring.fabrication.printers import load_printer, with_printer  # noqa: E402
from drawstring.fabrication.profiles import load_profile  # noqa: E402
from drawstring.fabrication.slicer import find_prusa_slicer  # noqa: E402
from drawstring.geometry.target.builtins import BUILTIN_TARGETS  # noqa: E402
from drawstring.output.folder import write_design  # noqa: E402
from drawstring.pipeline.record import DesignOptions  # noqa: E402
from drawstring.pipeline.run import design  # noqa: E402

#: (target, tiles, profile, printer) of the fitting set.
FIT_CASES: tuple[tuple[str, int, str, str], ...] = (
    ("saddle", 40, "fdm-dual", "generic-dual"),
    ("dome", 50, "fdm-dual", "bambu-h2d"),
    ("wave", 40, "fdm-dual", "snapmaker-u1"),
    ("chair", 40, "fdm-dual", "prusa-xl-2t"),
    ("peanut", 60, "fdm-dual", "generic-dual"),
    ("saddle", 40, "laser-epdm", "generic-single"),
    ("cloud", 40, "laser-epdm", "prusa-xl-2t"),
)
#: (profile, printer) of the test coupons in the fitting set.
FIT_COUPONS: tuple[tuple[str, str], ...] = (("fdm-dual", "bambu-h2d"), ("fdm-dual", "prusa-xl-2t"))
#: (tiles, profile, printer) of ``--builtins``; ``--fit`` takes every built-in so too.
BUILTIN_CASE = (200, "fdm-dual", "generic-dual")


def _case_name(target: str, tiles: int, profile: str, printer: str) -> str:
    return f"{target}-{tiles}-{profile}-{printer}"


_NUMBER = re.compile(rb'[xyz]="([-0-9.e]+)"')
_INDEX = re.compile(rb'v[123]="(\d+)"')


def read_bed(path: Path) -> list[PartMesh]:
    """The parts of a bed's 3MF (drawstring's own), as the design estimates them: each
    connected piece of a volume of the PrusaSlicer config (a volume holds a run of tiles or
    of hinge pads printed by one extruder), ``tile`` or ``pad`` by the volume's name; a file
    without that config (tiles alone) has each connected piece of its meshes as a tile."""
    with zipfile.ZipFile(path) as archive:
        model = archive.read("3D/3dmodel.model")
        names = archive.namelist()
        config = (
            ET.fromstring(archive.read("Metadata/Slic3r_PE_model.config"))
            if "Metadata/Slic3r_PE_model.config" in names
            else None
        )
    parts: list[PartMesh] = []
    for index, chunk in enumerate(model.split(b"<object ")[1:]):
        vertices_xml, _, triangles_xml = chunk.partition(b"<triangles>")
        vertices = np.array(_NUMBER.findall(vertices_xml), dtype=np.float64).reshape(-1, 3)
        triangles = np.array(_INDEX.findall(triangles_xml), dtype=np.int64).reshape(-1, 3)
        volumes = [("tile", triangles)]
        if config is not None:
            volumes = [
                (
                    next(m.get("value") for m in v if m.get("key") == "name") or "",
                    triangles[int(v.get("firstid", 0)) : int(v.get("lastid", 0)) + 1],
                )
                for v in config.findall("object")[index].findall("volume")
            ]
        for name, tri in volumes:
            kind = "pad" if name.startswith("hinge") else "tile"
            for k, piece in enumerate(_connected_pieces(tri)):
                used, local = np.unique(piece, return_inverse=True)
                parts.append(
                    PartMesh(f"{kind}_{len(parts)}_{k}", kind, vertices[used], local.reshape(-1, 3))
                )
    return parts


def _connected_pieces(triangles: np.ndarray) -> list[np.ndarray]:
    """``triangles`` split into the pieces that share no vertex, in the order they start."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    used, local = np.unique(triangles, return_inverse=True)
    local = local.reshape(-1, 3)
    edges = np.vstack([local[:, [0, 1]], local[:, [1, 2]]])
    graph = coo_matrix(
        (np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(len(used), len(used))
    )
    _, label = connected_components(graph, directed=False)
    of_triangle = label[local[:, 0]]
    order = list(dict.fromkeys(of_triangle.tolist()))
    return [triangles[of_triangle == k] for k in order]


def run_case(target: str, tiles: int, profile: str, printer: str, folder: Path) -> list[dict]:
    """Design, write and slice one case (or read the folder of an earlier run of it); one
    sample per bed: its features and what PrusaSlicer reported."""
    out = folder / _case_name(target, tiles, profile, printer)
    if not (out / "fabrication" / "slicer.json").is_file():
        options = DesignOptions(
            profile=profile, tiles=tiles, simulate=False, printer=printer, slice=True
        )
        write_design(design(target, options, quiet=True), out)
    return _samples(
        _case_name(target, tiles, profile, printer), out / "fabrication", profile, printer
    )


def coupon_case(profile: str, printer: str, folder: Path) -> list[dict]:
    """The test coupon of ``profile`` on ``printer`` (``drawstring coupon --slice``), as
    :func:`run_case`: a small job whose time is mostly per-layer overhead."""
    from drawstring.output.coupon import write_coupon

    out = folder / f"coupon-{profile}-{printer}"
    if not (out / "slicer.json").is_file():
        write_coupon(profile, printer, out, slice_beds=True)
    return _samples(f"coupon-{profile}-{printer}", out, profile, printer)


def _samples(case: str, fabrication: Path, profile: str, printer: str) -> list[dict]:
    """One sample per sliced bed of a fabrication folder: its features and what PrusaSlicer
    reported."""
    sliced = json.loads((fabrication / "slicer.json").read_text())
    used_printer = load_printer(printer)
    used_profile = with_printer(load_profile(profile), used_printer)
    samples = []
    for bed in sliced["beds"]:
        parts = read_bed(fabrication / bed["model"])
        features = pe.bed_features(parts, used_printer, used_profile)
        grams = bed["filament_g"]
        samples.append(
            {
                "case": case,
                "bed": bed["bed"],
                "features": features.to_json(),
                "time_s": bed["time_s"],
                "tile_mm3": 1000.0
                * grams.get(used_profile.tile_material, 0.0)
                / (used_profile.density_kg_m3 / 1000.0),
                "pad_mm3": 1000.0
                * grams.get(used_profile.hinge_material, 0.0)
                / (used_profile.hinge_density_kg_m3 / 1000.0),
                "slicer": sliced["slicer"],
            }
        )
    return samples


def fit(samples: list[dict]) -> dict[str, list[float]]:
    """Non-negative least squares of each estimate's weights, relative errors weighted alike
    (each sample's row divided by its target)."""
    features = [pe.BedFeatures(**s["features"]) for s in samples]

    def solve(rows: list[list[float]], targets: list[float]) -> list[float]:
        a = np.array(rows, dtype=np.float64)
        y = np.array(targets, dtype=np.float64)
        keep = y > 0
        scale = 1.0 / y[keep]
        weights, _ = nnls(a[keep] * scale[:, None], np.ones(int(keep.sum())))
        return [float(f"{w:.4g}") for w in weights]

    return {
        "TIME_WEIGHTS": solve([f.time_terms() for f in features], [s["time_s"] for s in samples]),
        "TILE_FILAMENT_WEIGHTS": solve(
            [f.tile_terms() for f in features], [s["tile_mm3"] for s in samples]
        ),
        "PAD_FILAMENT_WEIGHTS": solve(
            [f.pad_terms() for f in features], [s["pad_mm3"] for s in samples]
        ),
    }


def report(samples: list[dict], weights: dict[str, list[float]]) -> None:
    """Each sample's estimate with the weights against PrusaSlicer's numbers."""
    for s in samples:
        f = pe.BedFeatures(**s["features"])
        t = float(np.dot(weights["TIME_WEIGHTS"], f.time_terms()))
        tile = float(np.dot(weights["TILE_FILAMENT_WEIGHTS"], f.tile_terms()))
        pad = float(np.dot(weights["PAD_FILAMENT_WEIGHTS"], f.pad_terms()))
        pad_error = f"{pad / s['pad_mm3'] - 1:+6.1%}" if s["pad_mm3"] > 0 else "   -  "
        print(
            f"{s['case']:42s} bed {s['bed']}  time {s['time_s'] / 3600:6.2f} h "
            f"{t / s['time_s'] - 1:+6.1%}  PLA {tile / s['tile_mm3'] - 1:+6.1%}  TPU {pad_error}"
        )


def _placeholder_step_files(jobs: list[tuple[Any, ...]], workers: int | None) -> Beside:
    """Stands in for the STEP writers here (each job's first item is its file's path): the
    printing time does not depend on the STEP files, which take most of a 200-tile design's
    writing time."""
    del workers
    for path, *_ in jobs:
        path.write_text("left out by benchmarks/calibrate_print.py\n", encoding="utf-8")
    return Beside(workers=1)


def builtin_rows(folder: Path, names: list[str]) -> None:
    """Built-ins at 200 tiles (fdm-dual, its default printer): the estimate and what
    PrusaSlicer reported, and how far apart they are (a folder of an earlier run is read
    again rather than designed and sliced anew).  Each row is written into results.json as
    soon as it is measured, replacing an earlier row of the same built-in."""
    for name in names:
        out = folder / _case_name(name, *BUILTIN_CASE)
        if not (out / "fabrication" / "slicer.json").is_file():
            tiles, profile, printer = BUILTIN_CASE
            options = DesignOptions(
                profile=profile, tiles=tiles, simulate=False, printer=printer, slice=True
            )
            write_design(design(name, options, quiet=True), out)
        document = json.loads((out / "design.json").read_text())
        sliced = json.loads((out / "fabrication" / "slicer.json").read_text())
        estimate = json.loads((out / "fabrication" / "manifest.json").read_text())["estimates"]
        slicer_g = sliced["total"]["filament_g"]
        row: dict[str, Any] = {
            "case": name,
            "tiles": document["linkage"]["tiles"],
            "profile": document["profile"],
            "printer": document["options"]["printer"],
            "beds": len(sliced["beds"]),
            "tools": sorted({t for bed in sliced["beds"] for t in bed["tools"]}),
            "slicer": sliced["slicer"],
            "slicer_time_h": sliced["total"]["time_h"],
            "estimate_time_h": estimate["print_time_h"],
            "time_error": round(estimate["print_time_h"] / sliced["total"]["time_h"] - 1, 3),
            "slicer_filament_g": slicer_g,
            "estimate_filament_g": estimate["filament_g"],
            "filament_error": {
                material: round(estimate["filament_g"][material] / grams - 1, 3)
                for material, grams in slicer_g.items()
                if grams > 0
            },
        }
        print(json.dumps(row), flush=True)
        _record(row)


def _record(row: dict[str, Any]) -> None:
    """Put one built-in's row into results.json's ``print_estimate``: the built-ins in their
    order, then any other row (the coupon) as it was."""
    path = HERE / "results.json"
    results = json.loads(path.read_text()) if path.exists() else {}
    rows = {r["case"]: r for r in results.get("print_estimate", [])}
    rows[row["case"]] = row
    order = [*BUILTIN_TARGETS, *(n for n in rows if n not in BUILTIN_TARGETS)]
    results["print_estimate"] = [rows[n] for n in order if n in rows]
    path.write_text(json.dumps(results, indent=2) + "\n", encoding="utf-8")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--fit", action="store_true", help="slice the fitting set and fit")
    parser.add_argument("--refit", action="store_true", help="fit again from the saved samples")
    parser.add_argument(
        "--builtins", action="store_true", help="compare on every built-in at 200 tiles"
    )
    parser.add_argument(
        "--targets", nargs="+", choices=sorted(BUILTIN_TARGETS), help="only these built-ins"
    )
    parser.add_argument("--keep", type=Path, help="keep the design folders here")
    args = parser.parse_args()
    if (args.fit or args.builtins) and find_prusa_slicer() is None:
        sys.exit("prusa-slicer is not on PATH")
    # a busy machine slices a 200-tile bed in well over the command line's half hour
    slicer.SLICE_TIMEOUT_S = 6 * 3600.0
    exports.start_step_writers = _placeholder_step_files
    with tempfile.TemporaryDirectory(prefix="drawstring-calibrate-") as scratch:
        folder = args.keep or Path(scratch)
        folder.mkdir(parents=True, exist_ok=True)
        if args.fit:
            samples: list[dict] = []
            for case in (*FIT_CASES, *((name, *BUILTIN_CASE) for name in BUILTIN_TARGETS)):
                samples += run_case(*case, folder)
                print(f"sliced {case}", flush=True)
            for coupon in FIT_COUPONS:
                samples += coupon_case(*coupon, folder)
            SAMPLES.write_text(json.dumps(samples, indent=1) + "\n", encoding="utf-8")
        if args.fit or args.refit:
            samples = json.loads(SAMPLES.read_text())
            weights = fit(samples)
            for name, values in weights.items():
                print(f"{name}: tuple[float, ...] = {tuple(values)}")
            report(samples, weights)
        if args.builtins:
            builtin_rows(folder, args.targets or list(BUILTIN_TARGETS))


if __name__ == "__main__":
    main()
