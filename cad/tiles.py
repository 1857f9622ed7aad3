"""Exact planar-faced B-rep tiles from the eight vertices of a quad frustum.

Vertex order (CONTRACTS.md): top corners 0..3 counter-clockwise seen from outside (above), then
bottom corners 4..7 under them.  Faces, each counter-clockwise seen from outside:

* top ``(0, 1, 2, 3)``, bottom ``(4, 7, 6, 5)``;
* side ``k`` (from corner ``k`` to ``k + 1``): ``(k, 4 + k, 4 + (k + 1) % 4, (k + 1) % 4)``.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRepBuilderAPI import BRepBuilderAPI_Transform
from OCP.gp import gp_Trsf
from scipy.spatial import ConvexHull, HalfspaceIntersection

from drawstring.cad.kernel import polyhedron_solid
from drawstring.cad.paths import FACE_BOTTOM, FACE_INDICES, FACE_TOP, SOLID_FACES, face_planes
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.rigid import apply_rigid, rigid_fit
from drawstring.geometry.core.tolerances import CAD_MAX_FACE_DEVIATION_MM, CAD_PLANAR_EXACT_MM

log = logging.getLogger(__name__)


def face_deviation(vertices: NDArray[np.float64]) -> float:
    """Largest distance (mm) of a vertex from the best-fit plane of a face it belongs to."""
    centroids, normals = face_planes(vertices)
    quads = np.asarray(vertices, dtype=np.float64)[FACE_INDICES]
    return float(np.abs(np.einsum("fkd,fd->fk", quads - centroids[:, None], normals)).max())


def snap_to_planes(vertices: NDArray[np.float64]) -> NDArray[np.float64]:
    """Move each vertex to the intersection of the best-fit planes of its three faces.

    The result has exactly planar faces and differs from the input by about the input's face
    deviation.

    Parameters
    ----------
    vertices : (8, 3) float, mm.

    Returns
    -------
    (8, 3) float, mm.
    """
    centroids, normals = face_planes(vertices)
    offsets = np.einsum("fd,fd->f", centroids, normals)
    corner = np.arange(8) % 4
    cap = np.where(np.arange(8) < 4, FACE_TOP, FACE_BOTTOM)
    rows = np.stack([cap, corner, (corner - 1) % 4], axis=1)  # (8, 3) faces meeting at a vertex
    matrices = normals[rows]  # (8, 3, 3)
    rhs = offsets[rows]  # (8, 3)
    return np.asarray(np.linalg.solve(matrices, rhs[..., None])[..., 0])


def mesh_volume(vertices: NDArray[np.float64]) -> float:
    """Signed volume (mm^3) of the tile mesh, quads split along their 0-2 diagonal."""
    quads = np.asarray(vertices, dtype=np.float64)[FACE_INDICES]
    first = np.einsum("fd,fd->f", quads[:, 0], np.cross(quads[:, 1], quads[:, 2]))
    second = np.einsum("fd,fd->f", quads[:, 0], np.cross(quads[:, 2], quads[:, 3]))
    return float((first + second).sum() / 6.0)


def tile_solid(vertices: NDArray[np.float64]) -> bd.Solid:
    """Exact planar-faced B-rep of one tile.

    Parameters
    ----------
    vertices : (8, 3) float, mm, in the contract's vertex order.

    Returns
    -------
    build123d.Solid with six planar faces, twelve edges and eight vertices, closed and outward.
    Faces whose vertices deviate from a plane by more than ``CAD_PLANAR_EXACT_MM`` are first
    snapped (:func:`snap_to_planes`); beyond ``CAD_MAX_FACE_DEVIATION_MM`` the tile is rejected.
    """
    return polyhedron_solid(tile_solid_vertices(vertices), SOLID_FACES)


def tile_solid_vertices(vertices: NDArray[np.float64]) -> NDArray[np.float64]:
    """The vertices :func:`tile_solid` builds its solid on: checked, and snapped to planes
    where a face deviates from one by more than ``CAD_PLANAR_EXACT_MM``."""
    points = np.asarray(vertices, dtype=np.float64)
    if points.shape != (8, 3) or not np.all(np.isfinite(points)):
        raise InternalError(f"a tile needs (8, 3) finite vertices, got shape {points.shape}")
    if mesh_volume(points) <= 0.0:
        raise InternalError(
            "tile has non-positive volume: order corners counter-clockwise seen from the top, "
            "top corners 0..3 then bottom corners 4..7"
        )
    deviation = face_deviation(points)
    if deviation > CAD_MAX_FACE_DEVIATION_MM:
        raise InternalError(
            f"tile face is not planar (deviation {deviation:.3g} mm > "
            f"{CAD_MAX_FACE_DEVIATION_MM} mm)"
        )
    if deviation > CAD_PLANAR_EXACT_MM:
        points = snap_to_planes(points)
    return points


def relieved_tile_solid(
    vertices: NDArray[np.float64], cuts: Sequence[NDArray[np.float64]]
) -> bd.Solid:
    """:func:`tile_solid` cut by planes: what of the tile lies on the kept side ``n . x >= d``
    of each plane ``(n_x, n_y, n_z, d)`` of ``cuts`` (mm).

    A convex tile is made as one exact B-rep, the convex polyhedron of its six face planes and
    the cut planes (no boolean: the hinge reliefs of :mod:`drawstring.cad.clearance` pass
    within a fraction of a millimetre of the hinge strips' recesses, where OCCT's cuts of
    tools that close fail).  A tile that is not convex (a dart-shaped face) is cut by a
    half-space box per plane instead.

    Raises
    ------
    InternalError
        Where the tile is not a valid block (:func:`tile_solid`) or a plane leaves its centre.
    ValueError
        Where the kernel returns no valid solid (the caller keeps the plain block).
    """
    points = np.asarray(tile_solid_vertices(vertices), dtype=np.float64)
    if not len(cuts):
        return polyhedron_solid(points, SOLID_FACES)
    centroids, normals = face_planes(points)
    planes = np.array(cuts, dtype=np.float64).reshape(-1, 4)
    # scipy's half-spaces: A x + b <= 0
    outward = np.vstack([normals, -planes[:, :3]])
    offsets = np.concatenate([np.einsum("fd,fd->f", centroids, normals), -planes[:, 3]])
    centre = points.mean(axis=0)
    if np.any(planes[:, :3] @ centre - planes[:, 3] <= 0):
        raise InternalError("a relief plane cuts through the tile's centre")
    scale = 1.0 + float(np.ptp(points, axis=0).max())
    tol = _RELIEF_TOL * scale  # one tolerance for merging corners and for a corner on a plane
    if np.any(points @ normals.T - offsets[: len(normals)] > tol):
        return _cut_by_boxes(polyhedron_solid(points, SOLID_FACES), planes, scale)
    corners = HalfspaceIntersection(np.column_stack([outward, -offsets]), centre).intersections
    unique: list[NDArray[np.float64]] = []
    for corner in corners:  # a corner where four planes meet comes out more than once
        if not any(np.linalg.norm(corner - u) <= tol for u in unique):
            unique.append(corner)
    kept = np.array(unique)
    faces: list[list[int]] = []
    for normal, offset in zip(outward, offsets, strict=True):
        on = np.flatnonzero(np.abs(kept @ normal - offset) <= tol)
        if len(on) < 3:
            continue  # a plane that only touches the polyhedron
        ring = kept[on] - kept[on].mean(axis=0)
        axis_u = ring[int(np.argmax(np.linalg.norm(ring, axis=1)))]
        axis_u = axis_u / np.linalg.norm(axis_u)
        axis_v = np.cross(normal, axis_u)  # counter-clockwise seen from outside
        faces.append([int(on[k]) for k in np.argsort(np.arctan2(ring @ axis_v, ring @ axis_u))])
    used = sorted({k for face in faces for k in face})
    remap = {k: i for i, k in enumerate(used)}
    solid = polyhedron_solid(kept[used], [[remap[k] for k in face] for face in faces])
    if not solid.is_valid:
        raise ValueError("the relieved tile is not a valid solid")
    return solid


#: Relative tolerance (times the tile's size in mm) of :func:`relieved_tile_solid`: corners
#: nearer than this are one corner, and a corner this near a plane lies on it.
_RELIEF_TOL = 1e-8


def _cut_by_boxes(block: bd.Solid, planes: NDArray[np.float64], scale: float) -> bd.Solid:
    """``block`` less, per plane ``(n, d)``, a box filling the side ``n . x < d`` near it."""
    size = 4.0 * scale
    centre = np.asarray(tuple(block.center()), dtype=np.float64)
    result: bd.Shape = block
    for plane in planes:
        length = float(np.linalg.norm(plane[:3]))
        normal = plane[:3] / length
        origin = centre - (centre @ normal - plane[3] / length) * normal
        helper = np.eye(3)[int(np.argmin(np.abs(normal)))]
        along = np.cross(normal, helper)
        along /= np.linalg.norm(along)
        across = np.cross(-normal, along)  # the box frame's y direction
        corner = origin - 0.5 * size * (along + across)
        frame = bd.Plane(origin=tuple(corner), x_dir=tuple(along), z_dir=tuple(-normal))
        result = result - bd.Solid.make_box(size, size, size, frame)
    solids = result.solids()
    if len(solids) != 1 or not solids[0].is_valid:
        raise ValueError("cutting the tile's reliefs left no single valid solid")
    return bd.Solid(solids[0].wrapped)


def tile_solids(tiles: NDArray[np.float64]) -> list[bd.Solid]:
    """:func:`tile_solid` for every tile of a (T, 8, 3) array (mm)."""
    array = np.asarray(tiles, dtype=np.float64)
    if array.ndim != 3 or array.shape[1:] != (8, 3):
        raise InternalError(f"tiles must be a (T, 8, 3) array, got shape {array.shape}")
    return [tile_solid(t) for t in array]


def convex_solid(points: NDArray[np.float64]) -> bd.Solid:
    """Exact planar-faced B-rep of the convex hull of ``points`` ((k, 3) float, mm)."""
    array = np.asarray(points, dtype=np.float64)
    hull = ConvexHull(array)
    scale = float(np.ptp(array, axis=0).max())
    planes: dict[tuple[int, ...], list[int]] = {}
    for simplex, equation in zip(hull.simplices, hull.equations, strict=True):
        key = tuple(np.round(equation / np.array([1e-7, 1e-7, 1e-7, 1e-7 * scale])).astype(int))
        planes.setdefault(key, []).extend(int(i) for i in simplex)
    used = np.unique(hull.simplices)
    remap = -np.ones(len(array), dtype=np.int64)
    remap[used] = np.arange(len(used))
    polygons: list[list[int]] = []
    for key, ids in planes.items():
        normal = np.array(key[:3], dtype=np.float64)
        normal /= np.linalg.norm(normal)
        unique = np.unique(ids)
        centre = array[unique].mean(axis=0)
        axis_u = np.cross(normal, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis_u) < 0.5:
            axis_u = np.cross(normal, [0.0, 1.0, 0.0])
        axis_u /= np.linalg.norm(axis_u)
        axis_v = np.cross(normal, axis_u)
        rel = array[unique] - centre
        order = np.argsort(np.arctan2(rel @ axis_v, rel @ axis_u))
        polygons.append([int(remap[i]) for i in unique[order]])
    return polyhedron_solid(array[used], polygons)


def rigid_transforms(
    source: NDArray[np.float64], target: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Best rigid motion (Kabsch) taking each source tile onto the target tile.

    Parameters
    ----------
    source, target : (T, 8, 3) float, mm (for example T2D and T3D).

    Returns
    -------
    transforms : (T, 4, 4) float, homogeneous matrices ``target ~ R @ source + t``.
    residual : (T,) float, mm, largest vertex distance after the motion (0 for congruent tiles).
    """
    src = np.asarray(source, dtype=np.float64)
    dst = np.asarray(target, dtype=np.float64)
    rotation, translation = rigid_fit(src, dst)
    transforms = np.zeros((len(src), 4, 4))
    transforms[:, :3, :3] = rotation
    transforms[:, :3, 3] = translation
    transforms[:, 3, 3] = 1.0
    moved = apply_rigid(rotation, translation, src)
    residual = np.linalg.norm(moved - dst, axis=2).max(axis=1)
    return transforms, residual


def apply_transform(transform: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray:
    """Apply a (4, 4) homogeneous transform to (..., 3) points (mm)."""
    array = np.asarray(points, dtype=np.float64)
    return np.asarray(array @ transform[:3, :3].T + transform[:3, 3])


def move_solid(solid: bd.Shape, transform: NDArray[np.float64]) -> bd.Shape:
    """A copy of ``solid`` moved by a rigid (4, 4) transform."""
    trsf = gp_Trsf()
    m = np.asarray(transform, dtype=np.float64)
    trsf.SetValues(*(float(m[i, j]) for i in range(3) for j in range(4)))
    moved = BRepBuilderAPI_Transform(solid.wrapped, trsf, True).Shape()
    return type(solid)(moved)
