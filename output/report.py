"""The design report: one self-contained ``report.html`` a person reads before printing.

``write_report(folder)`` reads whatever the output folder already holds (``design.json``,
``assembled.obj``, ``flat.obj``, ``route.json``, ``deploy.npz``, the pictures) and writes
``folder/report.html``: a summary, every metric with its target and a pass/fail mark, the
pictures, the files and the assembly steps, plus an interactive 3D view (orbit, flat/assembled,
layers, deployment slider, tile picking).  Any of those files may be missing; the page says
plainly what the design does not have yet.

The page opens from disk with no server and no network: three.js (vendored in ``web/`` at a
pinned version, MIT licence), the pictures (data URIs) and the geometry (JSON, rounded to
0.01 mm) are all inlined.  ``open_report(folder)`` opens it in the default browser.
"""

from __future__ import annotations

import base64
import html
import json
import logging
import re
import webbrowser
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.tiling.linkage import TILE_FACES as TILE_FACES
from drawstring.output.design_folder import (
    COINCIDENT_CORNER_REL as COINCIDENT_CORNER_REL,
)
from drawstring.output.design_folder import (
    DESIGN_JSON_TYPES,
    FloatArray,
    Route,
    design_json_faults,
    hinges_from_flat,
    neighbour_lists,
    read_deploy_frames,
    read_obj_quads,
    read_obj_tiles,
    read_route,
    subsample_frames,
    tile_volumes,
    touching_tiles,
)
from drawstring.output.design_folder import (
    MAX_FRAME_VALUES as MAX_FRAME_VALUES,
)
from drawstring.output.design_folder import IntArray as IntArray
from drawstring.output.design_folder import (
    coincident_corners as coincident_corners,
)
from drawstring.output.design_folder import (
    median_edge_length as median_edge_length,
)
from drawstring.output.metric_rules import METRIC_RULES as METRIC_RULES
from drawstring.output.metric_rules import MetricRow, evaluate_metrics
from drawstring.output.metric_rules import MetricRule as MetricRule

log = logging.getLogger(__name__)

#: Vendored three.js build (npm ``three``), one self-contained ES module; see ``web/README.md``.
THREE_FILE = "three.module.min.js"
THREE_VERSION = "0.170.0"
THREE_LICENCE_FILE = "LICENSE-three.txt"

#: Decimals kept for inlined coordinates (mm): 0.01 mm is far below what the eye sees.
GEOMETRY_DECIMALS = 2

SIDE_NAMES = ("bottom", "right", "top", "left")


# ----------------------------------------------------------------------------------------------
# Page
# ----------------------------------------------------------------------------------------------

#: Files of the output folder and what each is for (ARCHITECTURE.md section 4).
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
    "cut), for scripts",
    "deploy.npz": "the simulated deployment, flat to assembled (frames of tile corners)",
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
    "scale_factor.png": "Conformal scale factor of the flattening (and splits, if any).",
    "lifted.png": "The quad grid lifted onto the target surface.",
    "lift.png": "Gap potential energy and the chosen lift points.",
    "deploy.gif": "Deployment from flat to assembled.",
}
#: What a complete design has; each missing one is named on the page.
EXPECTED: dict[str, str] = {
    "design.json": "design.json (options and metrics)",
    "assembled.obj": "the assembled tiles (assembled.obj)",
    "flat.obj": "the flat layout (flat.obj)",
    "route.json": "the string route and lift points (route.json)",
    "deploy.npz": "the deployment simulation (deploy.npz)",
    "fabrication": "fabrication files (fabrication/)",
}


def _e(value: Any) -> str:
    return html.escape(str(value), quote=True)


def _web_text(name: str) -> str:
    return (resources.files("drawstring.output") / "web" / name).read_text(encoding="utf-8")


def three_module_as_global() -> str:
    """The vendored three.js module with its final ``export {...}`` turned into ``THREE``.

    The module has no imports; its one export list at the end is rewritten to
    ``globalThis.THREE = {...}`` so the page's own module can use it without fetching anything
    (file:// pages cannot import modules from disk).
    """
    src = _web_text(THREE_FILE)
    match = re.search(r"export\s*\{([^}]*)\}\s*;?\s*$", src)
    if match is None or "</script" in src.lower():
        raise RuntimeError(f"web/{THREE_FILE} is not the expected single-file three.js module")
    members = []
    for item in match.group(1).split(","):
        parts = item.strip().split(" as ")
        local, exported = (parts[0], parts[-1])
        members.append(f"{exported.strip()}:{local.strip()}")
    return src[: match.start()] + "globalThis.THREE=Object.freeze({" + ",".join(members) + "});"


