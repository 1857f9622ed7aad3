"""Thin helpers over OCP (the OpenCASCADE kernel behind build123d).

build123d's own boolean wrappers clean every result (``UnifySameDomain``) and keep a history
object that cannot be pickled; the tile builder cuts hundreds of solids in worker processes, so it
calls the OCCT boolean directly: one ``BRepAlgoAPI_Cut`` with all tools at once, serial inside
the process (parallelism comes from processes), oriented bounding boxes on.
"""

from __future__ import annotations

from collections.abc import Sequence

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRep import BRep_Builder, BRep_Tool
from OCP.BRepAlgoAPI import BRepAlgoAPI_BooleanOperation, BRepAlgoAPI_Cut, BRepAlgoAPI_Fuse
from OCP.BRepBuilderAPI import (
    BRepBuilderAPI_MakeEdge,
    BRepBuilderAPI_MakeFace,
    BRepBuilderAPI_MakeVertex,
    BRepBuilderAPI_MakeWire,
)
from OCP.BRepMesh import BRepMesh_IncrementalMesh
from OCP.BRepTools import BRepTools
from OCP.collections import Array1_double, Array1_gp_Pnt, Array1_int, List_TopoDS_Shape
from OCP.Geom import Geom_BSplineCurve
from OCP.gp import gp_Dir, gp_Pln, gp_Pnt
from OCP.TopAbs import TopAbs_FACE, TopAbs_REVERSED, TopAbs_ShapeEnum, TopAbs_SOLID
from OCP.TopExp import TopExp_Explorer
from OCP.TopLoc import TopLoc_Location
from OCP.TopoDS import TopoDS, TopoDS_Shape, TopoDS_Shell, TopoDS_Solid

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import (
    CAD_INTERFERENCE_ANGLE_RAD,
    CAD_INTERFERENCE_DEFLECTION_MM,
)

#: A closed triangle mesh as manifold3d takes it: (n, 3) float32 vertices (mm) and (m, 3)
#: uint32 outward triangles.
CheckMesh = tuple[NDArray[np.float32], NDArray[np.uint32]]


def polyhedron_solid(
    vertices: NDArray[np.float64],
    faces: Sequence[Sequence[int]],
    planes: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None,
) -> bd.Solid:
    """Exact planar-faced solid from vertices and outward (counter-clockwise) polygon faces.

    Vertices and edges are shared between faces, so the shell is closed by construction (no
    sewing tolerance).  Each face must be planar; a non-planar face raises :class:`InternalError`.

    Parameters
    ----------
    vertices : (n, 3) float, mm.
    faces : polygons as vertex indices, counter-clockwise seen from outside.
    planes : each face's (Newell) normal and centre, computed together by a caller whose faces
        are planar by construction (no planarity check then); None: computed here, checked.
    """
    points = np.asarray(vertices, dtype=np.float64)
    occ_vertices = [BRepBuilderAPI_MakeVertex(gp_Pnt(*map(float, p))).Vertex() for p in points]
    edges: dict[tuple[int, int], object] = {}
    builder = BRep_Builder()
    shell = TopoDS_Shell()
    builder.MakeShell(shell)
    for face_index, polygon in enumerate(faces):
        wire_maker = BRepBuilderAPI_MakeWire()
        given = None if planes is None else (planes[0][face_index], planes[1][face_index])
        for position, start in enumerate(polygon):
            end = polygon[(position + 1) % len(polygon)]
            key = (min(start, end), max(start, end))
            if key not in edges:
                edges[key] = BRepBuilderAPI_MakeEdge(
                    occ_vertices[key[0]], occ_vertices[key[1]]
                ).Edge()
            wire_maker.Add(edges[key])
        # The face lies on the plane whose normal is the polygon's (Newell) normal, so it is
        # oriented by the vertex order (MakeFace from a bare wire picks its own orientation).
        ring = points[list(polygon)]
        if given is None:
            normal, centre = np.cross(ring, np.roll(ring, -1, axis=0)).sum(axis=0), ring.mean(0)
        else:
            normal, centre = given
        length = float(np.linalg.norm(normal))
        if length < 1e-300:
            raise InternalError(f"polyhedron face {face_index} has zero area")
        normal = normal / length
        if given is None:
            deviation = float(np.abs((ring - centre) @ normal).max())
            if deviation > 1e-7 * (1.0 + float(np.ptp(ring, axis=0).max())):
                raise InternalError(
                    f"polyhedron face {face_index} is not planar (deviation {deviation:.3g} mm)"
                )
        plane = gp_Pln(gp_Pnt(*map(float, centre)), gp_Dir(*map(float, normal)))
        face_maker = BRepBuilderAPI_MakeFace(plane, wire_maker.Wire(), True)
        if not face_maker.IsDone():
            raise RuntimeError(f"OCCT could not make polyhedron face {face_index}")
        builder.Add(shell, face_maker.Face())
    shell.Closed(True)
    solid = TopoDS_Solid()
    builder.MakeSolid(solid)
    builder.Add(solid, shell)
    return bd.Solid(solid)


