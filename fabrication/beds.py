"""Print beds: the fdm-dual print jobs (bands of the flat layout along rows of hinges, the
loose pads of the hinges between them) and the laser-epdm loose tiles nested, each job moved
onto a bed and the jobs that fit together sharing one (:mod:`.processes.print_jobs` writes
the 3MF files).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drawstring.fabrication import mesh3mf as m3f
from drawstring.fabrication.dxf import place_outlines, rotate, shelf_pack
from drawstring.fabrication.record import ExportRecord
from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:
    from drawstring.fabrication.profiles import Profile


#: Space left between loose tiles nested on a bed, mm (room for a brim of a few lines).
TILE_SPACING_MM = 4.0


def nest_footprints(
    points: Sequence[NDArray[np.float64]], bed: tuple[float, float]
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """Bed, turn (rad) and shift of each tile nested by the convex hull of its points' x, y
    (:func:`~.dxf.place_outlines`).

    Raises
    ------
    InputError
        When a tile does not fit an empty bed inside its margins, turned any way.
    """
    from scipy.spatial import ConvexHull

    outlines = [p[:, :2][ConvexHull(p[:, :2]).vertices] for p in points]
    try:
        sheet, angle, shift, _ = place_outlines(outlines, bed, TILE_SPACING_MM, m3f.BED_MARGIN_MM)
    except InputError as error:
        raise InputError(
            f"a tile does not fit the {bed[0]:g} x {bed[1]:g} mm bed with "
            f"{m3f.BED_MARGIN_MM:g} mm free round it, turned any way; use a printer with a "
            "larger bed (--printer) or more tiles"
        ) from error
    return sheet, angle, shift


def nested_tiles(meshes: list[m3f.PartMesh], bed: tuple[float, float]) -> list[list[m3f.PartMesh]]:
    """Tiles turned over onto their flat top faces (a tile is as thick as its assembled
    frustum, so their bottoms do not share a plane), each on z = 0, then turned about the
    vertical to their smallest bounding rectangles and shelf-packed onto beds (as the DXF
    parts are), one list of moved meshes per bed."""
    turned = [m3f.flip_upside_down(mesh) for mesh in meshes]
    meshes = [
        m3f.PartMesh(m.name, m.kind, m.vertices - [0.0, 0.0, m.vertices[:, 2].min()], m.triangles)
        for m in turned
    ]
    sheet, angle, shift = nest_footprints([mesh.vertices for mesh in meshes], bed)
    beds: list[list[m3f.PartMesh]] = [[] for _ in range(int(sheet.max(initial=-1)) + 1)]
    for mesh, b, a, move in zip(meshes, sheet, angle, shift, strict=True):
        vertices = mesh.vertices.copy()
        vertices[:, :2] = rotate(vertices[:, :2], float(a)) + move
        beds[int(b)].append(m3f.PartMesh(mesh.name, mesh.kind, vertices, mesh.triangles))
    return beds


def jobs_on_bed(
    jobs: list[m3f.PrintJob],
    tile_mesh: dict[int, m3f.PartMesh],
    pad_mesh: dict[int, m3f.PartMesh],
    record: ExportRecord,
) -> list[list[m3f.PartMesh]]:
    """Every job's parts moved onto the bed, in the job's own frame (centred on the bed), top
    faces down.

    The flat layout's top faces lie in one plane, its bottoms do not: a tile is as thick as its
    assembled frustum (up to a few tenths of a millimetre more or less than the profile's
    thickness where the quad mesh is not conical).  Printed on their bottoms, thinner tiles
    would start above the first layer; turned over (about the job's centre line along x) every
    tile rests on the bed.
    """
    job_parts: list[list[m3f.PartMesh]] = []
    for job in jobs:
        parts = [
            m3f.PartMesh(tile_mesh[t].name, "tile", tile_mesh[t].vertices, tile_mesh[t].triangles)
            for t in job.tiles
        ]
        parts += [
            m3f.PartMesh(pad_mesh[h].name, "pad", pad_mesh[h].vertices, pad_mesh[h].triangles)
            for h in job.pads
            if h in pad_mesh
        ]
        top = max(float(p.vertices[:, 2].max()) for p in parts)
        mirror_y = job.offset[1] + (
            min(float(p.vertices[:, 1].min()) for p in parts)
            + max(float(p.vertices[:, 1].max()) for p in parts)
        )
        parts = [
            m3f.PartMesh(
                p.name,
                p.kind,
                m3f.flip_upside_down(p).vertices + np.array([job.offset[0], mirror_y, top]),
                p.triangles,
            )
            for p in parts
        ]
        job_parts.append(parts)
        record.jobs.append(
            {
                "job": len(record.jobs) + 1,
                "tiles": list(job.tiles),
                "pads": list(job.pads),
                "size_mm": footprint_mm(parts),
            }
        )
    return job_parts


def loose_pads_and_beds(
    cut: list[int],
    pad_mesh: dict[int, m3f.PartMesh],
    job_parts: list[list[m3f.PartMesh]],
    bed: tuple[float, float],
    profile: Profile,
    record: ExportRecord,
) -> list[int]:
    """The job of the loose pads of ``cut`` hinges (appended), then every job's bed."""
    loose_cut = [h for h in cut if h in pad_mesh]
    if loose_cut:
        flipped = []
        for h in loose_cut:
            mesh = pad_mesh[h]
            side_top = bool(np.mean(mesh.vertices[:, 2]) > 0.5 * profile.thickness_mm)
            flipped.append(m3f.flip_upside_down(mesh) if side_top else mesh)
        # one job per bed the rows of pads fill, in the order of the cut hinges
        for placed in m3f.arrange_loose(flipped, bed, 3.0):
            job_parts.append(placed)
            record.jobs.append(
                {
                    "job": len(record.jobs) + 1,
                    "tiles": [],
                    "pads": [int(p.name.split("_")[1]) for p in placed],
                    "size_mm": footprint_mm(placed),
                    "loose": True,
                }
            )
    return fill_beds(job_parts, bed)


def extent(parts: Sequence[m3f.PartMesh]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Lowest and highest corner (3,) of the parts' bounding box, mm."""
    low = np.min([p.vertices.min(axis=0) for p in parts], axis=0)
    high = np.max([p.vertices.max(axis=0) for p in parts], axis=0)
    return low, high


def footprint_mm(parts: Sequence[m3f.PartMesh]) -> list[float]:
    """The parts' extent on the bed (x, y), mm, as the manifest's ``size_mm`` gives it."""
    low, high = extent(parts)
    return [round(float(v), 2) for v in (high - low)[:2]]


#: Space left between print jobs that share a bed, mm.
JOB_SPACING_MM = 5.0


def fill_beds(job_parts: list[list[m3f.PartMesh]], bed: tuple[float, float]) -> list[int]:
    """Put print jobs that fit together on one bed (shelves, first bed with room, as the DXF
    sheets are packed), moving the parts of each job in place (``job_parts`` lists each job's
    parts on the bed, centred) and turning a job by 90 degrees where it fits the bed only so
    (the job planner may cut its bands along the bed's other side); returns each job's bed.
    A bed that holds one job keeps it where it was unless it had to turn (then centred)."""
    if not job_parts:
        return []

    boxes = [extent(parts) for parts in job_parts]
    sizes = np.array([(high - low)[:2] for low, high in boxes])
    sheet, position, turned = shelf_pack(
        sizes, bed, JOB_SPACING_MM, m3f.BED_MARGIN_MM, long_side_x=False
    )
    # beds numbered in the order of their first job (the packing goes tallest first)
    first_seen = {int(b): None for b in sheet}
    sheet = np.array([list(first_seen).index(int(b)) for b in sheet], dtype=np.int64)
    quarter = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])  # +90 deg about z
    for index, parts in enumerate(job_parts):
        alone = np.count_nonzero(sheet == sheet[index]) == 1
        if alone and not turned[index]:
            continue
        if turned[index]:
            parts = [
                m3f.PartMesh(p.name, p.kind, p.vertices @ quarter.T, p.triangles) for p in parts
            ]
        low, high = extent(parts)
        if alone:
            target = 0.5 * np.array(bed) - 0.5 * (high - low)[:2]
        else:
            target = position[index]
        move = np.array([*(target - low[:2]), 0.0])
        job_parts[index] = [
            m3f.PartMesh(p.name, p.kind, p.vertices + move, p.triangles) for p in parts
        ]
    return [int(b) for b in sheet]


