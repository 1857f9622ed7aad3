"""The text of the assembly guide, ``DIR/fabrication/assembly.md``: make the parts (print, or
cut and glue), place the tiles, fit the magnets, thread the string, pull.

The threading starts at a lift point, so that the string's two ends stand up there; every lift
point is named in the steps where the string comes up out of a top face and goes back down
(:func:`~drawstring.output.assembly_order.plan_guide`).
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.paths import SIDE_TOP_FACE
from drawstring.fabrication.printers import Printer, print_bed
from drawstring.fabrication.profiles import Process, Profile, print_clearance_mm, string_is_cable
from drawstring.fabrication.record import ExportRecord
from drawstring.geometry.core.tile import HingeSide
from drawstring.geometry.tiling.linkage import id_runs
from drawstring.output.assembly_order import Stop, plan_guide

if TYPE_CHECKING:  # panels load the CAD kernel, which a --no-cad report never needs
    from drawstring.fabrication.panels import Panel


def write_assembly(
    path: Path,
    profile: Profile,
    design_name: str,
    record: ExportRecord,
    hinges: NDArray[np.int64],
    sides: Sequence[str],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    magnets: Sequence[Any],
    panels: Sequence[Panel],
    pictures: Sequence[str],
    *,
    printer: Printer | None = None,
) -> None:
    """``assembly.md``: make the parts, place the tiles, magnets, thread the string, pull.

    Sections are numbered as they are written.  Every lift point (the string up out of a top
    face and back down into the next tile's) is named in the two steps where it happens; the
    threading starts at one of them, so that the string's two ends stand up there.
    """
    est = record.estimates
    section = itertools.count(1)
    # each end to hold while pulling (bom.csv's string rule)
    tail = float(est["string_tail_mm"])
    lines = [
        f"# Assembling {design_name} ({profile.name})",
        "",
        f"Parts: see `bom.csv`. String: **{est['string_length_mm'] / 1000:.2f} m** of "
        f"{profile.string_material} ({est['string_rule']}).",
        "",
        *([coupon_text(profile, printer), ""] if design_name != COUPON_DESIGN else []),
    ]
    if profile.process == Process.FDM_DUAL:
        lines += _print_section(next(section), profile, record, hinges, sides, printer)
    else:
        lines += _make_parts_section(next(section), profile, record, sides, printer)
    lines += [
        f"## {next(section)}. Where each tile goes",
        "",
        f"![tiles]({pictures[0]})",
        "",
        "Blue circles: hinges on the top faces; orange squares: hinges on the bottom faces.",
        "",
    ]
    if magnets:
        lines += _magnets_section(next(section), profile, magnets)
    lines += threading_text(next(section), steps, lifts, pictures[1], tail)
    lines += pull_text(next(section), steps, lifts, pictures[2], string_is_cable(profile))
    if record.notes:
        lines += ["## Notes", ""] + [f"- {n}" for n in record.notes] + [""]
    del panels
    path.write_text("\n".join(lines), encoding="utf-8")


def _print_section(
    number: int,
    profile: Profile,
    record: ExportRecord,
    hinges: NDArray[np.int64],
    sides: Sequence[str],
    printer: Printer | None,
) -> list[str]:
    """The fdm-dual guide's first section: the print jobs, the printer and its slicer
    settings, and how to join the jobs of a layout larger than the bed."""
    lines = [f"## {number}. Print", ""]
    lines.append(
        f"`print.3mf` holds {len(record.jobs)} object(s), one per print job. Tiles are "
        f"assigned to extruder 1 ({profile.tile_material}), hinge pads to extruder 2 "
        f"({profile.hinge_material}); PrusaSlicer, Bambu Studio and OrcaSlicer read the "
        "assignment from the file. Each job lies top faces down (the tops share one plane, "
        "the bottoms follow each tile's thickness), so every tile starts on the first "
        "layer; turn the printed sheet over before you thread it. Each tile's number is "
        "engraved in its bottom face (it reads as printed, and from below once turned). "
        f"Hinged tiles print {print_clearance_mm(profile):g} mm apart, joined only by "
        "their pads (each tile is cut back that little along its hinge edges): before "
        "you thread the sheet, bend every hinge once, and cut any stray strand of "
        f"{profile.tile_material} across one."
        + _unnumbered_text(record.unlabelled)
        + _beds_text("print", record.jobs)
    )
    lines.append("")
    slicer = _slicer_text(printer, record, "print")
    if slicer:
        lines += [slicer, ""]
    for job in record.jobs:
        kind = (
            "loose hinge pads"
            if job.get("loose")
            else f"{len(job['tiles'])} tiles ({id_runs(job['tiles'])})"
        )
        lines.append(
            f"- job {job['job']}: {kind}, {len(job['pads'])} pads{_on_bed(job, record.jobs)}"
        )
    cut = record.estimates.get("cut_hinges", [])
    if cut:
        lines += [
            "",
            "The layout is larger than the bed, so it was split along rows of hinges. "
            "Join the jobs with the loose hinge pads (their jobs lay them out in rows, "
            "left to right, then row after row, in the order of this list; "
            "`assembly-tiles.png` rings these hinges in red): press each pad's pins "
            "into the holes of both tiles and glue it into the recess (CA glue):",
            "",
        ]
        for h in cut:
            a, _, b, _ = hinges[h]
            lines.append(f"- hinge {h}: tile {a} to tile {b} ({sides[h]} faces)")
    lines.append("")
    return lines


def _make_parts_section(
    number: int,
    profile: Profile,
    record: ExportRecord,
    sides: Sequence[str],
    printer: Printer | None,
) -> list[str]:
    """The laser-epdm and plywood-cnc guides' first section: the tiles (printed loose, or
    panels glued into boxes), the hinge strips and the placement templates."""
    lines = [f"## {number}. Make the parts", ""]
    if profile.process == Process.LASER_EPDM:
        lines += _loose_tiles_text(profile, record, printer)
    else:
        lines.append(_panels_text(profile, record))
    strip_sheets = _count(record.sheets["hinges"]["sheets"], "sheet")
    lines.append(
        f"Cut the hinge strips from `hinges.dxf` ({strip_sheets}; "
        "layers: ENGRAVE green first, CUT_INNER blue, CUT_OUTER black; SHEET red holds only "
        "each sheet's outline and its name below it, not to be cut). Each half of a strip "
        "is engraved with the number of the tile it joins."
    )
    lines.append("")
    lines.append(_placement_text(profile, record.estimates, sides))
    lines.append("")
    return lines


def _loose_tiles_text(profile: Profile, record: ExportRecord, printer: Printer | None) -> list[str]:
    """The laser-epdm tiles: printed loose, nested on the printer's beds."""
    lines: list[str] = []
    beds = len(record.jobs)
    bed = print_bed(profile, printer)
    text = (
        "Print the tiles from `tiles.3mf` (single material). They print loose, top "
        "faces down (tiles differ in thickness by a little, their top faces are "
        "flat), each turned about the vertical to take the least room, nested on "
        f"{_count(beds, 'bed')} of {bed[0]:g} x {bed[1]:g} mm"
    )
    if beds > 1:
        text += (
            ", one object per bed, side by side in that file (the first on the plate); "
            f"`tiles-bed1.3mf` to `tiles-bed{beds}.3mf` hold one bed each, on the plate"
        )
    lines.append(
        text + ". Each tile's number is engraved in its bottom face; the placement "
        "template (below) shows where it goes." + _unnumbered_text(record.unlabelled)
    )
    if beds > 1:
        lines.append("")
        lines += [f"- bed {job['bed']}: tiles {id_runs(job['tiles'])}" for job in record.jobs]
    slicer = _slicer_text(printer, record, "tiles")
    if slicer:
        lines += ["", slicer]
    lines.append("")  # the list ends before the next paragraph
    return lines


