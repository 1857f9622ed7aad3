"""``fdm-dual``: tiles and TPU hinge pads printed together on a dual-extruder printer."""

from __future__ import annotations

from typing import TYPE_CHECKING

from drawstring.fabrication.processes.base import ProcessWriter, bom_row
from drawstring.fabrication.processes.print_jobs import write_print_jobs
from drawstring.fabrication.profiles import Process

if TYPE_CHECKING:
    from drawstring.fabrication.measures import Measures


class FdmDual(ProcessWriter):
    """``print.3mf``: one object per print job, tiles as volumes for extruder 1 and TPU pads
    for extruder 2, with PrusaSlicer's and Bambu/Orca's configs.  A layout larger than the bed
    is split into jobs along rows of hinges; pads of the hinges between jobs are printed loose
    in a last job and glued in."""

    process = Process.FDM_DUAL

    def render(self, measures: Measures) -> None:
        job = self.job
        profile = job.profile
        write_print_jobs(job, True, "print.3mf")
        job.record.bom.append(
            bom_row(
                "tile",
                "printed tile",
                len(job.cad_flat.tiles),
                profile.tile_material,
                measures.tile_mass_g,
                "tile_<id> in print.3mf, extruder 1",
            )
        )
        job.record.bom.append(
            bom_row(
                "hinge pad",
                "printed hinge pad",
                len(job.cad_flat.pads),
                profile.hinge_material,
                measures.hinge_mass_g,
                "hinge_<id> in print.3mf, extruder 2",
            )
        )

    def assembly_rows(self) -> None:
        """CA glue for the loose hinge pads and the magnets, where there are any."""
        record = self.job.record
        loose = bool(record.estimates.get("cut_hinges"))
        magnets = bool(self.job.cad_flat.magnets)
        if not (magnets or loose):
            return
        glued = " and ".join(
            what for what, used in (("loose hinge pads", loose), ("magnets", magnets)) if used
        )
        record.bom.append(
            bom_row(
                "glue", f"CA (cyanoacrylate) glue for the {glued}", 1, "", 0.0, "one small tube"
            )
        )
