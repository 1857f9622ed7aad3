"""Building the tiles of a design in worker processes: each worker gets plain numbers and small
tool solids per tile (:class:`TileJob`), builds that tile's other tools, cuts them in one
boolean, and builds the hinge parts the tile owns (:func:`build_job`)."""

from __future__ import annotations

import logging
import multiprocessing
import os
import pickle
from collections.abc import Callable
from dataclasses import dataclass, field
from functools import partial
from typing import TYPE_CHECKING, Any

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRepTools import BRepTools

from drawstring.cad.feature_common import Footprint
from drawstring.cad.features import build_tile, lift_bore, string_channel, trim_tool
from drawstring.cad.hinge_frame import StripNeighbours
from drawstring.cad.hinge_parts import HingeParts, hinge_face_footprints, hinge_pad
from drawstring.cad.hinge_pins import HingePins
from drawstring.cad.kernel import solid_checks
from drawstring.cad.magnets_labels import fill_engraving, label_depth, label_engraving
from drawstring.cad.part_mesh import PartKind, PartMeshes, mesh_part, mesh_tolerance
from drawstring.cad.tiles import relieved_tile_solid, tile_solid
from drawstring.geometry.core import parallel
from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)

#: Below this many tiles the build runs in the calling process (worker start-up does not pay).
PARALLEL_MIN_TILES = 24
#: Chunks of tiles per worker process.  A worker takes the next chunk as it finishes one, so
#: the workers finish at most one chunk apart: a chunk of the default saddle's 196 tiles on
#: two workers is about 2 CPU s of the 45.  Each chunk carries the hinges' arrays (under
#: 1 MB).
CHUNKS_PER_WORKER = 12


@dataclass
class TileJob:
    """Everything a worker needs to build one tile (plain numbers and small tool solids)."""

    tile: int
    vertices: NDArray[np.float64]
    channels: list[tuple[int, int]] = field(default_factory=list)
    lifts: list[int] = field(default_factory=list)
    tools: list[bd.Solid] = field(default_factory=list)
    trims: list[NDArray[np.float64]] = field(default_factory=list)
    reliefs: list[NDArray[np.float64]] = field(default_factory=list)  # planes: keep n . x >= d
    hinges: list[tuple[int, bool]] = field(default_factory=list)
    label: bool = False
    pads: list[int] = field(default_factory=list)


#: One hinge as the workers build it: ``(tile_a, corner_a, tile_b, corner_b, side, pins,
#: neighbours)``, the tiles' (8, 3) vertices in the flat pose.
HingeData = tuple[
    NDArray[np.float64], int, NDArray[np.float64], int, HingeSide, HingePins | None, StripNeighbours
]


@dataclass
class JobResult:
    """A worker's tile: its solid, the pads it built, its notes, whether its number was
    engraved, and the features whose cut failed and were left out."""

    tile: int
    solid: bd.Solid
    pads: list[tuple[int, bd.Solid]]
    notes: list[str]
    labelled: bool
    failed: list[str]
    dropped_mm3: float = 0.0  # pieces the features cut off the tile (the largest is kept)
    #: (valid, volume) of the tile, then of each of ``pads`` (:func:`~drawstring.cad.kernel.
    #: solid_checks`), measured here, in the worker, rather than serially by the caller.
    checks: list[tuple[bool, float]] = field(default_factory=list)
    #: The tile without its engraved number and the number's outline (:func:`~drawstring.
    #: cad.magnets_labels.fill_engraving`), for the STEP files; None where it has none or its
    #: pockets could not be filled.
    unengraved: tuple[bd.Solid, list[NDArray[np.float64]]] | None = None
    #: The meshes of the tile, then of each of ``pads`` (:func:`~drawstring.cad.part_mesh.
    #: mesh_part`, made here in parallel: the interference checks measure the first, the 3MF
    #: writes the second), None where the kernel failed to mesh it closed.
    meshes: list[PartMeshes | None] = field(default_factory=list)
    #: Whether ``meshes`` were made on this machine (False for a cluster's tasks).
    meshed_here: bool = True


