"""The sweep's comparison table: ``sweep.csv`` and ``sweep.html``.

One row per variant, in the variants' order: its exit status and message, the values of the
list options, and what its design folder measured (``design.json``, and with CAD
``fabrication/manifest.json``).  A column a variant has no value for (no CAD, no simulation,
nothing written) is empty.
"""

from __future__ import annotations

import csv
import html
import io
import json
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

#: The measured columns, after the variant, its status and the list options' values.
MEASURED = (
    "tiles", "parts", "surface_mean_mm", "surface_max_mm", "deployed", "mass_g",
    "material_cost", "currency", "print_h", "cut_h", "beds", "sheets", "warnings", "design_s",
    "worker",
)  # fmt: skip

#: What each column holds (the header's tooltip in sweep.html; docs/output.md lists them).
MEANINGS = {
    "variant": "the variant's folder, linked to its report",
    "status": "the exit status drawstring design gives it: 0 within every target, 2 refused, "
    "3 a hard target missed, 4 an accuracy target missed, 1 an internal error",
    "tiles": "tiles designed",
    "parts": "parts the linkage is split into",
    "surface_mean_mm": "fit: mean distance of the tiles from the target, mm",
    "surface_max_mm": "fit: largest distance of the tiles from the target, mm",
    "deployed": "the simulated pull deploys it (empty without the simulation)",
    "mass_g": "mass as made, g (the tiles' alone without CAD)",
    "material_cost": "material cost (with CAD)",
    "currency": "the profile's currency",
    "print_h": "printing time, hours (with CAD)",
    "cut_h": "cutting time, hours (with CAD)",
    "beds": "print beds (with CAD)",
    "sheets": "sheets cut (with CAD)",
    "warnings": "warnings the design lists",
    "design_s": "seconds the worker took to design and write it",
    "worker": "the Dask worker that made it",
    "message": "why the status is not 0",
}


@dataclass
class Row:
    """One variant's row: its name, list values, status, message and measured values."""

    variant: str
    values: tuple[tuple[str, str], ...]
    status: int | None = None
    message: str = ""
    written: bool = False
    measured: dict[str, Any] = field(default_factory=dict)


def measured(files: dict[str, bytes], seconds: float, worker: str) -> dict[str, Any]:
    """The measured columns of a written design folder (relative path -> bytes)."""
    doc = json.loads(files["design.json"])
    metrics = doc.get("metrics", {})
    linkage = doc.get("linkage", {})
    cad = metrics.get("cad") or {}
    simulation = metrics.get("simulation")
    manifest = (
        json.loads(files["fabrication/manifest.json"])
        if ("fabrication/manifest.json" in files)
        else {}
    )
    estimates = manifest.get("estimates", {})
    sheets = manifest.get("sheets") or {}
    return {
        "tiles": linkage.get("tiles"),
        "parts": linkage.get("components"),
        "surface_mean_mm": _round(metrics.get("surface_distance_mean_mm"), 3),
        "surface_max_mm": _round(metrics.get("surface_distance_max_mm"), 3),
        "deployed": None if not simulation else ("yes" if simulation.get("deployed") else "no"),
        "mass_g": _round(cad.get("mass_g", metrics.get("mass_g")), 1),
        "material_cost": estimates.get("material_cost"),
        "currency": estimates.get("currency"),
        "print_h": estimates.get("print_time_h"),
        "cut_h": estimates.get("cut_time_h"),
        "beds": estimates.get("print_beds"),
        "sheets": sum(int(s.get("sheets", 0)) for s in sheets.values()) if sheets else None,
        "warnings": len(doc.get("warnings", [])),
        "design_s": round(seconds, 1),
        "worker": worker,
    }


def _round(value: Any, digits: int) -> Any:
    return round(float(value), digits) if isinstance(value, int | float) else None


def columns(rows: Sequence[Row]) -> list[str]:
    """The table's columns: variant, status, the list options (by flag: ``--tiles`` is the
    value asked for, ``tiles`` the tiles made), measured, message."""
    flags = [flag for flag, _ in rows[0].values] if rows else []
    return ["variant", "status", *flags, *MEASURED, "message"]


