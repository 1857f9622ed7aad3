"""Printer presets: the machine a design's tiles (and hinge pads) are printed on.

A preset is a TOML file, shipped under ``profiles/printers/`` (:data:`SHIPPED_PRINTERS`) or a
user's own, checked key by key as a profile is (:func:`~.profiles.parse_table`).  It gives the
bed the print jobs are planned on (the rectangle every toolhead reaches, and where it lies in
the machine's coordinates), the toolheads, the motion limits and speeds, and the PLA and TPU
temperatures: everything the PrusaSlicer settings of a print job (:mod:`.slicer`) and the
print-time estimate (:mod:`.print_estimate`) need.

A profile names its printer in ``machine.printer``; ``--printer`` picks another.  A profile
that names none (a file saved before the key existed) prints on the generic preset of its
process with the bed and nozzle of its own ``[machine]`` table.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from drawstring.fabrication.profiles import (
    Field,
    Process,
    Profile,
    parse_table,
    read_toml,
    table_toml,
)
from drawstring.geometry.core.errors import InputError

#: Printer presets shipped with drawstring, by name (``profiles/printers/NAME.toml``).
SHIPPED_PRINTERS: tuple[str, ...] = (
    "generic-dual",
    "generic-single",
    "prusa-xl-2t",
    "bambu-h2d",
    "snapmaker-u1",
)
#: The preset a printed profile without ``machine.printer`` falls back to, by toolheads needed.
GENERIC_PRINTER = {2: "generic-dual", 1: "generic-single"}
#: G-code flavours PrusaSlicer 2.5 knows (it reads an unknown one as reprap); Klipper
#: printers run marlin2-style G-code.
GCODE_FLAVORS = ("marlin2", "marlin", "reprapfirmware")

PRINTER_SCHEMA: dict[str, Field] = {
    "name": Field("", "name", str),
    "description": Field("", "description", str),
    "maker": Field("", "maker", str),
    "source": Field("", "source", str),
    "bed_x_mm": Field("bed", "x_mm", float, 20.0, 2000.0, "mm"),
    "bed_y_mm": Field("bed", "y_mm", float, 20.0, 2000.0, "mm"),
    "bed_origin_x_mm": Field("bed", "origin_x_mm", float, 0.0, 2000.0, "mm"),
    "bed_origin_y_mm": Field("bed", "origin_y_mm", float, 0.0, 2000.0, "mm"),
    "height_mm": Field("bed", "height_mm", float, 5.0, 2000.0, "mm"),
    "toolheads": Field("toolheads", "count", int, 1, 16, "toolheads"),
    "nozzle_mm": Field("toolheads", "nozzle_mm", float, 0.1, 2.0, "mm"),
    "filament_mm": Field("toolheads", "filament_mm", float, 1.0, 3.5, "mm"),
    "gcode_flavor": Field("motion", "gcode_flavor", str, choices=GCODE_FLAVORS),
    "max_speed_mm_s": Field("motion", "max_speed_mm_s", float, 10.0, 2000.0, "mm/s"),
    "max_acceleration_mm_s2": Field(
        "motion", "max_acceleration_mm_s2", float, 100.0, 100_000.0, "mm/s^2"
    ),
    "print_acceleration_mm_s2": Field(
        "motion", "print_acceleration_mm_s2", float, 100.0, 100_000.0, "mm/s^2"
    ),
    "travel_acceleration_mm_s2": Field(
        "motion", "travel_acceleration_mm_s2", float, 100.0, 100_000.0, "mm/s^2"
    ),
    "perimeter_mm_s": Field("speeds", "perimeter_mm_s", float, 5.0, 1000.0, "mm/s"),
    "external_perimeter_mm_s": Field(
        "speeds", "external_perimeter_mm_s", float, 5.0, 1000.0, "mm/s"
    ),
    "infill_mm_s": Field("speeds", "infill_mm_s", float, 5.0, 1000.0, "mm/s"),
    "solid_infill_mm_s": Field("speeds", "solid_infill_mm_s", float, 5.0, 1000.0, "mm/s"),
    "top_solid_infill_mm_s": Field("speeds", "top_solid_infill_mm_s", float, 5.0, 1000.0, "mm/s"),
    "first_layer_mm_s": Field("speeds", "first_layer_mm_s", float, 5.0, 500.0, "mm/s"),
    "travel_mm_s": Field("speeds", "travel_mm_s", float, 10.0, 2000.0, "mm/s"),
    "layer_height_mm": Field("print", "layer_height_mm", float, 0.05, 1.0, "mm"),
    "first_layer_height_mm": Field("print", "first_layer_height_mm", float, 0.05, 1.0, "mm"),
    "perimeters": Field("print", "perimeters", int, 1, 10, "loops"),
    "top_layers": Field("print", "top_layers", int, 0, 20, "layers"),
    "bottom_layers": Field("print", "bottom_layers", int, 0, 20, "layers"),
    "pla_nozzle_c": Field("pla", "nozzle_c", int, 150, 320, "C"),
    "pla_bed_c": Field("pla", "bed_c", int, 0, 130, "C"),
    "pla_max_flow_mm3_s": Field("pla", "max_flow_mm3_s", float, 0.5, 100.0, "mm^3/s"),
    "tpu_nozzle_c": Field("tpu", "nozzle_c", int, 150, 320, "C"),
    "tpu_bed_c": Field("tpu", "bed_c", int, 0, 130, "C"),
    "tpu_max_flow_mm3_s": Field("tpu", "max_flow_mm3_s", float, 0.5, 100.0, "mm^3/s"),
    # 0: no wipe tower (the slicer's tool changes prime nowhere)
    "wipe_tower_width_mm": Field("wipe_tower", "width_mm", float, 0.0, 200.0, "mm"),
    "wipe_tower_purge_mm3": Field("wipe_tower", "purge_mm3", float, 0.0, 1000.0, "mm^3"),
}


@dataclass(frozen=True)
class Printer:
    """A validated printer preset (lengths in mm, speeds in mm/s, temperatures in degrees C).

    The bed is the rectangle every toolhead reaches, ``bed_x_mm`` by ``bed_y_mm``, whose
    corner lies at (``bed_origin_x_mm``, ``bed_origin_y_mm``) in the machine's coordinates.
    """

    name: str
    description: str
    maker: str
    source: str
    bed_x_mm: float
    bed_y_mm: float
    bed_origin_x_mm: float
    bed_origin_y_mm: float
    height_mm: float
    toolheads: int
    nozzle_mm: float
    filament_mm: float
    gcode_flavor: str
    max_speed_mm_s: float
    max_acceleration_mm_s2: float
    print_acceleration_mm_s2: float
    travel_acceleration_mm_s2: float
    perimeter_mm_s: float
    external_perimeter_mm_s: float
    infill_mm_s: float
    solid_infill_mm_s: float
    top_solid_infill_mm_s: float
    first_layer_mm_s: float
    travel_mm_s: float
    layer_height_mm: float
    first_layer_height_mm: float
    perimeters: int
    top_layers: int
    bottom_layers: int
    pla_nozzle_c: int
    pla_bed_c: int
    pla_max_flow_mm3_s: float
    tpu_nozzle_c: int
    tpu_bed_c: int
    tpu_max_flow_mm3_s: float
    wipe_tower_width_mm: float
    wipe_tower_purge_mm3: float
    #: where the preset was read from (a shipped name or a file path)
    origin: str = ""

    @property
    def bed(self) -> tuple[float, float]:
        """The bed's size (x, y), mm."""
        return (self.bed_x_mm, self.bed_y_mm)

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}

    def to_toml(self) -> str:
        """The preset as TOML, in the layout of the shipped files, ready to copy and edit."""
        values = {attr: getattr(self, attr) for attr in PRINTER_SCHEMA}
        return table_toml(
            values, PRINTER_SCHEMA, f"drawstring printer preset (read from: {self.origin})"
        )