def _data_uri(path: Path) -> str:
    mime = "image/gif" if path.suffix.lower() == ".gif" else "image/png"
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _rounded(array: FloatArray) -> list[Any]:
    return np.round(np.asarray(array, dtype=float), GEOMETRY_DECIMALS).reshape(-1).tolist()


@dataclass(frozen=True)
class _Folder:
    """What the report found in the output folder."""

    folder: Path
    design: dict[str, Any]
    assembled: FloatArray | None
    flat: FloatArray | None
    frames: FloatArray | None
    route: Route | None
    problems: tuple[str, ...]
    assembled_source: str = "assembled.obj"


def _load(folder: Path) -> _Folder:
    problems: list[str] = []
    design: dict[str, Any] = {}
    path = folder / "design.json"
    if path.is_file():
        try:
            design = json.loads(path.read_text(encoding="utf-8"))
        except ValueError as err:
            problems.append(f"design.json is not valid JSON ({err})")
        faults = design_json_faults(design)
        if faults:  # the page is made of what is left
            problems += faults
            design = {} if not isinstance(design, dict) else design
            design = {k: v for k, v in design.items() if k not in DESIGN_JSON_TYPES
                      or isinstance(v, DESIGN_JSON_TYPES[k])}  # fmt: skip

    def attempt(name: str, reader: Callable[[Path], Any]) -> Any:
        if not (folder / name).is_file():
            return None
        try:
            return reader(folder / name)
        except (InputError, OSError, ValueError) as err:
            problems.append(f"{name} could not be read: {err}")
            return None

    assembled = attempt("assembled.obj", read_obj_tiles)
    assembled_source = "assembled.obj"
    if assembled is None and not (folder / "assembled.obj").exists():
        quads = attempt("lifted.obj", read_obj_quads)
        if quads is not None:  # the lifted grid stands in, as tiles without thickness
            assembled = np.concatenate([quads, quads], axis=1)
            assembled_source = "lifted.obj"
    flat = attempt("flat.obj", read_obj_tiles)
    frames = attempt("deploy.npz", read_deploy_frames)
    route = attempt("route.json", read_route)
    counts = {len(x) for x in (assembled, flat) if x is not None}
    if frames is not None:
        counts.add(frames.shape[1])
    if len(counts) > 1:
        problems.append(
            f"the files disagree on the number of tiles ({sorted(counts)}); the 3D view shows "
            "the assembled and flat poses only"
        )
        frames = None
    return _Folder(
        folder, design, assembled, flat, frames, route, tuple(problems), assembled_source
    )


def _neighbours(found: _Folder, n_tiles: int) -> tuple[list[list[int]], list[list[int]], str]:
    """Hinges (with side) and neighbour lists, from the best source the folder has."""
    design_hinges = found.design.get("linkage", {}).get("hinges")
    if isinstance(design_hinges, list) and design_hinges:
        hinges = np.asarray(design_hinges, dtype=np.int64).reshape(-1, 4)
        sides_raw = found.design.get("linkage", {}).get("hinge_side") or []
        side = [1 if s == "bottom" else 0 if s == "top" else 2 for s in sides_raw]
        side += [2] * (len(hinges) - len(side))
        rule = "sharing a hinge"
    elif found.flat is not None:
        hinges, side_arr = hinges_from_flat(found.flat)
        side = side_arr.tolist()
        rule = "sharing a hinge"
    elif found.assembled is not None:
        pairs = touching_tiles(found.assembled)
        return [], neighbour_lists(n_tiles, pairs), "touching along an edge"
    else:
        return [], [[] for _ in range(n_tiles)], "none known"
    rows = [
        [int(a), int(ca), int(b), int(cb), int(s)]
        for (a, ca, b, cb), s in zip(hinges, side, strict=True)
    ]
    return rows, neighbour_lists(n_tiles, hinges[:, [0, 2]]), rule


