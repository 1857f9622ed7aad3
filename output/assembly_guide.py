"""The assembly guide under ``DIR/fabrication/``: ``assembly.md`` and its pictures
(``assembly-tiles.png``, ``assembly-threading.png``, ``assembly-pull.png``).

Both follow one threading order (:mod:`~drawstring.output.assembly_order`); the text is
written by :mod:`~drawstring.output.assembly_text`, the pictures by
:mod:`~drawstring.output.assembly_pictures`.
"""

from __future__ import annotations

from pathlib import Path

from drawstring.fabrication.record import GuideInputs
from drawstring.output.assembly_pictures import write_pictures
from drawstring.output.assembly_text import write_assembly


def write_guide(out: Path, inputs: GuideInputs) -> list[str]:
    """The assembly guide of a fabrication folder: its pictures and ``assembly.md``."""
    pictures = write_pictures(
        out, inputs.tiles_flat, inputs.tiles_assembled, inputs.hinges, inputs.sides,
        inputs.steps, inputs.lifts,
        cut_hinges=[int(h) for h in inputs.record.estimates.get("cut_hinges", [])],
    )  # fmt: skip
    write_assembly(
        out / "assembly.md",
        inputs.profile,
        inputs.design_name,
        inputs.record,
        inputs.hinges,
        inputs.sides,
        inputs.steps,
        inputs.lifts,
        inputs.magnets,
        inputs.panels,
        pictures,
        printer=inputs.printer,
    )
    return [*pictures, "assembly.md"]
