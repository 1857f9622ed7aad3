"""Fabrication exports under ``DIR/fabrication/``: the files a maker prints, cuts and assembles.

All profiles: ``flat.step`` and ``assembled.step`` (assemblies with a named, coloured part per
tile ``tile_<id>`` and per hinge part ``hinge_<id>``), ``bom.csv``, ``manifest.json`` and
``assembly.md`` with pictures (written by the guide the caller hands in).  The files of each
process are its writer's (:data:`WRITERS`, :mod:`.processes`):

* ``fdm-dual``: ``print.3mf``, tiles and TPU hinge pads as two materials, in print jobs.
* ``laser-epdm``: ``tiles.3mf`` (loose tiles nested on beds), ``hinges.dxf`` (rubber strips
  nested on sheets), ``placement.dxf`` and ``placement.svg``.
* ``plywood-cnc``: ``panels.dxf`` (six panels per tile, nested on sheets), ``hinges.dxf``,
  ``cutlist.csv``, ``placement.dxf`` / ``.svg``; cable and channel-tube lengths in ``bom.csv``.

Every file is deterministic, also between processes: STEP headers carry a fixed timestamp and
the colour entities an order of their own (OCCT's follows memory addresses), zip members fixed
dates, DXF fixed metadata, PNGs no software tag.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import build123d as bd
import numpy as np

from drawstring.cad.design import normalize_route
from drawstring.cad.kernel import closed_polyline
from drawstring.fabrication.measures import STRING_MARGIN, STRING_TAIL_MIN_MM, measure_fabrication
from drawstring.fabrication.printers import resolve_printer
from drawstring.fabrication.processes.base import FabricationJob, ProcessWriter, bom_row
from drawstring.fabrication.processes.fdm_dual import FdmDual
from drawstring.fabrication.processes.laser_epdm import LaserEpdm
from drawstring.fabrication.processes.plywood_cnc import PlywoodCnc
from drawstring.fabrication.profiles import Process, string_is_cable
from drawstring.fabrication.record import AssemblyGuide, ExportRecord, GuideInputs
from drawstring.fabrication.slicing import finish_slicing, print_rows, start_slicing
from drawstring.fabrication.step import StepJob, StepPart, start_step_writers

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult
    from drawstring.fabrication.measures import Measures
    from drawstring.fabrication.panels import Panel
    from drawstring.fabrication.printers import Printer
    from drawstring.fabrication.profiles import Profile
    from drawstring.geometry.core.types import FloatArray, IntArray
    from drawstring.geometry.tiling.linkage import Linkage

#: The writer of each process's files.
WRITERS: dict[Process, type[ProcessWriter]] = {
    Process.FDM_DUAL: FdmDual,
    Process.LASER_EPDM: LaserEpdm,
    Process.PLYWOOD_CNC: PlywoodCnc,
}
#: Density of sintered NdFeB magnets, g/mm^3 (7.5 g/cm^3), for the magnets' mass in bom.csv.
NDFEB_DENSITY_G_MM3 = 7.5e-3


def write_fabrication(
    folder: Path,
    *,
    profile: Profile,
    linkage: Linkage,
    tiles_flat: FloatArray,
    tiles_assembled: FloatArray,
    hinge_side: Sequence[str],
    route_steps: IntArray | Sequence[Sequence[int]],
    lift_tiles: IntArray | Sequence[Sequence[int]],
    magnet_pairs: IntArray | Sequence[Sequence[int]],
    trims: dict[int, Sequence[FloatArray]] | None,
    cad_flat: CadResult,
    cad_assembled: CadResult,
    design_name: str,
    workers: int | None = None,
    guide: AssemblyGuide | None = None,
    printer: Printer | None = None,
    slice_beds: bool = False,
) -> list[str]:
    """Write every fabrication file of the profile's process under ``folder / "fabrication"``.

    Parameters
    ----------
    folder : the design's output folder.
    profile : the fabrication profile (its ``process`` picks the writer, :data:`WRITERS`).
    linkage : topology (hinges ``(H, 4)``).
    tiles_flat, tiles_assembled : (T, 8, 3) float, mm, T2D and T3D.
    hinge_side : (H,) ``"top"`` | ``"bottom"``.
    route_steps : (S, 3) or (S, 4) int route (see :func:`drawstring.cad.design.normalize_route`).
    lift_tiles : (L, 2) int ``(tile, side)`` extra lift bores.
    magnet_pairs : (M, 4) int (the polarity comes from ``cad_flat.magnets``).
    trims : tiles whose overlap with a neighbour is cut away (in the CAD solids already);
        plywood panels make whole boxes, so the guide names those tiles.
    cad_flat, cad_assembled : the solids in both poses.
    design_name : shown in titles.
    workers : processes for tessellation (default: CPU count).
    guide : writes the assembly guide and its pictures into the folder (the output layer's
        :func:`drawstring.output.assembly_guide.write_guide`); the manifest lists its files.
    printer : the printer the tiles print on (None: the profile's,
        :func:`~.printers.resolve_printer`).
    slice_beds : slice each print bed with PrusaSlicer where it is installed
        (:mod:`.slicer`); its numbers go into ``slicer.json``, bom.csv and manifest.json.

    Returns
    -------
    Paths written, relative to ``folder`` (``fabrication/...``), sorted.
    """
    del magnet_pairs
    if printer is None:
        printer = resolve_printer(profile)
    out = Path(folder) / "fabrication"
    out.mkdir(parents=True, exist_ok=True)
    job = FabricationJob(
        out=out,
        profile=profile,
        design_name=design_name,
        tiles_flat=np.asarray(tiles_flat, dtype=np.float64),
        tiles_assembled=np.asarray(tiles_assembled, dtype=np.float64),
        hinges=np.asarray(linkage.hinges, dtype=np.int64).reshape(-1, 4),
        sides=list(hinge_side),
        steps=normalize_route(route_steps),
        lifts=np.asarray(lift_tiles, dtype=np.int64).reshape(-1, 2),
        cad_flat=cad_flat,
        workers=workers,
        printer=printer,
    )
    job.record.notes += list(cad_flat.notes)
    job.record.trimmed = sorted(int(t) for t in (trims or {}))
    writer = WRITERS[profile.process](job)
    # OCCT's STEP writer is serial and the slowest export: write both files in forked
    # processes (they inherit the solids, nothing is pickled) while the rest is made here.
    step_writing = start_step_writers(_step_jobs(job, cad_assembled), workers)
    slicing = None
    try:
        job.written += ["flat.step", "assembled.step"]
        panels = writer.panels()
        measures = measure_fabrication(
            profile, job.tiles_flat, job.tiles_assembled, job.steps, job.lifts, cad_flat, panels
        )
        writer.render(measures)
        if slice_beds:
            job.writing.results()  # the slicer reads the 3MF files
            slicing = start_slicing(job)
        _rows(job, writer, measures)
        if slicing is not None:
            finish_slicing(job, slicing)
        _write_bom(out / "bom.csv", job.record, profile)
        job.written.append("bom.csv")
        if guide is not None:
            job.written += guide(out, _guide_inputs(job, panels))
        job.writing.results()  # the manifest reads their files
        step_writing.results()
    except BaseException:
        # an error or Ctrl-C: they write into the staging folder, about to be removed
        step_writing.stop()
        job.writing.stop()
        raise
    _write_manifest(job)
    return sorted(f"fabrication/{name}" for name in job.written)


def _rows(job: FabricationJob, writer: ProcessWriter, measures: Measures) -> None:
    """bom.csv's rows beside the process's parts (string, assembly, magnets) and its totals."""
    _string_rows(job, measures)
    job.record.unlabelled = list(job.cad_flat.unlabelled)
    writer.assembly_rows()
    _magnet_rows(job)
    _totals(job, measures)


def _guide_inputs(job: FabricationJob, panels: list[Panel]) -> GuideInputs:
    return GuideInputs(
        profile=job.profile,
        design_name=job.design_name,
        record=job.record,
        tiles_flat=job.tiles_flat,
        tiles_assembled=job.tiles_assembled,
        hinges=job.hinges,
        sides=job.sides,
        steps=job.steps,
        lifts=job.lifts,
        magnets=list(job.cad_flat.magnets),
        panels=panels,
        printer=job.printer,
    )


def _step_jobs(job: FabricationJob, cad_assembled: CadResult) -> list[StepJob]:
    """``flat.step`` (tiles, hinge parts, numbers) and ``assembled.step`` (tiles, numbers):
    each file's path, named parts with their materials, label and the motions that place the
    parts.

    Where the CAD stage filled the engraved numbers (``CadResult.unengraved``), the tiles
    are those solids and each engraved number follows as its outline (``number_N``, a closed
    polyline per stroke on the bottom face, no material); the assembled ones are moved there
    in the writing process.
    """
    profile, cad_flat, name = job.profile, job.cad_flat, job.design_name
    flat_path, assembled_path = job.out / "flat.step", job.out / "assembled.step"
    pads: list[StepPart] = [
        (f"hinge_{h}", s, profile.hinge_material)
        for h, s in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True)
    ]
    if not cad_flat.unengraved:
        flat_tiles: list[StepPart] = [
            (f"tile_{i}", s, profile.tile_material) for i, s in enumerate(cad_flat.tiles)
        ]
        assembled: list[StepPart] = [
            (f"tile_{i}", s, profile.tile_material) for i, s in enumerate(cad_assembled.tiles)
        ]
        return [
            (flat_path, flat_tiles + pads, f"{name} flat", None),
            (assembled_path, assembled, f"{name} assembled", None),
        ]
    tiles: list[StepPart] = [
        (f"tile_{i}", s, profile.tile_material) for i, s in enumerate(cad_flat.unengraved)
    ]
    numbered = [t for t, outline in enumerate(cad_flat.number_outlines) if outline is not None]
    numbers: list[StepPart] = [
        (f"number_{t}", bd.Compound([closed_polyline(p) for p in outline]), None)
        for t in numbered
        if (outline := cad_flat.number_outlines[t]) is not None
    ]
    motions = np.concatenate([cad_flat.transforms, cad_flat.transforms[numbered]])
    return [
        (flat_path, tiles + pads + numbers, f"{name} flat", None),
        (assembled_path, tiles + numbers, f"{name} assembled", motions),
    ]


def _string_rows(job: FabricationJob, measures: Measures) -> None:
    """The string to cut, and the ferrule that joins a cable's ends (a cable is not knotted:
    assembly.md, Pull)."""
    profile = job.profile
    flat_route, string_mm, tail = measures.route_flat_mm, measures.string_mm, measures.tail_mm
    string_section_mm2 = math.pi * (0.5 * profile.string_diameter_mm) ** 2
    job.record.bom.append(
        bom_row(
            "string",
            profile.string_material,
            1,
            profile.string_material,
            string_section_mm2 * string_mm * profile.string_density_kg_m3 * 1e-6,  # g
            f"{string_mm / 1000:.3f} m = flat route {flat_route / 1000:.3f} m x "
            f"{1 + STRING_MARGIN:g} + 2 tails of {tail:.0f} mm",
            length_mm=string_mm,
        )
    )
    if string_is_cable(profile):
        job.record.bom.append(
            bom_row(
                "ferrule",
                f"crimp ferrule for {profile.string_diameter_mm:g} mm cable (or two "
                "wire-rope clips)",
                1,
                "aluminium",
                0.0,
                "joins the two ends once the part is pulled shut",
            )
        )


def _magnet_rows(job: FabricationJob) -> None:
    """The disc magnets, two per pair, with each pair's polarity."""
    profile, magnets = job.profile, job.cad_flat.magnets
    if not magnets:
        return
    polarity = "; ".join(
        f"tile {m.tile_a} side {m.side_a} {m.polarity_a} out / "
        f"tile {m.tile_b} side {m.side_b} {m.polarity_b} out"
        for m in magnets
    )
    disc_mm3 = math.pi * (0.5 * profile.magnet_diameter_mm) ** 2 * profile.magnet_height_mm
    job.record.bom.append(
        bom_row(
            "magnet",
            f"disc magnet {profile.magnet_diameter_mm:g} x {profile.magnet_height_mm:g} mm",
            2 * len(magnets),
            "NdFeB",
            round(2 * len(magnets) * disc_mm3 * NDFEB_DENSITY_G_MM3, 1),
            polarity,
        )
    )