def _view_data(found: _Folder) -> dict[str, Any]:
    n_tiles = next(
        (len(x) for x in (found.assembled, found.flat) if x is not None),
        found.frames.shape[1] if found.frames is not None else 0,
    )
    hinges, neighbours, rule = _neighbours(found, n_tiles)
    frames = None if found.frames is None else subsample_frames(found.frames)
    route = None
    if found.route is not None and len(found.route.steps):
        steps = found.route.steps
        ok = (steps[:, 1] >= 0) & (steps[:, 1] < n_tiles)
        ok &= (steps[:, 2:] >= 0).all(axis=1) & (steps[:, 2:] < 4).all(axis=1)
        lift = found.route.lift[(found.route.lift[:, 1] >= 0) & (found.route.lift[:, 1] < n_tiles)]
        route = {"steps": steps[ok].tolist(), "lift": lift.tolist()}
    return {
        "tiles": int(n_tiles),
        "poses": {
            "flat": None if found.flat is None else _rounded(found.flat),
            "assembled": None if found.assembled is None else _rounded(found.assembled),
        },
        "frames": None if frames is None else [_rounded(f) for f in frames],
        "frames_in_file": None if found.frames is None else int(len(found.frames)),
        "hinges": hinges,
        "neighbours": neighbours,
        "neighbour_rule": rule,
        "route": route,
        "assembled_source": found.assembled_source,
    }


def _mass_g(found: _Folder) -> tuple[float | None, str]:
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


def _bed_note(found: _Folder) -> str:
    if found.flat is None:
        return ""
    extent = np.ptp(found.flat.reshape(-1, 3)[:, :2], axis=0)
    text = f"{extent[0]:.0f} × {extent[1]:.0f} mm"
    profile_name = found.design.get("options", {}).get("profile") or found.design.get("profile")
    if not profile_name:
        return text
    from drawstring.fabrication.profiles import BED_MARGIN_MM, load_profile

    try:
        profile = load_profile(str(profile_name))
    except (InputError, OSError):
        return text
    if profile.process == "plywood-cnc":  # cut as panels nested on sheets: no bed to fit
        return f"{text} (its tiles are cut as panels nested on the sheets)"
    bed = (profile.bed_x_mm, profile.bed_y_mm)
    room = (bed[0] - 2 * BED_MARGIN_MM, bed[1] - 2 * BED_MARGIN_MM)  # as the job planner
    fits = (extent[0] <= room[0] and extent[1] <= room[1]) or (
        extent[0] <= room[1] and extent[1] <= room[0]
    )
    verdict = "fits" if fits else "does not fit"
    note = (
        f"{text} ({verdict} the {bed[0]:g} × {bed[1]:g} mm bed of {profile.name} with "
        f"{BED_MARGIN_MM:g} mm free round it)"
    )
    if fits:
        return note
    jobs, beds = print_job_counts(found.folder)
    if not jobs:
        return f"{note}; the fabrication files split it into print jobs"
    if profile.process == "laser-epdm":
        return (
            f"{note}; the loose tiles print nested on {beds} bed{'s' if beds != 1 else ''} "
            "(see fabrication/assembly.md)"
        )
    return (
        f"{note}; fabrication/ splits it into {jobs} print jobs on {beds} "
        f"bed{'s' if beds != 1 else ''} (see fabrication/assembly.md)"
    )


def print_job_counts(folder: Path) -> tuple[int, int]:
    """Print jobs and beds listed in a design folder's ``fabrication/manifest.json`` (0, 0
    without one)."""
    try:
        manifest = json.loads((folder / "fabrication" / "manifest.json").read_text())
        jobs = [job for job in manifest.get("print_jobs", []) if isinstance(job, dict)]
    except (OSError, ValueError, AttributeError):
        return 0, 0
    return len(jobs), len({job.get("bed", 1) for job in jobs})


def _summary(found: _Folder, view: dict[str, Any]) -> str:
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
    bed = _bed_note(found)
    if bed:
        rows.append(("Flat layout", bed))
    grams, how = _mass_g(found)
    if grams is not None:
        rows.append(("Mass", f"{grams:.0f} g <span class=note>({_e(how)})</span>"))
    elif how:
        rows.append(("Mass", f"<span class=note>{_e(how)}</span>"))
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
    rows.append(("String length", length_text))
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
    rows.append(
        (
            "Lift points",
            (f"{lifts}" + (f" ({lift_tiles})" if lift_tiles else ""))
            if lifts is not None
            else "not computed yet",
        )
    )
    body = "".join(
        f"<tr><th>{_e(k)}</th><td>{v if '<span' in v else _e(v)}</td></tr>" for k, v in rows
    )
    return f"<table class=kv>{body}</table>"


