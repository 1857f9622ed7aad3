"""Fabrication profiles: TOML files loaded into a validated, frozen dataclass.

A profile is read from the package (``fdm-dual``, ``laser-epdm``, ``plywood-cnc``) or from a
user's file.  Every key is checked for its type and range; an unknown key, a missing key, a wrong
type or an out-of-range value raises :class:`InputError` naming the file, key, value and range.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass, fields
from enum import StrEnum
from importlib import resources
from pathlib import Path
from typing import Any, Literal, get_args

from drawstring.geometry.core.errors import InputError, InternalError


class Process(StrEnum):
    """How a design is made; a profile TOML names it by its value."""

    #: tiles and TPU hinge pads printed together on a dual-extruder FDM printer
    FDM_DUAL = "fdm-dual"
    #: tiles printed loose, rubber hinge strips laser-cut and glued into recesses
    LASER_EPDM = "laser-epdm"
    #: tiles as plywood boxes of six CNC-cut panels, rubber strips screwed or stapled on
    PLYWOOD_CNC = "plywood-cnc"


SHIPPED_PROFILES: tuple[str, ...] = ("fdm-dual", "laser-epdm", "plywood-cnc")
Interlock = Literal["through-holes", "dovetail", "glue-recess", "screws", "staples"]
Joint = Literal["none", "butt", "finger"]


@dataclass(frozen=True)
class Field:
    """Schema of one profile key: its TOML section, type, allowed range and unit."""

    section: str
    key: str
    kind: type
    low: float | None = None
    high: float | None = None
    unit: str = ""
    choices: tuple[str, ...] = ()
    #: value of a key that profiles written before it existed leave out (None: required)
    default: float | str | None = None


#: Fewest grid cells each way a design can have: the closed string route must pass every
#: boundary tile once through the gaps its contact rules allow, and a grid one or two cells
#: wide has no such loop.  Found with ``drawstring design saddle --no-cad --no-simulate``:
#: ``--grid`` 1 1, 2 2, 2 3, 3 2, 2 5 and 2 8 all fail in the route stage ("no valid closed
#: string route"), 3 3, 3 4 and 4 3 give designs without problems.
MIN_GRID_SIDE = 3
#: Fewest ``--tiles`` (or ``default_tiles``) that can give a valid design.  A tile count maps
#: to columns and rows ``round(sqrt(tiles * w / h))`` and ``round(sqrt(tiles * h / w))``
#: (``geometry.tiling.grid_shape_for``); on the squarest target (w = h) both reach
#: MIN_GRID_SIDE = 3 from 7 tiles on (round(sqrt(6)) = 2, round(sqrt(7)) = 3).  Found with
#: ``drawstring design saddle --tiles N --no-cad --no-simulate``: N = 1 to 6 fail in the route
#: stage, 7, 8, 9, 12 (all a 3 x 3 grid) and 16 give designs without problems.  Elongated
#: targets need more; the pipeline checks the grid once the target is flattened.
MIN_TILES = 7
#: Most tiles (or grid cells) a design may have.
MAX_TILES = 20_000
#: Largest design (``--size`` or a profile's sizes), mm.  The accuracy checks are absolute
#: (1e-3 mm) while the solvers' residuals grow with the size, so the checks are at their edge
#: here: the 60-tile saddle meets them at 5 m, and at 10 m in fdm-dual's 6 mm tiles (far
#: outside that profile's 80-450 mm, which the design warns about) its assembled tiles
#: interpenetrate by 1.02e-3 mm, a problem; at 20 m they miss by more.
MAX_SIZE_MM = 10_000.0
#: Free border (mm) the print jobs keep from the edge of a printer's bed: room for a slicer's
#: skirt (PrusaSlicer's default runs 6 mm from the parts, its line about 0.5 mm wide; at 5 mm
#: its G-code left a 330 x 240 mm bed by 1.6 mm).
BED_MARGIN_MM = 8.0
#: Largest of ``--weights``.  The weights are absolute, not only relative: the surface weight
#: also sets closeness against the flat edge lengths in the co-optimization.  The 60-tile
#: saddle with all three at 1e8 meets the targets (flat edge error 5.7e-4 mm), at 1e10 it
#: misses them (1.2e-3 mm), and at 1e308 its solver's matrix overflows to singular.
MAX_WEIGHT = 1e8

# Schema: attribute name on Profile -> where it lives in the TOML and what it may hold.
SCHEMA: dict[str, Field] = {
    "name": Field("", "name", str),
    "process": Field("", "process", str, choices=tuple(p.value for p in Process)),
    "description": Field("", "description", str),
    "default_size_mm": Field("design", "default_size_mm", float, 10.0, MAX_SIZE_MM, "mm"),
    "default_tiles": Field("design", "default_tiles", int, MIN_TILES, MAX_TILES, "tiles"),
    "size_min_mm": Field("design", "size_min_mm", float, 10.0, MAX_SIZE_MM, "mm"),
    "size_max_mm": Field("design", "size_max_mm", float, 10.0, MAX_SIZE_MM, "mm"),
    "tolerance_mm": Field("design", "tolerance_mm", float, 0.001, 10.0, "mm", default=0.05),
    "thickness_mm": Field("tile", "thickness_mm", float, 0.5, 500.0, "mm"),
    "min_gap_angle_deg": Field("tile", "min_gap_angle_deg", float, 0.0, 60.0, "deg"),
    "tile_material": Field("tile", "material", str),
    "density_kg_m3": Field("tile", "density_kg_m3", float, 10.0, 20_000.0, "kg/m^3"),
    "infill_fraction": Field("tile", "infill_fraction", float, 0.01, 1.0, "fraction"),
    "panel_thickness_mm": Field("tile", "panel_thickness_mm", float, 0.0, 100.0, "mm"),
    "joint": Field("tile", "joint", str, choices=get_args(Joint)),
    "string_diameter_mm": Field("string", "diameter_mm", float, 0.05, 50.0, "mm"),
    "channel_clearance_mm": Field("string", "channel_clearance_mm", float, 0.0, 20.0, "mm"),
    "min_bend_radius_mm": Field("string", "min_bend_radius_mm", float, 0.0, 1000.0, "mm"),
    "friction_coefficient": Field("string", "friction_coefficient", float, 0.0, 2.0, ""),
    "string_material": Field("string", "material", str),
    "string_density_kg_m3": Field(
        "string", "density_kg_m3", float, 10.0, 20_000.0, "kg/m^3", default=1000.0
    ),
    "hinge_material": Field("hinge", "material", str),
    "hinge_thickness_mm": Field("hinge", "thickness_mm", float, 0.05, 50.0, "mm"),
    "hinge_width_mm": Field("hinge", "width_mm", float, 0.1, 200.0, "mm"),
    "hinge_pad_length_mm": Field("hinge", "pad_length_mm", float, 0.1, 500.0, "mm"),
    "hinge_interlock": Field("hinge", "interlock", str, choices=get_args(Interlock)),
    "hinge_density_kg_m3": Field("hinge", "density_kg_m3", float, 100.0, 20_000.0, "kg/m^3"),
    "magnet_diameter_mm": Field("magnet", "diameter_mm", float, 0.5, 100.0, "mm"),
    "magnet_height_mm": Field("magnet", "height_mm", float, 0.2, 100.0, "mm"),
    "magnet_clearance_mm": Field("magnet", "clearance_mm", float, 0.0, 5.0, "mm"),
    # a printer preset (drawstring.fabrication.printers) or its .toml path; "" for none
    "printer": Field("machine", "printer", str, default=""),
    "bed_x_mm": Field("machine", "bed_x_mm", float, 10.0, 10_000.0, "mm"),
    "bed_y_mm": Field("machine", "bed_y_mm", float, 10.0, 10_000.0, "mm"),
    "nozzle_mm": Field("machine", "nozzle_mm", float, 0.0, 5.0, "mm"),
    "kerf_mm": Field("machine", "kerf_mm", float, 0.0, 5.0, "mm"),
    "tool_diameter_mm": Field("machine", "tool_diameter_mm", float, 0.0, 50.0, "mm"),
    "print_rate_mm3_s": Field("machine", "print_rate_mm3_s", float, 0.0, 500.0, "mm^3/s"),
    "cut_speed_mm_s": Field("machine", "cut_speed_mm_s", float, 0.0, 2000.0, "mm/s"),
    "currency": Field("cost", "currency", str),
    "tile_price_per_kg": Field("cost", "tile_material_per_kg", float, 0.0, 100_000.0, "per kg"),
    "hinge_price_per_kg": Field("cost", "hinge_material_per_kg", float, 0.0, 100_000.0, "per kg"),
    "string_price_per_m": Field("cost", "string_per_m", float, 0.0, 100_000.0, "per m"),
    "magnet_price_each": Field("cost", "magnet_each", float, 0.0, 100_000.0, "each"),
}


@dataclass(frozen=True)
class Profile:
    """A validated fabrication profile (lengths in mm)."""

    name: str
    process: Process
    description: str
    default_size_mm: float
    default_tiles: int
    size_min_mm: float
    size_max_mm: float
    #: the fabrication tolerance: a flat, hinge or contact measure above it is a problem
    tolerance_mm: float
    thickness_mm: float
    min_gap_angle_deg: float
    tile_material: str
    density_kg_m3: float
    infill_fraction: float
    panel_thickness_mm: float
    joint: Joint
    string_diameter_mm: float
    channel_clearance_mm: float
    min_bend_radius_mm: float
    friction_coefficient: float
    string_material: str
    string_density_kg_m3: float
    hinge_material: str
    hinge_thickness_mm: float
    hinge_width_mm: float
    hinge_pad_length_mm: float
    hinge_interlock: Interlock
    hinge_density_kg_m3: float
    magnet_diameter_mm: float
    magnet_height_mm: float
    magnet_clearance_mm: float
    bed_x_mm: float
    bed_y_mm: float
    nozzle_mm: float
    kerf_mm: float
    tool_diameter_mm: float
    print_rate_mm3_s: float
    cut_speed_mm_s: float
    printer: str
    currency: str
    tile_price_per_kg: float
    hinge_price_per_kg: float
    string_price_per_m: float
    magnet_price_each: float
    source: str = ""

    def to_json(self) -> dict[str, Any]:
        return {f.name: getattr(self, f.name) for f in fields(self)}

    def to_toml(self) -> str:
        """The profile as TOML, in the layout of the shipped files, ready to copy and edit."""
        values = {attr: getattr(self, attr) for attr in SCHEMA}
        return table_toml(
            values, SCHEMA, f"drawstring fabrication profile; lengths in mm (source: {self.source})"
        )


def _toml_value(value: object) -> str:
    if isinstance(value, str):
        escaped = value.replace("\\", "\\\\").replace('"', '\\"')
        return f'"{escaped}"'
    if isinstance(value, float):
        return repr(value)
    return str(value)


def _describe_range(spec: Field) -> str:
    if spec.choices:
        return "one of " + ", ".join(spec.choices)
    if spec.low is not None and spec.high is not None:
        return f"{spec.low:g} to {spec.high:g} {spec.unit}".rstrip()
    return f"a {spec.kind.__name__}"


def parse_table(data: dict[str, Any], schema: dict[str, Field], source: str) -> dict[str, Any]:
    """Check a parsed TOML table against ``schema``: every key known, present (or given a
    default), of its type and in its range; returns the values by attribute name.

    Raises
    ------
    InputError
        One line naming ``source``, the key, the value and what is allowed.
    """
    known: dict[tuple[str, str], str] = {(s.section, s.key): attr for attr, s in schema.items()}
    sections = {s.section for s in schema.values() if s.section}
    top_keys = ", ".join(s.key for s in schema.values() if not s.section)
    values: dict[str, Any] = {}
    for key, value in data.items():
        if isinstance(value, dict):
            if key not in sections:
                raise InputError(
                    f"{source}: unknown section [{key}]; allowed: " + ", ".join(sorted(sections))
                )
            for sub, sub_value in value.items():
                attr = known.get((key, sub))
                if attr is None:
                    allowed = sorted(k for s, k in known if s == key)
                    raise InputError(
                        f"{source}: unknown key {key}.{sub}; allowed in [{key}]: "
                        + ", ".join(allowed)
                    )
                values[attr] = sub_value
        else:
            attr = known.get(("", key))
            if attr is None:
                raise InputError(f"{source}: unknown key {key!r}; top-level keys are {top_keys}")
            values[attr] = value
    for attr, spec in schema.items():
        where = f"{spec.section}.{spec.key}" if spec.section else spec.key
        if attr not in values and spec.default is not None:
            values[attr] = spec.default
        if attr not in values:
            raise InputError(f"{source}: missing key {where} ({_describe_range(spec)})")
        value = values[attr]
        if spec.kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, spec.kind) or isinstance(value, bool):
            raise InputError(
                f"{source}: {where} = {value!r} must be {spec.kind.__name__}"
                f" ({_describe_range(spec)})"
            )
        if spec.choices and value not in spec.choices:
            raise InputError(f"{source}: {where} = {value!r} must be {_describe_range(spec)}")
        if spec.low is not None and spec.high is not None and isinstance(value, int | float):
            if not (spec.low <= value <= spec.high):
                raise InputError(
                    f"{source}: {where} = {value!r} is out of range ({_describe_range(spec)})"
                )
        values[attr] = value
    return values


def table_toml(values: dict[str, Any], schema: dict[str, Field], header: str) -> str:
    """``values`` (by attribute name) as TOML in the schema's layout, every key with its range
    in a comment, under the comment line ``header``."""
    lines = [f"# {header}"]
    sections: dict[str, list[str]] = {}
    for attr, spec in schema.items():
        text = _toml_value(values[attr])
        unit = f"  # {spec.unit}" if spec.unit and spec.unit != "mm" else ""
        if spec.low is not None:
            unit = f"  # {spec.low:g} .. {spec.high:g} {spec.unit}".rstrip()
        if spec.choices:
            unit = "  # one of: " + ", ".join(spec.choices)
        sections.setdefault(spec.section, []).append(f"{spec.key} = {text}{unit}")
    lines += sections.pop("")
    for section, rows in sections.items():
        lines += ["", f"[{section}]", *rows]
    return "\n".join(lines) + "\n"


def parse_profile(data: dict[str, Any], source: str) -> Profile:
    """Validate a parsed TOML table and build a :class:`Profile`.

    Raises
    ------
    InputError
        One line naming ``source``, the key, the value and what is allowed.
    """
    values = parse_table(data, SCHEMA, source)
    values["process"] = Process(values["process"])
    if values["size_min_mm"] > values["size_max_mm"]:
        raise InputError(
            f"{source}: design.size_min_mm ({values['size_min_mm']}) is above "
            f"design.size_max_mm ({values['size_max_mm']}); swap them"
        )
    if not values["size_min_mm"] <= values["default_size_mm"] <= values["size_max_mm"]:
        raise InputError(
            f"{source}: design.default_size_mm = {values['default_size_mm']} must lie between "
            f"design.size_min_mm ({values['size_min_mm']}) and design.size_max_mm "
            f"({values['size_max_mm']})"
        )
    return Profile(**values, source=source)


def load_profile(name_or_path: str | Path) -> Profile:
    """Load a shipped profile by name or a user's TOML file by path."""
    data, source = read_toml(name_or_path, SHIPPED_PROFILES, "", "profile")
    return parse_profile(data, source)


