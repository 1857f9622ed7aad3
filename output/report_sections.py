"""The sections of the report page, as HTML: the summary and its verdict, the checks, the
pictures, the assembly steps, the files and the controls of the 3D view.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path
from typing import Any

import numpy as np

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import Side
from drawstring.output.design_folder import Route, print_job_counts, tile_volumes
from drawstring.output.metric_rules import MetricRow
from drawstring.output.report_data import FolderContents
from drawstring.output.report_printing import print_bed, print_numbers

#: Tile sides by number, as the route names them.
SIDE_NAMES = tuple(side.label for side in Side)

#: Files of the output folder and what each is for (the output contract, docs/output.md).
FILE_PURPOSES: dict[str, str] = {
    "report.html": "this page",
    "design.json": "every option used and every number measured on the design",
    "lifted.obj": "the quad grid lifted onto the target, before optimization",
    "assembled.obj": "the tiles in their assembled (curved) pose, closed meshes, mm",
    "flat.obj": "the tiles in their flat (fabrication) pose, closed meshes, mm",
    "route.json": "the string route: the tiles and sides it passes, and the lift points",
    "hinges.json": "the hinges: the tiles and corners each joins, its face (top or bottom) "
    "and its point in the flat pose",
    "tiles.npz": "the tiles' vertex arrays in both poses (assembled; fabricated: as printed or "
    "cut) and each tile's distance from the target, for scripts",
    "deploy.npz": "the simulated deployment, flat to assembled (frames of tile corners)",
    "target.obj": "the target as the design approximates it: scaled, in the frame of assembled.obj",
    "fit.png": "picture: the assembled tiles coloured by their distance from the target",
    "scale_factor.png": "picture: conformal scale factor and splits",
    "lifted.png": "picture: the lifted grid on the target",
    "assembled.png": "picture: the assembled shape",
    "flat.png": "picture: flat layout with gaps, hinges, route and lift points",
    "lift.png": "picture: gap energy and the chosen lift points",
    "deploy.gif": "animation of the deployment",
    "fabrication": "files to print or cut, for the chosen profile",
}
#: Pictures in the order the page shows them, with captions.
PICTURES: dict[str, str] = {
    "flat.png": "Flat layout: tiles, gaps, hinges, the string route and the lift points.",
    "assembled.png": "The assembled shape.",
    "fit.png": "The assembled tiles coloured by how far their top faces sit from the target.",
    "scale_factor.png": "Conformal scale factor of the flattening (and splits, if any).",
    "lifted.png": "The quad grid lifted onto the target surface.",
    "lift.png": "Gap potential energy and the chosen lift points.",
    "deploy.gif": "Deployment from flat to assembled.",
}


def escaped(value: Any) -> str:
    """``value`` as text for HTML, quotes escaped too."""
    return html.escape(str(value), quote=True)


def _data_uri(path: Path) -> str:
    """A picture file as a ``data:`` URI."""
    mime = "image/gif" if path.suffix.lower() == ".gif" else "image/png"
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def summary_table(found: FolderContents, view: dict[str, Any]) -> str:
    """The summary: target, profile, tiles, size, flat layout, mass, string, lift points."""
    d = found.design
    target = d.get("target", {})
    linkage = d.get("linkage", {})
    metrics = d.get("metrics", {}) or {}
    rows: list[tuple[str, str]] = []
    name = target.get("name")
    if name:
        extra = f" ({target['source']})" if target.get("source") else ""
        rows.append(("Target", f"{name}{extra}"))
    profile = d.get("profile") or d.get("options", {}).get("profile")
    if profile:
        rows.append(("Profile", str(profile)))
    tiles = linkage.get("tiles", view["tiles"] or None)
    if tiles:
        grid = linkage.get("grid")
        grid_text = f" on a {grid[0]} × {grid[1]} grid" if isinstance(grid, list) else ""
        rows.append(("Tiles", f"{tiles}{grid_text}"))
    for key, label in (("hinges", "Hinges"), ("splits", "Splits"), ("components", "Parts")):
        if isinstance(linkage.get(key), int):
            rows.append((label, str(linkage[key])))
    if found.assembled is not None:
        ext = np.ptp(found.assembled.reshape(-1, 3), axis=0)
        what = "assembled" if found.assembled_source == "assembled.obj" else "lifted grid"
        rows.append((f"Size ({what})", f"{ext[0]:.0f} × {ext[1]:.0f} × {ext[2]:.0f} mm"))
    elif isinstance(target.get("size_mm"), int | float):
        rows.append(("Size", f"{target['size_mm']:.0f} mm longest side (target)"))
    bed = bed_note(found)
    if bed:
        rows.append(("Flat layout", bed))
    printing = print_numbers(found.folder)
    if printing:
        rows.append(("Printing", printing))
    grams, how = _mass_g(found)
    if grams is not None:
        rows.append(("Mass", f"{grams:.0f} g <span class=note>({escaped(how)})</span>"))
    elif how:
        rows.append(("Mass", f"<span class=note>{escaped(how)}</span>"))
    rows.append(("String length", _string_length_text(found, metrics)))
    rows.append(("Lift points", _lift_points_text(found, metrics)))
    body = "".join(
        f"<tr><th>{escaped(k)}</th><td>{v if '<span' in v else escaped(v)}</td></tr>"
        for k, v in rows
    )
    return f"<table class=kv>{body}</table>"


def _string_length_text(found: FolderContents, metrics: Any) -> str:
    """The route's length, and the string to cut when the fabrication files say it."""
    length = (metrics.get("route") or {}).get("length_mm") if isinstance(metrics, dict) else None
    if length is None and found.route is not None:
        length = found.route.length_mm
    if isinstance(length, dict):  # route length in both configurations
        parts = [f"{float(v):.0f} mm {k}" for k, v in length.items() if isinstance(v, int | float)]
        length_text = "route " + ", ".join(parts) if parts else "not computed yet"
    elif isinstance(length, int | float):
        length_text = f"{float(length):.0f} mm"
    else:
        length_text = "not computed yet"
    cad = metrics.get("cad") if isinstance(metrics, dict) else None
    cut = cad.get("string_length_mm") if isinstance(cad, dict) else None
    if isinstance(cut, int | float):  # what to cut: the flat route, a margin and two tails
        length_text += f"; cut {float(cut) / 1000:.2f} m of string (bom.csv)"
    return length_text


