"""Rubber hinge strips cut from sheet (``laser-epdm`` and ``plywood-cnc``): ``hinges.dxf``
nested and kerf-compensated, the 1:1 placement templates, and the cut time of the sheets."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from drawstring.fabrication.dxf import nest_parts, write_sheets_dxf
from drawstring.fabrication.parts import strip_part, write_placement
from drawstring.fabrication.processes.base import (
    ProcessWriter,
    bom_row,
    cut_length,
    nesting_record,
)
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:
    from drawstring.fabrication.measures import Measures
    from drawstring.fabrication.processes.base import FabricationJob
    from drawstring.geometry.core.types import FloatArray


class StripProcess(ProcessWriter):
    """A process whose hinges are rubber strips cut from sheet and fixed on the tiles on a
    placement template; :meth:`render` writes the strips, then the tiles
    (:meth:`render_tiles`), then the cut time of both."""

    def render(self, measures: Measures) -> None:
        cut, engrave = self.render_strips(measures)
        tiles_cut, tiles_engrave = self.render_tiles(measures)
        self.cut_time(cut + tiles_cut, engrave + tiles_engrave)

    def render_tiles(self, measures: Measures) -> tuple[float, float]:
        """Write the tiles' files and rows; returns the (cut, engrave) lengths (mm) they add
        to the strips'."""
        raise NotImplementedError

    def render_strips(self, measures: Measures) -> tuple[float, float]:
        """``hinges.dxf``, the placement templates and the strips' row; returns the strips'
        (cut, engrave) lengths, mm."""
        job = self.job
        profile, out, record = job.profile, job.out, job.record
        strips, placed = _strip_parts(job)
        spacing = max(2.0, 2.0 * profile.kerf_mm, profile.tool_diameter_mm + 2.0)
        nesting = nest_parts(strips, (profile.bed_x_mm, profile.bed_y_mm), profile.kerf_mm, spacing)
        write_sheets_dxf(out / "hinges.dxf", nesting, "H#")
        record.sheets["hinges"] = nesting_record("hinges.dxf", nesting)
        template = write_placement(
            out / "placement.dxf", out / "placement.svg", job.tiles_flat, placed
        )
        record.estimates["placement_size_mm"] = [round(float(v), 1) for v in template]
        job.written += ["hinges.dxf", "placement.dxf", "placement.svg"]
        _placement_from_below(job, placed)
        strip_length = profile.hinge_pad_length_mm + profile.hinge_width_mm
        strip_size = (
            f"{profile.hinge_width_mm:g} x {strip_length:g} x {profile.hinge_thickness_mm:g} mm"
        )
        record.bom.append(
            bom_row(
                "hinge strip",
                f"laser/CNC-cut strip {strip_size}",
                len(job.cad_flat.pads),
                profile.hinge_material,
                measures.hinge_mass_g,
                "hinges.dxf; glue/screw as placement.svg shows",
            )
        )
        return cut_length(nesting)

    def cut_time(self, cut: float, engrave: float) -> None:
        """The cut time estimate: every path cut and engraved once at the profile's speed."""
        profile = self.job.profile
        if profile.cut_speed_mm_s <= 0:
            return
        seconds = (cut + engrave) / profile.cut_speed_mm_s
        self.job.record.estimates["cut_time_h"] = round(seconds / 3600.0, 2)
        self.job.record.estimates["cut_time_basis"] = (
            f"{cut / 1000:.1f} m cut + {engrave / 1000:.1f} m engraved at "
            f"{profile.cut_speed_mm_s:g} mm/s, one pass"
        )


def _strip_parts(job: FabricationJob) -> tuple[list[Any], list[tuple[int, str, FloatArray]]]:
    """Each hinge's strip as a flat part, and ``(hinge, side, outline)`` where it lies on the
    flat layout; a note counts the strips too small for their engraved tile numbers."""
    profile, cad_flat = job.profile, job.cad_flat
    parts = []
    placed = []
    unlabelled = 0
    for h, pad in zip(cad_flat.pad_hinge, cad_flat.pads, strict=True):
        part, fits = strip_part(
            int(h),
            pad,
            job.tiles_flat,
            job.hinges[h],
            job.sides[h],
            profile.hinge_width_mm,
            0.5 * profile.hinge_pad_length_mm,
        )
        unlabelled += not fits
        parts.append(part)
        placed.append((int(h), job.sides[h], part.outline))
    if unlabelled:
        job.record.notes.append(f"{unlabelled} hinge strips too small for engraved tile numbers")
    return parts, placed


def _placement_from_below(job: FabricationJob, placed: list[tuple[int, str, FloatArray]]) -> None:
    """``placement-bottom.dxf`` / ``.svg`` for the strips on the bottom faces: the layout seen
    from below, the tiles lying on it top faces down (mirrored in x; the numbers still read
    the right way)."""
    below = [(h, side, outline) for h, side, outline in placed if side != HingeSide.TOP]
    if not below:
        return
    mirror = np.array([-1.0, 1.0])
    seen_from_below = job.tiles_flat.copy()
    seen_from_below[..., 0] *= -1.0
    write_placement(
        job.out / "placement-bottom.dxf",
        job.out / "placement-bottom.svg",
        seen_from_below,
        [(h, side, outline * mirror) for h, side, outline in below],
    )
    job.written += ["placement-bottom.dxf", "placement-bottom.svg"]