def closed_polyline(points: NDArray[np.float64]) -> bd.Edge:
    """One edge around a closed polygon ((k, 3) corners, mm, not repeating the first): a
    B-spline of degree 1, which a STEP file holds as one curve and its corners."""
    corners = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    count = len(corners) + 1
    poles = Array1_gp_Pnt(1, count)
    knots, multiplicities = Array1_double(1, count), Array1_int(1, count)
    for index in range(count):
        poles.SetValue(index + 1, gp_Pnt(*map(float, corners[index % len(corners)])))
        knots.SetValue(index + 1, float(index))
        multiplicities.SetValue(index + 1, 2 if index in (0, count - 1) else 1)
    curve = Geom_BSplineCurve(poles, knots, multiplicities, 1)
    return bd.Edge(BRepBuilderAPI_MakeEdge(curve).Edge())


def _solids_in(shape: TopoDS_Shape) -> list[bd.Solid]:
    explorer = TopExp_Explorer(shape, TopAbs_SOLID)
    found: list[bd.Solid] = []
    while explorer.More():
        found.append(bd.Solid(TopoDS.Solid(explorer.Current())))
        explorer.Next()
    return found


def _run(
    operation: BRepAlgoAPI_BooleanOperation, base: bd.Shape, tools: Sequence[bd.Shape]
) -> list[bd.Solid]:
    arguments = List_TopoDS_Shape()
    arguments.Append(base.wrapped)
    tool_list = List_TopoDS_Shape()
    for tool in tools:
        tool_list.Append(tool.wrapped)
    operation.SetArguments(arguments)
    operation.SetTools(tool_list)
    operation.SetRunParallel(False)
    operation.SetUseOBB(True)
    operation.SetCheckInverted(False)
    operation.Build()
    if not operation.IsDone():
        raise RuntimeError("OCCT boolean operation failed")
    return _solids_in(operation.Shape())


def cut(base: bd.Solid, tools: Sequence[bd.Shape]) -> list[bd.Solid]:
    """``base`` minus all ``tools`` in one OCCT operation; the resulting solids (usually one)."""
    if not tools:
        return [base]
    return _run(BRepAlgoAPI_Cut(), base, tools)


def fuse(base: bd.Solid, tools: Sequence[bd.Shape]) -> bd.Solid:
    """Union of ``base`` and ``tools`` in one OCCT operation; the largest resulting solid."""
    if not tools:
        return base
    solids = _run(BRepAlgoAPI_Fuse(), base, tools)
    if len(solids) == 1:  # the usual case: no volume integration needed to pick it
        return solids[0]
    return max(solids, key=lambda s: s.volume)


def unique_subshapes(shape: TopoDS_Shape, kind: TopAbs_ShapeEnum) -> list[TopoDS_Shape]:
    """The sub-shapes of one kind in ``shape``, each once, in the order build123d lists them
    (``Shape.faces()`` and the like: first found, the last occurrence kept), without wrapping
    each in a build123d object."""
    found: dict[int, TopoDS_Shape] = {}
    explorer = TopExp_Explorer(shape, kind)
    while explorer.More():
        item = explorer.Current()
        found[hash(item)] = item
        explorer.Next()
    return list(found.values())


def bounding_box(shape: bd.Shape) -> NDArray[np.float64]:
    """(2, 3) float, mm: axis-aligned box (min row, max row) of ``shape``."""
    box = shape.bounding_box()
    return np.array([[box.min.X, box.min.Y, box.min.Z], [box.max.X, box.max.Y, box.max.Z]])