def parse_printer(data: dict[str, Any], source: str) -> Printer:
    """Validate a parsed printer TOML table and build a :class:`Printer`.

    Raises
    ------
    InputError
        One line naming ``source``, the key, the value and what is allowed.
    """
    values = parse_table(data, PRINTER_SCHEMA, source)
    if values["layer_height_mm"] > 0.8 * values["nozzle_mm"]:
        raise InputError(
            f"{source}: print.layer_height_mm = {values['layer_height_mm']} is more than 0.8 x "
            f"the {values['nozzle_mm']} mm nozzle; use a thinner layer"
        )
    if values["first_layer_height_mm"] > values["nozzle_mm"]:
        raise InputError(
            f"{source}: print.first_layer_height_mm = {values['first_layer_height_mm']} is more "
            f"than the {values['nozzle_mm']} mm nozzle; use a thinner first layer"
        )
    return Printer(**values, origin=source)


def load_printer(name_or_path: str | Path) -> Printer:
    """Load a shipped printer preset by name or a user's TOML file by path."""
    data, source = read_toml(
        name_or_path, SHIPPED_PRINTERS, "printers/", "printer", " (drawstring profiles lists them)"
    )
    return parse_printer(data, source)


def toolheads_needed(profile: Profile) -> int:
    """Toolheads a process prints with: two for tiles and TPU hinge pads, one for loose tiles,
    none where nothing is printed."""
    if profile.process == Process.FDM_DUAL:
        return 2
    return 1 if profile.print_rate_mm3_s > 0 else 0