#: The design name of the test coupon (``drawstring coupon``), whose guide does not point to
#: itself.
COUPON_DESIGN = "coupon"


def coupon_text(profile: Profile, printer: Printer | None) -> str:
    """The guide's pointer to the test coupon of the design's profile and printer."""
    name = profile.name if profile.source.endswith("(shipped)") else profile.source
    command = f"drawstring coupon --profile {name}"
    if printer is not None:
        chosen = printer.name if printer.origin.endswith("(shipped)") else printer.origin
        command += f" --printer {chosen}"
    made = {
        Process.FDM_DUAL: "prints in well under an hour: check that the TPU pads bond to the "
        "tiles, that the hinges bend freely and that the string runs through the channels "
        "and the lift bore",
        Process.LASER_EPDM: "prints and cuts in well under an hour: check that the strips fit "
        "their recesses and hold when glued, and that the string runs through the channels "
        "and the lift bore",
        Process.PLYWOOD_CNC: "is a few panels and strips: check the finger joints, the strips' "
        "screws and the cable through the holes",
    }[profile.process]
    return (
        f"Before the whole part, make the test coupon: `{command}` writes 3 x 3 tiles with "
        "this profile's hinges, string channel, lift bore and magnet pockets, which "
        f"{made}."
    )


def _slicer_text(printer: Printer | None, record: ExportRecord, stem: str) -> str:
    """Which printer the beds are laid out for, and the slicer settings beside each 3MF."""
    settings = [e["settings"] for e in record.beds if "settings" in e]
    if printer is None or not settings:
        return ""
    files = (
        f"`{settings[0]}` holds"
        if len(settings) == 1
        else f"`{stem}-bed1.ini` to `{settings[-1]}` hold"
    )
    command = f"prusa-slicer --export-gcode --load {settings[0]} {record.beds[0]['model']}"
    return (
        f"The beds are laid out for the printer preset `{printer.name}` ({printer.description}; "
        f"another with `--printer`). {files} the PrusaSlicer settings this design assumes "
        "(nozzles, temperatures, speeds, layers, infill and the wipe tower's place): "
        f"`{command}` slices as drawstring did, and `bom.csv` gives the printing time and "
        "filament. In another slicer, use your printer's own profile with those temperatures."
    )


