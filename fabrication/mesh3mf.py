"""Triangle meshes of the CAD solids, print jobs that fit the bed, and deterministic 3MF files.

The 3MF is written with :mod:`zipfile` and plain XML: fixed member order, fixed timestamps and
fixed number formatting, so the same design gives the same bytes.  Extruder choice is not part
of the 3MF core spec; slicers read it from their own metadata, which is written alongside:

* PrusaSlicer: ``Metadata/Slic3r_PE_model.config`` (one ``<volume firstid lastid>`` per part, a
  contiguous range of the object's triangles, with ``extruder`` counted from 1);
* Bambu Studio / OrcaSlicer: ``Metadata/model_settings.config`` (``<part>`` per volume with the
  same ranges and an ``extruder`` key).
"""

from __future__ import annotations

import io
import multiprocessing
import os
import zipfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.part_mesh import PartKind, PartMesh, mesh_solid
from drawstring.fabrication.profiles import BED_MARGIN_MM
from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError

#: Fixed zip member timestamp (the earliest a zip can hold) for byte-identical files.
ZIP_EPOCH = (1980, 1, 1, 0, 0, 0)

#: Below this many parts meshing runs in the calling process.
PARALLEL_MIN_PARTS = 48


@dataclass(frozen=True)
class PrintJob:
    """Parts printed together on one bed.

    tiles : tile ids in the job.
    pads : hinge ids whose pads are printed in this job (both tiles in the job).
    offset : (3,) float, mm, translation from the flat pose onto the bed.
    size : (2,) float, mm, footprint of the job (x, y) after the offset.
    """

    tiles: tuple[int, ...]
    pads: tuple[int, ...]
    offset: NDArray[np.float64]
    size: NDArray[np.float64]


def _mesh_chunk(items: list[tuple[bd.Shape, str, PartKind]], tolerance: float) -> list[PartMesh]:
    return [mesh_solid(solid, name, kind, tolerance) for solid, name, kind in items]


#: The parts a forked meshing process reads (set before the fork, so nothing is pickled).
_FORKED_ITEMS: Sequence[tuple[bd.Shape, str, PartKind]] = ()


def _mesh_forked(indices: list[int], tolerance: float) -> list[PartMesh]:
    return _mesh_chunk([_FORKED_ITEMS[i] for i in indices], tolerance)


def mesh_solids(
    items: Sequence[tuple[bd.Shape, str, PartKind]], tolerance: float, workers: int | None = None
) -> list[PartMesh]:
    """:func:`mesh_solid` for many parts, in worker processes from ``PARALLEL_MIN_PARTS`` on.

    They are meshed on this machine even where the CAD stage's tiles are built on a Dask
    cluster: meshed in a Dask worker, a solid's triangles can differ from this machine's, and
    the 3MF is the same file wherever its design was made.  Forked workers read the solids
    from this process's memory (only their indices and the meshes cross a pipe)."""
    global _FORKED_ITEMS
    count = workers if workers is not None else (os.cpu_count() or 1)
    if count <= 1 or len(items) < PARALLEL_MIN_PARTS:
        return _mesh_chunk(list(items), tolerance)
    n_chunks = min(len(items), 4 * count)
    chunks = [list(range(len(items)))[i::n_chunks] for i in range(n_chunks)]
    methods = multiprocessing.get_all_start_methods()
    work: Callable[[Any, float], list[PartMesh]] = _mesh_chunk
    arguments: list[Any] = [[items[i] for i in chunk] for chunk in chunks]
    if "fork" in methods:
        _FORKED_ITEMS = items
        work, arguments = _mesh_forked, chunks
    context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    try:
        with parallel.process_pool(count, context) as pool:
            done = list(pool.map(work, arguments, [tolerance] * n_chunks))
    finally:
        _FORKED_ITEMS = ()
    meshes: list[PartMesh | None] = [None] * len(items)
    for chunk_index, chunk in enumerate(done):
        for position, mesh in enumerate(chunk):
            meshes[chunk_index + position * n_chunks] = mesh
    return [m for m in meshes if m is not None]


