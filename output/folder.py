"""The design folder on disk: the output folder's checks and its atomic write.

:func:`check_out_dir` refuses an output path before any work is done; :func:`write_design`
writes every file into a temporary sibling folder and renames it into place only when all were
written.  ``drawstring simulate`` on a folder already written is
:mod:`~drawstring.output.folder_simulation`'s.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import cast

from drawstring.fabrication.beside import Beside
from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError
from drawstring.pipeline.record import Design, Writer


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
    refused = write_refused(probe)
    if refused:
        raise InputError(f"cannot write into {probe} ({refused}); choose a writable --out folder")
    if out.is_dir():
        _probe_rename(out)
    return out


def write_refused(folder: Path) -> str | None:
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
        raise placement_error(out, exc) from None
    aside = retired / out.name
    with parallel.sigint_held():
        try:
            os.rename(out, aside)
        except OSError as exc:
            os.rmdir(retired)
            raise placement_error(out, exc) from None
        try:
            os.rename(aside, out)
        except OSError as exc:
            raise InputError(
                f"cannot rename {aside} back to {out} ({exc.strerror or exc}); rename it by hand"
            ) from None
        os.rmdir(retired)


def placement_error(out: Path, exc: OSError) -> InputError:
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
    staging = staging_dir(out)
    beside = Beside()
    try:
        chosen = writers or DEFAULT_WRITERS
        apart = [w for w in chosen if w in _beside_writers()] if beside.forks else []
        if apart:
            beside.start("the pictures", _written, apart, result, staging)
        files: list[str] = []
        for writer in chosen:
            if writer not in apart:
                files.extend(writer(result, staging))
        for written in beside.results():
            files.extend(cast(list[str], written))
        document = result.to_json()
        document["files"] = sorted([*files, "design.json", "report.html"])
        (staging / "design.json").write_text(
            json.dumps(document, indent=2, allow_nan=False) + "\n", encoding="utf-8"
        )
        write_report(staging)  # last: it reads every other file of the folder
        os.chmod(staging, 0o755)
        place_staged(staging, out)
    except BaseException as exc:
        beside.stop()  # it writes into the staging folder, about to be removed
        shutil.rmtree(staging, ignore_errors=True)
        if isinstance(exc, OSError):
            raise placement_error(out, exc) from None
        raise
    return out


def _beside_writers() -> frozenset[Writer]:
    """Writers that only draw pictures from the design's arrays (matplotlib, one core): with
    two cores :func:`write_design` runs them in a forked process beside the others
    (:class:`~drawstring.fabrication.beside.Beside`)."""
    from drawstring.output.writers import write_deployment, write_pictures, write_stage_pictures

    return frozenset((write_pictures, write_stage_pictures, write_deployment))


def _written(writers: list[Writer], result: Design, folder: Path) -> list[str]:
    """Run ``writers`` in order; the paths they wrote."""
    return [path for writer in writers for path in writer(result, folder)]


def staging_dir(out: Path) -> Path:
    """A new hidden folder beside ``out`` to write into before :func:`place_staged` moves it
    there (``out``'s parent made where missing); a refusal in one line where it cannot be."""
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as exc:
        raise placement_error(out, exc) from None


def place_staged(staging: Path, out: Path) -> None:
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