def _panels_text(profile: Profile, record: ExportRecord) -> str:
    """The plywood-cnc tiles: panels cut from sheets and glued into boxes."""
    panel_sheets = _count(record.sheets["panels"]["sheets"], "sheet")
    return (
        f"Cut the panels from `panels.dxf` ({panel_sheets}) "
        "with "
        "the inner face up: engraved labels (tile number + face: S0..S3 sides, T top, "
        "B bottom) end up inside the box. Glue each tile's six panels together; "
        "`cutlist.csv` gives each edge's dihedral and bevel angle (sand or bevel proud "
        "edges flush). Glue a channel tube through each pair of cable holes (each "
        "tube's tile, route step or lift bore and length in `manifest.json` "
        "channel_tubes). Layers: ENGRAVE green first, CUT_INNER blue (holes, the "
        "magnet holes in the side panels among them), CUT_OUTER black; DRILL magenta: "
        "drill these at the diameter drawn (the pilot holes of the hinge strips' "
        f"screws, and round holes narrower than the {profile.tool_diameter_mm:g} mm "
        "tool)." + _trimmed_text(record.trimmed)
    )


def _placement_text(profile: Profile, est: dict[str, Any], sides: Sequence[str]) -> str:
    """How to lay the tiles on the placement templates and fix the hinge strips."""
    width, height = est.get("placement_size_mm", (0.0, 0.0))
    # the numbers are engraved in the bottom faces (laser) or inside the boxes (plywood)
    on_top = (
        "by number (read each tile's number in its bottom face before you lay it down)"
        if profile.process == Process.LASER_EPDM
        else "matching their outlines (the engraved numbers are inside the boxes: pencil "
        "each box's number on its bottom as you glue it)"
    )
    text = (
        f"Print `placement.svg` at 100 % (1:1; it is {width:g} x {height:g} mm: on a large-"
        "format printer, or tiled over several sheets taped together), lay the tiles on it "
        f"top faces up {on_top}, and fix each strip where the template shows it (blue, "
        "marked with a circle: on the top faces; orange, marked with a square: on the "
        "bottom faces)."
    )
    if any(side != HingeSide.TOP for side in sides):
        # laser tiles carry their numbers in their bottom faces; plywood boxes inside
        by_number = (
            "by the numbers in their bottom faces"
            if profile.process == Process.LASER_EPDM
            else "by the numbers pencilled on their bottoms"
        )
        text += (
            " The bottom faces' strips go on first, from below: print "
            "`placement-bottom.svg` too (the layout seen from below, mirrored, with only "
            f"those strips), lay the tiles on it top faces down, {by_number}, and fix the "
            "orange strips; then turn the pieces over onto `placement.svg`, top faces up, "
            "and fix the blue ones."
        )
    return text


