"""Filling the engraved tile numbers of a solid again, for the STEP files
(:func:`fill_engraving`): the pockets' faces taken out and the bottom face closed over them,
without a boolean, with the pockets' outlines as the numbers' drawing."""

from __future__ import annotations

import logging
from collections.abc import Sequence

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRep import BRep_Builder, BRep_Tool
from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepCheck import BRepCheck_Analyzer, BRepCheck_NoError, BRepCheck_Shell
from OCP.BRepTools import BRepTools_ReShape, BRepTools_WireExplorer
from OCP.TopAbs import (
    TopAbs_EDGE,
    TopAbs_FACE,
    TopAbs_FORWARD,
    TopAbs_SHELL,
    TopAbs_VERTEX,
)
from OCP.TopExp import TopExp_Explorer
from OCP.TopoDS import TopoDS, TopoDS_Face, TopoDS_Iterator, TopoDS_Shape, TopoDS_Wire
from scipy.spatial import ConvexHull

from drawstring.cad.feature_common import TOOL_OVERSHOOT_MM
from drawstring.cad.kernel import unique_subshapes as _unique

log = logging.getLogger(__name__)


def fill_engraving(
    solid: bd.Solid, engraving: bd.Shape, depth: float, volume: float | None = None
) -> tuple[bd.Solid, list[NDArray[np.float64]]] | None:
    """``solid`` with the pockets that ``engraving``
    (:func:`~drawstring.cad.magnets_labels.label_engraving`) cut into its bottom face filled
    again: the pockets' faces taken out and the holes they left in the bottom face closed,
    the rest of the B-rep kept as it is (no boolean; milliseconds).

    A face is a pocket's when all its vertices lie in one of the engraving's convex prisms.
    Returns the filled solid and the pockets' rims (each the (k, 3) corners of a closed
    polygon on the bottom face, in order: the outlines of the engraved digits), or None where
    the result is not one valid solid whose volume is ``solid``'s (``volume`` where the caller
    measured it) plus the pockets' (the prisms' volume below the face, ``depth`` of their
    ``depth + TOOL_OVERSHOOT_MM``), for example where a pocket met another feature.  Valid is
    checked where the result differs from ``solid`` (:func:`_filled_valid`): ``solid`` is the
    checked result of the tile's cut.
    """
    prisms = engraving.solids()
    corners = [_corners_of(prism) for prism in prisms]
    normals, offsets = _stacked(
        [_halfspaces(prism, points) for prism, points in zip(prisms, corners, strict=True)]
    )
    faces = _unique(solid.wrapped, TopAbs_FACE)
    removed, pocket_edges = _ShapeSet(), _ShapeSet()
    for face in _maybe_in_prisms(faces, normals, offsets):
        points = np.array(
            [BRep_Tool.Pnt_s(TopoDS.Vertex(v)).Coord() for v in _unique(face, TopAbs_VERTEX)]
        ).reshape(-1, 3)
        # inside a prism: every point on the inner side of each of its faces
        if len(points) and bool(np.any(_inside(points, normals, offsets))):
            removed.Add(face)
            for edge in _unique(face, TopAbs_EDGE):
                pocket_edges.Add(edge)
    if not removed:
        return None
    reshape = BRepTools_ReShape()
    builder = BRep_Builder()
    rims: list[NDArray[np.float64]] = []
    rebuilt: list[TopoDS_Face] = []
    for face in faces:
        if removed.Contains(face):
            reshape.Remove(face)
            continue
        kept, dropped = [], False
        wires = TopoDS_Iterator(face.Oriented(TopAbs_FORWARD))
        while wires.More():
            wire = wires.Value()
            wires.Next()
            edges = TopExp_Explorer(wire, TopAbs_EDGE)
            inside = True
            while edges.More() and inside:
                inside = pocket_edges.Contains(edges.Current())
                edges.Next()
            if inside:
                dropped = True
                rims.append(_corners(TopoDS.Wire(wire)))
            else:
                kept.append(wire)
        if dropped:  # the same surface and edges, without the pockets' rims
            wrapped = TopoDS.Face(face)
            closed = TopoDS_Face()
            surface = BRep_Tool.Surface_s(wrapped)
            builder.MakeFace(closed, surface, wrapped.Location(), BRep_Tool.Tolerance_s(wrapped))
            for wire in kept:
                builder.Add(closed, wire)
            closed.Orientation(wrapped.Orientation())
            reshape.Replace(wrapped, closed)
            rebuilt.append(closed)
    try:
        filled = bd.Solid(reshape.Apply(solid.wrapped))
        prism_volume = sum(float(ConvexHull(points).volume) for points in corners)
        pockets = prism_volume * depth / (depth + TOOL_OVERSHOOT_MM)
        if len(filled.solids()) != 1 or not _filled_valid(filled, rebuilt):
            return None
        expected = (solid.volume if volume is None else volume) + pockets
    except Exception as exc:  # the kernel's own errors: keep the engraved solid
        log.debug("filling an engraving failed: %s: %s", type(exc).__name__, exc)
        return None
    if abs(filled.volume - expected) > 1e-6 * max(expected, 1.0):
        return None
    return filled, rims