def _lift_points_text(found: FolderContents, metrics: Any) -> str:
    """How many lift points, and on which tiles."""
    lifts = metrics.get("lift_points")
    if isinstance(lifts, list):
        lifts = len(lifts)
    elif isinstance(lifts, dict):
        lifts = lifts.get("count")
    if lifts is None and found.route is not None:
        lifts = len(found.route.lift)
    lift_tiles = (
        ", ".join(f"tile {t}" for t in found.route.lift[:, 1] if t >= 0)
        if found.route is not None
        else ""
    )
    if lifts is None:
        return "not computed yet"
    return f"{lifts}" + (f" ({lift_tiles})" if lift_tiles else "")


def bed_note(found: FolderContents) -> str:
    """The flat layout's size, and whether it fits the printer's bed (else how the
    fabrication files split it)."""
    if found.flat is None:
        return ""
    extent = np.ptp(found.flat.reshape(-1, 3)[:, :2], axis=0)
    text = f"{extent[0]:.0f} × {extent[1]:.0f} mm"
    profile_name = found.design.get("options", {}).get("profile") or found.design.get("profile")
    if not profile_name:
        return text
    from drawstring.fabrication.profiles import BED_MARGIN_MM, Process, load_profile

    try:
        profile = load_profile(str(profile_name))
    except (InputError, OSError):
        return text
    if profile.process == Process.PLYWOOD_CNC:  # cut as panels nested on sheets: no bed to fit
        return f"{text} (its tiles are cut as panels nested on the sheets)"
    bed, bed_name = print_bed(found.design, profile)
    room = (bed[0] - 2 * BED_MARGIN_MM, bed[1] - 2 * BED_MARGIN_MM)  # as the job planner
    fits = (extent[0] <= room[0] and extent[1] <= room[1]) or (
        extent[0] <= room[1] and extent[1] <= room[0]
    )
    verdict = "fits" if fits else "does not fit"
    note = (
        f"{text} ({verdict} the {bed[0]:g} × {bed[1]:g} mm bed of {bed_name} with "
        f"{BED_MARGIN_MM:g} mm free round it)"
    )
    if fits:
        return note
    jobs, beds = print_job_counts(found.folder)
    if not jobs:
        return f"{note}; the fabrication files split it into print jobs"
    if profile.process == Process.LASER_EPDM:
        return (
            f"{note}; the loose tiles print nested on {beds} bed{'s' if beds != 1 else ''} "
            "(see fabrication/assembly.md)"
        )
    return (
        f"{note}; fabrication/ splits it into {jobs} print jobs on {beds} "
        f"bed{'s' if beds != 1 else ''} (see fabrication/assembly.md)"
    )