def _totals(job: FabricationJob, measures: Measures) -> None:
    """Volumes, masses, string and the material cost into the manifest's estimates."""
    profile = job.profile
    cost = (
        measures.tile_mass_g / 1000 * profile.tile_price_per_kg
        + measures.hinge_mass_g / 1000 * profile.hinge_price_per_kg
        + measures.string_mm / 1000 * profile.string_price_per_m
        + 2 * len(job.cad_flat.magnets) * profile.magnet_price_each
    )
    job.record.estimates.update(
        {
            "tile_volume_mm3": measures.tile_volume_mm3,
            "hinge_volume_mm3": measures.hinge_volume_mm3,
            "tile_mass_g": measures.tile_mass_g,
            "hinge_mass_g": measures.hinge_mass_g,
            "mass_g": measures.mass_g,
            "string_length_mm": measures.string_mm,
            "flat_route_length_mm": measures.route_flat_mm,
            "string_tail_mm": measures.tail_mm,
            "string_rule": f"flat route x {1 + STRING_MARGIN:g} + 2 x "
            f"max({STRING_TAIL_MIN_MM:g} mm, 10 % of the route)",
            "material_cost": round(cost, 2),
            "currency": profile.currency,
        }
    )


def _write_manifest(job: FabricationJob) -> None:
    """``manifest.json``: the counts, print jobs, sheets, estimates, magnets and notes, and
    every file written so far with its size and SHA-256."""
    record, out = job.record, job.out
    manifest = {
        "design": job.design_name,
        "profile": job.profile.name,
        "process": job.profile.process,
        "tiles": len(job.cad_flat.tiles),
        "hinge_parts": len(job.cad_flat.pads),
        "printer": _printer_json(job.printer),
        "print_jobs": record.jobs,
        "beds": record.beds,
        "sheets": record.sheets,
        "estimates": record.estimates,
        "magnets": [m.to_json() for m in job.cad_flat.magnets],
        "notes": record.notes,
        **({"slicer": record.slicer} if record.slicer else {}),
        "files": [
            {
                "path": f"fabrication/{name}",
                "bytes": (out / name).stat().st_size,
                "sha256": hashlib.sha256((out / name).read_bytes()).hexdigest(),
            }
            for name in sorted(job.written)
        ],
    }
    (out / "manifest.json").write_text(
        json.dumps(manifest, indent=1, sort_keys=True) + "\n", encoding="utf-8"
    )
    job.written.append("manifest.json")