def read_toml(
    name_or_path: str | Path, shipped: Sequence[str], folder: str, kind: str, hint: str = ""
) -> tuple[dict[str, Any], str]:
    """The table of a shipped TOML file of ``drawstring.profiles`` (``folder`` + name) or of a
    user's ``.toml`` path, and where it came from; ``kind`` and ``hint`` word the refusals."""
    text_name = str(name_or_path)
    if text_name in shipped:
        resource = resources.files("drawstring.profiles").joinpath(f"{folder}{text_name}.toml")
        text = resource.read_text(encoding="utf-8")
        source = f"{folder}{text_name}.toml (shipped)"
    else:
        path = Path(name_or_path)
        if path.suffix.lower() != ".toml":
            raise InputError(
                f"unknown {kind} {text_name!r}; use one of {', '.join(shipped)} "
                f"or a path to a .toml file{hint}"
            )
        if not path.is_file():
            raise InputError(f"{kind} file {path} does not exist; check the path")
        text = path.read_text(encoding="utf-8")
        source = str(path)
    try:
        return tomllib.loads(text), source
    except tomllib.TOMLDecodeError as exc:
        raise InputError(f"{source}: not valid TOML ({exc})") from None


#: What each process needs and makes, for ``drawstring profiles``.
PROCESS_GUIDE: dict[Process, tuple[str, str]] = {
    Process.FDM_DUAL: (
        "a dual-extruder FDM printer (or one with a tool changer / multi-material unit)",
        "print.3mf with tiles on extruder 1 and hinge pads on extruder 2, STEP, BOM, guide",
    ),
    Process.LASER_EPDM: (
        "a single-material FDM printer for the tiles and a laser cutter for 1 mm EPDM sheet",
        "tiles.3mf, hinges.dxf (nested, kerf-compensated), a 1:1 placement template, BOM",
    ),
    Process.PLYWOOD_CNC: (
        "a laser cutter or CNC router for plywood sheet, a drill, glue and screws",
        "panels.dxf (finger-jointed box panels, nested), hinges.dxf, cutlist.csv, BOM, guide",
    ),
}