def _magnets_section(number: int, profile: Profile, magnets: Sequence[Any]) -> list[str]:
    """Which pole of each magnet faces out."""
    lines = [
        f"## {number}. Magnets",
        "",
        (
            "Press the magnets into their holes in the side panels, flush with the outer "
            "face, and glue them from inside, with these poles facing out:"
            if profile.process == Process.PLYWOOD_CNC
            else "Glue the magnets into their pockets with these poles facing out:"
        ),
        "",
    ]
    for m in magnets:
        lines.append(
            f"- tile {m.tile_a} side {m.side_a}: {m.polarity_a} out; "
            f"tile {m.tile_b} side {m.side_b}: {m.polarity_b} out"
        )
    lines.append("")
    return lines


def threading_text(
    number: int, steps: NDArray[np.int64], lifts: NDArray[np.int64], picture: str, tail: float
) -> list[str]:
    """The threading section of assembly.md, one line per step (see
    :func:`~drawstring.output.assembly_order.plan_guide`)."""
    guide = plan_guide(steps, lifts)
    lines = [
        f"## {number}. Thread the string",
        "",
        f"![threading]({picture})",
        "",
        "Follow the route step by step: tile, the side the string goes in by, the side it "
        "comes out by. Sides are numbered as the tiles lie in the pictures: 0 bottom, "
        "1 right, 2 top, 3 left; the *top face* is the face that is up on the table. "
        "Through a side the string runs in the tile's channel; through the top face it runs "
        "in a lift bore, which meets the channel at a side's hole.",
        "",
    ]
    if not len(steps):
        return lines + ["The design has no string route.", ""]
    first = guide.order[0]
    if guide.stops:
        lines.append(
            f"The string comes up out of the top faces at {len(guide.stops)} lift "
            f"point{'s' if len(guide.stops) != 1 else ''}, marked ▲ (up) and ▼ (back down) "
            "in the picture:"
        )
        lines.append("")
        for stop in guide.stops:
            out = (
                f"up out of tile {steps[guide.order[stop.out_step], 1]} in step {stop.out_step + 1}"
                if stop.out_step is not None
                else None
            )
            back = (
                f"down into tile {steps[guide.order[stop.in_step], 1]} in step {stop.in_step + 1}"
                if stop.in_step is not None
                else None
            )
            what = "the two string ends" if stop.tails else "a loop to pull"
            lines.append(f"- **{stop.letter}** ({what}): " + ", ".join(w for w in (out, back) if w))
        lines.append("")
    if first:
        lines += [
            f"The route is a closed loop; step 1 here is step {first + 1} of `route.json` "
            f"(the steps are counted from lift point {guide.stops[0].letter}, so that both "
            "string ends stand up there).",
            "",
        ]
    out_of = {s.out_step: s for s in guide.stops if s.out_step is not None}
    into = {s.in_step: s for s in guide.stops if s.in_step is not None}
    for g, index in enumerate(guide.order):
        _, tile, enter, leave = (int(v) for v in steps[index])
        stop_in, stop_out = into.get(g), out_of.get(g)
        start = ""
        if stop_in is None:
            came = f"in {enter}"
            if g == 0:
                start = f"start here, with a tail of {tail:.0f} mm left outside side {enter}; "
        else:
            came = f"**in through the top face ▼ at lift point {stop_in.letter}**"
            if enter != SIDE_TOP_FACE:
                came += (
                    f": down the lift bore to the hole in side {enter}, and on into the channel "
                    f"from side {enter}"
                )
            if g == 0:
                start = f"start here, with a tail of {tail:.0f} mm left standing up; "
        if stop_out is None:
            went = f"out {leave}"
        elif leave == SIDE_TOP_FACE:
            went = f"**out through the top face ▲ at lift point {stop_out.letter}**"
        else:
            went = (
                f"out {leave}, then back into that hole and up its lift bore: **out through "
                f"the top face ▲ at lift point {stop_out.letter}**"
            )
        if stop_out is not None:
            if stop_out.tails:
                went += f" (the other end: leave a tail of {tail:.0f} mm standing up)"
            elif stop_out.in_step is not None:
                went += " (leave a loop a hand wide standing up, to pull on)"
        lines.append(f"{g + 1}. tile {tile}: {start}{came}, {went}")
    if not any(s.tails for s in guide.stops):
        lines.append("")
        lines.append(
            f"After the last step the string is back at side {int(steps[first, 2])} of tile "
            f"{int(steps[first, 1])}, next to the first tail: leave a tail of {tail:.0f} mm."
        )
    if guide.spare:
        spare = "; ".join(f"tile {t} side {s}" for t, s in guide.spare)
        lines += ["", f"Lift bores the string does not pass (leave them empty): {spare}."]
    lines.append("")
    return lines