def _mass_g(found: FolderContents) -> tuple[float | None, str]:
    """The design's mass in grams (None when unknown) and where the number comes from."""
    metrics = found.design.get("metrics", {}) or {}
    for key in ("mass_g", "total_mass_g"):
        if isinstance(metrics.get(key), int | float):
            return float(metrics[key]), "from design.json"
    if found.assembled is None or found.assembled_source != "assembled.obj":
        return None, ""
    volume_mm3 = float(tile_volumes(found.assembled).sum())
    profile_name = found.design.get("options", {}).get("profile") or found.design.get("profile")
    if not profile_name:
        return None, f"tile volume {volume_mm3 / 1000:.1f} cm³ (no profile to give a density)"
    from drawstring.fabrication.profiles import load_profile

    try:
        profile = load_profile(str(profile_name))
    except (InputError, OSError):
        return None, f"tile volume {volume_mm3 / 1000:.1f} cm³ (profile {profile_name} not found)"
    grams = volume_mm3 * 1e-9 * profile.density_kg_m3 * profile.infill_fraction * 1000.0
    return grams, (
        f"estimate: tile volume {volume_mm3 / 1000:.1f} cm³ × {profile.density_kg_m3:g} kg/m³ "
        f"{profile.tile_material} × {profile.infill_fraction:g} infill; no hinges or string"
    )


def verdict(rows: list[MetricRow]) -> str:
    """One line over the summary: how many checks pass, and which fail or miss a target."""
    marked = [r for r in rows if r.passed is not None]
    failed = [r for r in marked if not r.passed]
    if not marked:
        return "<p class='verdict info'>No checks yet: this design has no metric with a target.</p>"
    hard = [r for r in failed if not r.advisory]
    off = [r for r in failed if r.advisory]
    off_text = (
        f"{len(off)} quality target{'s' if len(off) != 1 else ''} missed: "
        f"{', '.join(r.name for r in off)}"
    )
    if hard:
        names = ", ".join(r.name for r in hard)
        return (
            f"<p class='verdict fail'>✗ {len(hard)} of {len(marked)} checks fail: "
            f"{escaped(names)}. Look at these before printing."
            + (f" Also {escaped(off_text)}." if off else "")
            + "</p>"
        )
    if off:
        return (
            f"<p class='verdict warn'>⚠ {len(marked) - len(off)} of {len(marked)} checks pass; "
            f"{escaped(off_text)} (the design can be made; its warnings say what would bring "
            f"{'them' if len(off) != 1 else 'it'} in).</p>"
        )
    if len(marked) == 1:
        return f"<p class='verdict pass'>✓ The one check ({escaped(marked[0].name)}) passes.</p>"
    return f"<p class='verdict pass'>✓ All {len(marked)} checks pass.</p>"


def metrics_table(rows: list[MetricRow]) -> str:
    """The checks: every metric with its value, target, mark and meaning."""
    if not rows:
        return "<p class=note>design.json has no metrics yet.</p>"
    lines = []
    for r in rows:
        if r.passed is None:
            mark = "<td class='mark info'>–</td>"
        elif r.passed:
            mark = "<td class='mark pass'>✓ pass</td>"
        elif r.advisory:
            mark = "<td class='mark warn'>⚠ off target</td>"
        else:
            mark = "<td class='mark fail'>✗ fail</td>"
        cls = "" if r.passed is not False else " class=warn" if r.advisory else " class=fail"
        meaning = escaped(r.meaning) if r.meaning else "<span class=note>(no target known)</span>"
        lines.append(
            f"<tr{cls}><td class=mono>{escaped(r.name)}</td><td class=num>{escaped(r.value)}</td>"
            f"<td>{escaped(r.target)}</td>{mark}<td>{meaning}</td></tr>"
        )
    head = "<tr><th>metric</th><th>value</th><th>target</th><th></th><th>what it measures</th></tr>"
    return f"<table>{head}{''.join(lines)}</table>"


