"""Files the studio takes in and gives out: uploads checked by the command line's loaders, the
3D preview of a target, the zip of a design folder and its key numbers.

An upload's name is never used as a path: files are stored under the hash of their content,
and the name a person gave is kept only to show (reduced to letters, digits, ``-`` and ``_``,
it also names the design, as a mesh file's stem names it on the command line).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import tempfile
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from drawstring.fabrication.profiles import Profile, load_profile
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.target.meshfiles import SUPPORTED_EXTENSIONS
from drawstring.geometry.target.surface import Target, load_target
from drawstring.output.design_folder import print_job_counts

#: The largest request body (a mesh upload), bytes.
MAX_UPLOAD_BYTES = 64 * 1024 * 1024
#: The largest profile file, bytes.
MAX_PROFILE_BYTES = 256 * 1024
#: Triangles the 3D preview of an uploaded mesh shows at most (every k-th beyond).
PREVIEW_FACES = 200_000
#: Triangles of a built-in target's preview.
BUILTIN_PREVIEW_RESOLUTION = 4_000
#: Size the preview's mesh is scaled to when none is given, mm.
PREVIEW_SIZE_MM = 160.0


def safe_name(filename: str | None, fallback: str) -> str:
    """A file name's stem reduced to ``[A-Za-z0-9_-]``, at most 60 characters."""
    stem = Path(filename or "").stem if filename else ""
    name = re.sub(r"[^A-Za-z0-9_-]+", "-", stem).strip("-_")[:60]
    return name or fallback


def content_id(data: bytes) -> str:
    return "upload:" + hashlib.sha256(data).hexdigest()[:20]


def stored_name(upload_id: str, suffix: str) -> str:
    """The file name an upload is stored under: its content hash, never the name it came
    with."""
    return upload_id.removeprefix("upload:") + suffix


