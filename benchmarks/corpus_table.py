"""The corpus table of docs/limits.md, from ``benchmarks/results.json``'s ``corpus`` rows.

``python benchmarks/corpus_table.py`` prints the Markdown table and a count line; paste them
into docs/limits.md after a ``benchmarks/run.py --corpus`` run.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent

HEADER = (
    "| mesh | exit | tool chose | retry with | exit after | hinges | tiles / parts | deploys "
    "| flat edge mm | hinge gap mm (from above) | fit mean / max mm "
    "| fit % of side / % of diagonal | s |"
)


def _g(value: Any, digits: int = 2) -> str:
    if value is None:
        return "–"
    return f"{float(value):.{digits}g}"


def row_text(row: dict[str, Any]) -> str:
    """One table row."""
    retried = row.get("retried_options")
    chosen = row.get("chosen_options")
    written = row.get("tiles") is not None
    deployed = row.get("deployed")
    seconds = row.get("design_time_s", 0.0) + row.get("retry_time_s", 0.0)
    cells = [
        row["mesh"].removesuffix(".obj"),
        str(row["exit"]),
        f"`{' '.join(chosen)}`" if chosen else "–",
        f"`{' '.join(retried)}`" if retried else "–",
        str(row["exit_after_retry"]) if "exit_after_retry" in row else "–",
        row.get("hinges") or "–",
        f"{row['tiles']} / {row['parts']}" if written else "–",
        "–" if deployed is None else "yes" if deployed else "**no**",
        _g(row.get("flat_edge_error_max_mm")),
        f"{_g(row.get('hinge_gap_max_mm'))} ({_g(row.get('hinge_gap_in_plane_max_mm'))})"
        if written
        else "–",
        f"{_g(row.get('fit_mean_mm'))} / {_g(row.get('fit_max_mm'))}" if written else "–",
        f"{_g(row.get('fit_mean_pct_side'))} / {_g(row.get('fit_max_pct_diagonal'))}"
        if row.get("fit_mean_pct_side") is not None
        else "–",
        f"{seconds:.0f}",
    ]
    return "| " + " | ".join(cells) + " |"


def table(rows: list[dict[str, Any]]) -> str:
    """The header, the rows by mesh name and a count of designs that deploy with exit 0."""
    lines = [HEADER, "|" + "---|" * HEADER.count(" | ") + "---|"]
    lines += [row_text(r) for r in sorted(rows, key=lambda r: r["mesh"])]
    good = sum(1 for r in rows if r.get("success"))
    fitted = [r for r in rows if r.get("tiles") is not None]
    met = sum(1 for r in fitted if r.get("fit_met"))
    lines.append("")
    lines.append(
        f"{good} of {len(rows)} end in a design that deploys with exit status 0; "
        f"{met} of {len(fitted)} written designs meet both fit levels."
    )
    return "\n".join(lines)


if __name__ == "__main__":
    results = json.loads((HERE / "results.json").read_text(encoding="utf-8"))
    print(table(results["corpus"]["rows"]))