def pictures_section(folder: Path) -> str:
    """The folder's pictures, inlined, in :data:`PICTURES` order and then the others."""
    figures = []
    names = list(PICTURES) + sorted(p.name for p in folder.glob("*.png") if p.name not in PICTURES)
    for name in names:
        path = folder / name
        if path.is_file():
            caption = PICTURES.get(name, name)
            figures.append(
                f"<figure><img alt='{escaped(name)}' src='{_data_uri(path)}'>"
                f"<figcaption>{escaped(caption)} <span class=mono>{escaped(name)}</span>"
                "</figcaption>"
                "</figure>"
            )
    missing = [n for n in PICTURES if not (folder / n).is_file()]
    note = (
        f"<p class=note>Not in this design yet: {escaped(', '.join(missing))}.</p>"
        if missing
        else ""
    )
    if not figures:
        return "<p class=note>No pictures in this design yet.</p>" + note
    return f"<div class=pictures>{''.join(figures)}</div>{note}"


def files_table(folder: Path) -> str:
    """The folder's files with their sizes and what each is for."""
    rows = []
    # this page is listed as such, without the size of the one it replaces (simulate rewrites it)
    entries = sorted(
        p for p in folder.iterdir() if not p.name.startswith(".") and p.name != "report.html"
    )
    for path in entries:
        name = path.name + ("/" if path.is_dir() else "")
        purpose = FILE_PURPOSES.get(path.name, "")
        if path.is_dir():
            inner = sorted(q.relative_to(path).as_posix() for q in path.rglob("*") if q.is_file())
            shown = ", ".join(inner[:12]) + (f", … ({len(inner)} files)" if len(inner) > 12 else "")
            purpose = f"{purpose}: {shown}" if purpose else shown
            size = ""
        else:
            size = _size(path.stat().st_size)
        rows.append(
            f"<tr><td class=mono><a href='{escaped(path.name)}'>{escaped(name)}</a></td>"
            f"<td class=num>{size}</td><td>{escaped(purpose)}</td></tr>"
        )
    rows.append("<tr><td class=mono>report.html</td><td></td><td>this page</td></tr>")
    head = "<tr><th>file</th><th>size</th><th>what it is for</th></tr>"
    return f"<table>{head}{''.join(rows)}</table>"


def _size(n_bytes: int) -> str:
    """``512 B``, ``1.5 kB``, ``2.0 MB``."""
    if n_bytes < 1000:
        return f"{n_bytes} B"
    if n_bytes < 1_000_000:
        return f"{n_bytes / 1e3:.1f} kB"
    return f"{n_bytes / 1e6:.1f} MB"


def assembly_steps(found: FolderContents) -> str:
    """The assembly in a few numbered steps (the full guide is ``fabrication/assembly.md``)."""
    d = found.design
    profile = d.get("profile") or d.get("options", {}).get("profile") or "the chosen profile"
    splits = d.get("linkage", {}).get("splits")
    has_fab = (found.folder / "fabrication").is_dir()
    steps = [
        (
            f"Print or cut the flat layout with <b>{escaped(profile)}</b> from the files in "
            "<span class=mono>fabrication/</span>."
            if has_fab
            else "Print or cut the flat layout (<span class=mono>flat.obj</span>). "
            "<span class=note>The fabrication files are not in this design yet.</span>"
        ),
        "Check every hinge bends freely and clear any strings or burrs out of the channels.",
    ]
    if isinstance(splits, int) and splits > 0:
        steps.append(
            f"The design has {splits} split{'s' if splits != 1 else ''}: press the magnets into "
            "the pockets on the split faces, minding the poles so that facing magnets attract."
        )
    route = found.route
    if route is None or len(route.steps) == 0:
        steps.append(
            "<span class=note>The string route is not computed yet (no route.json): threading "
            "and lift-point steps will appear here once it is.</span>"
        )
    else:
        steps += _threading_steps(route)
    items = "".join(f"<li>{s}</li>" for s in steps)
    return f"<ol class=steps>{items}</ol>"