def tile_bed_refusal(
    tiles_flat: NDArray[np.float64], bed: tuple[float, float]
) -> InputError | None:
    """The one-line refusal of a tile, printed as it lies in the flat layout (the layout may
    turn a quarter as a whole), that does not fit the bed inside its margins, or None."""
    usable = np.array(bed, dtype=np.float64) - 2 * BED_MARGIN_MM
    tile_size = tiles_flat.max(axis=1)[:, :2] - tiles_flat.min(axis=1)[:, :2]
    if np.all(tile_size.max(axis=1) <= usable.max()) and np.all(
        tile_size.min(axis=1) <= usable.min()
    ):
        return None
    need = tile_size.max(axis=0)
    return InputError(
        f"a tile ({need[0]:.0f} x {need[1]:.0f} mm) does not fit the {bed[0]:g} x {bed[1]:g} mm "
        f"bed with {BED_MARGIN_MM:g} mm free round it; use a printer with a larger bed "
        "(--printer) or more tiles"
    )


def plan_print_jobs(
    tiles_flat: NDArray[np.float64],
    hinges: NDArray[np.int64],
    bed: tuple[float, float],
    pad_boxes: dict[int, NDArray[np.float64]] | None = None,
) -> tuple[list[PrintJob], list[int]]:
    """Split the flat layout into print jobs that fit the bed, along rows of hinges.

    Tiles are sorted by the x (then y) coordinate of their centroids and cut into bands whose
    extent fits the bed; a band too deep for the bed is cut again along y.  Both bed
    orientations are tried and the one with fewer jobs wins.  A hinge whose tiles land in two
    jobs is *cut*: its pad is printed loose (see :func:`loose_pad_job`) and glued in later.

    Parameters
    ----------
    tiles_flat : (T, 8, 3) float, mm.
    hinges : (H, 4) int ``(tile_a, corner_a, tile_b, corner_b)``.
    bed : (x, y) bed size, mm.
    pad_boxes : hinge -> (2, 3) bounding box of its pad (widens a job's footprint).

    Returns
    -------
    jobs : print jobs (offset centres each on the bed).
    cut_hinges : hinges whose two tiles are printed in different jobs.

    Raises
    ------
    InputError
        When a single tile is larger than the bed.
    """
    too_big = tile_bed_refusal(tiles_flat, bed)
    if too_big is not None:
        raise too_big
    usable = np.array(bed, dtype=np.float64) - 2 * BED_MARGIN_MM
    lo = tiles_flat.min(axis=1)[:, :2]
    hi = tiles_flat.max(axis=1)[:, :2]
    best: list[list[int]] | None = None
    best_rotated = False
    for rotated in (False, True):
        limit = usable[::-1] if rotated else usable
        groups = _bands(lo, hi, limit)
        if groups is not None and (best is None or len(groups) < len(best)):
            best, best_rotated = groups, rotated
    if best is None:
        raise InputError(
            f"the flat layout cannot be split into jobs on a {bed[0]:.0f} x {bed[1]:.0f} mm bed"
        )
    job_of = np.empty(len(tiles_flat), dtype=np.int64)
    for index, group in enumerate(best):
        job_of[group] = index
    hinge_rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
    cut = [h for h, (a, _, b, _) in enumerate(hinge_rows) if job_of[a] != job_of[b]]
    jobs = []
    bed_centre = 0.5 * np.array(bed, dtype=np.float64)
    for index, group in enumerate(best):
        pads = tuple(
            int(h) for h, (a, _, b, _) in enumerate(hinge_rows) if job_of[a] == job_of[b] == index
        )
        points = [tiles_flat[group].reshape(-1, 3)[:, :2]]
        for h in pads:
            if pad_boxes is not None and h in pad_boxes:
                points.append(pad_boxes[h][:, :2])
        stacked = np.vstack(points)
        box_lo, box_hi = stacked.min(axis=0), stacked.max(axis=0)
        offset = np.zeros(3)
        offset[:2] = bed_centre - 0.5 * (box_lo + box_hi)
        jobs.append(PrintJob(tuple(int(t) for t in group), pads, offset, box_hi - box_lo))
    del best_rotated  # the layout keeps its orientation; a rotated bed only changes the bands
    return jobs, cut