def _printer_json(printer: Printer | None) -> dict[str, object] | None:
    """The manifest's ``printer``: the preset's name, where it was read from, its bed."""
    if printer is None:
        return None
    return {
        "name": printer.name,
        "description": printer.description,
        "preset": printer.origin,
        "bed_mm": [printer.bed_x_mm, printer.bed_y_mm],
        "bed_origin_mm": [printer.bed_origin_x_mm, printer.bed_origin_y_mm],
        "toolheads": printer.toolheads,
        "nozzle_mm": printer.nozzle_mm,
    }


def _write_bom(path: Path, record: ExportRecord, profile: Profile) -> None:
    buffer = io.StringIO()
    writer = csv.DictWriter(
        buffer,
        ["item", "description", "count", "material", "mass_g", "length_mm", "note"],
        lineterminator="\n",
    )
    writer.writeheader()
    for row in record.bom:
        writer.writerow(row)
    estimates = record.estimates
    for row in print_rows(record, profile):
        writer.writerow(row)
    if "cut_time_h" in estimates:
        writer.writerow(
            {
                "item": "cut_time",
                "description": f"{estimates['cut_time_h']} h",
                "note": estimates["cut_time_basis"],
            }
        )
    writer.writerow(
        {
            "item": "mass",
            "description": f"{estimates['mass_g']} g",
            "note": "tiles + hinge parts as made (design.json metrics.cad.mass_g); no magnets "
            "or string",
        }
    )
    writer.writerow(
        {
            "item": "material cost",
            "description": f"{estimates['material_cost']} {profile.currency}",
            "note": "rough: masses x the profile's [cost] prices",
        }
    )
    path.write_text(buffer.getvalue(), encoding="utf-8")
