"""Target surfaces: read a mesh file (:mod:`~drawstring.geometry.target.meshfiles`) or build a
built-in one, check it is a disk, scale it.

The pipeline needs one connected, edge- and vertex-manifold, consistently oriented triangle
mesh with exactly one boundary loop and no handles (a topological disk). Anything else raises
:class:`~drawstring.geometry.core.errors.InputError` with one line naming the defect and the fix.

Repairs that cannot change the surface are done and recorded in ``Target.notes``: dropping
unreferenced vertices, merging coincident vertices, removing duplicated faces.  A zero-area
(degenerate) face is refused unless the caller asks for repairs (``repair=True``, the CLI's
``--repair``): removing one can change what the surface is (it may be all that joins two parts,
or it may be the trace of a collapsed region of the scan), so the user decides.  Built-in
targets are always repaired.

Orientation policy: inconsistent face orientation is refused, never guessed. Which side of the
surface is "outside" decides the side on which tiles are extruded, so the user has to say it
by fixing the winding (a flipped face is also the usual sign of a broken export).
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import igl
import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components

from drawstring.geometry.core.errors import InputError, InternalError
from drawstring.geometry.core.tolerances import (
    DEGENERATE_FACE_REL_AREA,
)
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.target.builtins import BUILTIN_TARGETS
from drawstring.geometry.target.meshfiles import (
    SUPPORTED_EXTENSIONS,
    coincident_remap,
    exact_rescale,
    read_mesh,
)

logger = logging.getLogger(__name__)

#: Triangle counts accepted for built-in targets.
MIN_RESOLUTION = 32
MAX_RESOLUTION = 5_000_000


@dataclass(frozen=True, eq=False)
class Target:
    """A validated, scaled disk-topology target surface.

    Attributes
    ----------
    name : str
        Built-in name or the file's stem.
    vertices : (n, 3) float, mm
        Read-only. Scaled so that the longest bounding-box side is the requested size; x and y
        centred on 0, lowest z at 0; z is up.
    faces : (m, 3) int
        Read-only. Consistently oriented triangles forming a disk (one boundary loop).
    source : str
        ``"builtin"`` or the file path as given.
    notes : tuple of str
        Repairs done while loading, e.g. ``"removed 3 zero-area faces"``.
    vertex_of_input : (n_input,) int or None
        For each vertex as read (the file's order, counting from 0), its index in
        ``vertices``, or -1 where the repairs dropped it (unused by any face, or only by
        removed ones); coincident vertices map to the one they were merged into.
    """

    name: str
    vertices: FloatArray
    faces: IntArray
    source: str
    notes: tuple[str, ...]
    vertex_of_input: IntArray | None = None

    @property
    def bbox_diagonal_mm(self) -> float:
        """Length of the bounding-box diagonal, mm."""
        return float(np.linalg.norm(np.ptp(self.vertices, axis=0)))


# --- loading ------------------------------------------------------------------------------


def load_target(
    spec: str | os.PathLike[str], size_mm: float, resolution: int = 10_000, *, repair: bool = False
) -> Target:
    """Load a built-in target or a mesh file, check it is a disk and scale it to size.

    Parameters
    ----------
    spec : str or path
        A built-in name (see :data:`~drawstring.geometry.target.builtins.BUILTIN_TARGETS`) or a
        path to an .obj, .off, .ply or .stl file.
    size_mm : float
        Longest bounding-box side of the result, mm.
    resolution : int
        Approximate triangle count of a built-in target (ignored for files).
    repair : bool
        Remove the zero-area faces of a mesh file instead of refusing it.

    Returns
    -------
    Target

    Raises
    ------
    InputError
        Bad size or resolution, unreadable file, or a mesh that is not a disk.
    """
    _check_size(size_mm)
    builtin = BUILTIN_TARGETS.get(spec.strip().lower()) if isinstance(spec, str) else None
    if builtin is not None:
        _check_resolution(resolution)
        raw_vertices, raw_faces = builtin.make(int(resolution))
        vertices, faces, notes, vertex_of_input = _clean_disk_mesh(
            raw_vertices, raw_faces, repair=True
        )
        name, source = builtin.name, "builtin"
    else:
        path = Path(spec)
        if path.suffix == "" and not path.exists():
            names = ", ".join(BUILTIN_TARGETS)
            raise InputError(
                f"unknown target '{os.fspath(spec)}': not a built-in ({names}) and not a mesh "
                f"file ({', '.join(SUPPORTED_EXTENSIONS)}); see `drawstring targets`"
            )
        raw_vertices, raw_faces = read_mesh(path)
        try:
            vertices, faces, notes, vertex_of_input = _clean_disk_mesh(
                raw_vertices, raw_faces, repair=repair
            )
        except InputError as error:
            raise InputError(f"{path}: {error}") from None
        vertices, faces, vertex_of_input = canonical_order(vertices, faces, vertex_of_input)
        name, source = path.stem, os.fspath(spec)
    scaled = scale_to_size(vertices, size_mm)
    for note in notes:
        logger.info("%s: %s", name, note)
    scaled.setflags(write=False)
    faces.setflags(write=False)
    vertex_of_input.setflags(write=False)
    return Target(
        name=name,
        vertices=scaled,
        faces=faces,
        source=source,
        notes=notes,
        vertex_of_input=vertex_of_input,
    )


def _check_size(size_mm: object) -> None:
    """Raise unless ``size_mm`` is a finite positive number."""
    if isinstance(size_mm, bool) or not isinstance(size_mm, int | float | np.integer | np.floating):
        valid = False
    else:
        value = float(size_mm)
        valid = math.isfinite(value) and value > 0.0
    if not valid:
        raise InputError(f"--size must be a positive number of millimetres (got {size_mm!r})")


def _check_resolution(resolution: object) -> None:
    """Raise unless ``resolution`` is an integer triangle count in the accepted range."""
    if isinstance(resolution, bool) or not isinstance(resolution, int | np.integer):
        valid = False
    else:
        valid = MIN_RESOLUTION <= int(resolution) <= MAX_RESOLUTION
    if not valid:
        raise InputError(
            f"resolution must be a whole number of triangles from {MIN_RESOLUTION} to "
            f"{MAX_RESOLUTION} (got {resolution!r})"
        )


def scale_to_size(vertices: FloatArray, size_mm: float) -> FloatArray:
    """Scale uniformly to a longest bounding-box side of ``size_mm`` and place on the ground.

    Parameters
    ----------
    vertices : (n, 3) float
        Any units; the bounding box must not be a single point.
    size_mm : float
        Wanted longest bounding-box side, mm.

    Returns
    -------
    (n, 3) float, mm
        x and y centred on 0, lowest z at 0.
    """
    _check_size(size_mm)
    low = vertices.min(axis=0)
    high = vertices.max(axis=0)
    longest = float((high - low).max())
    if not longest > 0.0:
        raise InputError("mesh has no extent (all vertices coincide); export the real surface")
    anchor = np.array([(low[0] + high[0]) / 2.0, (low[1] + high[1]) / 2.0, low[2]])
    return np.ascontiguousarray((vertices - anchor) * (float(size_mm) / longest))


def _count(n: int, singular: str, plural: str | None = None) -> str:
    """``"1 face"``, ``"3 faces"``: a number with its noun in the right number."""
    return f"{n} {singular if n == 1 else (plural or singular + 's')}"


# --- validation ---------------------------------------------------------------------------


def validate_disk_mesh(
    vertices: FloatArray, faces: IntArray, *, repair: bool = False
) -> tuple[FloatArray, IntArray, tuple[str, ...]]:
    """Check that a triangle mesh is a clean topological disk; make safe repairs.

    Repairs (each recorded in the notes): drop unreferenced vertices, merge coincident
    vertices, remove duplicated faces, and with ``repair`` zero-area faces (repeated index or
    area below ``DEGENERATE_FACE_REL_AREA`` times the mean), provided the rest is still a
    disk.  Without ``repair`` a zero-area face is refused.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int

    Returns
    -------
    V : (k, 3) float
        Only referenced vertices, order kept.
    F : (p, 3) int
        Orientation as given.
    notes : tuple of str
        The repairs made.

    Raises
    ------
    InputError
        One line naming the first defect found and how to fix it.
    """
    V, F, notes, _ = _clean_disk_mesh(vertices, faces, repair=repair)
    return V, F, notes


def _clean_disk_mesh(
    vertices: FloatArray, faces: IntArray, *, repair: bool
) -> tuple[FloatArray, IntArray, tuple[str, ...], IntArray]:
    """:func:`validate_disk_mesh`, and where each input vertex went (``vertex_of_input`` of
    :class:`Target`)."""
    V = np.asarray(vertices, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise InternalError(f"vertices must be an (n, 3) array of coordinates, got {V.shape}")
    if F.size == 0:
        raise InputError(
            "mesh has no faces; export the surface as a triangle mesh, not as points or lines"
        )
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise InternalError(f"faces must be an (m, 3) integer array of triangles, got {F.shape}")
    F = F.astype(np.int64)
    notes: list[str] = []
    where = np.arange(len(V))  # input vertex -> current index, -1 once dropped

    def follow(new_index: IntArray) -> None:
        where[where >= 0] = new_index[where[where >= 0]]

    out_of_range = np.any((F < 0) | (F >= len(V)), axis=1)
    if out_of_range.any():
        raise InputError(
            f"face indices out of range in {_count(int(out_of_range.sum()), 'face')} (the mesh "
            f"has {len(V)} vertices); the file is truncated or corrupt, re-export it"
        )
    V, F, dropped = _drop_unreferenced(V, F, follow)
    if dropped:
        notes.append(f"dropped {_count(dropped, 'unreferenced vertex', 'unreferenced vertices')}")
    non_finite = ~np.isfinite(V).all(axis=1)
    if non_finite.any():
        raise InputError(
            "non-finite (NaN or infinite) coordinates at "
            f"{_count(int(non_finite.sum()), 'vertex', 'vertices')}; fix or remove them and "
            "export again"
        )
    V, rescaled = exact_rescale(V)
    if rescaled:
        notes.append(rescaled)
    keep, remap = coincident_remap(V)
    merged = 0
    if remap is not None:
        V, F, merged = V[keep], remap[F], len(V) - len(keep)
        follow(remap)
    if merged:
        notes.append(f"merged {_count(merged, 'coincident vertex', 'coincident vertices')}")

    degenerate = _degenerate_faces(V, F)
    if degenerate.all():
        raise InputError(
            f"all {len(F)} faces have zero area; the mesh is collapsed, export the real surface"
        )
    n_degenerate = int(degenerate.sum())
    if n_degenerate and _is_closed(F[~_repeats_vertex(F)], len(V)):
        raise InputError(_closed_message())
    if n_degenerate and not repair:
        first = V[F[np.flatnonzero(degenerate)[0]]].mean(axis=0)
        found = (
            f"{_count(n_degenerate, 'degenerate (zero-area) face')}, the first at "
            f"({', '.join(f'{c:.6g}' for c in first)})"
        )
        them = "it" if n_degenerate == 1 else "them"
        try:  # offer --repair only where it would give a disk
            _clean_disk_mesh(vertices, faces, repair=True)
        except InputError as error:
            raise InputError(
                f"{found}; {error}: mend the mesh around {them} in a mesh editor"
            ) from None
        raise InputError(
            f"{found}; delete {them} in a mesh editor (MeshLab: Filters > Cleaning and Repairing "
            f"> Remove Zero Area Faces) or pass --repair to drop {them}"
        )
    F = F[~degenerate]
    duplicated = _duplicated_faces(F)
    F = F[~duplicated]
    if n_degenerate:
        notes.append(f"removed {_count(n_degenerate, 'zero-area face')}")
    if duplicated.any():
        notes.append(f"removed {_count(int(duplicated.sum()), 'duplicated face')}")
    V, F, dropped = _drop_unreferenced(V, F, follow)
    if dropped and (n_degenerate or duplicated.any()):
        notes.append(f"dropped {_count(dropped, 'vertex', 'vertices')} used only by removed faces")

    try:
        check_disk_topology(F, len(V))
    except InputError as error:
        if n_degenerate:
            removed = _count(n_degenerate, "zero-area face")
            raise InputError(
                f"removing {removed} leaves a surface that is not a disk ({error})"
            ) from None
        raise
    return np.ascontiguousarray(V), np.ascontiguousarray(F), tuple(notes), where


def canonical_order(
    vertices: FloatArray, faces: IntArray, vertex_of_input: IntArray
) -> tuple[FloatArray, IntArray, IntArray]:
    """The mesh renumbered by its geometry alone: vertices sorted by x, then y, then z; each
    face turned (keeping its orientation) to start at its smallest vertex; faces sorted.

    Every later step sums, solves and breaks ties in vertex and face order, and a conformal map
    of a few thousand vertices carries last-bit differences through to a different tiling; so
    the same surface written by another exporter, as STL instead of OBJ or with its vertices
    renumbered, would give another design.  ``vertex_of_input`` follows the renumbering.
    """
    order = np.lexsort((vertices[:, 2], vertices[:, 1], vertices[:, 0]))
    new_index = np.empty(len(order), dtype=np.int64)
    new_index[order] = np.arange(len(order))
    F = new_index[faces]
    start = np.argmin(F, axis=1)
    F = F[np.arange(len(F))[:, None], (start[:, None] + np.arange(3)) % 3]
    F = F[np.lexsort((F[:, 2], F[:, 1], F[:, 0]))]
    where = np.where(vertex_of_input >= 0, new_index[np.maximum(vertex_of_input, 0)], -1)
    return np.ascontiguousarray(vertices[order]), np.ascontiguousarray(F), where


def _drop_unreferenced(
    vertices: FloatArray,
    faces: IntArray,
    follow: Callable[[IntArray], None],
) -> tuple[FloatArray, IntArray, int]:
    """Remove vertices no face uses; keep the order of the rest.  ``follow`` gets each old
    vertex's new index (-1: removed)."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    if used.all():
        return vertices, faces, 0
    new_index = np.where(used, np.cumsum(used) - 1, -1)
    follow(new_index)
    return vertices[used], new_index[faces], int((~used).sum())


def _repeats_vertex(faces: IntArray) -> BoolArray:
    """(m,) bool: the face uses some vertex twice."""
    return (
        (faces[:, 0] == faces[:, 1]) | (faces[:, 1] == faces[:, 2]) | (faces[:, 2] == faces[:, 0])
    )


def _degenerate_faces(vertices: FloatArray, faces: IntArray) -> BoolArray:
    """(m,) bool: repeated vertex or area at most ``DEGENERATE_FACE_REL_AREA`` of the mean."""
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    areas = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    threshold = DEGENERATE_FACE_REL_AREA * float(areas.mean())
    return _repeats_vertex(faces) | (areas <= threshold)


def _duplicated_faces(faces: IntArray) -> BoolArray:
    """(m,) bool: the face repeats the vertex set of an earlier face (either orientation)."""
    if len(faces) == 0:
        return np.zeros(0, dtype=bool)
    _, first = np.unique(np.sort(faces, axis=1), axis=0, return_index=True)
    duplicated = np.ones(len(faces), dtype=bool)
    duplicated[first] = False
    return duplicated


@dataclass(frozen=True)
class _Edges:
    """Undirected edges of a triangle mesh, seen from its 3m half-edges.

    Half-edge ``h = 3 f + k`` runs from ``F[f, k]`` to ``F[f, (k + 1) % 3]``; it starts at
    corner ``h`` and ends at corner ``3 f + (k + 1) % 3`` (corner = index into ``F.ravel()``).
    """

    start: IntArray  # (3m,) start vertex of each half-edge
    end: IntArray  # (3m,) end vertex
    edge: IntArray  # (3m,) undirected edge id of each half-edge
    valence: IntArray  # (e,) faces per edge
    pair_first: IntArray  # (i,) one half-edge of each two-face edge
    pair_second: IntArray  # (i,) the other one


def _edges(faces: IntArray, n_vertices: int) -> _Edges:
    """Build the half-edge / edge tables (vectorized)."""
    start = faces.ravel()
    end = faces[:, [1, 2, 0]].ravel()
    low = np.minimum(start, end)
    high = np.maximum(start, end)
    _, edge, valence = np.unique(
        low * np.int64(n_vertices) + high, return_inverse=True, return_counts=True
    )
    edge = edge.ravel()
    order = np.argsort(edge, kind="stable")
    first_of_edge = np.cumsum(valence) - valence
    interior = np.flatnonzero(valence == 2)
    return _Edges(
        start=start,
        end=end,
        edge=edge,
        valence=valence,
        pair_first=order[first_of_edge[interior]],
        pair_second=order[first_of_edge[interior] + 1],
    )


def _is_closed(faces: IntArray, n_vertices: int) -> bool:
    """True when every edge has exactly two faces."""
    return bool(np.all(_edges(faces, n_vertices).valence == 2))


def _closed_message(genus: int = 0) -> str:
    """InputError text for a surface without boundary."""
    handles = f", genus {genus}" if genus > 0 else ""
    return (
        f"surface is closed (no boundary{handles}); cut it open into a disk-like patch, "
        "e.g. remove the faces of one region"
    )


#: A disk's boundary is mapped onto a rectangle, one boundary vertex per corner.
MIN_BOUNDARY_VERTICES = 4


def check_disk_topology(faces: IntArray, n_vertices: int) -> None:
    """Raise InputError unless the faces form an oriented topological disk.

    Checks, in this order: edge-manifold, one connected piece, vertex-manifold, consistent
    orientation (and orientability), a boundary, one boundary loop, genus 0.

    Parameters
    ----------
    faces : (m, 3) int
        Non-degenerate triangles; every vertex ``0..n_vertices-1`` referenced.
    n_vertices : int
    """
    n_faces = len(faces)
    edges = _edges(faces, n_vertices)
    crowded = int((edges.valence > 2).sum())
    if crowded:
        raise InputError(
            f"surface is not edge-manifold: {_count(crowded, 'edge')} shared by more than two "
            "faces; remove the extra faces (fins, duplicated or intersecting sheets)"
        )
    # Pieces that share no vertex are separate; patches that touch at a vertex only (one
    # piece by vertices, several by edges) are a bow-tie, found with the pinched vertices.
    faces_at = sp.coo_matrix(
        (np.ones(faces.size), (np.repeat(np.arange(n_faces), 3), faces.ravel())),
        shape=(n_faces, n_vertices),
    ).tocsr()
    n_pieces, _ = connected_components(faces_at @ faces_at.T, directed=False)
    if n_pieces > 1:
        raise InputError(
            f"mesh has {n_pieces} separate pieces (connected components); keep one patch and "
            "delete the others"
        )
    pinched = _count_pinched_vertices(faces, edges, n_vertices)
    if pinched:
        raise InputError(
            f"surface is not vertex-manifold: at {_count(pinched, 'vertex', 'vertices')} "
            "separate fans of faces touch (bow-tie); split or remove the faces meeting there"
        )
    same_direction = edges.start[edges.pair_first] == edges.start[edges.pair_second]
    if same_direction.any():
        raise InputError(_orientation_message(faces, n_vertices))
    boundary = edges.valence[edges.edge] == 1  # per half-edge
    n_edges = len(edges.valence)
    euler = n_vertices - n_edges + n_faces
    if not boundary.any():
        raise InputError(_closed_message((2 - euler) // 2))
    n_loops = _count_boundary_loops(edges.start[boundary], edges.end[boundary], n_vertices)
    genus = (2 - n_loops - euler) // 2
    if n_loops > 1 and genus > 0:
        raise InputError(
            f"surface has {n_loops} boundary loops and genus {genus} (Euler characteristic "
            f"{euler}; a disk has 1 loop and characteristic 1); fill all holes but the outer "
            "boundary and cut the handles open"
        )
    if n_loops > 1:
        holes = n_loops - 1
        raise InputError(
            f"surface has {n_loops} boundary loops ({_count(holes, 'hole')}); "
            "fill all holes but the outer boundary so that one boundary loop remains"
        )
    n_boundary = int(boundary.sum())
    if genus == 0 and n_boundary < MIN_BOUNDARY_VERTICES:
        raise InputError(
            f"the boundary has only {n_boundary} vertices, and the flattening maps it onto a "
            f"rectangle with {MIN_BOUNDARY_VERTICES} corners; subdivide the mesh (e.g. MeshLab "
            "Filters > Remeshing > Subdivision Surfaces) and export again"
        )
    if genus > 0:
        raise InputError(
            f"surface has genus {genus} (Euler characteristic {euler}, a disk has 1): it has "
            f"{_count(genus, 'handle')}; cut {'them' if genus > 1 else 'it'} open (or cut the "
            "patch smaller) so that it becomes a disk"
        )


def _count_pinched_vertices(faces: IntArray, edges: _Edges, n_vertices: int) -> int:
    """Number of vertices whose incident faces form more than one edge-connected fan."""
    n_corners = 3 * len(faces)
    first, second = edges.pair_first, edges.pair_second
    start_a, end_a = first, 3 * (first // 3) + (first % 3 + 1) % 3
    start_b, end_b = second, 3 * (second // 3) + (second % 3 + 1) % 3
    same = edges.start[first] == edges.start[second]
    # join the two corners at each end vertex of every interior edge
    rows = np.concatenate([start_a, end_a])
    cols = np.concatenate([np.where(same, start_b, end_b), np.where(same, end_b, start_b)])
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_corners, n_corners))
    n_labels, labels = connected_components(graph, directed=False)
    corner_vertex = faces.ravel()
    fans = np.unique(corner_vertex * np.int64(n_labels) + labels) // n_labels
    return int((np.bincount(fans, minlength=n_vertices) > 1).sum())


def _orientation_message(faces: IntArray, n_vertices: int) -> str:
    """InputError text for inconsistent orientation: how many faces are flipped, or Möbius."""
    oriented, _ = igl.bfs_orient(np.ascontiguousarray(faces, dtype=np.int64))
    reoriented = _edges(oriented, n_vertices)
    still_bad = reoriented.start[reoriented.pair_first] == reoriented.start[reoriented.pair_second]
    if still_bad.any():
        return (
            "surface is not orientable (one-sided, like a Moebius strip); it cannot be "
            "flattened, cut it so that it has two sides"
        )
    kept = (
        np.all(oriented == faces, axis=1)
        | np.all(oriented == faces[:, [1, 2, 0]], axis=1)
        | np.all(oriented == faces[:, [2, 0, 1]], axis=1)
    )
    flipped = int(min((~kept).sum(), kept.sum()))
    return (
        f"faces are inconsistently oriented (inverted triangles): {flipped} of {len(faces)} "
        "faces are flipped relative to their neighbours; re-orient them consistently "
        "(e.g. MeshLab 'Re-Orient all faces coherently') and export again"
    )


def _count_boundary_loops(start: IntArray, end: IntArray, n_vertices: int) -> int:
    """Number of connected components of the boundary-edge graph."""
    graph = sp.coo_matrix((np.ones(len(start)), (start, end)), shape=(n_vertices, n_vertices))
    _, labels = connected_components(graph, directed=False)
    return len(np.unique(labels[start]))
