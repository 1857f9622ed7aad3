"""Fabrication exports under ``DIR/fabrication/``: the files a maker prints, cuts and assembles.

All profiles: ``flat.step`` and ``assembled.step`` (assemblies with a named, coloured part per
tile ``tile_<id>`` and per hinge part ``hinge_<id>``), ``bom.csv``, ``manifest.json`` and
``assembly.md`` with pictures (written by :mod:`.assembly_guide`).

* ``fdm-dual``: ``print.3mf``, one object per print job, tiles as volumes for extruder 1 and TPU
  pads for extruder 2, with PrusaSlicer's and Bambu/Orca's configs.  A layout larger than the
  bed is split into jobs along rows of hinges; pads of the hinges between jobs are printed loose
  in a last job and glued in (listed in ``assembly.md``).
* ``laser-epdm``: ``tiles.3mf`` (single material; the loose tiles turned and nested on as few
  beds as shelf packing takes, one object per bed), ``hinges.dxf`` (kerf-compensated rubber strips
  nested on sheets, tile numbers engraved as strokes), ``placement.dxf`` and ``placement.svg``.
* ``plywood-cnc``: ``panels.dxf`` (six panels per tile, butt or finger joints with dog-bones,
  cable holes, engraved labels, nested on sheets), ``hinges.dxf``, ``cutlist.csv``,
  ``placement.dxf`` / ``.svg``; cable and channel-tube lengths in ``bom.csv``.

Every file is deterministic, also between processes: STEP headers carry a fixed timestamp and
the colour entities an order of their own (OCCT's follows memory addresses), zip members fixed
dates, DXF fixed metadata, PNGs no software tag.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.design import normalize_route
from drawstring.cad.paths import route_lengths
from drawstring.fabrication import mesh3mf as m3f
from drawstring.fabrication.beds import (
    footprint_mm,
    jobs_on_bed,
    loose_pads_and_beds,
    nested_tiles,
)
from drawstring.fabrication.dxf import (
    Nesting,
    nest_parts,
    write_sheets_dxf,
)
from drawstring.fabrication.panels import CableRun, Panel, cable_runs, tile_panels
from drawstring.fabrication.parts import strip_part, write_placement
from drawstring.fabrication.profiles import string_is_cable
from drawstring.fabrication.record import AssemblyGuide, ExportRecord, GuideInputs
from drawstring.fabrication.step import (
    finish_step_writers,
    start_step_writers,
    stop_step_writers,
)

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult
    from drawstring.fabrication.profiles import Profile
    from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)

#: String length = flat route length x (1 + margin) + two tails to hold while pulling.
STRING_MARGIN = 0.20
STRING_TAIL_MIN_MM = 150.0
#: Assumed seconds per tool change (dual extruder); two changes per layer with both materials.
TOOL_CHANGE_S = 15.0
#: Density of sintered NdFeB magnets, g/mm^3 (7.5 g/cm^3), for the magnets' mass in bom.csv.
NDFEB_DENSITY_G_MM3 = 7.5e-3


@dataclass(frozen=True)
class Measures:
    """Quantities of a design measured on its fabricated geometry, rounded once: every output
    that states them (bom.csv, manifest.json, assembly.md, route.json, design.json's
    ``metrics.cad``) takes them from :func:`measure_fabrication`.

    Attributes
    ----------
    route_flat_mm, route_assembled_mm : string route along the channels of the printed tiles,
        straight across the gaps and up, over and down the lift bores at lift points
        (:func:`~drawstring.cad.paths.route_lengths`), 0.1 mm.
    string_mm : string to cut, ``route_flat_mm x (1 + STRING_MARGIN) + 2 x tail_mm``, 0.1 mm.
    tail_mm : each of the two ends to hold while pulling, 0.1 mm.
    tile_volume_mm3, hinge_volume_mm3 : volumes of the tile and hinge-part solids, 0.1 mm^3.
    tile_mass_g : printed tiles (solid volume x density x infill) or, for plywood, the panels
        (area x panel thickness x density), 0.1 g.
    hinge_mass_g : hinge parts (volume x hinge density), 0.1 g.
    mass_g : ``tile_mass_g + hinge_mass_g`` (magnets and string left out), 0.1 g.
    """

    route_flat_mm: float
    route_assembled_mm: float
    string_mm: float
    tail_mm: float
    tile_volume_mm3: float
    hinge_volume_mm3: float
    tile_mass_g: float
    hinge_mass_g: float
    mass_g: float

    def to_json(self) -> dict[str, Any]:
        """Keys of design.json's ``metrics.cad``."""
        return {
            "mass_g": self.mass_g,
            "tile_mass_g": self.tile_mass_g,
            "hinge_mass_g": self.hinge_mass_g,
            "route_length_mm": {"flat": self.route_flat_mm, "assembled": self.route_assembled_mm},
            "string_length_mm": self.string_mm,
        }


