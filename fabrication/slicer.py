"""PrusaSlicer settings for each print bed, and slicing with PrusaSlicer where it is installed.

:func:`prusa_ini` writes the settings a design assumes for one bed (its printer's bed and
limits, both nozzles, PLA and TPU temperatures and speeds, the wipe tower where it was placed,
layer height, perimeters, infill): ``prusa-slicer --export-gcode --load print.ini print.3mf``
slices that bed as drawstring did.  :func:`slice_bed` runs exactly that command and reads
PrusaSlicer's own estimate of the printing time and the filament per extruder from the end of
the G-code (:func:`read_gcode_summary`).

The settings file is deterministic (fixed formatting, no date or version in it); what the
slicer reports depends on the slicer's version, so it is kept apart (``slicer.json``, the rows
of bom.csv and manifest.json that name the version) and only written when the slicer ran.
"""

from __future__ import annotations

import logging
import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from drawstring.fabrication.printers import Printer
    from drawstring.fabrication.profiles import Profile

log = logging.getLogger(__name__)

#: The PrusaSlicer command looked up on PATH.
PRUSA_SLICER = "prusa-slicer"
#: Longest a slice of one bed may take before it is given up (s).
SLICE_TIMEOUT_S = 1800.0
#: The wipe tower's brim (mm).
WIPE_TOWER_BRIM_MM = 2.0
#: PrusaSlicer's ``solid_infill_below_area`` (mm^2): interior regions smaller than this are
#: filled solid.  Kept at PrusaSlicer's default; the print estimate models it.
SOLID_INFILL_BELOW_AREA_MM2 = 70.0
#: Sparse infill pattern of the tiles.
FILL_PATTERN = "grid"


@dataclass(frozen=True)
class IniJob:
    """What one bed's settings depend on besides the printer and the profile.

    extruders : 2 for tiles and hinge pads together, 1 for tiles alone.
    wipe_tower : the wipe tower's corner (x, y) in machine coordinates, mm, or None for a bed
        that prints one material.
    title : named in the file's first comment line.
    """

    extruders: int
    wipe_tower: tuple[float, float] | None
    title: str


def _number(value: float) -> str:
    text = f"{value:.3f}".rstrip("0").rstrip(".")
    return text if text not in ("", "-0") else "0"


def _pair(values: list[float] | list[int], extruders: int) -> str:
    return ",".join(_number(float(v)) for v in values[:extruders])


def fill_density_percent(profile: Profile) -> int:
    """The sparse infill density of the tiles (%), the profile's infill fraction."""
    return round(100 * profile.infill_fraction)


def wipe_tower_footprint(printer: Printer) -> tuple[float, float]:
    """Width and depth (mm) to keep free for the wipe tower of a two-material bed, its brim
    included: the printer's tower width by the depth that holds a layer's two primes of
    ``purge_mm3`` at the first layer's height, with four walls.  It is generous: PrusaSlicer
    2.5 made the coupon's tower (generic-dual, 70 mm^3) 40 x 9 mm, within these 44 x 23 mm."""
    line = 1.125 * printer.nozzle_mm
    area = 2.0 * printer.wipe_tower_purge_mm3 / printer.first_layer_height_mm
    depth = area / printer.wipe_tower_width_mm + 4.0 * line
    margin = 2.0 * WIPE_TOWER_BRIM_MM
    return (printer.wipe_tower_width_mm + margin, depth + margin)


