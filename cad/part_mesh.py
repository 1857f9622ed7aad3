"""The meshes of a part, made once where it is built (:func:`mesh_part`): a closed, outward
triangle mesh at the print files' tolerance, which the solid checks (interference, clearance)
measure, and the same coarsened where needed to keep within a triangle budget, which the print
files (3MF) write."""

from __future__ import annotations

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
    with tempfile.TemporaryDirectory(prefix="drawstring-mesh-") as folder:
        target = str(Path(folder) / "part.stl")
        writer = StlAPI_Writer()
        writer.ASCIIMode = False
        if not writer.Write(solid.wrapped, target):
            raise RuntimeError(f"OCCT could not triangulate {name}")
        records = np.fromfile(target, dtype=_STL_RECORD, offset=84)
    corners = records["corners"].reshape(-1, 3)
    unique, inverse = np.unique(corners, axis=0, return_inverse=True)
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


def is_closed_oriented(triangles: NDArray[np.int64]) -> bool:
    """Whether every directed edge appears once and its reverse appears once (closed, oriented).

    Parameters
    ----------
    triangles : (m, 3) int.
    """
    if len(triangles) == 0:
        return False
    directed = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    unique, counts = np.unique(directed, axis=0, return_counts=True)
    if np.any(counts != 1):
        return False
    reverse = unique[:, ::-1]
    order = np.lexsort((unique[:, 1], unique[:, 0]))
    keys = unique[order]
    # Each reversed edge must be in the set.
    search = np.lexsort((reverse[:, 1], reverse[:, 0]))
    return bool(np.array_equal(keys, reverse[search]))
