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

What the folder holds is read by :mod:`~drawstring.output.report_data`; each section's HTML is
made by :mod:`~drawstring.output.report_sections`.
"""

from __future__ import annotations

import json
import logging
import re
import webbrowser
from importlib import resources
from pathlib import Path
from typing import Any

from drawstring.geometry.core.errors import InputError
from drawstring.output.metric_rules import evaluate_metrics
from drawstring.output.report_data import FolderContents, read_folder, view_data
from drawstring.output.report_sections import (
    assembly_steps,
    escaped,
    files_table,
    metrics_table,
    pictures_section,
    summary_table,
    verdict,
    viewer_controls,
)

log = logging.getLogger(__name__)

#: Vendored three.js build (npm ``three``), one self-contained ES module; see ``web/README.md``.
THREE_FILE = "three.module.min.js"
THREE_VERSION = "0.170.0"
THREE_LICENCE_FILE = "LICENSE-three.txt"

#: What a complete design has; each missing one is named on the page.
EXPECTED: dict[str, str] = {
    "design.json": "design.json (options and metrics)",
    "assembled.obj": "the assembled tiles (assembled.obj)",
    "flat.obj": "the flat layout (flat.obj)",
    "route.json": "the string route and lift points (route.json)",
    "deploy.npz": "the deployment simulation (deploy.npz)",
    "fabrication": "fabrication files (fabrication/)",
}


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


def _missing(found: FolderContents) -> list[str]:
    return [text for name, text in EXPECTED.items() if not (found.folder / name).exists()]


def _json_for_script(value: Any) -> str:
    text = json.dumps(value, separators=(",", ":"), allow_nan=False)
    return text.replace("</", "<\\/").replace("<!--", "<\\!--")


def render_report(folder: Path) -> str:
    """The report page of an output folder, as HTML text."""
    found = read_folder(folder)
    view = view_data(found)
    rows = evaluate_metrics(found.design)
    target = found.design.get("target", {}).get("name") or folder.name
    missing = _missing(found)
    missing_html = (
        "<div class=missing><b>This design does not have yet:</b><ul>"
        + "".join(f"<li>{escaped(m)}</li>" for m in missing)
        + "</ul>The sections below show what there is.</div>"
        if missing
        else ""
    )
    problems_html = "".join(f"<p class='verdict fail'>{escaped(p)}</p>" for p in found.problems)
    version = found.design.get("drawstring_version", "")
    version_text = f" · drawstring {version}" if version else ""
    source = str(found.design.get("target", {}).get("source", "")) or target
    profile = str(found.design.get("profile", ""))
    # The page names the target and profile, not the folder: a design is written into a
    # temporary folder first, and the page must be byte-identical whatever folder it lands in.
    origin = f"target {source}" + (f" · profile {profile}" if profile else "")
    summary = verdict(rows) + problems_html + summary_table(found, view) + missing_html
    licence = _web_text(THREE_LICENCE_FILE)
    body = f"""
<header><h1>drawstring design: {escaped(target)}</h1>
<div class=sub>{escaped(origin)}{escaped(version_text)}</div></header>
<main>
<div class=top>
<section id=summary><h2>Summary</h2>{summary}</section>
<section id=view3d><h2>3D view</h2>{viewer_controls(view)}</section>
</div>
<section id=metrics><h2>Checks</h2>{metrics_table(rows)}</section>
<section id=pictures><h2>Pictures</h2>{pictures_section(folder)}</section>
<section id=assembly><h2>Assembly</h2>{assembly_steps(found)}</section>
<section id=files><h2>Files</h2>{files_table(folder)}</section>
</main>
<footer>Written by drawstring from the files of this folder. The 3D view uses three.js
r{THREE_VERSION.split(".")[1]} (MIT licence), included in this page.
<details><summary>three.js licence</summary><pre>{escaped(licence)}</pre></details></footer>
"""
    parts = {
        "title": escaped(f"drawstring design: {target}"),
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
