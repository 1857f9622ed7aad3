"""Printed tiles as 3MF print jobs: meshed, grouped into jobs, placed on beds and written with
the slicers' configs; with the hinge pads as a second material (``fdm-dual``) or the tiles
alone, nested (``laser-epdm``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import TYPE_CHECKING

import build123d as bd
import numpy as np

from drawstring.fabrication import mesh3mf as m3f
from drawstring.fabrication.beds import footprint_mm, jobs_on_bed, loose_pads_and_beds, nested_tiles

if TYPE_CHECKING:
    from drawstring.fabrication.measures import Measures
    from drawstring.fabrication.processes.base import FabricationJob

#: Assumed seconds per tool change (dual extruder); two changes per layer with both materials.
TOOL_CHANGE_S = 15.0
#: Beds side by side in the 3MF of all jobs: the gap between two, mm.
BED_GAP_MM = 20.0


def write_print_jobs(
    job: FabricationJob, measures: Measures, with_pads: bool, file_name: str
) -> None:
    """Meshes, print jobs and the 3MF (dual material when ``with_pads``): ``file_name`` with
    every job, one object each, the beds side by side, and one file per bed where there are
    several; the jobs, beds and print time go into ``job.record``."""
    record = job.record
    tile_mesh, pad_mesh = _meshes(job, with_pads)
    job_parts, beds, cut = _place_jobs(job, tile_mesh, pad_mesh, with_pads)
    for entry, bed_index in zip(record.jobs, beds, strict=True):
        entry["bed"] = bed_index + 1
    n_beds = int(max(beds, default=0)) + 1
    record.estimates["cut_hinges"] = [int(h) for h in cut]
    record.estimates["print_beds"] = n_beds
    _write_files(job, job_parts, beds, n_beds, with_pads, file_name)
    _print_time(job, measures, n_beds, with_pads)


def _meshes(
    job: FabricationJob, with_pads: bool
) -> tuple[dict[int, m3f.PartMesh], dict[int, m3f.PartMesh]]:
    """The tiles' meshes by tile and the pads' by hinge (none without pads)."""
    cad_flat = job.cad_flat
    tolerance = m3f.mesh_tolerance(job.profile.thickness_mm)
    items: list[tuple[bd.Shape, str, m3f.PartKind]] = [
        (solid, f"tile_{i}", "tile") for i, solid in enumerate(cad_flat.tiles)
    ]
    if with_pads:
        items += [
            (s, f"hinge_{h}", "pad") for h, s in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True)
        ]
    meshes = m3f.mesh_solids(items, tolerance, job.workers)
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
) -> tuple[list[list[m3f.PartMesh]], list[int], list[int]]:
    """Each print job's parts on its bed, each job's bed, and the hinges cut between jobs
    (their pads printed loose); the jobs are listed in ``job.record.jobs``."""
    profile, record = job.profile, job.record
    bed = (profile.bed_x_mm, profile.bed_y_mm)
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


def _write_files(
    job: FabricationJob,
    job_parts: list[list[m3f.PartMesh]],
    beds: list[int],
    n_beds: int,
    with_pads: bool,
    file_name: str,
) -> None:
    """``file_name`` with every job, and one file per bed, on the bed, for slicers that show
    one bed at a time (where there is more than one)."""
    profile, record = job.profile, job.record
    stride = profile.bed_x_mm + BED_GAP_MM

    def job_object(index: int, dx: float) -> m3f.Object3mf:
        """Job ``index``'s parts as one 3MF object, moved ``dx`` mm along x."""
        loose = " loose hinge pads" if record.jobs[index].get("loose") else ""
        move = np.array([dx, 0.0, 0.0])
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
    m3f.write_3mf(
        job.out / file_name, objects, title=title, extruders=extruders, materials=materials
    )
    job.written.append(file_name)
    if n_beds > 1:
        stem = Path(file_name).stem
        for bed_index in range(n_beds):
            name = f"{stem}-bed{bed_index + 1}.3mf"
            on_bed = [job_object(i, 0.0) for i in range(len(job_parts)) if beds[i] == bed_index]
            m3f.write_3mf(
                job.out / name, on_bed, title=f"{title}, bed {bed_index + 1} of {n_beds}",
                extruders=extruders, materials=materials,
            )  # fmt: skip
            job.written.append(name)


def _print_time(job: FabricationJob, measures: Measures, n_beds: int, with_pads: bool) -> None:
    """The print time estimate: printed volume over the profile's rate, and two tool changes
    per layer of each bed with pads."""
    profile, estimates = job.profile, job.record.estimates
    if profile.print_rate_mm3_s <= 0:
        return
    pad_volume = measures.hinge_volume_mm3 if with_pads else 0.0
    printed = measures.tile_volume_mm3 * profile.infill_fraction + pad_volume
    seconds = printed / profile.print_rate_mm3_s
    layer = max(0.5 * profile.nozzle_mm, 0.1)
    layers = math.ceil(profile.thickness_mm / layer)
    if with_pads:  # each bed is one print
        seconds += n_beds * layers * 2 * TOOL_CHANGE_S
    estimates["print_time_h"] = round(seconds / 3600.0, 2)
    estimates["print_time_basis"] = f"printed volume / {profile.print_rate_mm3_s} mm^3/s" + (
        f" + 2 tool changes of {TOOL_CHANGE_S:.0f} s per layer" if with_pads else ""
    )