def _bands(lo: NDArray, hi: NDArray, limit: NDArray) -> list[list[int]] | None:
    """Greedy bands along x, each cut along y, with every group's extent within ``limit``."""
    centre = 0.5 * (lo + hi)
    groups: list[list[int]] = []
    for band in _greedy(np.arange(len(lo)), centre[:, 0], lo[:, 0], hi[:, 0], limit[0]):
        if band is None:
            return None
        for cell in _greedy(np.asarray(band), centre[band, 1], lo[band, 1], hi[band, 1], limit[1]):
            if cell is None:
                return None
            groups.append(sorted(int(t) for t in cell))
    return groups


def _greedy(ids: NDArray, key: NDArray, lo: NDArray, hi: NDArray, limit: float):
    """Cut ``ids`` sorted by ``key`` into runs whose [min lo, max hi] extent is <= ``limit``."""
    order = np.argsort(key, kind="stable")
    run: list[int] = []
    run_lo, run_hi = np.inf, -np.inf
    for position in order:
        new_lo, new_hi = min(run_lo, lo[position]), max(run_hi, hi[position])
        if run and new_hi - new_lo > limit:
            yield [int(ids[p]) for p in run]
            run, new_lo, new_hi = [], lo[position], hi[position]
        if hi[position] - lo[position] > limit:
            yield None
            return
        run.append(int(position))
        run_lo, run_hi = new_lo, new_hi
    if run:
        yield [int(ids[p]) for p in run]


def arrange_loose(
    meshes: Sequence[PartMesh], bed: tuple[float, float], spacing: float
) -> list[list[PartMesh]]:
    """Lay loose parts (cut hinge pads) flat in rows on beds, lowest z on the bed: left to
    right, row after row, in the order given, a new bed when the next row would leave this one.

    Returns each bed's moved meshes.

    Raises
    ------
    InputError
        When a part alone does not fit a bed inside its margins.
    """
    beds: list[list[PartMesh]] = [[]]
    x = y = BED_MARGIN_MM
    row = 0.0
    for mesh in meshes:
        vertices = mesh.vertices - mesh.vertices.min(axis=0)
        size = vertices.max(axis=0)
        if np.any(size[:2] > np.array(bed) - 2 * BED_MARGIN_MM):
            raise InputError(
                f"a loose hinge pad ({size[0]:.0f} x {size[1]:.0f} mm) does not fit the "
                f"{bed[0]:g} x {bed[1]:g} mm bed with {BED_MARGIN_MM:g} mm free round it; use a "
                "printer with a larger bed (--printer)"
            )
        if x + size[0] > bed[0] - BED_MARGIN_MM and x > BED_MARGIN_MM:
            x, y, row = BED_MARGIN_MM, y + row + spacing, 0.0
        if y + size[1] > bed[1] - BED_MARGIN_MM and beds[-1]:
            beds.append([])
            x, y, row = BED_MARGIN_MM, BED_MARGIN_MM, 0.0
        vertices = vertices + [x, y, 0.0]
        x += size[0] + spacing
        row = max(row, size[1])
        beds[-1].append(PartMesh(mesh.name, mesh.kind, vertices, mesh.triangles))
    return [placed for placed in beds if placed]


def flip_upside_down(mesh: PartMesh) -> PartMesh:
    """The mesh turned over (180 degrees about the x axis); orientation stays outward."""
    vertices = mesh.vertices * np.array([1.0, -1.0, -1.0])
    return PartMesh(mesh.name, mesh.kind, vertices, mesh.triangles)


@dataclass(frozen=True)
class Object3mf:
    """One 3MF object: a name and its parts, each becoming one volume (a triangle range)."""

    name: str
    parts: tuple[PartMesh, ...]


_MATERIAL_COLOUR: dict[PartKind, str] = {"tile": "#E8A33D", "pad": "#2A5DB0"}