def plywood_panels(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    holes: Sequence[tuple[int, int, NDArray[np.float64], float]] = (),
    pilots: Sequence[tuple[int, int, NDArray[np.float64], float]] = (),
) -> tuple[list[Panel], list[CableRun]]:
    """The six panels of every tile, with the cable holes of the route, and the runs;
    ``holes`` (magnets) and ``pilots`` (hinge strip screws) are ``(tile, face, point,
    radius)`` in the pose of ``tiles_flat`` (see :func:`panel_holes`)."""
    drill: dict[int, list[tuple[int, NDArray[np.float64]]]] = {}
    runs = cable_runs(tiles_flat, steps, lifts)
    for run in runs:
        drill.setdefault(run.tile, []).extend(run.drill_points)
    panels: list[Panel] = []
    for tile in range(len(tiles_flat)):
        panels += tile_panels(
            tile, tiles_flat[tile], profile, drill.get(tile, []),
            [(f, p, r) for t, f, p, r in holes if t == tile],
            [(f, p, r) for t, f, p, r in pilots if t == tile],
        )  # fmt: skip
    return panels, runs


def panel_holes(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[str],
    cad_flat: CadResult,
) -> tuple[
    list[tuple[int, int, NDArray[np.float64], float]],
    list[tuple[int, int, NDArray[np.float64], float]],
]:
    """Magnet holes (through the side panels, where the solids have their pockets) and the
    hinge strips' pilot holes (through the top or bottom panels, as
    :func:`~drawstring.cad.design.strip_hole_plans` places them on the solids), each
    ``(tile, face, point, radius)`` on the flat tiles."""
    from drawstring.cad.design import strip_hole_plans

    magnets = []
    for pair in cad_flat.magnets:
        for tile, side, point in pair.flat_points(tiles_assembled, tiles_flat):
            magnets.append((int(tile), int(side), point, 0.5 * pair.diameter_mm))
    pilots = []
    if profile.hinge_interlock in ("screws", "staples"):
        rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
        sides = [str(side) for side in hinge_side]
        for (a, _, b, _), side, plan in zip(
            rows, sides, strip_hole_plans(tiles_flat, rows, sides, profile), strict=True
        ):
            face = 4 if side == "top" else 5
            for tile, points in zip((a, b), plan.points, strict=True):
                pilots += [(int(tile), face, point, plan.radius) for point in points]
    return magnets, pilots


