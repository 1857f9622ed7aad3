"""The design folder on disk: the output folder's checks, its atomic write, and the
``drawstring simulate`` run on a folder already written.

:func:`check_out_dir` refuses an output path before any work is done; :func:`write_design`
writes every file into a temporary sibling folder and renames it into place only when all were
written; :func:`simulate_folder` reads a written folder back and adds the deployment simulation.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.simulate.deploy import simulate_stage
from drawstring.geometry.tiling.linkage import Linkage
from drawstring.output.design_folder import design_json_faults
from drawstring.pipeline.record import Design, Progress, Writer, jsonable


def default_out_dir(target: str | os.PathLike[str]) -> Path:
    """``./NAME-drawstring`` for a built-in name (as ``design.json`` spells it: ``SADDLE`` is
    ``saddle``) or a mesh file's stem."""
    from drawstring.geometry.target.builtins import BUILTIN_TARGETS

    name = str(target)
    if name.strip().lower() in BUILTIN_TARGETS and not Path(name).suffix:
        return Path.cwd() / f"{name.strip().lower()}-drawstring"
    return Path.cwd() / f"{Path(name).stem}-drawstring"


def check_out_dir(out_dir: str | os.PathLike[str]) -> Path:
    """Refuse an output path that cannot become the design folder, before any work is done."""
    out = Path(out_dir).absolute()
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {out} exists and is a file; choose another --out")
    try:
        here = Path.cwd().resolve()
    except OSError:  # the working folder was removed
        here = None
    if here is not None and (out.resolve() == here or out.resolve() in here.parents):
        raise InputError(
            f"output folder {out} is the folder you are working in, or holds it; a design "
            "folder is replaced whole, so give --out a folder of its own (e.g. --out design)"
        )
    if out.is_dir() and any(out.iterdir()) and not (out / "design.json").is_file():
        raise InputError(
            f"output folder {out} exists and is not a drawstring design; choose another --out"
        )
    if out.is_dir():
        _refuse_foreign_files(out)
    parent = out.parent
    probe = parent
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise InputError(f"cannot write into {probe}: not a folder; choose another --out")
    refused = _write_refused(probe)
    if refused:
        raise InputError(f"cannot write into {probe} ({refused}); choose a writable --out folder")
    if out.is_dir():
        _probe_rename(out)
    return out


def _write_refused(folder: Path) -> str | None:
    """Why a file cannot be made in ``folder``, or None.  A folder is made and removed there
    rather than os.access asked, which answers yes to root everywhere (on /proc, on a read-only
    mount), so that a run fails now rather than after its work."""
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".drawstring-probe-", dir=folder))
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    return None


def _refuse_foreign_files(out: Path) -> None:
    """Refuse a design folder holding files its ``design.json`` does not list (a user's notes,
    a slicer project): replacing the folder would delete them.  The clutter macOS leaves
    (``.DS_Store``, ``._*``) does not count; with an unreadable ``design.json`` every other file
    but ``report.html`` does."""
    try:
        listed = set(json.loads((out / "design.json").read_text(encoding="utf-8"))["files"])
    except (OSError, ValueError, KeyError, TypeError):
        listed = set()
    listed |= {"design.json", "report.html"}
    foreign = sorted(
        path.relative_to(out).as_posix()
        for path in out.rglob("*")
        if not path.is_dir()
        and not (path.name == ".DS_Store" or path.name.startswith("._"))
        and path.relative_to(out).as_posix() not in listed
    )
    if foreign:
        more = f" and {len(foreign) - 1} more" if len(foreign) > 1 else ""
        raise InputError(
            f"output folder {out} holds files drawstring did not write ({foreign[0]}{more}), "
            "which replacing the design would delete; move them out or choose another --out"
        )


def _probe_rename(out: Path) -> None:
    """Refuse a folder that cannot be moved aside (immutable, a mount point, a sticky parent
    owned by someone else, a folder without write permission, which a move into another
    folder needs for its ``..`` entry): :func:`write_design` moves it into a temporary sibling
    folder to replace it, at the very end.  The probe makes the same move and straight back."""
    try:
        retired = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".probe", dir=out.parent))
    except OSError as exc:
        raise _placement_error(out, exc) from None
    aside = retired / out.name
    with parallel.sigint_held():
        try:
            os.rename(out, aside)
        except OSError as exc:
            os.rmdir(retired)
            raise _placement_error(out, exc) from None
        try:
            os.rename(aside, out)
        except OSError as exc:
            raise InputError(
                f"cannot rename {aside} back to {out} ({exc.strerror or exc}); rename it by hand"
            ) from None
        os.rmdir(retired)


def _placement_error(out: Path, exc: OSError) -> InputError:
    """The one-line refusal for an OSError while writing or placing the output folder."""
    reason = exc.strerror or type(exc).__name__
    if exc.filename is not None and Path(exc.filename) != out:
        reason = f"{reason}: {exc.filename}"
    return InputError(
        f"cannot write the design to {out} ({reason}); choose another --out, or make {out} "
        "and its parent folder writable"
    )