def prusa_ini(printer: Printer, profile: Profile, job: IniJob) -> str:
    """PrusaSlicer settings (``.ini``) for one bed of ``printer``: bed, nozzles, PLA (extruder
    1, the tiles) and TPU (extruder 2, the hinge pads) temperatures and flows, speeds and
    machine limits (which PrusaSlicer's time estimate uses), layers, perimeters, infill, the
    wipe tower at ``job.wipe_tower``."""
    n = job.extruders
    x0, y0 = printer.bed_origin_x_mm, printer.bed_origin_y_mm
    x1, y1 = x0 + printer.bed_x_mm, y0 + printer.bed_y_mm
    bed = f"{_number(x0)}x{_number(y0)},{_number(x1)}x{_number(y0)},"
    bed += f"{_number(x1)}x{_number(y1)},{_number(x0)}x{_number(y1)}"
    density = [profile.density_kg_m3 / 1000.0, profile.hinge_density_kg_m3 / 1000.0]
    tower = job.wipe_tower is not None and n > 1
    purge = _number(printer.wipe_tower_purge_mm3)
    rows: list[tuple[str, str]] = [
        ("printer_technology", "FFF"),
        ("bed_shape", bed),
        ("max_print_height", _number(printer.height_mm)),
        ("gcode_flavor", printer.gcode_flavor),
        ("use_relative_e_distances", "1"),
        ("layer_gcode", "G92 E0"),
        ("start_gcode", "G28 ; home all axes\\nG1 Z5 F3000 ; lift nozzle"),
        ("end_gcode", "M104 S0 ; nozzle off\\nM140 S0 ; bed off\\nM84 ; motors off"),
        ("nozzle_diameter", _pair([printer.nozzle_mm] * 2, n)),
        ("filament_diameter", _pair([printer.filament_mm] * 2, n)),
        ("filament_type", ",".join(["PLA", "FLEX"][:n])),
        ("filament_density", _pair(density, n)),
        ("filament_colour", ",".join(["#E8A33D", "#2A5DB0"][:n])),
        ("extruder_colour", ",".join(["#E8A33D", "#2A5DB0"][:n])),
        ("temperature", _pair([printer.pla_nozzle_c, printer.tpu_nozzle_c], n)),
        ("first_layer_temperature", _pair([printer.pla_nozzle_c, printer.tpu_nozzle_c], n)),
        ("bed_temperature", _pair([printer.pla_bed_c, printer.tpu_bed_c], n)),
        ("first_layer_bed_temperature", _pair([printer.pla_bed_c, printer.tpu_bed_c], n)),
        (
            "filament_max_volumetric_speed",
            _pair([printer.pla_max_flow_mm3_s, printer.tpu_max_flow_mm3_s], n),
        ),
        ("retract_length", _pair([0.8, 1.5], n)),
        ("retract_length_toolchange", _pair([2.0, 2.0], n)),
        ("layer_height", _number(printer.layer_height_mm)),
        ("first_layer_height", _number(printer.first_layer_height_mm)),
        ("perimeters", str(printer.perimeters)),
        # PrusaSlicer's extra-perimeter and overhang detection compare every island of a layer
        # with the whole next layer: minutes for hundreds of tiles, for a few mm of filament
        ("extra_perimeters", "0"),
        ("overhangs", "0"),
        ("top_solid_layers", str(printer.top_layers)),
        ("bottom_solid_layers", str(printer.bottom_layers)),
        ("fill_density", f"{fill_density_percent(profile)}%"),
        ("fill_pattern", FILL_PATTERN),
        ("solid_infill_below_area", _number(SOLID_INFILL_BELOW_AREA_MM2)),
        ("perimeter_speed", _number(printer.perimeter_mm_s)),
        ("external_perimeter_speed", _number(printer.external_perimeter_mm_s)),
        ("small_perimeter_speed", _number(printer.external_perimeter_mm_s)),
        ("infill_speed", _number(printer.infill_mm_s)),
        ("solid_infill_speed", _number(printer.solid_infill_mm_s)),
        ("top_solid_infill_speed", _number(printer.top_solid_infill_mm_s)),
        ("gap_fill_speed", _number(printer.external_perimeter_mm_s)),
        ("bridge_speed", _number(printer.external_perimeter_mm_s)),
        ("first_layer_speed", _number(printer.first_layer_mm_s)),
        ("travel_speed", _number(printer.travel_mm_s)),
        ("max_print_speed", _number(printer.infill_mm_s)),
        ("default_acceleration", _number(printer.print_acceleration_mm_s2)),
        ("machine_limits_usage", "time_estimate_only"),
        ("machine_max_feedrate_x", _pair([printer.max_speed_mm_s] * 2, 2)),
        ("machine_max_feedrate_y", _pair([printer.max_speed_mm_s] * 2, 2)),
        ("machine_max_acceleration_x", _pair([printer.max_acceleration_mm_s2] * 2, 2)),
        ("machine_max_acceleration_y", _pair([printer.max_acceleration_mm_s2] * 2, 2)),
        ("machine_max_acceleration_extruding", _pair([printer.print_acceleration_mm_s2] * 2, 2)),
        ("machine_max_acceleration_travel", _pair([printer.travel_acceleration_mm_s2] * 2, 2)),
        ("skirts", "1"),
        ("skirt_distance", "6"),
        ("brim_width", "0"),
        ("complete_objects", "0"),
        ("wipe_tower", "1" if tower else "0"),
    ]
    if tower and job.wipe_tower is not None:
        rows += [
            ("wipe_tower_x", _number(job.wipe_tower[0])),
            ("wipe_tower_y", _number(job.wipe_tower[1])),
            ("wipe_tower_width", _number(printer.wipe_tower_width_mm)),
            ("wipe_tower_brim_width", _number(WIPE_TOWER_BRIM_MM)),
            ("wipe_tower_rotation_angle", "0"),
            ("wiping_volumes_matrix", f"0,{purge},{purge},0"),
            (
                "wiping_volumes_extruders",
                ",".join([_number(0.5 * printer.wipe_tower_purge_mm3)] * 4),
            ),
        ]
    header = [
        f"# PrusaSlicer settings drawstring assumes for {job.title}",
        f"# printer: {printer.name} ({printer.description}); profile: {profile.name}",
        "# slice with: prusa-slicer --export-gcode --load THIS.ini THE.3mf",
    ]
    return "\n".join(header + [f"{key} = {value}" for key, value in rows]) + "\n"


class SliceFailed(RuntimeError):
    """PrusaSlicer did not slice a bed (it failed, or took too long): one line saying why."""