def measure_fabrication(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    route_steps: NDArray[np.int64] | Sequence[Sequence[int]],
    lift_tiles: NDArray[np.int64] | Sequence[Sequence[int]],
    cad_flat: CadResult,
    panels: Sequence[Panel] | None = None,
    hinges: NDArray[np.int64] | None = None,
    hinge_side: Sequence[str] = (),
) -> Measures:
    """Route, string and mass of a design, measured on what is fabricated.

    Parameters
    ----------
    profile : the fabrication profile (process, densities, infill, panel thickness).
    tiles_flat, tiles_assembled : (T, 8, 3) float, mm: the tiles as printed (the pose of
        ``flat.step``) and assembled.
    route_steps, lift_tiles : the route and the extra lift bores (as :func:`write_fabrication`).
    cad_flat : the solids in the print pose (tile and hinge-part volumes).
    panels : plywood panels when the caller has them (made here otherwise, with the magnet
        and pilot holes of :func:`panel_holes` where ``hinges`` and ``hinge_side`` are given).
    """
    steps = normalize_route(route_steps)
    flat_route, assembled_route = route_lengths(
        np.asarray(tiles_flat, dtype=np.float64),
        np.asarray(tiles_assembled, dtype=np.float64),
        steps,
        lift_tiles,
    )
    tail = max(STRING_TAIL_MIN_MM, 0.1 * flat_route)
    tile_volume = float(sum(s.volume for s in cad_flat.tiles))
    pad_volume = float(sum(s.volume for s in cad_flat.pads))
    if profile.process == "plywood-cnc":
        if panels is None:
            lifts = np.asarray(lift_tiles, dtype=np.int64).reshape(-1, 2)
            flat = np.asarray(tiles_flat, dtype=np.float64)
            holes: tuple[list[Any], list[Any]] = ([], [])
            if hinges is not None:
                holes = panel_holes(
                    profile, flat, np.asarray(tiles_assembled, dtype=np.float64), hinges,
                    hinge_side, cad_flat,
                )  # fmt: skip
            panels = plywood_panels(profile, flat, steps, lifts, *holes)[0]
        area = sum(p.area for p in panels)
        tile_mass = area * profile.panel_thickness_mm * 1e-9 * profile.density_kg_m3 * 1e3
    else:
        tile_mass = _tile_mass_g(tile_volume, profile)
    tile_g = round(tile_mass, 1)
    hinge_g = round(pad_volume * 1e-9 * profile.hinge_density_kg_m3 * 1e3, 1)
    return Measures(
        route_flat_mm=flat_route,
        route_assembled_mm=assembled_route,
        string_mm=round(flat_route * (1.0 + STRING_MARGIN) + 2.0 * tail, 1),
        tail_mm=round(tail, 1),
        tile_volume_mm3=round(tile_volume, 1),
        hinge_volume_mm3=round(pad_volume, 1),
        tile_mass_g=tile_g,
        hinge_mass_g=hinge_g,
        mass_g=round(tile_g + hinge_g, 1),
    )


# --------------------------------------------------------------------------------------------
# STEP


def _tile_mass_g(volume_mm3: float, profile: Profile) -> float:
    return volume_mm3 * 1e-9 * profile.density_kg_m3 * profile.infill_fraction * 1e3


def _fdm_exports(
    out: Path,
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    hinges: NDArray[np.int64],
    cad_flat: CadResult,
    design_name: str,
    record: ExportRecord,
    workers: int | None,
    with_pads: bool,
    file_name: str,
) -> list[str]:
    """Meshes, print jobs and the 3MF (dual material when ``with_pads``)."""
    tolerance = m3f.mesh_tolerance(profile.thickness_mm)
    items: list[tuple[bd.Shape, str, m3f.PartKind]] = [
        (solid, f"tile_{i}", "tile") for i, solid in enumerate(cad_flat.tiles)
    ]
    if with_pads:
        items += [
            (s, f"hinge_{h}", "pad") for h, s in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True)
        ]
    meshes = m3f.mesh_solids(items, tolerance, workers)
    tile_mesh = {i: meshes[i] for i in range(len(cad_flat.tiles))}
    pad_mesh = (
        {int(h): meshes[len(cad_flat.tiles) + k] for k, h in enumerate(cad_flat.pad_hinge)}
        if with_pads
        else {}
    )
    pad_boxes = {
        h: np.stack([m.vertices.min(axis=0), m.vertices.max(axis=0)]) for h, m in pad_mesh.items()
    }
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
        beds = list(range(len(job_parts)))
        cut: list[int] = []
    else:
        jobs, cut = m3f.plan_print_jobs(tiles_flat, hinges, bed, pad_boxes)
        job_parts = jobs_on_bed(jobs, tile_mesh, pad_mesh, record)
        beds = loose_pads_and_beds(cut, pad_mesh, job_parts, bed, profile, record)
    for entry, bed_index in zip(record.jobs, beds, strict=True):
        entry["bed"] = bed_index + 1
    n_beds = int(max(beds, default=0)) + 1
    stride = profile.bed_x_mm + 20.0  # beds side by side, one object per job

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
    record.estimates["cut_hinges"] = [int(h) for h in cut]
    record.estimates["print_beds"] = n_beds
    title = f"{design_name} ({profile.name})"
    extruders = {"tile": 1, "pad": 2} if with_pads else None
    materials = {"tile": profile.tile_material}
    if with_pads:
        materials["pad"] = profile.hinge_material
    written = [file_name]
    m3f.write_3mf(out / file_name, objects, title=title, extruders=extruders, materials=materials)
    if n_beds > 1:
        # one file per bed, on the bed, for slicers that show one bed at a time
        stem = Path(file_name).stem
        for bed_index in range(n_beds):
            name = f"{stem}-bed{bed_index + 1}.3mf"
            on_bed = [job_object(i, 0.0) for i in range(len(job_parts)) if beds[i] == bed_index]
            m3f.write_3mf(
                out / name, on_bed, title=f"{title}, bed {bed_index + 1} of {n_beds}",
                extruders=extruders, materials=materials,
            )  # fmt: skip
            written.append(name)
    tile_volume = record.estimates["_tile_volume"]
    pad_volume = record.estimates["_pad_volume"] if with_pads else 0.0
    if profile.print_rate_mm3_s > 0:
        printed = tile_volume * profile.infill_fraction + pad_volume
        seconds = printed / profile.print_rate_mm3_s
        layer = max(0.5 * profile.nozzle_mm, 0.1)
        layers = math.ceil(profile.thickness_mm / layer)
        if with_pads:  # each bed is one print
            seconds += n_beds * layers * 2 * TOOL_CHANGE_S
        record.estimates["print_time_h"] = round(seconds / 3600.0, 2)
        record.estimates["print_time_basis"] = (
            f"printed volume / {profile.print_rate_mm3_s} mm^3/s"
            + (f" + 2 tool changes of {TOOL_CHANGE_S:.0f} s per layer" if with_pads else "")
        )
    return written