#: Free space between a wipe tower and the parts, mm.
TOWER_GAP_MM = 5.0
#: Step of the search for a wipe tower's place, mm.
TOWER_STEP_MM = 2.0


def place_wipe_towers(
    job_parts: list[list[m3f.PartMesh]],
    beds: list[int],
    bed: tuple[float, float],
    footprint: tuple[float, float],
) -> list[tuple[float, float] | None]:
    """Where each bed's wipe tower goes: the corner (x, y) of a ``footprint`` rectangle inside
    the bed's margins, :data:`TOWER_GAP_MM` clear of every part's bounding box, nearest the
    bed's far x edge and then its near y edge; None on a bed that prints one material, or that
    has no such room.

    Parameters
    ----------
    job_parts : each job's parts, on its bed.
    beds : each job's bed.
    bed : the bed's size (x, y), mm.
    footprint : the tower's size (x, y), mm, its brim included.
    """
    n_beds = int(max(beds, default=-1)) + 1
    towers: list[tuple[float, float] | None] = [None] * n_beds
    margin = m3f.BED_MARGIN_MM
    xs = np.arange(bed[0] - margin - footprint[0], margin - 1e-9, -TOWER_STEP_MM)
    ys = np.arange(margin, bed[1] - margin - footprint[1] + 1e-9, TOWER_STEP_MM)
    if len(xs) == 0 or len(ys) == 0:
        return towers
    corner_x, corner_y = (a.ravel() for a in np.meshgrid(xs, ys, indexing="ij"))
    for index in range(n_beds):
        parts = [p for parts, b in zip(job_parts, beds, strict=True) if b == index for p in parts]
        if {p.kind for p in parts} != {"tile", "pad"}:
            continue
        low = np.array([p.vertices[:, :2].min(axis=0) for p in parts]) - TOWER_GAP_MM
        high = np.array([p.vertices[:, :2].max(axis=0) for p in parts]) + TOWER_GAP_MM
        clear = np.ones(len(corner_x), dtype=bool)
        for (lx, ly), (hx, hy) in zip(low, high, strict=True):
            clear &= (
                (corner_x + footprint[0] <= lx)
                | (corner_x >= hx)
                | (corner_y + footprint[1] <= ly)
                | (corner_y >= hy)
            )
        free = np.flatnonzero(clear)
        if len(free):
            towers[index] = (float(corner_x[free[0]]), float(corner_y[free[0]]))
    return towers
