"""What the exports measured while writing a fabrication folder, and what its assembly guide
reads: shared by the exports, the print beds and the output layer's guide, so that none of them
imports another's module for its types.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication.profiles import Profile

if TYPE_CHECKING:  # panels load the CAD kernel
    from drawstring.fabrication.panels import Panel
    from drawstring.fabrication.printers import Printer


@dataclass
class ExportRecord:
    """What the exports measured, for bom.csv and manifest.json."""

    bom: list[dict[str, Any]] = field(default_factory=list)
    estimates: dict[str, Any] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    jobs: list[dict[str, Any]] = field(default_factory=list)
    sheets: dict[str, Any] = field(default_factory=dict)
    #: per print bed: its 3MF file, PrusaSlicer settings, wipe tower, estimate and (where the
    #: slicer ran) what PrusaSlicer reported
    beds: list[dict[str, Any]] = field(default_factory=list)
    #: what PrusaSlicer reported (empty where it did not run): manifest.json's ``slicer``
    slicer: dict[str, Any] = field(default_factory=dict)
    #: tiles without an engraved number
    unlabelled: list[int] = field(default_factory=list)
    #: tiles with an overlap cut away (hinges.json trims)
    trimmed: list[int] = field(default_factory=list)


@dataclass(frozen=True)
class GuideInputs:
    """What the assembly guide reads of a fabrication folder being written."""

    profile: Profile
    design_name: str
    record: ExportRecord
    tiles_flat: NDArray[np.float64]
    tiles_assembled: NDArray[np.float64]
    hinges: NDArray[np.int64]
    sides: list[str]
    steps: NDArray[np.int64]
    lifts: NDArray[np.int64]
    magnets: list[Any]
    panels: list[Panel]
    #: the printer the tiles print on (None where nothing is printed)
    printer: Printer | None = None


#: Writes the assembly guide into a fabrication folder; returns the file names it wrote.
AssemblyGuide = Callable[[Path, GuideInputs], list[str]]