def kernel_failure(what: str, exc: Exception) -> None:
    """Re-raise bad data (:class:`InternalError`) and bad input (:class:`InputError`); log any
    other exception (OCP's Standard_Failure, build123d's errors) as the kernel failure of
    ``what``, which the caller leaves out."""
    if isinstance(exc, InputError | InternalError):
        raise exc
    log.debug("%s: %s: %s", what, type(exc).__name__, exc, exc_info=exc)


class _Tools:
    """The tools to cut from one tile, each with its feature's name, and the features whose
    tool the kernel failed to make."""

    def __init__(self, job: TileJob) -> None:
        self.tile = job.tile
        self.solids: list[bd.Shape] = list(job.tools)
        self.names = ["magnet pocket"] * len(self.solids)
        self.failed: list[str] = []

    def add(self, name: str, make: Callable[[], bd.Shape | tuple[bd.Shape, ...] | None]) -> bool:
        """Add a tool (or the several solids of one feature); False only where ``make`` finds
        no room for it (returns None)."""
        try:
            tool = make()
        except Exception as exc:  # the kernel's own errors, whatever their class
            kernel_failure(f"tile {self.tile}: {name}", exc)
            self.failed.append(name)
            return True
        if tool is None:
            return False
        solids = tool if isinstance(tool, tuple) else (tool,)
        self.solids.extend(solids)
        self.names += [name] * len(solids)
        return True

    def extend(self, name: str, solids: tuple[bd.Solid, ...]) -> None:
        self.solids.extend(solids)
        self.names += [name] * len(solids)


def build_job(job: TileJob, profile: Profile, hinge_data: tuple[HingeData, ...]) -> JobResult:
    """Worker: build the tools of one tile, cut them, and build the pads this tile owns.

    A feature whose tool or cut fails in the kernel (any exception but bad data) is left out
    and named in the result's ``failed``; a tile whose cut fails altogether is the plain
    block, every feature named; a hinge part that cannot be built is left out, named too.
    """
    tools = _Tools(job)
    for a, b in job.channels:
        tools.add("string channel", partial(string_channel, job.vertices, a, b, profile))
    opened = {side for pair in job.channels for side in pair}
    for side in job.lifts:
        tools.add(
            "lift bore", partial(lift_bore, job.vertices, side, profile, shared=side in opened)
        )
    for points in job.trims:
        tools.add("trim", partial(trim_tool, points))
    notes: list[str] = []
    built_pads, bottom = _hinge_tools(job, profile, hinge_data, tools, notes)
    labelled = False
    if job.label:
        labelled = tools.add(
            "number engraving", partial(label_engraving, job.vertices, job.tile, profile, bottom)
        )
    solid, dropped, known = _cut(job, tools)
    # the tile's checks come from its cut where it measured them on its way
    tile_check = known if known is not None else solid_checks(solid)
    unengraved = _unengraved(job, solid, tools, profile, tile_check) if labelled else None
    pads = _own_pads(job, profile, hinge_data, built_pads, tools.failed)
    checks = [tile_check]
    meshes: list[PartMeshes | None] = []
    tolerance = mesh_tolerance(profile.thickness_mm)
    names = [f"tile_{job.tile}", *(f"hinge_{hinge}" for hinge, _ in pads)]
    for index, part in enumerate([solid, *(pad for _, pad in pads)]):
        if index:
            checks.append(solid_checks(part))
        # the meshes, made here in parallel; they travel as arrays, so the solid goes without
        # its triangulation (the pickle is a third of the size).  OCCT meshes a solid read
        # back from its serialisation with other triangles here and there, so the mesh is
        # made of the solid as the caller reads it (pickled once, as from any worker or a
        # cluster): the same files wherever the tiles were built.
        kind: PartKind = "pad" if index else "tile"
        try:
            meshes.append(
                mesh_part(pickle.loads(pickle.dumps(part)), names[index], kind, tolerance)
            )
        except Exception as exc:  # the checks mesh it again and count it as not valid
            kernel_failure(f"tile {job.tile}: mesh", exc)
            meshes.append(None)
        BRepTools.Clean_s(part.wrapped)
    result = JobResult(job.tile, solid, pads, notes, labelled, tools.failed, sum(dropped))
    result.checks = checks
    result.meshes = meshes
    result.unengraved = unengraved
    return result


