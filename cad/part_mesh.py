"""The meshes of a part, made once where it is built (:func:`mesh_part`): a closed, outward
triangle mesh at the print files' tolerance, which the solid checks (interference, clearance)
measure, and the same coarsened where needed to keep within a triangle budget, which the print
files (3MF) write."""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.BRepTools import BRepTools
from OCP.StlAPI import StlAPI_Writer

#: Chordal tessellation tolerance as a fraction of the tile thickness (at least 0.02 mm).
MESH_TOLERANCE_FRACTION = 0.007
#: Angular tessellation tolerance (rad).
MESH_ANGLE_RAD = 0.4
#: Most triangles a part's mesh may have (a slicer's time and the 3MF's size grow with them):
#: a part over its budget is meshed again with twice the tolerances, up to
#: ``MESH_COARSEN_STEPS`` times.  A tile's flat faces (engraved digits included) take a few
#: hundred; its round bores the rest.
TRIANGLE_BUDGET: dict[str, int] = {"tile": 1600, "pad": 700}
MESH_COARSEN_STEPS = 2

PartKind = Literal["tile", "pad"]


@dataclass(frozen=True)
class PartMesh:
    """A closed, outward-oriented triangle mesh of one part.

    name : ``tile_<id>`` or ``pad_<hinge>``.
    kind : ``"tile"`` or ``"pad"``.
    vertices : (n, 3) float, mm.
    triangles : (m, 3) int.
    """

    name: str
    kind: PartKind
    vertices: NDArray[np.float64]
    triangles: NDArray[np.int64]

    @property
    def volume(self) -> float:
        """Enclosed volume (mm^3, positive for outward triangles)."""
        tri = self.vertices[self.triangles]
        return float(np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])).sum() / 6)


_STL_RECORD = np.dtype([("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])


def mesh_tolerance(thickness_mm: float) -> float:
    """Chordal tessellation tolerance (mm) for tiles of the given thickness."""
    return max(0.02, MESH_TOLERANCE_FRACTION * thickness_mm)


def mesh_solid(solid: bd.Shape, name: str, kind: PartKind, tolerance: float = 0.05) -> PartMesh:
    """Tessellate a solid into a closed oriented mesh within its :data:`TRIANGLE_BUDGET` and
    check that it is closed (the print mesh of :func:`mesh_part`).

    Raises
    ------
    RuntimeError
        When, at ``tolerance``, an edge is not shared by exactly two triangles with opposite
        directions.
    """
    return mesh_part(solid, name, kind, tolerance)[1]


#: A part's meshes (:func:`mesh_part`): at the tolerances asked, and within its triangle budget
#: (the same object where that one is).
PartMeshes = tuple[PartMesh, PartMesh]


def mesh_part(solid: bd.Shape, name: str, kind: PartKind, tolerance: float) -> PartMeshes:
    """A solid's closed oriented mesh at chordal ``tolerance`` (mm) and angular
    ``MESH_ANGLE_RAD``, which the solid checks measure, and its print mesh, within its
    :data:`TRIANGLE_BUDGET`.

    OCCT meshes the faces afresh (a mesh the solid carries is dropped first, so the result
    depends on the solid alone); a mesh over the budget is made again with both tolerances
    doubled (at most ``MESH_COARSEN_STEPS`` times) for the print, and where the coarser mesh
    would not be closed the finer one is kept over the budget.  The triangles are read back
    through OCCT's binary STL writer (fast, and it orients each face's triangles by the face
    orientation); coincident corners are merged (float32, exact for shared nodes).

    Raises
    ------
    RuntimeError
        When, at ``tolerance``, an edge is not shared by exactly two triangles with opposite
        directions.
    """
    budget = TRIANGLE_BUDGET[kind]
    fine = mesh = _mesh_once(solid, name, kind, tolerance, MESH_ANGLE_RAD)
    for step in range(1, MESH_COARSEN_STEPS + 1):
        if len(mesh.triangles) <= budget:
            break
        scale = 2.0**step
        try:
            mesh = _mesh_once(solid, name, kind, scale * tolerance, scale * MESH_ANGLE_RAD)
        except RuntimeError:  # too coarse to stay closed: the finer mesh, over the budget
            break
    return fine, mesh


def _mesh_once(
    solid: bd.Shape, name: str, kind: PartKind, tolerance: float, angle: float
) -> PartMesh:
    """:func:`mesh_solid` at one pair of tolerances."""
    BRepTools.Clean_s(solid.wrapped)
    BRepMesh_IncrementalMesh(solid.wrapped, tolerance, False, angle, False)
    with tempfile.TemporaryDirectory(prefix="drawstring-mesh-", dir=_SCRATCH) as folder:
        target = str(Path(folder) / "part.stl")
        writer = StlAPI_Writer()
        writer.ASCIIMode = False
        if not writer.Write(solid.wrapped, target):
            raise RuntimeError(f"OCCT could not triangulate {name}")
        records = np.fromfile(target, dtype=_STL_RECORD, offset=84)
    corners = records["corners"].reshape(-1, 3)
    unique, inverse = _unique_rows(corners)
    triangles = inverse.reshape(-1, 3).astype(np.int64)
    keep = (
        (triangles[:, 0] != triangles[:, 1])
        & (triangles[:, 1] != triangles[:, 2])
        & (triangles[:, 2] != triangles[:, 0])
    )
    triangles = triangles[keep]
    if not is_closed_oriented(triangles):
        raise RuntimeError(f"the tessellation of {name} is not closed and oriented")
    mesh = PartMesh(name, kind, unique.astype(np.float64), triangles)
    if mesh.volume < 0:
        mesh = PartMesh(name, kind, mesh.vertices, triangles[:, ::-1].copy())
    return mesh


#: Where the STL files of :func:`_mesh_once` go for the moment OCCT writes and numpy reads
#: them: memory where the system offers it (a file on disk costs milliseconds per part).
_SCRATCH = "/dev/shm" if os.path.isdir("/dev/shm") and os.access("/dev/shm", os.W_OK) else None


def _unique_rows(
    points: NDArray[np.float32],
) -> tuple[NDArray[np.float32], NDArray[np.int64]]:
    """The distinct rows of ``points`` in lexicographic order and each row's index among
    them (``np.unique(points, axis=0, return_inverse=True)``, by one sort of three keys)."""
    if not len(points):
        return points.reshape(0, 3), np.zeros(0, dtype=np.int64)
    order = np.lexsort((points[:, 2], points[:, 1], points[:, 0]))
    ranked = points[order]
    starts = np.empty(len(ranked), dtype=bool)
    starts[0] = True
    np.any(ranked[1:] != ranked[:-1], axis=1, out=starts[1:])
    inverse = np.empty(len(points), dtype=np.int64)
    inverse[order] = np.cumsum(starts) - 1
    return ranked[starts], inverse


def is_closed_oriented(triangles: NDArray[np.int64]) -> bool:
    """Whether every directed edge appears once and its reverse appears once (closed, oriented).

    Parameters
    ----------
    triangles : (m, 3) int.
    """
    if len(triangles) == 0:
        return False
    count = int(triangles.max()) + 1
    starts = triangles.reshape(-1)
    ends = triangles[:, [1, 2, 0]].reshape(-1)
    directed = np.sort(starts * count + ends)
    if np.any(directed[1:] == directed[:-1]):
        return False
    # each reversed edge must be in the set: the same keys, sorted
    return bool(np.array_equal(directed, np.sort(ends * count + starts)))