def _threading_steps(route: Route) -> list[str]:
    """The threading, lift-point and pulling steps, in the assembly guide's order: the guide
    (``fabrication/assembly.md``) starts the closed route at the lift point where both string
    ends stand up, and this page names the same start (the guide's own function decides it)."""
    from drawstring.output.assembly_order import plan_guide
    from drawstring.pipeline.cad_stage import lift_bores

    guide = plan_guide(route.steps, lift_bores(route.steps, route.lift[:, 0]))
    first = guide.order[0]
    gap, tile, enter, _ = (int(v) for v in route.steps[first])
    tails = next((stop for stop in guide.stops if stop.in_step == 0), None)
    if tails is not None:
        start = (
            f"lift point {tails.letter}, down through the top face into tile {tile}, with both "
            "string ends left standing up there"
        )
    elif gap < 0:
        start = f"tile {tile}, {SIDE_NAMES[enter % 4]} side"
    else:
        start = f"gap {gap} into tile {tile} ({SIDE_NAMES[enter % 4]} side)"
    counted = (
        f" (the route is a closed loop; step 1 here is step {first + 1} of "
        f"<span class=mono>route.json</span>, as in the assembly guide)"
        if first
        else ""
    )
    order = " → ".join(str(t) for t in route.steps[guide.order, 1])
    steps = [
        f"Thread the string through the {len(route.steps)} tiles of the route, starting at "
        f"{escaped(start)}{counted}, in this order (tile ids, shown in the 3D view when you "
        "click a tile): <details><summary>tile order</summary>"
        f"<p class=mono>{escaped(order)}</p></details>"
    ]

    def tile_at(step: int | None) -> str | None:
        return None if step is None else f"tile {route.steps[guide.order[step], 1]}"

    if guide.stops:
        points = []
        for stop in guide.stops:
            where = " → ".join(t for t in (tile_at(stop.out_step), tile_at(stop.in_step)) if t)
            what = "the two string ends" if stop.tails else "a loop: hold it there"
            points.append(f"{stop.letter} ({where}): {what}")
        count = len(guide.stops)
        steps.append(
            f"At the {count} lift point{'s' if count != 1 else ''} the string leaves through "
            f"the top face: {escaped('; '.join(points))}."
        )
    elif len(route.lift):
        where = ", ".join(f"tile {t}" for t in route.lift[:, 1] if t >= 0) or "see route.json"
        steps.append(
            f"At the {len(route.lift)} lift point{'s' if len(route.lift) != 1 else ''} "
            f"({escaped(where)}) the string leaves through the top face: hold it there as a loop."
        )
    lifted = bool(guide.stops) or bool(len(route.lift))
    steps.append(
        "Lay the linkage flat, pull both ends of the string steadily "
        + ("while lifting the lift loops, " if lifted else "")
        + "until every gap has closed, then tie the string off."
    )
    return steps


def viewer_controls(view: dict[str, Any]) -> str:
    """The 3D view's element with its controls and notes (``report.js`` draws in it)."""
    frames, in_file = view["frames"], view["frames_in_file"]
    if frames is None:
        frames_note = "deploy.npz is not in this design yet: there is no deployment to scrub."
    else:
        shown = f", {len(frames)} shown" if len(frames) != in_file else ""
        frames_note = f"{in_file} frames from deploy.npz{shown}"
    route_note = "" if view["route"] else " (none yet)"
    if view["assembled_source"] != "assembled.obj" and view["poses"]["assembled"] is not None:
        frames_note += (
            " The assembled pose shown is lifted.obj: the quad grid on the target before "
            "optimization, without thickness (assembled.obj is not in this design yet)."
        )
    hinge_note = "" if view["hinges"] else " (none known)"
    fit_note = "" if view.get("fit") else " (not in tiles.npz)"
    return f"""
<div class=controls>
  <span class=group><button data-pose=flat>Flat</button>
    <button data-pose=assembled>Assembled</button></span>
  <label><input type=checkbox id=show-tiles checked> tiles</label>
  <label><input type=checkbox id=show-edges checked> edges</label>
  <label><input type=checkbox id=show-hinges checked{" disabled" if hinge_note else ""}>
    <span class=legend style="background:#1c7ed6"></span>hinges{hinge_note}</label>
  <label><input type=checkbox id=show-route checked{" disabled" if route_note else ""}>
    <span class=legend style="background:#e03131"></span>string route{route_note}</label>
  <label><input type=checkbox id=show-lifts checked{" disabled" if route_note else ""}>
    <span class=legend style="background:#a61e4d"></span>lift points{route_note}</label>
  <label><input type=checkbox id=colour-fit{" disabled" if fit_note else ""}>
    colour by distance from the target{fit_note}</label>
  <span id=fit-scale hidden><span class=fit-bar></span> <span id=fit-scale-label></span></span>
</div>
<div class=viewer><div id=view></div></div>
<div class=deploy><span>Deployment: flat</span>
  <input type=range id=deploy min=0 max=0 step=1 value=0><span>assembled</span>
  <button id=play>Play</button><span id=deploy-label>{escaped(frames_note)}</span></div>
<div id=tile-info>Click a tile to see its id and its neighbours.</div>
<p class=note>Drag to turn, shift-drag or right-drag to pan, wheel to zoom, double-click to reset.
Neighbours: tiles {escaped(view["neighbour_rule"])}.
The string is drawn through the tiles on top of them.</p>
"""