def _number(values: NDArray[np.float64]) -> list[str]:
    """Fixed-precision text of floats, without negative zero."""
    rounded = np.round(values, 5) + 0.0
    return [f"{v:.5f}".rstrip("0").rstrip(".") if v else "0" for v in rounded.ravel().tolist()]


def _object_xml(object_id: int, obj: Object3mf) -> tuple[str, list[tuple[int, int]]]:
    """The ``<object>`` element and the inclusive triangle range of each part."""
    chunks = [f'<object id="{object_id}" name="{_escape(obj.name)}" type="model"><mesh><vertices>']
    ranges = []
    base = 0
    first = 0
    vertex_blocks = []
    triangle_blocks = []
    for part in obj.parts:
        text = _number(part.vertices)
        vertex_blocks.append(
            "".join(
                f'<vertex x="{x}" y="{y}" z="{z}"/>'
                for x, y, z in zip(text[0::3], text[1::3], text[2::3], strict=True)
            )
        )
        material = 0 if part.kind == "tile" else 1
        tri = (part.triangles + base).tolist()  # Python ints: formatting numpy's is slow
        triangle_blocks.append(
            "".join(
                f'<triangle v1="{a}" v2="{b}" v3="{c}" pid="1" p1="{material}"/>' for a, b, c in tri
            )
        )
        ranges.append((first, first + len(part.triangles) - 1))
        first += len(part.triangles)
        base += len(part.vertices)
    chunks += vertex_blocks
    chunks.append("</vertices><triangles>")
    chunks += triangle_blocks
    chunks.append("</triangles></mesh></object>")
    return "".join(chunks), ranges


def _escape(text: str) -> str:
    return (
        text.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;")
    )


_CONTENT_TYPES = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Types xmlns="http://schemas.openxmlformats.org/package/2006/content-types">'
    '<Default Extension="rels" '
    'ContentType="application/vnd.openxmlformats-package.relationships+xml"/>'
    '<Default Extension="model" '
    'ContentType="application/vnd.ms-package.3dmanufacturing-3dmodel+xml"/>'
    '<Default Extension="config" ContentType="application/xml"/>'
    "</Types>\n"
)
_RELS = (
    '<?xml version="1.0" encoding="UTF-8"?>\n'
    '<Relationships xmlns="http://schemas.openxmlformats.org/package/2006/relationships">'
    '<Relationship Target="/3D/3dmodel.model" Id="rel0" '
    'Type="http://schemas.microsoft.com/3dmanufacturing/2013/01/3dmodel"/>'
    "</Relationships>\n"
)


def write_3mf(
    path: Path,
    objects: Sequence[Object3mf],
    *,
    title: str,
    extruders: dict[PartKind, int] | None = None,
    materials: dict[PartKind, str] | None = None,
) -> list[list[tuple[int, int]]]:
    """Write a 3MF with one object per entry and one volume per part.

    Parameters
    ----------
    path : output file.
    objects : the objects (print jobs) in order; object ids are 1, 2, ...
    title : model title metadata.
    extruders : extruder (from 1) per part kind; when given, the PrusaSlicer and Bambu/Orca
        configs that assign them are written.
    materials : material name per part kind (3MF base materials, for colour only).

    Returns
    -------
    The inclusive triangle range of every part of every object.
    """
    names: dict[PartKind, str] = {"tile": "tile", "pad": "pad", **(materials or {})}
    model = [
        '<?xml version="1.0" encoding="UTF-8"?>\n'
        '<model unit="millimeter" xml:lang="en-US" '
        'xmlns="http://schemas.microsoft.com/3dmanufacturing/core/2015/02">',
        f'<metadata name="Title">{_escape(title)}</metadata>',
        '<metadata name="Application">drawstring</metadata>',
        "<resources>",
        '<basematerials id="1">'
        + "".join(
            f'<base name="{_escape(names[kind])}" displaycolor="{colour}"/>'
            for kind, colour in _MATERIAL_COLOUR.items()
            # the pad material (the last, index 1) only where a part uses it: a file of loose
            # tiles (laser-epdm) declares no material that no triangle uses
            if kind == "tile" or any(p.kind == kind for obj in objects for p in obj.parts)
        )
        + "</basematerials>",
    ]
    all_ranges = []
    for index, obj in enumerate(objects):
        xml, ranges = _object_xml(index + 2, obj)
        model.append(xml)
        all_ranges.append(ranges)
    model.append("</resources><build>")
    model += [f'<item objectid="{index + 2}"/>' for index in range(len(objects))]
    model.append("</build></model>\n")
    members = [
        ("[Content_Types].xml", _CONTENT_TYPES),
        ("_rels/.rels", _RELS),
        ("3D/3dmodel.model", "".join(model)),
    ]
    if extruders is not None:
        members.append(
            ("Metadata/Slic3r_PE_model.config", _prusa_config(objects, all_ranges, extruders))
        )
        members.append(
            ("Metadata/model_settings.config", _bambu_config(objects, all_ranges, extruders))
        )
    write_zip(path, members)
    return all_ranges