def _cells(row: Row) -> dict[str, Any]:
    return {
        "variant": row.variant,
        "status": row.status,
        **dict(row.values),
        **row.measured,
        "message": row.message,
    }


def write_tables(out: Path, rows: Sequence[Row]) -> None:
    """Write ``sweep.csv`` and ``sweep.html`` into ``out``, each replacing the earlier one
    whole."""
    names = columns(rows)
    text = io.StringIO()
    writer = csv.writer(text, lineterminator="\n")
    writer.writerow(names)
    for row in rows:
        cells = _cells(row)
        writer.writerow(["" if cells.get(n) is None else cells[n] for n in names])
    _replace(out / "sweep.csv", text.getvalue())
    _replace(out / "sweep.html", _html(out.name, names, rows))


def _replace(path: Path, text: str) -> None:
    partial = path.with_name(f".{path.name}.tmp")
    partial.write_text(text, encoding="utf-8")
    os.replace(partial, path)


def _html(title: str, names: list[str], rows: Sequence[Row]) -> str:
    meanings = [MEANINGS.get(n, f"the value of {n} asked for") for n in names]
    head = "".join(
        f'<th title="{html.escape(meaning)}">{html.escape(n)}</th>'
        for n, meaning in zip(names, meanings, strict=True)
    )
    body = []
    for row in rows:
        cells = _cells(row)
        tds = []
        for n in names:
            value = cells.get(n)
            shown = "" if value is None else html.escape(str(value))
            key = "" if value is None else html.escape(str(value), quote=True)
            number = isinstance(value, int | float) and not isinstance(value, bool)
            if n == "variant" and row.written:
                shown = f'<a href="{html.escape(row.variant)}/report.html">{shown}</a>'
            cls = ' class="num"' if number else ""
            if n == "status" and value is not None:
                cls = f' class="num {"ok" if value == 0 else "bad"}"'
            tds.append(f'<td{cls} data-key="{key}">{shown}</td>')
        body.append(f"<tr>{''.join(tds)}</tr>")
    return _PAGE.format(title=html.escape(title), head=head, body="\n".join(body), count=len(rows))


#: The page: one table, sorted by a click on a column's header (again: the other way).
_PAGE = """<!DOCTYPE html>
<html lang="en">
<head>
<meta charset="utf-8">
<title>{title}: drawstring sweep</title>
<style>
body {{ font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #222; }}
table {{ border-collapse: collapse; }}
th, td {{ border-bottom: 1px solid #ddd; padding: 0.3em 0.6em; text-align: left;
  white-space: nowrap; }}
td:last-child {{ white-space: normal; max-width: 40em; }}
th {{ cursor: pointer; user-select: none; background: #f4f4f4; position: sticky; top: 0; }}
th.up::after {{ content: " \\25B2"; }} th.down::after {{ content: " \\25BC"; }}
td.num {{ text-align: right; font-variant-numeric: tabular-nums; }}
td.ok {{ color: #176c2e; }} td.bad {{ color: #b00020; font-weight: bold; }}
</style>
</head>
<body>
<h1>{title}</h1>
<p>{count} variants. Click a column's header to sort by it; a variant's name opens its
report.</p>
<table id="sweep">
<thead><tr>{head}</tr></thead>
<tbody>
{body}
</tbody>
</table>
<script>
const table = document.getElementById("sweep");
const heads = Array.from(table.tHead.rows[0].cells);
heads.forEach((th, column) => th.addEventListener("click", () => {{
  const down = th.classList.contains("up");
  heads.forEach((h) => h.classList.remove("up", "down"));
  th.classList.add(down ? "down" : "up");
  const rows = Array.from(table.tBodies[0].rows);
  const key = (row) => row.cells[column].dataset.key;
  rows.sort((a, b) => {{
    const x = key(a), y = key(b);
    if (x === "" || y === "") return (x === "") - (y === "");
    const nx = Number(x), ny = Number(y);
    const order = Number.isNaN(nx) || Number.isNaN(ny) ? x.localeCompare(y) : nx - ny;
    return down ? -order : order;
  }});
  rows.forEach((row) => table.tBodies[0].appendChild(row));
}}));
</script>
</body>
</html>
"""
