"""``drawstring simulate``: the deployment simulation run on a design folder already written.

:func:`simulate_folder` reads the folder back (the tiles at full precision, the hinges, the
route and the lift points), repeats the design's own simulation and adds its files to the
folder: ``deploy.npz``, ``deploy.gif``, the ``simulation`` metrics in ``design.json`` and a new
``report.html``.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.simulate.deploy import simulate_stage
from drawstring.geometry.simulate.result import SimulationResult
from drawstring.geometry.tiling.linkage import Linkage, Split, build_linkage
from drawstring.output.design_folder import design_json_faults
from drawstring.output.folder import write_refused
from drawstring.output.report import write_report
from drawstring.output.writers import save_deployment
from drawstring.pipeline.record import Progress, jsonable

#: Errors of a damaged design folder's files, as the readers raise them.
_DAMAGED = (
    OSError,
    EOFError,
    ValueError,
    KeyError,
    AttributeError,
    TypeError,
    IndexError,
    zipfile.BadZipFile,
    zlib.error,
)


@dataclass(frozen=True)
class _Stored:
    """What a design folder holds for its simulation."""

    doc: dict[str, Any]
    linkage: Linkage
    assembled: FloatArray
    fabricated: FloatArray
    hinge_vertices: IntArray
    steps: IntArray
    lift_gaps: IntArray
    thickness: float


def simulate_folder(folder: str | os.PathLike[str], *, quiet: bool = True) -> Path:
    """Run the deployment simulation on a design folder written by
    :func:`~drawstring.output.folder.write_design`.

    Reads ``design.json`` (options, linkage cells and splits, lift points), ``tiles.npz`` (the
    tiles at full precision), ``hinges.json`` and ``route.json``, so that a design's own run is
    repeated exactly; writes ``deploy.npz`` and ``deploy.gif``,
    the ``simulation`` metrics and timing into ``design.json``, and rewrites ``report.html``.
    Every file is written next to its final name first and renamed into place.
    """
    root = Path(folder)
    stored = _read_checked(root)
    # the files are written beside the folder's own and renamed into it: check both places
    # now rather than after the simulation
    for place in (root.parent, root):
        refused = write_refused(place)
        if refused:
            raise InputError(
                f"cannot write into {place} ({refused}); make it writable, or copy the design "
                "folder somewhere writable and simulate that"
            )
    progress = Progress(quiet=quiet)
    with progress.stage("simulate"):
        simulation = simulate_stage(
            stored.linkage,
            stored.fabricated,
            stored.assembled,
            stored.hinge_vertices,
            stored.steps,
            stored.lift_gaps,
            stored.thickness,
        )
    doc = stored.doc
    _record(doc, simulation, progress)
    _write(root, doc, simulation, stored.steps)
    return root


def _read_checked(root: Path) -> _Stored:
    """The folder's design, refused (:class:`InputError`, naming the fix) when a file is
    missing, damaged or does not match the others."""
    design_path = root / "design.json"
    if not root.exists():
        raise InputError(f"{root} does not exist; give the folder drawstring design wrote")
    if not design_path.is_file():
        raise InputError(f"{root} is not a drawstring design folder (no design.json)")
    needed = ("tiles.npz", "hinges.json", "route.json")
    missing = [name for name in needed if not (root / name).is_file()]
    if missing:
        raise InputError(f"{root} lacks {', '.join(missing)}; run drawstring design again")
    try:
        stored = _read_design(root, design_path)
    except InputError:
        raise
    except _DAMAGED as exc:
        what = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__
        raise InputError(
            f"{root}: the design files cannot be read ({what}); run drawstring design again"
        ) from exc
    linkage, steps = stored.linkage, stored.steps
    if (
        stored.assembled.shape != (linkage.n_tiles, 8, 3)
        or stored.fabricated.shape != stored.assembled.shape
    ):
        raise InputError(f"{root}: tiles.npz does not match design.json; run design again")
    in_range = (
        np.all((steps[:, 0] >= 0) & (steps[:, 0] < linkage.n_gaps))
        and np.all((steps[:, 1] >= 0) & (steps[:, 1] < linkage.n_tiles))
        and np.all((steps[:, 2:] >= 0) & (steps[:, 2:] <= 4))
        and np.all((stored.hinge_vertices >= 0) & (stored.hinge_vertices < 8 * linkage.n_tiles))
        and np.all((stored.lift_gaps >= 0) & (stored.lift_gaps < linkage.n_gaps))
    )
    if not in_range:
        raise InputError(
            f"{root}: route.json, hinges.json or the lift points do not match design.json; "
            "run drawstring design again"
        )
    return stored


def _read_design(root: Path, design_path: Path) -> _Stored:
    """What :func:`simulate_folder` reads from a design folder (raises what the readers
    raise on damaged files)."""
    doc = json.loads(design_path.read_text(encoding="utf-8"))
    faults = design_json_faults(doc)
    if faults:
        raise InputError(f"{root}: {faults[0]}; run drawstring design again")
    block = doc.get("linkage", {})
    if "tile_cells" not in block:
        raise InputError(
            f"{design_path} predates 'drawstring simulate'; run drawstring design again"
        )
    grid = tuple(block["grid"])
    cells = np.zeros(grid, dtype=bool)
    tile_cells = np.asarray(block["tile_cells"], dtype=np.int64).reshape(-1, 2)
    cells[tile_cells[:, 0], tile_cells[:, 1]] = True
    splits = tuple(
        Split(s["axis"], int(s["line"]), int(s["lo"]), int(s["hi"]))
        for s in block.get("split_lines", [])
    )
    linkage = build_linkage(cells, splits)
    stated = block.get("tiles", linkage.n_tiles)
    if isinstance(stated, bool) or not isinstance(stated, int):
        raise InputError(
            f"{root}: design.json's linkage.tiles is {stated!r}, not a count; run drawstring "
            "design again"
        )
    if stated != linkage.n_tiles:
        raise InputError(
            f"{root}: design.json's linkage gives {block['tiles']} tiles but its cells make "
            f"{linkage.n_tiles}; run drawstring design again"
        )
    with np.load(root / "tiles.npz") as stored:
        assembled, fabricated = stored["assembled"], stored["fabricated"]
    hinges = json.loads((root / "hinges.json").read_text(encoding="utf-8"))["hinges"]
    hinge_vertices = np.array([h["vertices"] for h in hinges], dtype=np.int64).reshape(-1, 2)
    route_doc = json.loads((root / "route.json").read_text(encoding="utf-8"))
    steps = np.array(
        [[s["gap"], s["tile"], s["enter_side"], s["leave_side"]] for s in route_doc["steps"]],
        dtype=np.int64,
    ).reshape(-1, 4)
    points = doc.get("metrics", {}).get("lift_points", {}).get("points", [])
    lift_gaps = np.array([p["gap"] for p in points], dtype=np.int64)
    thickness = float(doc["options"]["thickness_mm"])
    return _Stored(doc, linkage, assembled, fabricated, hinge_vertices, steps, lift_gaps, thickness)


def _record(doc: dict[str, Any], simulation: SimulationResult, progress: Progress) -> None:
    """The simulation's metrics and timing in ``design.json``'s document."""
    result_block = jsonable(simulation.to_json())
    # the lift sweep's count is the design's; a design made without simulating has run once now
    runs = doc.get("metrics", {}).get("simulation", {}).get("runs")
    result_block["runs"] = runs if isinstance(runs, int) else 1
    result_block.pop("time_s", None)
    per_step = float(result_block.pop("per_step_ms", 0.0)) / 1000.0
    doc.setdefault("metrics", {})["simulation"] = result_block
    # the options record what the folder holds: now a simulation
    if isinstance(doc.get("options"), dict):
        doc["options"]["simulate"] = True
    # lift points chosen without a simulation keep their check, and say what ran since
    lift = doc.get("metrics", {}).get("lift_points")
    if isinstance(lift, dict) and "not a simulation" in str(lift.get("check", "")):
        lift["simulated_later"] = (
            "the simulation ran afterwards (drawstring simulate) with these lift points: "
            "see metrics.simulation"
        )
    # a linkage that does not deploy is a problem, as when the design itself simulates
    problems = [p for p in doc.get("problems", []) if not str(p).startswith(STUCK)]
    if not simulation.deployed:
        problems.append(
            f"{STUCK} ({len(simulation.open_gaps)} route gaps open, tiles up to "
            f"{simulation.final_max_deviation_mm:.2f} mm from the assembled shape; see "
            "design.json metrics.simulation)"
        )
    doc["problems"] = problems
    doc.setdefault("timings_s", {})["simulate"] = round(progress.timings["simulate"], 3)
    doc["timings_s"]["simulate_per_step"] = round(per_step, 3)


#: How a stuck simulation's problem line starts (the design's own, and this command's).
STUCK = "the deployment simulation got stuck"


def _write(root: Path, doc: dict[str, Any], simulation: SimulationResult, steps: IntArray) -> None:
    """The simulation's files, ``design.json`` and the report, written beside the folder and
    renamed into it together."""
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{root.name}.", suffix=".tmp", dir=root.parent))
    except OSError as exc:
        raise InputError(
            f"cannot write beside {root} ({exc.strerror}); check the folder's permissions"
        ) from exc
    try:
        written = save_deployment(simulation, steps, staging)
        doc["files"] = sorted(set(doc.get("files", [])) | set(written))
        (staging / "design.json").write_text(
            json.dumps(doc, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        with parallel.sigint_held():  # the folder's files and its report change together
            for name in [*written, "design.json"]:
                os.replace(staging / name, root / name)
            write_report(root)
    except OSError as exc:
        raise InputError(
            f"cannot write into {root} ({exc.strerror}); check the folder's permissions and "
            "free space"
        ) from exc
    finally:
        shutil.rmtree(staging, ignore_errors=True)