def write_design(
    result: Design,
    out_dir: str | os.PathLike[str],
    writers: tuple[Writer, ...] | None = None,
) -> Path:
    """Write the output folder atomically.

    Everything is written into a temporary sibling folder, which replaces ``out_dir`` only when
    every file was written.  On any failure the temporary folder is removed and ``out_dir`` is
    left as it was.
    """
    from drawstring.output.report import write_report
    from drawstring.output.writers import DEFAULT_WRITERS

    out = check_out_dir(out_dir)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as exc:
        raise _placement_error(out, exc) from None
    try:
        files: list[str] = []
        for writer in writers or DEFAULT_WRITERS:
            files.extend(writer(result, staging))
        document = result.to_json()
        document["files"] = sorted([*files, "design.json", "report.html"])
        (staging / "design.json").write_text(
            json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        write_report(staging)  # last: it reads every other file of the folder
        os.chmod(staging, 0o755)
        _place(staging, out)
    except OSError as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise _placement_error(out, exc) from None
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out


def _place(staging: Path, out: Path) -> None:
    """Rename the finished ``staging`` folder to ``out``, replacing an earlier folder there.

    The earlier folder is first renamed into a temporary sibling, removed only once the new
    one is in place; when a rename fails it is renamed back and the temporary sibling removed,
    so an :class:`OSError` leaves ``out`` as it was (the caller removes ``staging``).
    """
    if not out.exists():
        os.rename(staging, out)
        return
    retired = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".old", dir=out.parent))
    aside = retired / out.name
    with parallel.sigint_held():
        try:
            os.rename(out, aside)
        except OSError:
            shutil.rmtree(retired, ignore_errors=True)
            raise
        try:
            os.rename(staging, out)
        except OSError as exc:
            try:
                os.rename(aside, out)
            except OSError:
                raise InputError(
                    f"cannot write the design to {out} ({exc.strerror or exc}), nor put the "
                    f"earlier folder back: it is now {aside}; rename it by hand"
                ) from None
            shutil.rmtree(retired, ignore_errors=True)
            raise
    shutil.rmtree(retired, ignore_errors=True)


def simulate_folder(folder: str | os.PathLike[str], *, quiet: bool = True) -> Path:
    """Run the deployment simulation on a design folder written by :func:`write_design`.

    Reads ``design.json`` (options, linkage cells and splits, lift points), ``tiles.npz`` (the
    tiles at full precision), ``hinges.json`` and ``route.json``, so that a design's own run is
    repeated exactly; writes ``deploy.npz`` and ``deploy.gif``,
    the ``simulation`` metrics and timing into ``design.json``, and rewrites ``report.html``.
    Every file is written next to its final name first and renamed into place.
    """
    from drawstring.output.report import write_report
    from drawstring.output.writers import save_deployment

    root = Path(folder)
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
        doc, linkage, assembled, fabricated, hinge_vertices, steps, lift_gaps = _read_design(
            root, design_path
        )
        thickness = float(doc["options"]["thickness_mm"])
    except InputError:
        raise
    except (
        OSError,
        EOFError,
        ValueError,
        KeyError,
        AttributeError,
        TypeError,
        IndexError,
        zipfile.BadZipFile,
        zlib.error,
    ) as exc:
        what = exc.strerror if isinstance(exc, OSError) and exc.strerror else type(exc).__name__
        raise InputError(
            f"{root}: the design files cannot be read ({what}); run drawstring design again"
        ) from exc
    if assembled.shape != (linkage.n_tiles, 8, 3) or fabricated.shape != assembled.shape:
        raise InputError(f"{root}: tiles.npz does not match design.json; run design again")
    in_range = (
        np.all((steps[:, 0] >= 0) & (steps[:, 0] < linkage.n_gaps))
        and np.all((steps[:, 1] >= 0) & (steps[:, 1] < linkage.n_tiles))
        and np.all((steps[:, 2:] >= 0) & (steps[:, 2:] <= 4))
        and np.all((hinge_vertices >= 0) & (hinge_vertices < 8 * linkage.n_tiles))
        and np.all((lift_gaps >= 0) & (lift_gaps < linkage.n_gaps))
    )
    if not in_range:
        raise InputError(
            f"{root}: route.json, hinges.json or the lift points do not match design.json; "
            "run drawstring design again"
        )
    # the files are written beside the folder's own and renamed into it: check both places
    # now rather than after the simulation
    for place in (root.parent, root):
        refused = _write_refused(place)
        if refused:
            raise InputError(
                f"cannot write into {place} ({refused}); make it writable, or copy the design "
                "folder somewhere writable and simulate that"
            )
    progress = Progress(quiet=quiet)
    with progress.stage("simulate"):
        simulation = simulate_stage(
            linkage,
            fabricated,
            assembled,
            hinge_vertices,
            steps,
            lift_gaps,
            thickness,
        )
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
    doc.setdefault("timings_s", {})["simulate"] = round(progress.timings["simulate"], 3)
    doc["timings_s"]["simulate_per_step"] = round(per_step, 3)
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
    return root


def _read_design(
    root: Path, design_path: Path
) -> tuple[
    dict[str, Any],
    Linkage,
    NDArray[np.float64],
    NDArray[np.float64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
]:
    """What :func:`simulate_folder` reads from a design folder (raises what the readers
    raise on damaged files)."""
    from drawstring.geometry.tiling.linkage import Split, build_linkage

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
    return doc, linkage, assembled, fabricated, hinge_vertices, steps, lift_gaps