def write_zip(path: Path, members: Sequence[tuple[str, str | bytes]]) -> None:
    """A zip with the members in the given order, fixed timestamps and permissions."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w") as archive:
        for name, data in members:
            info = zipfile.ZipInfo(name, date_time=ZIP_EPOCH)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            info.create_system = 3
            archive.writestr(info, data.encode("utf-8") if isinstance(data, str) else data)
    path.write_bytes(buffer.getvalue())


def _prusa_config(
    objects: Sequence[Object3mf], ranges: list[list[tuple[int, int]]], extruders: dict
) -> str:
    """PrusaSlicer's volumes: one per run of consecutive parts of one kind (all the tiles, all
    the hinge pads), named by its first and last part.  PrusaSlicer clips every volume against
    the others layer by layer, so hundreds of volumes take it minutes where two take seconds;
    the per-part ranges are in the Bambu/Orca config."""
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<config>"]
    for index, (obj, obj_ranges) in enumerate(zip(objects, ranges, strict=True)):
        lines.append(f' <object id="{index + 2}" instances_count="1">')
        lines.append(f'  <metadata type="object" key="name" value="{_escape(obj.name)}"/>')
        runs: list[list[tuple[PartMesh, tuple[int, int]]]] = []
        for part, span in zip(obj.parts, obj_ranges, strict=True):
            if runs and runs[-1][0][0].kind == part.kind:
                runs[-1].append((part, span))
            else:
                runs.append([(part, span)])
        for run in runs:
            (part, (first, _)), (last_part, (_, last)) = run[0], run[-1]
            name = part.name if len(run) == 1 else f"{part.name} to {last_part.name}"
            lines.append(f'  <volume firstid="{first}" lastid="{last}">')
            lines.append(f'   <metadata type="volume" key="name" value="{name}"/>')
            lines.append('   <metadata type="volume" key="volume_type" value="ModelPart"/>')
            lines.append(
                f'   <metadata type="volume" key="extruder" value="{extruders[part.kind]}"/>'
            )
            lines.append("  </volume>")
        lines.append(" </object>")
    lines.append("</config>")
    return "\n".join(lines) + "\n"


def _bambu_config(
    objects: Sequence[Object3mf], ranges: list[list[tuple[int, int]]], extruders: dict
) -> str:
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<config>"]
    for index, (obj, obj_ranges) in enumerate(zip(objects, ranges, strict=True)):
        lines.append(f'  <object id="{index + 2}">')
        lines.append(f'    <metadata key="name" value="{_escape(obj.name)}"/>')
        lines.append(f'    <metadata key="extruder" value="{extruders["tile"]}"/>')
        for number, (part, (first, last)) in enumerate(zip(obj.parts, obj_ranges, strict=True)):
            lines.append(
                f'    <part id="{number + 1}" subtype="normal_part" '
                f'firstid="{first}" lastid="{last}">'
            )
            lines.append(f'      <metadata key="name" value="{part.name}"/>')
            lines.append(f'      <metadata key="extruder" value="{extruders[part.kind]}"/>')
            lines.append("    </part>")
        lines.append("  </object>")
    lines.append("</config>")
    return "\n".join(lines) + "\n"