@dataclass(frozen=True)
class RoughEstimate:
    """Order-of-magnitude material and machine time for a design of a given size."""

    size_mm: float
    tiles: int
    mass_g: float
    cost: float
    hours: float
    basis: str


#: Tile volume over size^2 x thickness, as :func:`rough_estimate` takes it: the designs of the
#: built-ins and scans at their profiles' default sizes measure 1.03 (face) to 1.29 (dome at
#: 350 mm), 1.19-1.22 for the saddle and the dome, 0.87 for the wave and 1.55 for a hemisphere.
ESTIMATE_AREA_FACTOR = 1.15


def rough_estimate(profile: Profile, size_mm: float, tiles: int) -> RoughEstimate:
    """Estimate mass, material cost and print or cut time before designing anything.

    The tiles are taken to cover :data:`ESTIMATE_AREA_FACTOR` size^2, each of the profile's
    thickness, printed tiles filled to its infill fraction, plywood boxes made of their six
    panels; every tile has about two hinges; the string runs about 1.2 times around a square
    of the size.  Print time is the printed volume over the profile's rate (mm³ per second of
    PrusaSlicer's printing time at its default size and tiles, walls and tool changes
    included; fewer, larger tiles print faster than that); cut time is the cut length (every
    hinge strip's outline, and six panel outlines per tile for box tiles) over the cut speed.
    The real numbers in ``fabrication/bom.csv`` differ by the shape (a hemisphere takes a
    third more tiles' volume than the factor says).
    """
    if not (math.isfinite(size_mm) and size_mm > 0) or tiles < 1:
        raise InternalError("an estimate needs a positive size in mm and at least one tile")
    area = ESTIMATE_AREA_FACTOR * size_mm**2
    side = math.sqrt(area / tiles)
    if profile.process == Process.PLYWOOD_CNC:  # the panels of every box
        panels = 2 * side**2 + 4 * side * profile.thickness_mm
        tile_volume = tiles * panels * profile.panel_thickness_mm  # mm^3
    else:
        tile_volume = area * profile.thickness_mm * profile.infill_fraction
    hinge_volume = (
        2 * tiles * profile.hinge_thickness_mm * profile.hinge_width_mm
        * profile.hinge_pad_length_mm
    )  # fmt: skip
    tile_g = tile_volume * 1e-6 * profile.density_kg_m3
    hinge_g = hinge_volume * 1e-6 * profile.hinge_density_kg_m3
    string_m = 4.0 * size_mm * 1.2 / 1000.0
    cost = (
        tile_g / 1000 * profile.tile_price_per_kg
        + hinge_g / 1000 * profile.hinge_price_per_kg
        + string_m * profile.string_price_per_m
    )
    seconds = 0.0
    basis = []
    if profile.print_rate_mm3_s > 0:
        printed = tile_volume + (hinge_volume if profile.process == Process.FDM_DUAL else 0.0)
        seconds += printed / profile.print_rate_mm3_s
        basis.append("printing")
    if profile.cut_speed_mm_s > 0:
        cut = 2 * tiles * 2 * (profile.hinge_pad_length_mm + profile.hinge_width_mm)
        if profile.process == Process.PLYWOOD_CNC:
            # six panel outlines per box: top and bottom round the side, four sides round
            # side x thickness; finger joints jog in and out by a panel thickness per finger
            outlines = 16 * side + 8 * profile.thickness_mm
            if profile.joint == "finger":
                finger = max(3.0 * profile.panel_thickness_mm, 2.0 * profile.tool_diameter_mm)
                outlines *= 1.0 + 2.0 * profile.panel_thickness_mm / finger
            cut += tiles * outlines
        seconds += cut / profile.cut_speed_mm_s
        basis.append("cutting")
    return RoughEstimate(
        size_mm=size_mm,
        tiles=tiles,
        mass_g=tile_g + hinge_g,
        cost=cost,
        hours=seconds / 3600.0,
        basis=" + ".join(basis) or "no machine time",
    )


def string_is_cable(profile: Profile) -> bool:
    """Whether the profile's string is a wire cable (steel, wire rope), whose ends are joined
    with a crimp ferrule or a wire-rope clip: it cannot be knotted."""
    material = profile.string_material.lower()
    return any(word in material for word in ("cable", "wire", "steel"))


def print_clearance_mm(profile: Profile) -> float:
    """How far apart (mm) the tiles of a design must stay in the flat pose: one nozzle width
    where they are printed together with their hinges in place (``fdm-dual``: a slicer lays
    each tile's perimeter lines inside its own outline, so outlines a nozzle apart keep the
    two tiles' lines from running into each other); 0 where they are made loose."""
    return profile.nozzle_mm if profile.process == Process.FDM_DUAL else 0.0