def ensure_mesh(
    shape: bd.Shape, tolerance: float, angular_tolerance: float, relative: bool = False
) -> None:
    """Attach an OCCT triangulation to ``shape`` unless it carries one at least that fine.

    The triangulation travels with the shape when it is pickled, so a worker process can mesh
    the solids it built and the parent reads the meshes without redoing the work.
    ``tolerance``: chordal deflection (fraction of edge size when ``relative``, else mm);
    ``angular_tolerance``: rad.
    """
    wrapped = shape.wrapped
    if relative or not BRepTools.Triangulation_s(wrapped, tolerance):
        BRepMesh_IncrementalMesh(wrapped, tolerance, relative, angular_tolerance, False)


def tessellate(
    shape: bd.Shape,
    tolerance: float = 0.01,
    angular_tolerance: float = 0.2,
    relative: bool = True,
) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Closed triangle mesh of ``shape`` with coincident vertices merged.

    The shape is meshed by OCCT (``BRepMesh_IncrementalMesh``) unless it already carries a mesh
    at least that fine; nodes and triangles are read straight from OCCT's triangulation (no
    per-node Python objects).  ``tolerance`` is the chordal deflection: a fraction of each
    edge's size when ``relative`` (as build123d meshes), else mm; ``angular_tolerance`` in rad.

    Returns
    -------
    V : (n, 3) float, mm.
    F : (m, 3) int, outward triangles.
    """
    ensure_mesh(shape, tolerance, angular_tolerance, relative)
    wrapped = shape.wrapped
    node_blocks: list[NDArray[np.float64]] = []
    face_blocks: list[NDArray[np.int64]] = []
    offset = 0
    explorer = TopExp_Explorer(wrapped, TopAbs_FACE)
    while explorer.More():
        face = TopoDS.Face(explorer.Current())
        explorer.Next()
        location = TopLoc_Location()
        poly = BRep_Tool.Triangulation_s(face, location)
        if poly is None:
            continue
        count = poly.NbNodes()
        nodes = np.array([poly.Node(i).Coord() for i in range(1, count + 1)], dtype=np.float64)
        if not location.IsIdentity():
            trsf = location.Transformation()
            matrix = np.array([[trsf.Value(r, c) for c in range(1, 5)] for r in range(1, 4)])
            nodes = nodes @ matrix[:, :3].T + matrix[:, 3]
        triangles = np.array(
            [poly.Triangle(i).Get() for i in range(1, poly.NbTriangles() + 1)], dtype=np.int64
        ).reshape(-1, 3)
        if face.Orientation() == TopAbs_REVERSED:
            triangles = triangles[:, [0, 2, 1]]
        node_blocks.append(nodes.reshape(-1, 3))
        face_blocks.append(triangles + (offset - 1))
        offset += count
    vertices = np.concatenate(node_blocks) if node_blocks else np.zeros((0, 3))
    faces = np.concatenate(face_blocks) if face_blocks else np.zeros((0, 3), dtype=np.int64)
    # Faces are meshed separately; shared edges carry the same nodes, so merge exact duplicates
    # (rounded far below any model length).
    key = np.round(vertices / 1e-9).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    keep = (
        (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 2] != faces[:, 0])
    )
    return vertices[first], faces[keep]


def check_mesh(shape: bd.Shape, tolerance: float = CAD_INTERFERENCE_DEFLECTION_MM) -> CheckMesh:
    """The mesh of ``shape`` the interference and clearance checks measure
    (:func:`tessellate` with an absolute chordal ``tolerance``, mm, and
    ``CAD_INTERFERENCE_ANGLE_RAD``), as manifold3d takes it."""
    vertices, faces = tessellate(shape, tolerance, CAD_INTERFERENCE_ANGLE_RAD, relative=False)
    return (
        np.ascontiguousarray(vertices, dtype=np.float32),
        np.ascontiguousarray(faces, dtype=np.uint32),
    )


def solid_checks(solid: bd.Shape) -> tuple[bool, float]:
    """Whether ``solid`` is one solid that passes BRepCheck, is closed and has volume > 0
    (False where the kernel raises while checking it), and its volume (mm^3; 0 when the
    kernel fails on it)."""
    try:
        volume = float(solid.volume)
    except Exception:  # the kernel failing on the shape: not a valid solid
        return False, 0.0
    try:
        valid = bool(
            isinstance(solid, bd.Solid) and solid.is_valid and solid.is_manifold and volume > 0.0
        )
    except Exception:
        valid = False
    return valid, volume


def clean_solid(shape: bd.Shape) -> bd.Solid:
    """A fresh :class:`build123d.Solid` around ``shape.wrapped`` (drops history; pickles)."""
    return bd.Solid(shape.wrapped)