def _inside(
    points: NDArray[np.float64], normals: NDArray[np.float64], offsets: NDArray[np.float64]
) -> NDArray[np.bool_]:
    """(P,) whether all ``points`` ((k, 3)) lie in each prism (:func:`_stacked`), to 1e-5 mm."""
    return np.asarray(np.all(points @ normals - offsets <= 1e-5, axis=(1, 2)))


def _maybe_in_prisms(
    faces: list[TopoDS_Shape], normals: NDArray[np.float64], offsets: NDArray[np.float64]
) -> list[TopoDS_Shape]:
    """The ``faces`` (in order) whose first vertex lies in a prism: only those can have all
    their vertices in one, so the others are passed over without listing their vertices."""
    firsts, kept = [], []
    for face in faces:
        explorer = TopExp_Explorer(face, TopAbs_VERTEX)
        if explorer.More():
            firsts.append(BRep_Tool.Pnt_s(TopoDS.Vertex(explorer.Current())).Coord())
            kept.append(face)
    if not kept:
        return []
    points = np.array(firsts, dtype=np.float64)[:, None, None, :]  # (F, 1, 1, 3)
    # per face and prism: the point on the inner side of each of the prism's faces (a
    # nanometre looser than :func:`_inside`, which decides on the faces passed on)
    inside = np.all(points @ normals - offsets <= 1e-5 + 1e-9, axis=(2, 3))  # (F, P)
    return [face for face, hit in zip(kept, inside.any(axis=1), strict=True) if hit]


def _filled_valid(filled: bd.Solid, rebuilt: Sequence[TopoDS_Face]) -> bool:
    """Whether the solid :func:`fill_engraving` made passes BRepCheck where it differs from
    the engraved solid, which its builder checked whole: each face rebuilt without its
    pockets' rims (surface, wires, edges) and each shell (closed, consistently oriented,
    with the pockets' faces gone)."""
    for face in rebuilt:
        if not BRepCheck_Analyzer(face).IsValid():
            return False
    for shell in _unique(filled.wrapped, TopAbs_SHELL):
        check = BRepCheck_Shell(TopoDS.Shell(shell))
        if check.Closed(False) != BRepCheck_NoError:
            return False
        if check.Orientation(False) != BRepCheck_NoError:
            return False
    return True


def _corners_of(prism: bd.Solid) -> NDArray[np.float64]:
    """(k, 3) the corners of a solid, each once."""
    return np.array(
        [BRep_Tool.Pnt_s(TopoDS.Vertex(v)).Coord() for v in _unique(prism.wrapped, TopAbs_VERTEX)],
        dtype=np.float64,
    ).reshape(-1, 3)


class _ShapeSet:
    """Shapes kept once each as build123d's sets keep them: by hash, then ``IsSame`` (the
    same TShape and location, whatever the orientation)."""

    def __init__(self) -> None:
        self._by_hash: dict[int, list[TopoDS_Shape]] = {}

    def Add(self, shape: TopoDS_Shape) -> None:  # noqa: N802 (OCCT's map names)
        if not self.Contains(shape):
            self._by_hash.setdefault(hash(shape), []).append(shape)

    def Contains(self, shape: TopoDS_Shape) -> bool:  # noqa: N802
        return any(shape.IsSame(known) for known in self._by_hash.get(hash(shape), ()))

    def __bool__(self) -> bool:
        return bool(self._by_hash)


def _corners(wire: TopoDS_Wire) -> NDArray[np.float64]:
    """(k, 3) the vertices of a closed wire in the order its edges run."""
    explorer = BRepTools_WireExplorer(wire)
    points = []
    while explorer.More():
        point = BRep_Tool.Pnt_s(explorer.CurrentVertex())
        points.append((point.X(), point.Y(), point.Z()))
        explorer.Next()
    return np.array(points, dtype=np.float64).reshape(-1, 3)


def _halfspaces(
    prism: bd.Solid, corners: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(normals, offsets)`` of a convex planar-faced solid with these ``corners``
    (:func:`_corners_of`): inside is ``normals @ x <= offsets`` (outward normals), from the
    planes of its faces."""
    # any point inside tells the faces' outward side: the mean of the corners of the convex
    # prism (no volume integral)
    middle = np.mean(corners, axis=0)
    normals, offsets = [], []
    for face in _unique(prism.wrapped, TopAbs_FACE):
        plane = BRepAdaptor_Surface(TopoDS.Face(face)).Plane()
        n = np.array(plane.Axis().Direction().Coord())
        p = np.array(plane.Location().Coord())
        if n @ (middle - p) > 0:
            n = -n
        normals.append(n)
        offsets.append(n @ p)
    return np.array(normals), np.array(offsets)


def _stacked(
    halfspaces: list[tuple[NDArray[np.float64], NDArray[np.float64]]],
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The prisms' :func:`_halfspaces` as (P, 3, F) normals and (P, 1, F) offsets, padded with
    planes every point is inside of (a zero normal and offset) where a prism has fewer faces."""
    most = max((len(n) for n, _ in halfspaces), default=0)
    normals = np.zeros((len(halfspaces), 3, most))
    offsets = np.zeros((len(halfspaces), 1, most))
    for index, (n, d) in enumerate(halfspaces):
        normals[index, :, : len(n)] = n.T
        offsets[index, 0, : len(d)] = d
    return normals, offsets
