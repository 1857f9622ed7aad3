"""What every process writer shares: the job it writes (:class:`FabricationJob`), the
interface (:class:`ProcessWriter`) and the helpers for bom.csv rows and nested sheets."""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from drawstring.fabrication.beside import Beside
from drawstring.fabrication.record import ExportRecord
from drawstring.geometry.core.types import FloatArray, IntArray

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult
    from drawstring.fabrication.dxf import Nesting
    from drawstring.fabrication.measures import Measures
    from drawstring.fabrication.panels import Panel
    from drawstring.fabrication.printers import Printer
    from drawstring.fabrication.profiles import Process, Profile


@dataclass
class FabricationJob:
    """One fabrication folder being written: what the writers read, and what they fill in
    (``record`` for bom.csv and manifest.json, ``written``: the file names under ``out``).

    Attributes
    ----------
    out : the ``fabrication/`` folder.
    tiles_flat, tiles_assembled : (T, 8, 3) float, mm.
    hinges : (H, 4) int ``(tile_a, corner_a, tile_b, corner_b)``.
    sides : (H,) ``"top"`` | ``"bottom"``.
    steps : (S, 4) int route steps (:func:`~drawstring.cad.design.normalize_route`).
    lifts : (L, 2) int ``(tile, side)`` extra lift bores.
    cad_flat : the solids in the print pose.
    workers : processes for tessellation (None: CPU count).
    printer : the printer the tiles print on (None where nothing is printed).
    """

    out: Path
    profile: Profile
    design_name: str
    tiles_flat: FloatArray
    tiles_assembled: FloatArray
    hinges: IntArray
    sides: list[str]
    steps: IntArray
    lifts: IntArray
    cad_flat: CadResult
    workers: int | None
    printer: Printer | None = None
    record: ExportRecord = field(default_factory=ExportRecord)
    written: list[str] = field(default_factory=list)
    #: files still being written in forked processes (:meth:`write_beside`), which
    #: :func:`~drawstring.fabrication.exports.write_fabrication` waits for
    writing: Beside = field(init=False)

    def __post_init__(self) -> None:
        self.writing = Beside(self.workers)

    def write_beside(self, write: Callable[..., object], *args: Any, **kwargs: Any) -> None:
        """``write(*args, **kwargs)`` in a forked process while the caller goes on (here where
        fork is unavailable or ``workers == 1``): a file nothing else in the folder reads
        before the manifest, such as a 3MF, whose text and compression take seconds."""
        self.writing.start(
            args[0].name if args and isinstance(args[0], Path) else write.__name__,
            functools.partial(write, **kwargs),
            *args,
        )


class ProcessWriter:
    """The files of one fabrication process and their rows in bom.csv.

    A writer is made for one :class:`FabricationJob`.  The shared steps (STEP files, string,
    magnets, cost, bom.csv, the guide, manifest.json) are
    :func:`~drawstring.fabrication.exports.write_fabrication`'s; between them it calls, in
    this order, :meth:`panels`, :meth:`render` and :meth:`assembly_rows`.
    """

    #: the process this writer makes
    process: ClassVar[Process]

    def __init__(self, job: FabricationJob) -> None:
        self.job = job

    def panels(self) -> list[Panel]:
        """The flat panels the tiles are made of (none for printed tiles); measured for the
        tiles' mass and handed to the guide."""
        return []

    def render(self, measures: Measures) -> None:
        """Write the process's files into ``job.out`` (their names into ``job.written``) and
        add the rows of the parts they make to ``job.record.bom``."""
        raise NotImplementedError

    def assembly_rows(self) -> None:
        """Rows of bom.csv listed after the string's: what the process glues in at assembly
        (none by default)."""


def bom_row(
    item: str,
    description: str,
    count: int,
    material: str,
    mass_g: float,
    note: str,
    length_mm: float | None = None,
) -> dict[str, Any]:
    """One row of bom.csv."""
    return {
        "item": item,
        "description": description,
        "count": int(count),
        "material": material,
        "mass_g": round(float(mass_g), 1),
        "length_mm": "" if length_mm is None else round(float(length_mm), 1),
        "note": note,
    }


def nesting_record(name: str, nesting: Nesting) -> dict[str, Any]:
    """The manifest's ``sheets`` entry of a nested DXF file."""
    return {
        "file": name,
        "sheets": len(nesting.sheets),
        "sheet_mm": [float(v) for v in nesting.sheet_size],
        "parts": sum(len(s) for s in nesting.sheets),
        "utilisation": [round(float(u), 3) for u in nesting.utilisation],
    }


def cut_length(nesting: Nesting) -> tuple[float, float]:
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
