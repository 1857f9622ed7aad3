"""The report's word on printing: the bed the flat layout is checked against (the chosen
printer's), and the printing time and filament of the fabrication files."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:
    from drawstring.fabrication.profiles import Profile


def print_bed(design: dict[str, Any], profile: Profile) -> tuple[tuple[float, float], str]:
    """The bed the tiles print on and its printer's name: design.json's ``options.printer``,
    else the profile's own bed."""
    from drawstring.fabrication.printers import load_printer

    chosen = design.get("options", {}).get("printer")
    if chosen:
        try:
            printer = load_printer(str(chosen))
        except (InputError, OSError):
            pass
        else:
            return printer.bed, printer.name
    return (profile.bed_x_mm, profile.bed_y_mm), profile.name


def print_numbers(folder: Path) -> str:
    """The printing time and filament of a design folder's fabrication files: PrusaSlicer's
    (naming its version) where it sliced them, else drawstring's estimate; empty without
    them."""
    try:
        manifest = json.loads((folder / "fabrication" / "manifest.json").read_text())
    except (OSError, ValueError):
        return ""
    sliced = manifest.get("slicer") or {}
    estimates = manifest.get("estimates") or {}
    if sliced:
        hours, grams = sliced.get("print_time_h", 0.0), sliced.get("filament_g") or {}
        source = f"{sliced.get('slicer', 'PrusaSlicer')} with the shipped .ini"
    elif "print_time_h" in estimates:
        hours, grams = estimates["print_time_h"], estimates.get("filament_g") or {}
        source = "drawstring's estimate, fitted to PrusaSlicer 2.5.0's"
    else:
        return ""
    filament = "".join(f", {float(g):.0f} g {name}" for name, g in grams.items())
    return f"{float(hours):.1f} h{filament} ({source}; bom.csv)"