def write_file(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` whole or not at all (a crash leaves no half file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    handle, staging = tempfile.mkstemp(dir=path.parent, prefix=".upload.", suffix=".tmp")
    try:
        with os.fdopen(handle, "wb") as out:
            out.write(data)
            out.flush()
            os.fsync(out.fileno())
        os.replace(staging, path)
    except BaseException:
        Path(staging).unlink(missing_ok=True)
        raise


def mesh_suffix(filename: str | None) -> str:
    """The mesh file's extension, lower case, or InputError naming those the loader reads."""
    suffix = Path(filename or "").suffix.lower()
    if suffix not in SUPPORTED_EXTENSIONS:
        raise InputError(
            f"{safe_name(filename, 'the file')}{suffix}: not a mesh file drawstring reads; "
            f"upload {', '.join(SUPPORTED_EXTENSIONS)}"
        )
    return suffix


def check_mesh(path: Path, shown: str, *, size_mm: float, repair: bool) -> Target:
    """Load a mesh file as ``drawstring design`` does; its refusal names ``shown``, not the
    server's path."""
    try:
        return load_target(path, size_mm=size_mm, repair=repair)
    except InputError as exc:
        raise InputError(str(exc).replace(str(path), shown)) from None


def check_profile(path: Path, shown: str) -> Profile:
    """Load a profile file as ``--profile FILE.toml`` does; its refusal names ``shown``."""
    try:
        return load_profile(path)
    except InputError as exc:
        raise InputError(str(exc).replace(str(path), shown)) from None
    except UnicodeDecodeError:
        raise InputError(f"{shown}: not a text file; a profile is TOML") from None


def preview(target: Target, max_faces: int = PREVIEW_FACES) -> dict[str, Any]:
    """A target's mesh for the page's 3D view: coordinates to 0.01 mm, and every k-th
    triangle beyond ``max_faces``."""
    faces = np.asarray(target.faces)
    step = max(1, -(-len(faces) // max_faces))
    shown = faces[::step]
    extent = np.ptp(target.vertices, axis=0)
    return {
        "name": target.name,
        "vertices": np.round(np.asarray(target.vertices, dtype=float), 2).reshape(-1).tolist(),
        "faces": shown.reshape(-1).astype(int).tolist(),
        "triangles": int(len(faces)),
        "triangles_shown": int(len(shown)),
        "extent_mm": [round(float(v), 1) for v in extent],
        "notes": list(target.notes),
    }


def builtin_preview(name: str, size_mm: float = PREVIEW_SIZE_MM) -> dict[str, Any]:
    return preview(load_target(name, size_mm=size_mm, resolution=BUILTIN_PREVIEW_RESOLUTION))


def zip_folder(folder: Path, top: str, out_dir: Path) -> Path:
    """``folder`` zipped under the folder name ``top`` into a temporary file in ``out_dir``
    (entries sorted, so the same folder gives the same listing)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    handle, name = tempfile.mkstemp(dir=out_dir, prefix=".zip.", suffix=".zip")
    os.close(handle)
    try:
        with zipfile.ZipFile(name, "w", zipfile.ZIP_DEFLATED, compresslevel=6) as archive:
            for path in sorted(folder.rglob("*")):
                if path.is_file() and not path.is_symlink():
                    archive.write(path, f"{top}/{path.relative_to(folder).as_posix()}")
    except BaseException:
        Path(name).unlink(missing_ok=True)
        raise
    return Path(name)


#: The numbers of a design that a comparison puts side by side: (label, unit, where in
#: design.json, digits).
KEY_NUMBERS: tuple[tuple[str, str, tuple[str, ...], int], ...] = (
    ("profile", "", ("profile",), 0),
    ("size", "mm", ("options", "size_mm"), 0),
    ("thickness", "mm", ("options", "thickness_mm"), 1),
    ("tiles", "", ("linkage", "tiles"), 0),
    ("parts", "", ("linkage", "components"), 0),
    ("hinges", "", ("linkage", "hinges"), 0),
    ("hinges on the bottom faces", "", ("metrics", "hinges_bottom"), 0),
    ("mass", "g", ("metrics", "mass_g"), 0),
    ("tile side, mean", "mm", ("metrics", "tile_side_mean_mm"), 1),
    ("distance from the target, mean", "mm", ("metrics", "surface_distance_mean_mm"), 2),
    ("distance from the target, largest", "mm", ("metrics", "surface_distance_max_mm"), 2),
    ("flat edge error, largest", "mm", ("metrics", "flat_edge_error_max_mm"), 5),
    ("hinge gap, largest", "mm", ("metrics", "hinge_gap_max_mm"), 5),
    ("gap angle, least", "°", ("metrics", "flat_gap_angle_min_deg"), 1),
    ("tile area ratio, largest", "", ("metrics", "scale_factor_max"), 3),
    ("string route, flat", "mm", ("metrics", "route", "length_mm", "flat"), 0),
    ("string friction factor", "", ("metrics", "route", "capstan_factor"), 0),
    ("lift points", "", ("metrics", "lift_points", "count"), 0),
    ("deployed in simulation", "", ("metrics", "simulation", "deployed"), 0),
    ("problems", "", ("problems",), 0),
    ("warnings", "", ("warnings",), 0),
)


def _dig(data: Any, path: tuple[str, ...]) -> Any:
    for key in path:
        if not isinstance(data, dict):
            return None
        data = data.get(key)
    return data


def key_numbers(folder: Path) -> list[dict[str, Any]] | None:
    """The design's key numbers for a comparison (:data:`KEY_NUMBERS`, then the print jobs
    and the design's time), or None without a readable ``design.json``."""
    try:
        document = json.loads((folder / "design.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    rows = []
    for label, unit, path, digits in KEY_NUMBERS:
        value = _dig(document, path)
        if isinstance(value, list):
            value = len(value)
        elif isinstance(value, float):
            value = round(value, digits) if digits else round(value)
        rows.append({"label": label, "unit": unit, "value": value})
    jobs, beds = print_job_counts(folder)
    rows.append({"label": "print jobs", "unit": "", "value": jobs if jobs else None})
    rows.append({"label": "print beds", "unit": "", "value": beds if beds else None})
    timings = document.get("timings_s")
    total = sum(v for v in timings.values() if isinstance(v, int | float)) if timings else None
    rows.append({"label": "design time", "unit": "s", "value": round(total, 1) if total else None})
    return rows
