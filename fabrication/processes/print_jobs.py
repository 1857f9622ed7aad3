"""Printed tiles as 3MF print jobs: meshed, grouped into jobs, placed on beds and written with
the slicers' configs; with the hinge pads as a second material (``fdm-dual``) or the tiles
alone, nested (``laser-epdm``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import build123d as bd
import numpy as np

from drawstring.cad.part_mesh import mesh_tolerance
from drawstring.fabrication import mesh3mf as m3f
from drawstring.fabrication.beds import (
    TOWER_GAP_MM,
    footprint_mm,
    jobs_on_bed,
    loose_pads_and_beds,
    nested_tiles,
    place_wipe_towers,
)
from drawstring.fabrication.print_estimate import bed_features, estimate_bed
from drawstring.fabrication.printers import print_bed
from drawstring.fabrication.slicer import IniJob, prusa_ini, wipe_tower_footprint
from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:
    from drawstring.fabrication.processes.base import FabricationJob
    from drawstring.fabrication.profiles import Profile

#: Beds side by side in the 3MF of all jobs: the gap between two, mm.
BED_GAP_MM = 20.0


def write_print_jobs(job: FabricationJob, with_pads: bool, file_name: str) -> None:
    """Meshes, print jobs and the 3MF (dual material when ``with_pads``): ``file_name`` with
    every job, one object each, the beds side by side, and one file per bed where there are
    several; beside each file that holds one bed, its PrusaSlicer settings (``.ini``).  The
    jobs, beds, the wipe towers and the estimated printing time and filament go into
    ``job.record``."""
    record = job.record
    tile_mesh, pad_mesh = _meshes(job, with_pads)
    job_parts, beds, cut, towers = _plan_beds(job, tile_mesh, pad_mesh, with_pads)
    for entry, bed_index in zip(record.jobs, beds, strict=True):
        entry["bed"] = bed_index + 1
    n_beds = int(max(beds, default=0)) + 1
    record.estimates["cut_hinges"] = [int(h) for h in cut]
    record.estimates["print_beds"] = n_beds
    _write_files(job, job_parts, beds, n_beds, with_pads, file_name, towers)
    _estimate(job, job_parts, beds, n_beds, with_pads)


def _plan_beds(
    job: FabricationJob,
    tile_mesh: dict[int, m3f.PartMesh],
    pad_mesh: dict[int, m3f.PartMesh],
    with_pads: bool,
) -> tuple[list[list[m3f.PartMesh]], list[int], list[int], list[tuple[float, float] | None]]:
    """The jobs on their beds (:func:`_place_jobs`) and each bed's wipe tower corner (None on a
    bed that prints one material).  Where a bed has no room left for its wipe tower, the jobs
    are planned again on the bed less a strip along its far x edge (or else its far y edge),
    where the towers go."""
    record = job.record
    bed = print_bed(job.profile, job.printer)
    printer = job.printer
    if not with_pads or printer is None or printer.wipe_tower_width_mm <= 0:
        job_parts, beds, cut = _place_jobs(job, tile_mesh, pad_mesh, with_pads, bed)
        return job_parts, beds, cut, [None] * (int(max(beds, default=0)) + 1)
    footprint = wipe_tower_footprint(printer)
    strip = (footprint[0] + TOWER_GAP_MM, footprint[1] + TOWER_GAP_MM)
    # the whole bed, else the bed less a strip along its far x edge, else along its far y edge
    for reserve in ((0.0, 0.0), (strip[0], 0.0), (0.0, strip[1])):
        planned = (bed[0] - reserve[0], bed[1] - reserve[1])
        if min(planned) <= 2 * m3f.BED_MARGIN_MM:
            continue
        record.jobs.clear()
        try:
            job_parts, beds, cut = _place_jobs(job, tile_mesh, pad_mesh, with_pads, planned)
        except InputError:
            if reserve == (0.0, 0.0):
                raise  # a tile larger than the whole bed: refused as such
            continue
        towers = place_wipe_towers(job_parts, beds, bed, footprint)
        on_beds = _bed_parts(job_parts, beds)
        if all(t is not None for t, parts in zip(towers, on_beds, strict=True) if _dual(parts)):
            return job_parts, beds, cut, towers
    raise InputError(
        f"no room for the wipe tower ({footprint[0]:.0f} x {footprint[1]:.0f} mm) beside the "
        f"print jobs on the {bed[0]:g} x {bed[1]:g} mm bed of {printer.name}; use a printer "
        "with a larger bed (--printer) or more tiles"
    )


def _meshes(
    job: FabricationJob, with_pads: bool
) -> tuple[dict[int, m3f.PartMesh], dict[int, m3f.PartMesh]]:
    """The tiles' meshes by tile and the pads' by hinge (none without pads): the print meshes
    the CAD workers made on this machine (the second of each pair of :attr:`~drawstring.cad.
    design.CadResult.tile_meshes`), each part they could not mesh (or all, where they were
    made elsewhere) meshed here."""
    cad_flat = job.cad_flat
    tolerance = mesh_tolerance(job.profile.thickness_mm)
    items: list[tuple[bd.Shape, str, m3f.PartKind]] = [
        (solid, f"tile_{i}", "tile") for i, solid in enumerate(cad_flat.tiles)
    ]
    made: list[m3f.PartMesh | None] = [None] * len(items)
    if cad_flat.meshed_here and len(cad_flat.tile_meshes) == len(cad_flat.tiles):
        made = [None if m is None else m[1] for m in cad_flat.tile_meshes]
    if with_pads:
        items += [
            (s, f"hinge_{h}", "pad") for h, s in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True)
        ]
        pads_made = cad_flat.meshed_here and len(cad_flat.pad_meshes) == len(cad_flat.pads)
        made += (
            [None if m is None else m[1] for m in cad_flat.pad_meshes]
            if pads_made
            else [None] * len(cad_flat.pads)
        )
    missing = [k for k, mesh in enumerate(made) if mesh is None]
    for k, mesh in zip(
        missing, m3f.mesh_solids([items[k] for k in missing], tolerance, job.workers), strict=True
    ):
        made[k] = mesh
    meshes = [mesh for mesh in made if mesh is not None]
    tile_mesh = {i: meshes[i] for i in range(len(cad_flat.tiles))}
    pad_mesh = (
        {int(h): meshes[len(cad_flat.tiles) + k] for k, h in enumerate(cad_flat.pad_hinge)}
        if with_pads
        else {}
    )
    return tile_mesh, pad_mesh


def _place_jobs(
    job: FabricationJob,
    tile_mesh: dict[int, m3f.PartMesh],
    pad_mesh: dict[int, m3f.PartMesh],
    with_pads: bool,
    bed: tuple[float, float],
) -> tuple[list[list[m3f.PartMesh]], list[int], list[int]]:
    """Each print job's parts on a bed of size ``bed``, each job's bed, and the hinges cut
    between jobs (their pads printed loose); the jobs are listed in ``job.record.jobs``."""
    profile, record = job.profile, job.record
    if not with_pads:
        # loose tiles (their hinges are glued on later, on the placement template): nested
        job_parts = nested_tiles([tile_mesh[t] for t in range(len(tile_mesh))], bed)
        for parts in job_parts:
            record.jobs.append(
                {
                    "job": len(record.jobs) + 1,
                    "tiles": sorted(int(p.name.split("_")[1]) for p in parts),
                    "pads": [],
                    "size_mm": footprint_mm(parts),
                    "nested": True,
                }
            )
        return job_parts, list(range(len(job_parts))), []
    pad_boxes = {
        h: np.stack([m.vertices.min(axis=0), m.vertices.max(axis=0)]) for h, m in pad_mesh.items()
    }
    jobs, cut = m3f.plan_print_jobs(job.tiles_flat, job.hinges, bed, pad_boxes)
    job_parts = jobs_on_bed(jobs, tile_mesh, pad_mesh, record)
    beds = loose_pads_and_beds(cut, pad_mesh, job_parts, bed, profile, record)
    return job_parts, beds, cut


def _bed_parts(job_parts: list[list[m3f.PartMesh]], beds: list[int]) -> list[list[m3f.PartMesh]]:
    """Every part on each bed, bed by bed."""
    on_bed: list[list[m3f.PartMesh]] = [[] for _ in range(int(max(beds, default=0)) + 1)]
    for parts, bed_index in zip(job_parts, beds, strict=True):
        on_bed[bed_index] += parts
    return on_bed


def _dual(parts: list[m3f.PartMesh]) -> bool:
    """Whether the parts print in two materials (tiles and pads)."""
    return {p.kind for p in parts} == {"tile", "pad"}


def _write_files(
    job: FabricationJob,
    job_parts: list[list[m3f.PartMesh]],
    beds: list[int],
    n_beds: int,
    with_pads: bool,
    file_name: str,
    towers: list[tuple[float, float] | None],
) -> None:
    """``file_name`` with every job, the beds side by side, and, where there is more than one
    bed, one file per bed on the bed, for slicers that show one bed at a time; beside the file
    of each bed (``file_name`` itself for one bed) its PrusaSlicer settings, listed in
    ``job.record.beds``."""
    profile, record, printer = job.profile, job.record, job.printer
    bed = print_bed(profile, printer)
    origin = (
        np.array([printer.bed_origin_x_mm, printer.bed_origin_y_mm, 0.0])
        if printer is not None
        else np.zeros(3)
    )
    stride = bed[0] + BED_GAP_MM

    def job_object(index: int, dx: float) -> m3f.Object3mf:
        """Job ``index``'s parts as one 3MF object, moved onto the machine's bed and ``dx``
        mm along x."""
        loose = " loose hinge pads" if record.jobs[index].get("loose") else ""
        move = origin + np.array([dx, 0.0, 0.0])
        return m3f.Object3mf(
            f"job {index + 1}{loose}",
            tuple(
                m3f.PartMesh(p.name, p.kind, p.vertices + move, p.triangles)
                for p in job_parts[index]
            ),
        )

    objects = [job_object(index, beds[index] * stride) for index in range(len(job_parts))]
    title = f"{job.design_name} ({profile.name})"
    extruders: dict[m3f.PartKind, int] | None = {"tile": 1, "pad": 2} if with_pads else None
    materials: dict[m3f.PartKind, str] = {"tile": profile.tile_material}
    if with_pads:
        materials["pad"] = profile.hinge_material
    # written in a forked process while the estimates and the guide are made here
    job.write_beside(
        m3f.write_3mf,
        job.out / file_name,
        objects,
        title=title,
        extruders=extruders,
        materials=materials,
    )
    job.written.append(file_name)
    stem = Path(file_name).stem
    on_beds = _bed_parts(job_parts, beds)
    for bed_index in range(n_beds):
        name = file_name if n_beds == 1 else f"{stem}-bed{bed_index + 1}.3mf"
        bed_title = title if n_beds == 1 else f"{title}, bed {bed_index + 1} of {n_beds}"
        if n_beds > 1:
            on_bed = [job_object(i, 0.0) for i in range(len(job_parts)) if beds[i] == bed_index]
            job.write_beside(
                m3f.write_3mf, job.out / name, on_bed, title=bed_title, extruders=extruders,
                materials=materials,
            )  # fmt: skip
            job.written.append(name)
        entry: dict[str, object] = {"bed": bed_index + 1, "model": name}
        if printer is not None:
            tower = towers[bed_index]
            corner = None if tower is None else (tower[0] + origin[0], tower[1] + origin[1])
            ini = Path(name).with_suffix(".ini").name
            settings = IniJob(
                extruders=2 if with_pads else 1,
                wipe_tower=corner,
                title=f"{name} ({bed_title})",
            )
            (job.out / ini).write_text(prusa_ini(printer, profile, settings), encoding="utf-8")
            job.written.append(ini)
            entry["settings"] = ini
            entry["wipe_tower_mm"] = None if corner is None else [round(v, 2) for v in corner]
            entry["materials"] = sorted({p.kind for p in on_beds[bed_index]}, reverse=True)
        record.beds.append(entry)


def _estimate(
    job: FabricationJob,
    job_parts: list[list[m3f.PartMesh]],
    beds: list[int],
    n_beds: int,
    with_pads: bool,
) -> None:
    """The printing time and filament of each bed (:mod:`..print_estimate`), into
    ``job.record.beds`` and the totals into its estimates."""
    profile, printer, estimates = job.profile, job.printer, job.record.estimates
    if printer is None:
        return
    total_s = tile_g = pad_g = 0.0
    for entry, parts in zip(job.record.beds, _bed_parts(job_parts, beds), strict=True):
        guess = estimate_bed(bed_features(parts, printer, profile), profile)
        entry["estimate"] = {
            "time_h": round(guess.time_s / 3600.0, 2),
            "filament_g": _by_material(profile, guess.tile_g, guess.pad_g, with_pads),
        }
        total_s += guess.time_s
        tile_g += guess.tile_g
        pad_g += guess.pad_g
    estimates["print_time_h"] = round(total_s / 3600.0, 2)
    estimates["filament_g"] = _by_material(profile, tile_g, pad_g, with_pads)
    estimates["print_time_basis"] = (
        f"estimate for {printer.name} with the shipped .ini, fitted to PrusaSlicer "
        f"2.5.0's; {n_beds} bed{'s' if n_beds > 1 else ''}"
    )


def _by_material(
    profile: Profile, tile_g: float, pad_g: float, with_pads: bool
) -> dict[str, float]:
    grams = {profile.tile_material: round(tile_g, 1)}
    if with_pads:
        grams[profile.hinge_material] = round(pad_g, 1)
    return grams