@dataclass(frozen=True)
class SliceSummary:
    """What PrusaSlicer reported for one bed.

    time_s : estimated printing time (normal mode), s.
    filament_mm, filament_cm3, filament_g : per extruder used, from extruder 1.
    toolchanges : tool changes in the G-code.
    tools : the tool numbers (``T0``, ``T1``, ...) the G-code selects.
    """

    time_s: float
    filament_mm: tuple[float, ...]
    filament_cm3: tuple[float, ...]
    filament_g: tuple[float, ...]
    toolchanges: int
    tools: tuple[int, ...]


_DURATION = re.compile(r"(?:(\d+)d\s*)?(?:(\d+)h\s*)?(?:(\d+)m\s*)?(?:(\d+)s)?")


def _duration_s(text: str) -> float:
    match = _DURATION.fullmatch(text.strip())
    if match is None or not any(match.groups()):
        raise ValueError(f"not a PrusaSlicer duration: {text!r}")
    days, hours, minutes, seconds = (int(g) if g else 0 for g in match.groups())
    return float(((days * 24 + hours) * 60 + minutes) * 60 + seconds)


def read_gcode_summary(gcode: Path) -> SliceSummary:
    """PrusaSlicer's printing time and filament from the comments at the end of its G-code,
    and the tools the G-code selects.

    Raises
    ------
    ValueError
        When the G-code lacks PrusaSlicer's summary.
    """
    values: dict[str, str] = {}
    tools: set[int] = set()
    with open(gcode, encoding="utf-8", errors="replace") as stream:
        for line in stream:
            if line.startswith("T") and line[1:2].isdigit():
                tools.add(int(re.match(r"T(\d+)", line).group(1)))  # type: ignore[union-attr]
            elif line.startswith("; ") and " = " in line:
                key, _, value = line[2:].partition(" = ")
                if key.startswith(("estimated printing time", "filament used", "total tool")):
                    values[key.strip()] = value.strip()
    try:
        time_s = _duration_s(values["estimated printing time (normal mode)"])

        def floats(key: str) -> tuple[float, ...]:
            return tuple(float(v) for v in values[key].split(","))

        mm, cm3, grams = (
            floats("filament used [mm]"),
            floats("filament used [cm3]"),
            floats("filament used [g]"),
        )
    except KeyError as missing:
        raise ValueError(f"{gcode.name} has no PrusaSlicer summary ({missing})") from None
    return SliceSummary(
        time_s=time_s,
        filament_mm=mm,
        filament_cm3=cm3,
        filament_g=grams,
        toolchanges=int(values.get("total toolchanges", "0")),
        tools=tuple(sorted(tools)),
    )


def find_prusa_slicer() -> str | None:
    """The path of ``prusa-slicer`` on PATH, or None."""
    return shutil.which(PRUSA_SLICER)


def slicer_version(executable: str) -> str:
    """PrusaSlicer's version as it names itself (``PrusaSlicer-2.5.0+UNKNOWN``)."""
    done = subprocess.run(
        [executable, "--help"], capture_output=True, text=True, timeout=60, check=False
    )
    for line in (done.stdout + done.stderr).splitlines():
        if line.startswith("PrusaSlicer-"):
            return line.split()[0]
    return "PrusaSlicer (unknown version)"


def slice_bed(
    executable: str, ini: Path, model: Path, timeout_s: float | None = None
) -> SliceSummary:
    """Slice ``model`` with the settings ``ini`` (``prusa-slicer --export-gcode --load``) into
    a temporary G-code and read its summary; PrusaSlicer's output is logged (``-v``), not
    printed.  ``timeout_s`` defaults to :data:`SLICE_TIMEOUT_S`.

    Raises
    ------
    SliceFailed
        When PrusaSlicer fails, or takes longer than ``timeout_s``: one line with its last
        message.
    """
    with tempfile.TemporaryDirectory(prefix="drawstring-slice-") as folder:
        gcode = Path(folder) / "out.gcode"
        command = [executable, "--export-gcode", "--load", str(ini), str(model), "-o", str(gcode)]
        log.info("slicing: %s", " ".join(command))
        timeout_s = SLICE_TIMEOUT_S if timeout_s is None else timeout_s
        try:
            done = subprocess.run(
                command, capture_output=True, text=True, timeout=timeout_s, check=False
            )
        except subprocess.TimeoutExpired:
            raise SliceFailed(
                f"PrusaSlicer took over {timeout_s:.0f} s to slice {model.name}"
            ) from None
        messages = [
            line for line in (done.stdout + done.stderr).splitlines() if "[trace]" not in line
        ]
        for line in messages:
            log.info("prusa-slicer: %s", line)
        if done.returncode != 0 or not gcode.is_file():
            last = messages[-1] if messages else f"exit status {done.returncode}"
            raise SliceFailed(f"PrusaSlicer could not slice {model.name} with {ini.name} ({last})")
        try:
            return read_gcode_summary(gcode)
        except ValueError as unread:
            raise SliceFailed(str(unread)) from None
