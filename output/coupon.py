"""``drawstring coupon``: the test coupon of a profile and printer, written as a folder.

The coupon (:func:`~drawstring.fabrication.coupon.coupon_design`, 3 x 3 tiles with a split,
its magnet pockets, hinges on both faces, the string channel and a lift bore) goes through
the same solids and fabrication files as a design: the folder holds what a design's
``fabrication/`` holds (the 3MF and its PrusaSlicer settings, or the DXF sheets; STEP, bom.csv,
manifest.json, assembly.md) and ``coupon.md``, what to check on it.  Like a design folder it
is written whole into a temporary sibling and renamed into place; an earlier coupon folder
there is replaced.
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
from pathlib import Path

from drawstring.fabrication.profiles import Process, Profile, load_profile, print_clearance_mm
from drawstring.geometry.core.errors import InputError
from drawstring.output.assembly_text import COUPON_DESIGN
from drawstring.output.folder import place_staged, placement_error, staging_dir, write_refused

#: The name a coupon's manifest.json gives as its design.
COUPON_NAME = COUPON_DESIGN

CHECKS: dict[Process, list[str]] = {
    Process.FDM_DUAL: [
        "The TPU pads hold to both tiles: bend each hinge to 90 degrees a few times; a pad "
        "that peels off needs a hotter TPU nozzle or a slower first TPU layer.",
        "Every hinge bends freely: the tiles print a nozzle width apart; cut any strand of "
        "PLA across a gap.",
        "The string runs through: thread it through the channels of all nine tiles and up "
        "and out of the lift bore without forcing it.",
        "The magnets fit their pockets in the split's side faces, poles as bom.csv says.",
    ],
    Process.LASER_EPDM: [
        "The rubber strips fit their recesses and hold when glued; bend each hinge a few times.",
        "The string runs through the channels of all nine tiles and out of the lift bore.",
        "The magnets fit their pockets in the split's side faces.",
    ],
    Process.PLYWOOD_CNC: [
        "The panels' finger joints close and the boxes glue up square.",
        "The rubber strips' screws hold in the panels' edges; bend each hinge a few times.",
        "The cable runs through the holes and tubes of all nine boxes.",
        "The magnets fit their holes in the split's side panels.",
    ],
}


def check_coupon_dir(out: Path) -> Path:
    """Refuse an output path that cannot become the coupon folder, before any work."""
    out = out.absolute()
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {out} exists and is a file; choose another --out")
    if out.is_dir() and any(out.iterdir()):
        try:
            manifest = json.loads((out / "manifest.json").read_text(encoding="utf-8"))
            ours = manifest.get("design") == COUPON_NAME
        except (OSError, ValueError, AttributeError):
            ours = False
        if not ours:
            raise InputError(
                f"output folder {out} exists and is not a drawstring coupon; choose another --out"
            )
    probe = out.parent
    while not probe.exists():
        probe = probe.parent
    refused = write_refused(probe) if probe.is_dir() else "not a folder"
    if refused:
        raise InputError(f"cannot write into {probe} ({refused}); choose a writable --out folder")
    return out


def write_coupon(
    profile_name: str,
    printer_name: str | None,
    out: Path,
    *,
    slice_beds: bool = True,
) -> tuple[Path, Profile]:
    """Build the coupon of ``profile_name`` on ``printer_name`` (None: the profile's printer)
    and write its folder at ``out``; returns the folder and the profile as used.

    Raises
    ------
    InputError
        An unknown or invalid profile or printer, or an output path that cannot be written:
        nothing is written.
    """
    from drawstring.cad.design import build_design_solids
    from drawstring.cad.tiles import move_solid
    from drawstring.fabrication.coupon import coupon_design
    from drawstring.fabrication.exports import write_fabrication
    from drawstring.fabrication.printers import resolve_printer, with_printer
    from drawstring.output.assembly_guide import write_guide

    profile = load_profile(profile_name)
    printer = resolve_printer(profile, printer_name)
    profile = with_printer(profile, printer)
    out = check_coupon_dir(out)
    design = coupon_design(profile)
    flat = build_design_solids(
        *design.solid_inputs(), profile, workers=1, print_clearance_mm=print_clearance_mm(profile)
    )
    assembled = dataclasses.replace(
        flat,
        pose="assembled",
        tiles=tuple(move_solid(s, m) for s, m in zip(flat.tiles, flat.transforms, strict=True)),
        pads=(),
    )
    staging = staging_dir(out)
    try:
        write_fabrication(
            staging,
            profile=profile,
            linkage=design.linkage,
            tiles_flat=design.tiles_2d,
            tiles_assembled=design.tiles_3d,
            hinge_side=design.hinge_side,
            route_steps=design.route_steps,
            lift_tiles=design.lift_tiles,
            magnet_pairs=design.magnet_pairs,
            trims=design.trims,
            cad_flat=flat,
            cad_assembled=assembled,
            design_name=COUPON_NAME,
            workers=1,
            guide=write_guide,
            printer=printer,
            slice_beds=slice_beds,
        )
        folder = staging / "fabrication"
        _write_checks(folder / "coupon.md", profile)
        os.chmod(folder, 0o755)
        place_staged(folder, out)
    except OSError as exc:
        raise placement_error(out, exc) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    return out, profile


def _write_checks(path: Path, profile: Profile) -> None:
    """``coupon.md``: what the coupon is for and what to check on it."""
    lines = [
        f"# Test coupon ({profile.name})",
        "",
        "Nine tiles of this profile's default design, 3 x 3, with its hinges on both faces, "
        "the string channel through every tile, a lift bore and a split joined by a magnet "
        "pair. Make it as `assembly.md` says (`bom.csv` gives the time and material), then "
        "check:",
        "",
        *(f"- {check}" for check in CHECKS[profile.process]),
        "",
    ]
    path.write_text("\n".join(lines), encoding="utf-8")