def _unengraved(
    job: TileJob, solid: bd.Solid, tools: _Tools, profile: Profile, check: tuple[bool, float]
) -> tuple[bd.Solid, list[NDArray[np.float64]]] | None:
    """The tile without the number engraved into it and the number's outline, or None (no
    engraving was cut, or its pockets could not be filled: the STEP files then show the
    number cut)."""
    if "number engraving" in tools.failed or "number engraving" not in tools.names:
        return None
    engraving = tools.solids[tools.names.index("number engraving")]
    try:
        volume = check[1] if check[0] else None  # measured (a kernel failure measures 0)
        filled = fill_engraving(solid, engraving, label_depth(profile), volume)
    except Exception as exc:
        kernel_failure(f"tile {job.tile}: filling its number", exc)
        return None
    if filled is None:
        log.debug("tile %d: its number's pockets could not be filled", job.tile)
    return filled


def _hinge_parts(data: HingeData, profile: Profile, build_pad: bool) -> HingeParts:
    tile_a, corner_a, tile_b, corner_b, side, pins, crowd = data
    return hinge_pad(
        tile_a,
        corner_a,
        tile_b,
        corner_b,
        side,
        profile,
        build_pad=build_pad,
        pins=pins,
        neighbours=crowd,
    )


def _hinge_tools(
    job: TileJob,
    profile: Profile,
    hinge_data: tuple[HingeData, ...],
    tools: _Tools,
    notes: list[str],
) -> tuple[dict[int, bd.Solid], list[Footprint]]:
    """The recesses and keys of the tile's hinges into ``tools`` (their notes into ``notes``,
    from tile a's side); returns the pads built on the way (by hinge) and what the hinges put
    where the tile's number goes."""
    owned = set(job.pads)
    built_pads: dict[int, bd.Solid] = {}
    bottom: list[Footprint] = []
    for hinge, is_a in job.hinges:
        tile_a, corner_a, tile_b, corner_b, side, pins, crowd = hinge_data[hinge]
        # The pad this tile owns comes out of the same call as its tools (one frame, one build).
        make_pad = hinge in owned and hinge not in built_pads
        try:
            if job.label:
                on_a, on_b = hinge_face_footprints(
                    tile_a, corner_a, tile_b, corner_b, side, profile, pins, crowd
                )
                bottom.extend(on_a if is_a else on_b)
            parts = _hinge_parts(hinge_data[hinge], profile, make_pad)
        except Exception as exc:
            kernel_failure(f"tile {job.tile}: hinge {hinge}", exc)
            tools.failed.append(f"hinge {hinge} recess or key")
            continue
        tools.extend(f"hinge {hinge} recess or key", parts.tools_a if is_a else parts.tools_b)
        if is_a:
            notes.extend(f"hinge {hinge}: {n}" for n in parts.notes)
        if make_pad and parts.pad is not None:
            built_pads[hinge] = parts.pad
    return built_pads, bottom


def _cut(job: TileJob, tools: _Tools) -> tuple[bd.Solid, list[float], tuple[bool, float] | None]:
    """The tile's block (relieved at its hinges where it has reliefs) minus the tools, the
    volumes of the pieces the cut dropped, and the solid's :func:`~drawstring.cad.kernel.
    solid_checks` where the cut measured them (else None); the features whose cut failed go
    to ``tools.failed``."""
    block: bd.Solid | None = None
    if job.reliefs:
        try:
            block = relieved_tile_solid(job.vertices, job.reliefs)
        except Exception as exc:  # the plain block follows, its reliefs named as failed
            kernel_failure(f"tile {job.tile}: hinge relief", exc)
            tools.failed.append("hinge relief")
    try:
        block = block if block is not None else tile_solid(job.vertices)
    except Exception as exc:
        kernel_failure(f"tile {job.tile}: block", exc)
        raise InternalError(
            f"tile {job.tile}: the CAD kernel cannot make a solid of its 8 vertices "
            f"({type(exc).__name__})"
        ) from exc
    failed_tools: list[int] = []
    dropped: list[float] = []
    checked: list[tuple[bool, float]] = []
    try:
        solid = build_tile(
            block, tools.solids, failed=failed_tools, dropped=dropped, checked=checked
        )
    except Exception as exc:
        kernel_failure(f"tile {job.tile}: cut", exc)
        solid, failed_tools = block, list(range(len(tools.solids)))
        dropped.clear()  # the uncut block is kept
        checked.clear()
    tools.failed += [tools.names[i] for i in failed_tools]
    return solid, dropped, checked[0] if checked else None