def _missing(found: _Folder) -> list[str]:
    return [text for name, text in EXPECTED.items() if not (found.folder / name).exists()]


def _verdict(rows: list[MetricRow]) -> str:
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
            f"<p class='verdict fail'>✗ {len(hard)} of {len(marked)} checks fail: {_e(names)}. "
            "Look at these before printing." + (f" Also {_e(off_text)}." if off else "") + "</p>"
        )
    if off:
        return (
            f"<p class='verdict warn'>⚠ {len(marked) - len(off)} of {len(marked)} checks pass; "
            f"{_e(off_text)} (the design can be made; its warnings say what would bring "
            f"{'them' if len(off) != 1 else 'it'} in).</p>"
        )
    if len(marked) == 1:
        return f"<p class='verdict pass'>✓ The one check ({_e(marked[0].name)}) passes.</p>"
    return f"<p class='verdict pass'>✓ All {len(marked)} checks pass.</p>"


def _metrics_table(rows: list[MetricRow]) -> str:
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
        meaning = _e(r.meaning) if r.meaning else "<span class=note>(no target known)</span>"
        lines.append(
            f"<tr{cls}><td class=mono>{_e(r.name)}</td><td class=num>{_e(r.value)}</td>"
            f"<td>{_e(r.target)}</td>{mark}<td>{meaning}</td></tr>"
        )
    head = "<tr><th>metric</th><th>value</th><th>target</th><th></th><th>what it measures</th></tr>"
    return f"<table>{head}{''.join(lines)}</table>"


def _pictures(folder: Path) -> str:
    figures = []
    names = list(PICTURES) + sorted(p.name for p in folder.glob("*.png") if p.name not in PICTURES)
    for name in names:
        path = folder / name
        if path.is_file():
            caption = PICTURES.get(name, name)
            figures.append(
                f"<figure><img alt='{_e(name)}' src='{_data_uri(path)}'>"
                f"<figcaption>{_e(caption)} <span class=mono>{_e(name)}</span></figcaption>"
                "</figure>"
            )
    missing = [n for n in PICTURES if not (folder / n).is_file()]
    note = f"<p class=note>Not in this design yet: {_e(', '.join(missing))}.</p>" if missing else ""
    if not figures:
        return "<p class=note>No pictures in this design yet.</p>" + note
    return f"<div class=pictures>{''.join(figures)}</div>{note}"


def _files(folder: Path) -> str:
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
            f"<tr><td class=mono><a href='{_e(path.name)}'>{_e(name)}</a></td>"
            f"<td class=num>{size}</td><td>{_e(purpose)}</td></tr>"
        )
    rows.append("<tr><td class=mono>report.html</td><td></td><td>this page</td></tr>")
    head = "<tr><th>file</th><th>size</th><th>what it is for</th></tr>"
    return f"<table>{head}{''.join(rows)}</table>"


def _size(n_bytes: int) -> str:
    if n_bytes < 1000:
        return f"{n_bytes} B"
    if n_bytes < 1_000_000:
        return f"{n_bytes / 1e3:.1f} kB"
    return f"{n_bytes / 1e6:.1f} MB"