def _strip_parts(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[str],
    cad_flat: CadResult,
    record: ExportRecord,
) -> tuple[list[Any], list[tuple[int, str, NDArray[np.float64]]]]:
    parts = []
    placed = []
    unlabelled = 0
    for h, pad in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True):
        part, fits = strip_part(
            int(h),
            pad,
            tiles_flat,
            hinges[h],
            hinge_side[h],
            profile.hinge_width_mm,
            0.5 * profile.hinge_pad_length_mm,
        )
        unlabelled += not fits
        parts.append(part)
        placed.append((int(h), hinge_side[h], part.outline))
    if unlabelled:
        record.notes.append(f"{unlabelled} hinge strips too small for engraved tile numbers")
    return parts, placed


def _nesting_record(name: str, nesting: Nesting) -> dict[str, Any]:
    return {
        "file": name,
        "sheets": len(nesting.sheets),
        "sheet_mm": [float(v) for v in nesting.sheet_size],
        "parts": sum(len(s) for s in nesting.sheets),
        "utilisation": [round(float(u), 3) for u in nesting.utilisation],
    }


def _cut_length(nesting: Nesting) -> tuple[float, float]:
    """(cut, engrave) path lengths in mm."""
    cut = engrave = 0.0
    for sheet in nesting.sheets:
        for part in sheet:
            for ring in [part.outline, *part.holes]:
                cut += float(np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).sum())
            cut += float(2 * np.pi * part.circles[:, 2].sum()) if len(part.circles) else 0.0
            for stroke in part.strokes:
                engrave += float(np.linalg.norm(np.diff(stroke, axis=0), axis=1).sum())
    return cut, engrave


def _write_cutlist(path: Path, panels: Sequence[Panel], sheet_of: dict[str, int]) -> None:
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    header = ["panel", "tile", "face", "blank_x_mm", "blank_y_mm", "thickness_mm", "area_mm2"]
    header += ["holes", "sheet"]
    for k in range(4):
        header += [
            f"edge{k}_neighbour",
            f"edge{k}_dihedral_deg",
            f"edge{k}_bevel_deg",
            f"edge{k}_fingers",
        ]
    writer.writerow(header)
    for panel in panels:
        span = np.ptp(panel.part.outline, axis=0)
        row: list[Any] = [
            panel.name,
            panel.tile,
            panel.face,
            f"{span[0]:.2f}",
            f"{span[1]:.2f}",
            f"{panel.thickness:g}",
            f"{panel.area:.1f}",
            len(panel.part.circles) + len(panel.part.drills),
            sheet_of.get(panel.part.name, 0),
        ]
        for edge in panel.edges:
            row += [
                edge.neighbour,
                f"{edge.dihedral_deg:.2f}",
                f"{edge.bevel_deg:.2f}",
                edge.fingers,
            ]
        writer.writerow(row)
    path.write_text(buffer.getvalue(), encoding="utf-8")