def _own_pads(
    job: TileJob,
    profile: Profile,
    hinge_data: tuple[HingeData, ...],
    built_pads: dict[int, bd.Solid],
    failed: list[str],
) -> list[tuple[int, bd.Solid]]:
    """The hinge parts this tile owns, built where :func:`_hinge_tools` did not (a part that
    cannot be built is named in ``failed``)."""
    pads = []
    for hinge in job.pads:
        if hinge not in built_pads:
            try:
                pad = _hinge_parts(hinge_data[hinge], profile, True).pad
            except Exception as exc:
                kernel_failure(f"tile {job.tile}: hinge {hinge} part", exc)
                pad = None
            if pad is None:
                failed.append(f"hinge {hinge} part")
                continue
            built_pads[hinge] = pad
        pads.append((hinge, built_pads[hinge]))
    return pads


def _build_chunk(
    jobs: list[TileJob], profile: Profile, hinge_data: tuple[HingeData, ...]
) -> list[JobResult]:
    return [build_job(job, profile, hinge_data) for job in jobs]


def run_jobs(
    jobs: list[TileJob],
    profile: Profile,
    hinge_data: tuple[HingeData, ...],
    workers: int | None,
) -> list[JobResult]:
    """Every tile built, in worker processes from :data:`PARALLEL_MIN_TILES` tiles on, or as
    tasks of the runner :func:`~drawstring.geometry.core.parallel.tasks_on` set."""
    runner = parallel.task_runner()
    if runner is not None and len(jobs) > 1:  # on a cluster (drawstring design --scheduler)
        n_chunks = min(len(jobs), 4 * runner.thread_count())
        chunks = [jobs[i::n_chunks] for i in range(n_chunks)]
        arguments = [(chunk, profile, hinge_data) for chunk in chunks]
        done = runner.starmap(_build_chunk, arguments, name="cad-tiles")
        remote = [result for chunk_results in done for result in chunk_results]
        for result in remote:
            result.meshed_here = False
        return remote
    count = workers if workers is not None else (os.cpu_count() or 1)
    if count <= 1 or len(jobs) < PARALLEL_MIN_TILES:
        return _build_chunk(jobs, profile, hinge_data)
    # Interleave tiles over chunks so each chunk gets a similar mix of features; small chunks
    # (CHUNKS_PER_WORKER each) keep every worker busy until the last tiles are built.
    n_chunks = min(len(jobs), CHUNKS_PER_WORKER * count)
    chunks = [jobs[i::n_chunks] for i in range(n_chunks)]
    methods = multiprocessing.get_all_start_methods()
    context = multiprocessing.get_context("fork" if "fork" in methods else "spawn")
    results: list[JobResult] = []
    with parallel.process_pool(count, context) as pool:
        futures = [pool.submit(_build_chunk, chunk, profile, hinge_data) for chunk in chunks]
        for future in futures:
            results.extend(future.result())
    return results


def _per_part(results: list[JobResult], field: str) -> dict[tuple[str, int], Any]:
    """One of the workers' per-part lists (``field``: the tile's entry, then one per pad),
    keyed ``("tile", tile)`` and ``("pad", hinge)``; jobs without a full list are left out."""
    found: dict[tuple[str, int], Any] = {}
    for done in results:
        entries = getattr(done, field)
        if len(entries) != 1 + len(done.pads):
            continue
        found[("tile", done.tile)] = entries[0]
        for (hinge, _), entry in zip(done.pads, entries[1:], strict=True):
            found[("pad", int(hinge))] = entry
    return found


def part_checks(results: list[JobResult]) -> dict[tuple[str, int], tuple[bool, float]]:
    """The workers' ``(valid, volume)`` of each tile (``("tile", tile)``) and hinge part
    (``("pad", hinge)``)."""
    return _per_part(results, "checks")


def part_meshes(results: list[JobResult]) -> dict[tuple[str, int], PartMeshes | None]:
    """The workers' meshes of each tile and hinge part, keyed as :func:`part_checks`."""
    return _per_part(results, "meshes")
