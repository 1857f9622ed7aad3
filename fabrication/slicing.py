"""Slicing a fabrication folder's print beds with PrusaSlicer while the rest is written, and
the rows of bom.csv that state the printing time and filament.

Each bed's 3MF is sliced with its own settings file (:func:`~.slicer.slice_bed`), one bed
after another in a background thread (the work is PrusaSlicer's, in its own process), so the
STEP files and the guide are written meanwhile.  What PrusaSlicer reports goes into
``slicer.json`` and manifest.json's ``slicer``, and bom.csv states it in place of the
estimate; a bed PrusaSlicer cannot slice leaves the estimate and a note.
"""

from __future__ import annotations

import json
import logging
import math
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from drawstring.fabrication.slicer import (
    SliceFailed,
    SliceSummary,
    find_prusa_slicer,
    slice_bed,
    slicer_version,
)

if TYPE_CHECKING:
    from drawstring.fabrication.processes.base import FabricationJob
    from drawstring.fabrication.profiles import Profile
    from drawstring.fabrication.record import ExportRecord

log = logging.getLogger(__name__)


@dataclass
class Slicing:
    """Beds being sliced in the background."""

    executor: ThreadPoolExecutor
    future: Future[list[SliceSummary]]
    version: str


def start_slicing(job: FabricationJob) -> Slicing | None:
    """Start slicing every bed that has a settings file, when PrusaSlicer is on PATH (None
    when it is not, or nothing is printed)."""
    beds = [entry for entry in job.record.beds if "settings" in entry]
    executable = find_prusa_slicer()
    if not beds or executable is None:
        if executable is None and beds:
            log.info("prusa-slicer is not on PATH: bom.csv gives drawstring's estimate")
        return None
    version = slicer_version(executable)
    out = job.out

    def run() -> list[SliceSummary]:
        return [
            slice_bed(executable, out / entry["settings"], out / entry["model"]) for entry in beds
        ]

    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="drawstring-slice")
    return Slicing(executor, executor.submit(run), version)


def finish_slicing(job: FabricationJob, slicing: Slicing) -> None:
    """Wait for the slices; write ``slicer.json`` and put PrusaSlicer's numbers into the
    record (or, where a bed could not be sliced, a note)."""
    try:
        summaries = slicing.future.result()
    except SliceFailed as failed:
        job.record.notes.append(f"{failed}; bom.csv gives drawstring's estimate instead")
        return
    finally:
        slicing.executor.shutdown(wait=True)
    profile, record = job.profile, job.record
    materials = [profile.tile_material, profile.hinge_material]
    beds = [entry for entry in record.beds if "settings" in entry]
    rows: list[dict[str, Any]] = []
    for entry, summary in zip(beds, summaries, strict=True):
        used = [k for k, mm in enumerate(summary.filament_mm) if mm > 0]
        rows.append(
            {
                "bed": entry["bed"],
                "model": entry["model"],
                "settings": entry["settings"],
                "time_s": summary.time_s,
                "time_h": round(summary.time_s / 3600.0, 2),
                "filament_g": {materials[k]: summary.filament_g[k] for k in used},
                "filament_mm": {materials[k]: summary.filament_mm[k] for k in used},
                "tools": [f"T{t}" for t in summary.tools],
                "toolchanges": summary.toolchanges,
            }
        )
    total_g: dict[str, float] = {}
    total_mm: dict[str, float] = {}
    for row in rows:
        for name, grams in row["filament_g"].items():
            total_g[name] = round(total_g.get(name, 0.0) + grams, 2)
            total_mm[name] = round(total_mm.get(name, 0.0) + row["filament_mm"][name], 2)
    total_s = sum(row["time_s"] for row in rows)
    document: dict[str, Any] = {
        "slicer": slicing.version,
        "command": "prusa-slicer --export-gcode --load SETTINGS.ini MODEL.3mf",
        "beds": rows,
        "total": {
            "time_h": round(total_s / 3600.0, 2),
            "filament_g": total_g,
            "filament_mm": total_mm,
        },
        "estimate": {
            "time_h": record.estimates.get("print_time_h"),
            "filament_g": record.estimates.get("filament_g"),
        },
    }
    (job.out / "slicer.json").write_text(
        json.dumps(document, indent=1, sort_keys=True) + "\n", encoding="utf-8"
    )
    job.written.append("slicer.json")
    record.slicer = {
        "slicer": slicing.version,
        "print_time_h": document["total"]["time_h"],
        "filament_g": total_g,
        "file": "fabrication/slicer.json",
    }


def print_rows(record: ExportRecord, profile: Profile) -> list[dict[str, Any]]:
    """bom.csv's rows of printing time and filament per material: PrusaSlicer's where it ran,
    else drawstring's estimate (none where nothing is printed)."""
    estimates = record.estimates
    if "print_time_h" not in estimates:
        return []
    sliced = record.slicer
    settings = ", ".join(e["settings"] for e in record.beds if "settings" in e)
    if sliced:
        source = f"{sliced['slicer']} with {settings} (slicer.json)"
        rows: list[dict[str, Any]] = [
            {
                "item": "print_time",
                "description": f"{sliced['print_time_h']} h",
                "note": f"{source}; drawstring's estimate {estimates['print_time_h']} h",
            }
        ]
        grams = sliced["filament_g"]
    else:
        rows = [
            {
                "item": "print_time",
                "description": f"{estimates['print_time_h']} h",
                "note": estimates["print_time_basis"],
            }
        ]
        grams = estimates.get("filament_g", {})
    for material, mass in grams.items():
        rows.append(
            {
                "item": "filament",
                "description": f"{material} filament",
                "count": 1,
                "material": material,
                "mass_g": round(float(mass), 1),
                "note": (
                    f"{source}; wipe tower included"
                    if sliced
                    else "estimate, wipe tower included; "
                    f"{_metres(mass, material, profile):.1f} m of 1.75 mm filament"
                ),
            }
        )
    return rows


def _metres(grams: float, material: str, profile: Profile) -> float:
    """Filament length (m) of ``grams`` of 1.75 mm filament of the profile's density for
    ``material`` (the tiles' or the hinges')."""
    kg_m3 = (
        profile.density_kg_m3 if material == profile.tile_material else profile.hinge_density_kg_m3
    )
    return grams / (kg_m3 * 1e-3) / (math.pi * 0.875**2)