def pull_text(
    number: int,
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    picture: str,
    cable: bool = False,
) -> list[str]:
    """The pull section of assembly.md: what to hold and lift, where, and how to finish
    (``cable``: a wire cable, crimped rather than knotted)."""
    join = (
        "join the two ends with the crimp ferrule (or two wire-rope clips), pulled tight,"
        if cable
        else "knot the two ends together"
    )
    guide = plan_guide(steps, lifts)
    lines = [f"## {number}. Pull", "", f"![pull]({picture})", ""]
    ends = [s for s in guide.stops if s.tails]
    loops = [s for s in guide.stops if not s.tails]

    def tiles_of(stop: Stop) -> str:
        found = [
            int(steps[guide.order[g], 1]) for g in (stop.out_step, stop.in_step) if g is not None
        ]
        if len(found) == 2 and found[0] != found[1]:
            return f"tiles {found[0]} and {found[1]}"
        return f"tile {found[0]}" if found else "the top faces"

    if ends:
        held = f"the two string ends at lift point {ends[0].letter} ({tiles_of(ends[0])})"
        finish = f"{join} on top of {tiles_of(ends[0])}"
    elif len(steps):
        tile = int(steps[guide.order[0], 1])
        held = f"the two string ends at tile {tile}"
        finish = f"{join} at tile {tile}"
    else:
        held, finish = "the string", "tie it off"
    grip = "Hold " + held
    if loops:
        names = " and ".join(s.letter for s in loops)
        grip += " in one hand and hook a finger of the other through the " + (
            f"loop at {names}" if len(loops) == 1 else f"loops at {names}"
        )
    lines.append(
        "Lay the flat linkage on a table, top faces up. "
        + grip
        + ". Lift them straight up together, slowly and evenly, as the arrows show: the "
        "string draws the tiles together, they rotate about the hinges and close into the "
        "shape. When every gap has closed, pull the ends until "
        + (
            f"the loop{'s lie' if len(loops) > 1 else ' lies'} tight on the top faces, and "
            if loops
            else "the string is tight, and "
        )
        + finish
        + "."
    )
    lines.append("")
    return lines


def _beds_text(stem: str, jobs: Sequence[dict[str, Any]]) -> str:
    """How the print jobs share the beds, and which file prints each bed."""
    beds = max((int(job.get("bed", 1)) for job in jobs), default=1)
    if beds <= 1:
        return " Print them together: they share one bed." if len(jobs) > 1 else ""
    return (
        f" The jobs fill {beds} beds, side by side in that file (the first on the plate); "
        f"`{stem}-bed1.3mf` to `{stem}-bed{beds}.3mf` hold one bed each, on the plate: "
        "print them one after the other."
    )


def _on_bed(job: dict[str, Any], jobs: Sequence[dict[str, Any]]) -> str:
    """`` (bed 2)`` where the jobs fill more than one bed."""
    several = len({int(j.get("bed", 1)) for j in jobs}) > 1
    return f" (bed {job['bed']})" if several and "bed" in job else ""


def _unnumbered_text(unlabelled: Sequence[int]) -> str:
    """The guide's word on tiles too small for an engraved number (empty when there are
    none)."""
    if not unlabelled:
        return ""
    which = id_runs(unlabelled)
    return (
        f" {_count(len(unlabelled), 'tile')} too small for the digits carry no number "
        f"(tile{'s' if len(unlabelled) > 1 else ''} {which}): mark them by hand as they come "
        "off the bed, matching each outline to the placement template or the tile picture "
        "below; a larger --size makes room for the numbers."
    )


def _trimmed_text(trimmed: Sequence[int]) -> str:
    """The plywood guide's word on tiles whose overlap with a neighbour must be cut away (the
    panels make whole boxes; empty when there are none)."""
    if not trimmed:
        return ""
    return (
        f" {_count(len(trimmed), 'tile')} overlap a hinged neighbour in the flat pose "
        f"(tile{'s' if len(trimmed) > 1 else ''} {id_runs(trimmed)}; `hinges.json` trims): "
        "the panels make whole boxes, so once each is glued, saw or sand its overlap off as "
        "`flat.step` shows that tile, or the flat sheet will not lie flat."
    )


def _count(number: int, noun: str) -> str:
    """``1 sheet``, ``3 sheets``."""
    return f"{number} {noun}" if number == 1 else f"{number} {noun}s"