def resolve_printer(profile: Profile, chosen: str | None = None) -> Printer | None:
    """The printer a design with ``profile`` prints on: ``chosen`` (``--printer``) if given,
    else the profile's ``machine.printer``, else the generic preset of the process on the
    profile's own bed and nozzle; None where the process prints nothing.

    Raises
    ------
    InputError
        An unknown or invalid preset, ``--printer`` for a process that prints nothing, or a
        printer with fewer toolheads than the process prints with.
    """
    need = toolheads_needed(profile)
    if need == 0:
        if chosen:
            raise InputError(
                f"--printer {chosen}: the {profile.name} profile prints nothing (its tiles are "
                "cut); --printer applies to fdm-dual and laser-epdm"
            )
        return None
    name = chosen or profile.printer
    if name:
        printer = load_printer(name)
    else:
        generic = load_printer(GENERIC_PRINTER[need])
        printer = dataclasses.replace(
            generic,
            bed_x_mm=profile.bed_x_mm,
            bed_y_mm=profile.bed_y_mm,
            bed_origin_x_mm=0.0,
            bed_origin_y_mm=0.0,
            nozzle_mm=profile.nozzle_mm,
            description=f"{generic.description}, on the profile's {profile.bed_x_mm:g} x "
            f"{profile.bed_y_mm:g} mm bed",
            origin=f"{generic.origin} with {profile.source}'s [machine] bed",
        )
    if printer.toolheads < need:
        raise InputError(
            f"printer {printer.name} has {printer.toolheads} toolhead; the {profile.name} "
            f"profile prints tiles and hinge pads in two materials and needs {need}: pick a "
            "dual-material printer (drawstring profiles lists them)"
        )
    return printer


def with_printer(profile: Profile, printer: Printer | None) -> Profile:
    """The profile as the design uses it: the printer's nozzle (its clearances and walls are
    the nozzle's) and ``machine.printer`` naming the preset."""
    if printer is None:
        return profile
    return dataclasses.replace(profile, nozzle_mm=printer.nozzle_mm, printer=printer.name)


def print_bed(profile: Profile, printer: Printer | None) -> tuple[float, float]:
    """The bed (x, y) the tiles are printed on, mm: the printer's, or without one the profile's
    ``[machine]`` bed."""
    if printer is not None:
        return printer.bed
    return (profile.bed_x_mm, profile.bed_y_mm)
