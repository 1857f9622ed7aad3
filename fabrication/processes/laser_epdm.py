"""``laser-epdm``: tiles printed loose in one material, rubber hinge strips laser-cut from EPDM
sheet and glued into the tiles' recesses on a placement template."""

from __future__ import annotations

from typing import TYPE_CHECKING

from drawstring.fabrication.processes.base import bom_row
from drawstring.fabrication.processes.print_jobs import write_print_jobs
from drawstring.fabrication.processes.strips import StripProcess
from drawstring.fabrication.profiles import Process

if TYPE_CHECKING:
    from drawstring.fabrication.measures import Measures


class LaserEpdm(StripProcess):
    """``tiles.3mf`` (single material; the loose tiles turned and nested on as few beds as
    shelf packing takes, one object per bed), ``hinges.dxf`` (kerf-compensated rubber strips
    nested on sheets, tile numbers engraved as strokes), ``placement.dxf`` and
    ``placement.svg``."""

    process = Process.LASER_EPDM

    def render_tiles(self, measures: Measures) -> tuple[float, float]:
        job = self.job
        write_print_jobs(job, False, "tiles.3mf")
        job.record.bom.append(
            bom_row(
                "tile",
                "printed tile",
                len(job.cad_flat.tiles),
                job.profile.tile_material,
                measures.tile_mass_g,
                "tiles.3mf, one object per print job (manifest.json print_jobs)",
            )
        )
        job.record.bom.append(
            bom_row(
                "glue",
                "contact glue for rubber to PLA"
                + (" (and the magnets)" if job.cad_flat.magnets else ""),
                1,
                "",
                0.0,
                "one small tube",
            )
        )
        return 0.0, 0.0
