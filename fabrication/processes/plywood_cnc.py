"""``plywood-cnc``: tiles as plywood boxes of six CNC- or laser-cut panels, rubber hinge strips
screwed or stapled on, the cable in channel tubes through the boxes."""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from drawstring.fabrication.dxf import nest_parts, write_sheets_dxf
from drawstring.fabrication.panels import (
    CableRun,
    Panel,
    PanelHole,
    panel_holes,
    plywood_panels,
)
from drawstring.fabrication.processes.base import bom_row, cut_length, nesting_record
from drawstring.fabrication.processes.strips import StripProcess
from drawstring.fabrication.profiles import Process

if TYPE_CHECKING:
    from drawstring.fabrication.measures import Measures


class PlywoodCnc(StripProcess):
    """``panels.dxf`` (six panels per tile, butt or finger joints with dog-bones, cable holes,
    engraved labels, nested on sheets), ``hinges.dxf``, ``cutlist.csv``, ``placement.dxf`` /
    ``.svg``; cable and channel-tube lengths in ``bom.csv``."""

    process = Process.PLYWOOD_CNC

    runs: list[CableRun]
    pilot_holes: list[PanelHole]
    made: list[Panel]

    def panels(self) -> list[Panel]:
        """Every tile's six panels with the holes of the cable, the magnets and the strips'
        pilot holes (made once, kept for :meth:`render_tiles`)."""
        job = self.job
        magnet_holes, self.pilot_holes = panel_holes(
            job.profile, job.tiles_flat, job.tiles_assembled, job.hinges, job.sides, job.cad_flat
        )
        self.made, self.runs = plywood_panels(
            job.profile, job.tiles_flat, job.steps, job.lifts, magnet_holes, self.pilot_holes
        )
        return self.made

    def render_tiles(self, measures: Measures) -> tuple[float, float]:
        job = self.job
        profile, record = job.profile, job.record
        spacing = max(5.0, 2.0 * profile.tool_diameter_mm)
        nesting = nest_parts(
            [p.part for p in self.made],
            (profile.bed_x_mm, profile.bed_y_mm),
            profile.kerf_mm,
            spacing,
        )
        write_sheets_dxf(job.out / "panels.dxf", nesting, "P#")
        record.sheets["panels"] = nesting_record("panels.dxf", nesting)
        sheet_of = {part.name: k + 1 for k, sheet in enumerate(nesting.sheets) for part in sheet}
        _write_cutlist(job.out / "cutlist.csv", self.made, sheet_of)
        job.written += ["panels.dxf", "cutlist.csv"]
        record.bom.append(
            bom_row(
                "panel",
                f"plywood panel {profile.panel_thickness_mm:g} mm ({profile.joint} joints)",
                len(self.made),
                profile.tile_material,
                measures.tile_mass_g,
                f"panels.dxf on {len(nesting.sheets)} sheets of "
                f"{profile.bed_x_mm:g} x {profile.bed_y_mm:g} mm; cutlist.csv",
            )
        )
        self._tube_rows()
        self._fastener_rows()
        record.bom.append(
            bom_row(
                "glue",
                "wood glue for the panel joints and channel tubes"
                + (" (and the magnets)" if job.cad_flat.magnets else ""),
                1,
                "",
                0.0,
                "",
            )
        )
        return cut_length(nesting)

    def _tube_rows(self) -> None:
        """The channel tubes: one bom.csv row, and each tube's tile and length in the
        manifest (the runs come in route order, then the lift bores: ``cable_runs``)."""
        job, runs = self.job, self.runs
        steps = job.steps
        tube_total = sum(r.tube_length_mm for r in runs)
        job.record.bom.append(
            bom_row(
                "channel tube",
                "plastic tube, outer diameter "
                f"{job.profile.string_diameter_mm + job.profile.channel_clearance_mm:g} mm",
                len(runs),
                "plastic",
                0.0,
                f"total {tube_total / 1000:.2f} m; one per route step "
                f"({len(steps)}) and lift bore ({len(runs) - len(steps)}), each with "
                "its tile and length in manifest.json channel_tubes",
            )
        )
        job.record.estimates["channel_tubes_mm"] = [round(r.tube_length_mm, 1) for r in runs]
        job.record.estimates["channel_tubes"] = [
            {
                "tile": r.tile,
                **({"route_step": k} if k < len(steps) else {"lift_bore": k - len(steps)}),
                "length_mm": round(r.tube_length_mm, 1),
            }
            for k, r in enumerate(runs)
        ]

    def _fastener_rows(self) -> None:
        """One screw per pilot hole, or one staple per pair, as cut: holes that found no room
        on a small tile are left out and not counted."""
        job = self.job
        profile, fasteners = job.profile, job.cad_flat.fasteners
        if not fasteners:
            return
        if profile.hinge_interlock == "screws":
            pilot = 2.0 * max((r for *_, r in self.pilot_holes), default=0.0)
            grip = profile.hinge_thickness_mm + profile.panel_thickness_mm
            row = bom_row(
                "screw",
                f"wood screw for a {pilot:g} mm pilot hole, at least {grip:g} mm "
                f"long (the {profile.hinge_thickness_mm:g} mm strip and the "
                f"{profile.panel_thickness_mm:g} mm panel)",
                fasteners,
                "steel",
                0.0,
                "one per pilot hole: up to 2 per tile per hinge",
            )
        else:
            row = bom_row(
                "staple",
                "staple through the rubber strip",
                fasteners,
                "steel",
                0.0,
                "one per pair of pilot holes: up to 1 per tile per hinge",
            )
        job.record.bom.append(row)


def _write_cutlist(path: Path, panels: Sequence[Panel], sheet_of: dict[str, int]) -> None:
    """``cutlist.csv``: every panel's blank, holes, sheet and edges (neighbour, dihedral and
    bevel angle, fingers)."""
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