# --------------------------------------------------------------------------------------------
# entry point


def write_fabrication(
    folder: Path,
    *,
    profile: Profile,
    linkage: Linkage,
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    hinge_side: Sequence[str],
    route_steps: NDArray[np.int64] | Sequence[Sequence[int]],
    lift_tiles: NDArray[np.int64] | Sequence[Sequence[int]],
    magnet_pairs: NDArray[np.int64] | Sequence[Sequence[int]],
    trims: dict[int, Sequence[NDArray[np.float64]]] | None,
    cad_flat: CadResult,
    cad_assembled: CadResult,
    design_name: str,
    workers: int | None = None,
    guide: AssemblyGuide | None = None,
) -> list[str]:
    """Write every fabrication file of the profile's process under ``folder / "fabrication"``.

    Parameters
    ----------
    folder : the design's output folder.
    profile : the fabrication profile (its ``process`` picks the files).
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

    Returns
    -------
    Paths written, relative to ``folder`` (``fabrication/...``), sorted.
    """
    del magnet_pairs
    out = Path(folder) / "fabrication"
    out.mkdir(parents=True, exist_ok=True)
    tiles_flat = np.asarray(tiles_flat, dtype=np.float64)
    tiles_assembled = np.asarray(tiles_assembled, dtype=np.float64)
    hinges = np.asarray(linkage.hinges, dtype=np.int64).reshape(-1, 4)
    sides = list(hinge_side)
    steps = normalize_route(route_steps)
    lifts = np.asarray(lift_tiles, dtype=np.int64).reshape(-1, 2)
    record = ExportRecord()
    record.notes += list(cad_flat.notes)
    record.trimmed = sorted(int(t) for t in (trims or {}))
    written: list[str] = []

    tile_parts = [(f"tile_{i}", s, profile.tile_material) for i, s in enumerate(cad_flat.tiles)]
    pad_parts = [
        (f"hinge_{h}", s, profile.hinge_material)
        for h, s in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True)
    ]
    assembled_parts = [
        (f"tile_{i}", s, profile.tile_material) for i, s in enumerate(cad_assembled.tiles)
    ]
    step_jobs = [
        (out / "flat.step", tile_parts + pad_parts, f"{design_name} flat"),
        (out / "assembled.step", assembled_parts, f"{design_name} assembled"),
    ]
    # OCCT's STEP writer is serial and the slowest export: write both files in forked
    # processes (they inherit the solids, nothing is pickled) while the rest is made here.
    step_processes = start_step_writers(step_jobs, workers)
    try:
        written += ["flat.step", "assembled.step"]

        panels: list[Panel] = []
        runs: list[CableRun] = []
        if profile.process == "plywood-cnc":
            magnet_holes, pilot_holes = panel_holes(
                profile, tiles_flat, tiles_assembled, linkage.hinges, hinge_side, cad_flat
            )
            panels, runs = plywood_panels(
                profile, tiles_flat, steps, lifts, magnet_holes, pilot_holes
            )
        measures = measure_fabrication(
            profile, tiles_flat, tiles_assembled, steps, lifts, cad_flat, panels
        )
        record.estimates["_tile_volume"] = measures.tile_volume_mm3
        record.estimates["_pad_volume"] = measures.hinge_volume_mm3
        n_tiles, n_pads = len(cad_flat.tiles), len(cad_flat.pads)
        hinge_mass = measures.hinge_mass_g
        tile_mass = measures.tile_mass_g

        def print_job(with_pads: bool, file_name: str) -> list[str]:
            return _fdm_exports(
                out, profile, tiles_flat, hinges, cad_flat, design_name, record, workers,
                with_pads, file_name,
            )  # fmt: skip

        if profile.process == "fdm-dual":
            written += print_job(True, "print.3mf")
            record.bom.append(
                _row(
                    "tile",
                    "printed tile",
                    n_tiles,
                    profile.tile_material,
                    tile_mass,
                    "tile_<id> in print.3mf, extruder 1",
                )
            )
            record.bom.append(
                _row(
                    "hinge pad",
                    "printed hinge pad",
                    n_pads,
                    profile.hinge_material,
                    hinge_mass,
                    "hinge_<id> in print.3mf, extruder 2",
                )
            )
        else:
            strips, placed = _strip_parts(profile, tiles_flat, hinges, sides, cad_flat, record)
            spacing = max(2.0, 2.0 * profile.kerf_mm, profile.tool_diameter_mm + 2.0)
            strip_nesting = nest_parts(
                strips, (profile.bed_x_mm, profile.bed_y_mm), profile.kerf_mm, spacing
            )
            write_sheets_dxf(out / "hinges.dxf", strip_nesting, "H#")
            record.sheets["hinges"] = _nesting_record("hinges.dxf", strip_nesting)
            template = write_placement(
                out / "placement.dxf", out / "placement.svg", tiles_flat, placed
            )
            record.estimates["placement_size_mm"] = [round(float(v), 1) for v in template]
            written += ["hinges.dxf", "placement.dxf", "placement.svg"]
            below = [(h, side, outline) for h, side, outline in placed if side != "top"]
            if below:
                # The layout seen from below, for the bottom faces' strips: the tiles lie on
                # it top faces down (mirrored in x; the numbers still read the right way).
                mirror = np.array([-1.0, 1.0])
                seen_from_below = tiles_flat.copy()
                seen_from_below[..., 0] *= -1.0
                write_placement(
                    out / "placement-bottom.dxf",
                    out / "placement-bottom.svg",
                    seen_from_below,
                    [(h, side, outline * mirror) for h, side, outline in below],
                )
                written += ["placement-bottom.dxf", "placement-bottom.svg"]
            cut, engrave = _cut_length(strip_nesting)
            strip_length = profile.hinge_pad_length_mm + profile.hinge_width_mm
            strip_size = (
                f"{profile.hinge_width_mm:g} x {strip_length:g} x {profile.hinge_thickness_mm:g} mm"
            )
            record.bom.append(
                _row(
                    "hinge strip",
                    f"laser/CNC-cut strip {strip_size}",
                    n_pads,
                    profile.hinge_material,
                    hinge_mass,
                    "hinges.dxf; glue/screw as placement.svg shows",
                )
            )
            cut_total, engrave_total = cut, engrave
            if profile.process == "laser-epdm":
                written += print_job(False, "tiles.3mf")
                record.bom.append(
                    _row(
                        "tile",
                        "printed tile",
                        n_tiles,
                        profile.tile_material,
                        tile_mass,
                        "tiles.3mf, one object per print job (manifest.json print_jobs)",
                    )
                )
                record.bom.append(
                    _row(
                        "glue",
                        "contact glue for rubber to PLA"
                        + (" (and the magnets)" if cad_flat.magnets else ""),
                        1,
                        "",
                        0.0,
                        "one small tube",
                    )
                )
            else:
                panel_spacing = max(5.0, 2.0 * profile.tool_diameter_mm)
                panel_nesting = nest_parts(
                    [p.part for p in panels],
                    (profile.bed_x_mm, profile.bed_y_mm),
                    profile.kerf_mm,
                    panel_spacing,
                )
                write_sheets_dxf(out / "panels.dxf", panel_nesting, "P#")
                record.sheets["panels"] = _nesting_record("panels.dxf", panel_nesting)
                sheet_of = {
                    part.name: k + 1
                    for k, sheet in enumerate(panel_nesting.sheets)
                    for part in sheet
                }
                _write_cutlist(out / "cutlist.csv", panels, sheet_of)
                written += ["panels.dxf", "cutlist.csv"]
                record.bom.append(
                    _row(
                        "panel",
                        f"plywood panel {profile.panel_thickness_mm:g} mm ({profile.joint} joints)",
                        len(panels),
                        profile.tile_material,
                        tile_mass,
                        f"panels.dxf on {len(panel_nesting.sheets)} sheets of "
                        f"{profile.bed_x_mm:g} x {profile.bed_y_mm:g} mm; cutlist.csv",
                    )
                )
                tube_total = sum(r.tube_length_mm for r in runs)
                record.bom.append(
                    _row(
                        "channel tube",
                        "plastic tube, outer diameter "
                        f"{profile.string_diameter_mm + profile.channel_clearance_mm:g} mm",
                        len(runs),
                        "plastic",
                        0.0,
                        f"total {tube_total / 1000:.2f} m; one per route step "
                        f"({len(steps)}) and lift bore ({len(runs) - len(steps)}), each with "
                        "its tile and length in manifest.json channel_tubes",
                    )
                )
                record.estimates["channel_tubes_mm"] = [round(r.tube_length_mm, 1) for r in runs]
                # runs come in route order, then the lift bores (cable_runs)
                record.estimates["channel_tubes"] = [
                    {
                        "tile": r.tile,
                        **({"route_step": k} if k < len(steps) else {"lift_bore": k - len(steps)}),
                        "length_mm": round(r.tube_length_mm, 1),
                    }
                    for k, r in enumerate(runs)
                ]
                # one screw per pilot hole, one staple per pair (as cut: holes that found no
                # room on a small tile are left out and not counted)
                fasteners = cad_flat.fasteners
                if fasteners and profile.hinge_interlock == "screws":
                    pilot = 2.0 * max((r for *_, r in pilot_holes), default=0.0)
                    grip = profile.hinge_thickness_mm + profile.panel_thickness_mm
                    record.bom.append(
                        _row(
                            "screw",
                            f"wood screw for a {pilot:g} mm pilot hole, at least {grip:g} mm "
                            f"long (the {profile.hinge_thickness_mm:g} mm strip and the "
                            f"{profile.panel_thickness_mm:g} mm panel)",
                            fasteners,
                            "steel",
                            0.0,
                            "one per pilot hole: up to 2 per tile per hinge",
                        )
                    )
                elif fasteners:
                    record.bom.append(
                        _row(
                            "staple",
                            "staple through the rubber strip",
                            fasteners,
                            "steel",
                            0.0,
                            "one per pair of pilot holes: up to 1 per tile per hinge",
                        )
                    )
                record.bom.append(
                    _row(
                        "glue",
                        "wood glue for the panel joints and channel tubes"
                        + (" (and the magnets)" if cad_flat.magnets else ""),
                        1,
                        "",
                        0.0,
                        "",
                    )
                )
                pc, pe = _cut_length(panel_nesting)
                cut_total += pc
                engrave_total += pe
            if profile.cut_speed_mm_s > 0:
                seconds = (cut_total + engrave_total) / profile.cut_speed_mm_s
                record.estimates["cut_time_h"] = round(seconds / 3600.0, 2)
                record.estimates["cut_time_basis"] = (
                    f"{cut_total / 1000:.1f} m cut + {engrave_total / 1000:.1f} m engraved at "
                    f"{profile.cut_speed_mm_s:g} mm/s, one pass"
                )

        flat_route, string_mm, tail = measures.route_flat_mm, measures.string_mm, measures.tail_mm
        string_section_mm2 = math.pi * (0.5 * profile.string_diameter_mm) ** 2
        record.bom.append(
            _row(
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
        if string_is_cable(profile):  # a cable is not knotted (assembly.md, Pull)
            record.bom.append(
                _row(
                    "ferrule",
                    f"crimp ferrule for {profile.string_diameter_mm:g} mm cable (or two "
                    "wire-rope clips)",
                    1,
                    "aluminium",
                    0.0,
                    "joins the two ends once the part is pulled shut",
                )
            )
        record.unlabelled = list(cad_flat.unlabelled)
        magnets = cad_flat.magnets
        if profile.process == "fdm-dual" and (magnets or record.estimates.get("cut_hinges")):
            glued = " and ".join(
                what
                for what, used in (
                    ("loose hinge pads", bool(record.estimates.get("cut_hinges"))),
                    ("magnets", bool(magnets)),
                )
                if used
            )
            record.bom.append(_row("glue", f"CA (cyanoacrylate) glue for the {glued}", 1, "",
                                   0.0, "one small tube"))  # fmt: skip
        if magnets:
            polarity = "; ".join(
                f"tile {m.tile_a} side {m.side_a} {m.polarity_a} out / "
                f"tile {m.tile_b} side {m.side_b} {m.polarity_b} out"
                for m in magnets
            )
            disc_mm3 = math.pi * (0.5 * profile.magnet_diameter_mm) ** 2 * profile.magnet_height_mm
            record.bom.append(
                _row(
                    "magnet",
                    f"disc magnet {profile.magnet_diameter_mm:g} x {profile.magnet_height_mm:g} mm",
                    2 * len(magnets),
                    "NdFeB",
                    round(2 * len(magnets) * disc_mm3 * NDFEB_DENSITY_G_MM3, 1),
                    polarity,
                )
            )
        cost = (
            tile_mass / 1000 * profile.tile_price_per_kg
            + hinge_mass / 1000 * profile.hinge_price_per_kg
            + string_mm / 1000 * profile.string_price_per_m
            + 2 * len(magnets) * profile.magnet_price_each
        )
        del record.estimates["_tile_volume"], record.estimates["_pad_volume"]
        record.estimates.update(
            {
                "tile_volume_mm3": measures.tile_volume_mm3,
                "hinge_volume_mm3": measures.hinge_volume_mm3,
                "tile_mass_g": tile_mass,
                "hinge_mass_g": hinge_mass,
                "mass_g": measures.mass_g,
                "string_length_mm": string_mm,
                "flat_route_length_mm": flat_route,
                "string_tail_mm": tail,
                "string_rule": f"flat route x {1 + STRING_MARGIN:g} + 2 x "
                f"max({STRING_TAIL_MIN_MM:g} mm, 10 % of the route)",
                "material_cost": round(cost, 2),
                "currency": profile.currency,
            }
        )
    except BaseException:
        stop_step_writers(step_processes)  # an error or Ctrl-C: they write into the staging
        raise
    finish_step_writers(step_processes)
    _write_bom(out / "bom.csv", record, profile)
    written.append("bom.csv")
    if guide is not None:
        written += guide(
            out,
            GuideInputs(
                profile=profile,
                design_name=design_name,
                record=record,
                tiles_flat=tiles_flat,
                tiles_assembled=tiles_assembled,
                hinges=hinges,
                sides=sides,
                steps=steps,
                lifts=lifts,
                magnets=magnets,
                panels=panels,
            ),
        )
    manifest = {
        "design": design_name,
        "profile": profile.name,
        "process": profile.process,
        "tiles": n_tiles,
        "hinge_parts": n_pads,
        "print_jobs": record.jobs,
        "sheets": record.sheets,
        "estimates": record.estimates,
        "magnets": [m.to_json() for m in magnets],
        "notes": record.notes,
        "files": [
            {
                "path": f"fabrication/{name}",
                "bytes": (out / name).stat().st_size,
                "sha256": hashlib.sha256((out / name).read_bytes()).hexdigest(),
            }
            for name in sorted(written)
        ],
    }
    (out / "manifest.json").write_text(
        json.dumps(manifest, indent=1, sort_keys=True) + "\n", encoding="utf-8"
    )
    written.append("manifest.json")
    return sorted(f"fabrication/{name}" for name in written)


def _row(
    item: str,
    description: str,
    count: int,
    material: str,
    mass_g: float,
    note: str,
    length_mm: float | None = None,
) -> dict[str, Any]:
    return {
        "item": item,
        "description": description,
        "count": int(count),
        "material": material,
        "mass_g": round(float(mass_g), 1),
        "length_mm": "" if length_mm is None else round(float(length_mm), 1),
        "note": note,
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
    for key in ("print_time_h", "cut_time_h"):
        if key in estimates:
            basis = estimates[key.replace("_h", "_basis")]
            writer.writerow(
                {"item": key.replace("_h", ""), "description": f"{estimates[key]} h", "note": basis}
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