def _assembly(found: _Folder) -> str:
    d = found.design
    profile = d.get("profile") or d.get("options", {}).get("profile") or "the chosen profile"
    splits = d.get("linkage", {}).get("splits")
    has_fab = (found.folder / "fabrication").is_dir()
    steps = [
        (
            f"Print or cut the flat layout with <b>{_e(profile)}</b> from the files in "
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
        f"{_e(start)}{counted}, in this order (tile ids, shown in the 3D view when you click a "
        f"tile): <details><summary>tile order</summary><p class=mono>{_e(order)}</p></details>"
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
            f"the top face: {_e('; '.join(points))}."
        )
    elif len(route.lift):
        where = ", ".join(f"tile {t}" for t in route.lift[:, 1] if t >= 0) or "see route.json"
        steps.append(
            f"At the {len(route.lift)} lift point{'s' if len(route.lift) != 1 else ''} "
            f"({_e(where)}) the string leaves through the top face: hold it there as a loop."
        )
    lifted = bool(guide.stops) or bool(len(route.lift))
    steps.append(
        "Lay the linkage flat, pull both ends of the string steadily "
        + ("while lifting the lift loops, " if lifted else "")
        + "until every gap has closed, then tie the string off."
    )
    return steps


def _viewer(view: dict[str, Any]) -> str:
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
</div>
<div class=viewer><div id=view></div></div>
<div class=deploy><span>Deployment: flat</span>
  <input type=range id=deploy min=0 max=0 step=1 value=0><span>assembled</span>
  <button id=play>Play</button><span id=deploy-label>{_e(frames_note)}</span></div>
<div id=tile-info>Click a tile to see its id and its neighbours.</div>
<p class=note>Drag to turn, shift-drag or right-drag to pan, wheel to zoom, double-click to reset.
Neighbours: tiles {_e(view["neighbour_rule"])}.
The string is drawn through the tiles on top of them.</p>
"""


def _json_for_script(value: Any) -> str:
    text = json.dumps(value, separators=(",", ":"), allow_nan=False)
    return text.replace("</", "<\\/").replace("<!--", "<\\!--")


def render_report(folder: Path) -> str:
    """The report page of an output folder, as HTML text."""
    found = _load(folder)
    view = _view_data(found)
    rows = evaluate_metrics(found.design)
    target = found.design.get("target", {}).get("name") or folder.name
    missing = _missing(found)
    missing_html = (
        "<div class=missing><b>This design does not have yet:</b><ul>"
        + "".join(f"<li>{_e(m)}</li>" for m in missing)
        + "</ul>The sections below show what there is.</div>"
        if missing
        else ""
    )
    problems_html = "".join(f"<p class='verdict fail'>{_e(p)}</p>" for p in found.problems)
    version = found.design.get("drawstring_version", "")
    version_text = f" · drawstring {version}" if version else ""
    source = str(found.design.get("target", {}).get("source", "")) or target
    profile = str(found.design.get("profile", ""))
    # The page names the target and profile, not the folder: a design is written into a
    # temporary folder first, and the page must be byte-identical whatever folder it lands in.
    origin = f"target {source}" + (f" · profile {profile}" if profile else "")
    summary = _verdict(rows) + problems_html + _summary(found, view) + missing_html
    licence = _web_text(THREE_LICENCE_FILE)
    body = f"""
<header><h1>drawstring design: {_e(target)}</h1>
<div class=sub>{_e(origin)}{_e(version_text)}</div></header>
<main>
<div class=top>
<section id=summary><h2>Summary</h2>{summary}</section>
<section id=view3d><h2>3D view</h2>{_viewer(view)}</section>
</div>
<section id=metrics><h2>Checks</h2>{_metrics_table(rows)}</section>
<section id=pictures><h2>Pictures</h2>{_pictures(folder)}</section>
<section id=assembly><h2>Assembly</h2>{_assembly(found)}</section>
<section id=files><h2>Files</h2>{_files(folder)}</section>
</main>
<footer>Written by drawstring from the files of this folder. The 3D view uses three.js
r{THREE_VERSION.split(".")[1]} (MIT licence), included in this page.
<details><summary>three.js licence</summary><pre>{_e(licence)}</pre></details></footer>
"""
    parts = {
        "title": _e(f"drawstring design: {target}"),
        "style": _web_text("report.css"),
        "body": body,
        "data": _json_for_script(view),
        "three": three_module_as_global(),
        "app": _web_text("report.js"),
    }
    template = _web_text("report.html")
    return re.sub(r"\{\{(\w+)\}\}", lambda m: parts[m.group(1)], template)


def write_report(folder: Path | str) -> Path:
    """Write ``folder/report.html`` from the files already in the output folder.

    Raises
    ------
    InputError
        If ``folder`` is not a folder.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder} is not a folder; pass the output folder of drawstring design")
    page = render_report(folder)
    path = folder / "report.html"
    path.write_text(page, encoding="utf-8")
    log.info("wrote %s (%.1f MB)", path.name, len(page.encode("utf-8")) / 1e6)
    return path


def open_report(folder: Path | str) -> tuple[Path, bool]:
    """Open ``folder/report.html`` in the default browser, writing it first if missing; the
    page's path, and whether a browser took it (False on a machine without one)."""
    folder = Path(folder)
    path = folder / "report.html"
    if not path.is_file():
        path = write_report(folder)
    return path, bool(webbrowser.open(path.resolve().as_uri()))
