"""Checks measured on the built solids (not on the arrays they were built from).

* :func:`check_valid` - BRepCheck, closed (every edge between two faces), positive volume.
* :func:`interference` - intersection volumes of overlapping pairs, with manifold3d meshes.
* :func:`face_openings` - round holes in a planar face of a solid (centre, radius).
* :func:`channel_continuity` - where consecutive tiles' channel openings meet when assembled.
* :func:`pockets_paired` - where the two pockets of each magnet pair meet when assembled.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import build123d as bd
import manifold3d
import numpy as np
from numpy.typing import NDArray
from OCP.Bnd import Bnd_Box
from OCP.BRepAdaptor import BRepAdaptor_Surface
from OCP.BRepBndLib import BRepBndLib
from OCP.GeomAbs import GeomAbs_Plane
from OCP.TopAbs import TopAbs_FACE
from OCP.TopoDS import TopoDS
from scipy.spatial import cKDTree

from drawstring.cad.design import route_links
from drawstring.cad.feature_common import channel_radius
from drawstring.cad.kernel import (
    CheckMesh,
    check_mesh,
    solid_checks,
    unique_subshapes,
)
from drawstring.cad.magnets_labels import MagnetPair
from drawstring.cad.part_mesh import PartMeshes
from drawstring.cad.paths import face_planes
from drawstring.cad.tiles import apply_transform
from drawstring.geometry.core import parallel
from drawstring.geometry.core.tolerances import CAD_INTERFERENCE_DEFLECTION_MM

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


def check_valid(solids: Sequence[bd.Shape]) -> NDArray[np.bool_]:
    """(n,) bool: each shape is one solid that passes BRepCheck, is closed and has volume > 0
    (False where the kernel raises while checking it)."""
    return np.array([solid_checks(s)[0] for s in solids], dtype=bool)


def to_manifold(
    solid: bd.Shape, tolerance: float = CAD_INTERFERENCE_DEFLECTION_MM
) -> manifold3d.Manifold:
    """manifold3d solid from a tessellation of ``solid``.

    ``tolerance`` is the absolute chordal deflection (mm) of the triangles from the exact faces;
    the angle between neighbouring triangles stays below ``CAD_INTERFERENCE_ANGLE_RAD``.  A mesh
    the solid already carries is reused when it is at least that fine.
    """
    return manifold_of(check_mesh(solid, tolerance))


def manifold_of(arrays: CheckMesh) -> manifold3d.Manifold:
    """manifold3d solid of a :func:`~drawstring.cad.kernel.check_mesh`, or of a print mesh's
    arrays (made where the solid was built, :attr:`~drawstring.cad.design.CadResult.
    tile_meshes`) as float32 vertices and uint32 triangles."""
    vertices, faces = arrays
    mesh = manifold3d.Mesh(vert_properties=vertices, tri_verts=faces)
    manifold = manifold3d.Manifold(mesh)
    if manifold.status() != manifold3d.Error.NoError:
        mesh.merge()
        manifold = manifold3d.Manifold(mesh)
    if manifold.status() != manifold3d.Error.NoError:
        raise RuntimeError(f"tessellation is not a closed manifold: {manifold.status()}")
    return manifold


def part_manifolds(
    solids: Sequence[bd.Shape], made: Sequence[PartMeshes | None] = ()
) -> tuple[list[manifold3d.Manifold], NDArray[np.bool_]]:
    """manifold3d solids of those ``solids`` that mesh into a closed manifold, in order, and
    which do ((n,) bool).  ``made``: their meshes where the workers that built them made
    them (the first of each pair of :attr:`~drawstring.cad.design.CadResult.tile_meshes`;
    one per solid, None where the kernel failed), else each is meshed here
    (:func:`to_manifold`)."""
    known = list(made) if len(made) == len(solids) else [None] * len(solids)
    manifolds, meshed = [], np.zeros(len(solids), dtype=bool)
    for index, (solid, mesh) in enumerate(zip(solids, known, strict=True)):
        try:
            manifolds.append(
                manifold_of(
                    (
                        np.ascontiguousarray(mesh[0].vertices, dtype=np.float32),
                        np.ascontiguousarray(mesh[0].triangles, dtype=np.uint32),
                    )
                )
                if mesh is not None
                else to_manifold(solid)
            )
        except Exception:  # open seams, or the kernel failing to mesh it
            continue
        meshed[index] = True
    return manifolds, meshed


@dataclass(frozen=True)
class Interference:
    """Intersection volumes of the candidate pairs (bounding boxes overlap).

    pairs : (K, 2) int, index into the first and the second list.
    volumes : (K,) float, mm^3.
    """

    pairs: NDArray[np.int64]
    volumes: NDArray[np.float64]

    @property
    def max_volume(self) -> float:
        return float(self.volumes.max()) if self.volumes.size else 0.0

    def worst(self) -> tuple[int, int] | None:
        if not self.volumes.size:
            return None
        a, b = self.pairs[int(np.argmax(self.volumes))]
        return int(a), int(b)


def _boxes(meshes: Sequence[manifold3d.Manifold]) -> NDArray[np.float64]:
    return np.array([m.bounding_box() for m in meshes], dtype=np.float64).reshape(-1, 2, 3)


def _as_manifold(solid: bd.Shape | manifold3d.Manifold, tolerance: float) -> manifold3d.Manifold:
    return solid if isinstance(solid, manifold3d.Manifold) else to_manifold(solid, tolerance)


def _near_pairs(
    meshes_a: Sequence[manifold3d.Manifold],
    meshes_b: Sequence[manifold3d.Manifold],
    within: bool,
    reach: float,
) -> NDArray[np.int64]:
    """(K, 2) pairs (i in a, j in b; i < j when ``within`` one list) whose bounding boxes
    come within ``reach`` (mm) of each other."""
    boxes_a, boxes_b = _boxes(meshes_a), _boxes(meshes_b)
    if not len(boxes_a) or not len(boxes_b):
        return np.zeros((0, 2), dtype=np.int64)
    centres_a, centres_b = boxes_a.mean(axis=1), boxes_b.mean(axis=1)
    radius = 0.5 * (
        np.linalg.norm(np.ptp(boxes_a, axis=1), axis=1).max()
        + np.linalg.norm(np.ptp(boxes_b, axis=1), axis=1).max()
    )
    tree_a, tree_b = cKDTree(centres_a), cKDTree(centres_b)
    candidates = []
    for i, near in enumerate(tree_a.query_ball_tree(tree_b, radius + reach + 1e-9)):
        for j in near:
            if within and j <= i:
                continue
            if np.all(boxes_a[i, 0] - reach <= boxes_b[j, 1]) and np.all(
                boxes_b[j, 0] - reach <= boxes_a[i, 1]
            ):
                candidates.append((i, j))
    return np.array(sorted(candidates), dtype=np.int64).reshape(-1, 2)


def interference(
    solids_a: Sequence[bd.Shape | manifold3d.Manifold],
    solids_b: Sequence[bd.Shape | manifold3d.Manifold] | None = None,
    allowed_contact: set[tuple[int, int]] | None = None,
    tolerance: float = CAD_INTERFERENCE_DEFLECTION_MM,
) -> Interference:
    """Intersection volume of every pair whose bounding boxes overlap.

    Parameters
    ----------
    solids_a : solids (or their :func:`to_manifold` meshes, to reuse one tessellation across
        calls); with ``solids_b`` None, pairs within ``solids_a`` (i < j) are tested.
    solids_b : a second list; then pairs (i in a, j in b) are tested.
    allowed_contact : pairs that may touch (hinges); they are measured all the same, since a
        touching contact has no volume; listed pairs are reported for context only.
    tolerance : absolute chordal tessellation tolerance (mm, see :func:`to_manifold`); curved
        faces shared by two solids are meshed alike, so touching solids give volumes near zero
        (about ``tolerance`` times the shared curved area at most).
    """
    del allowed_contact
    meshes_a = [_as_manifold(s, tolerance) for s in solids_a]
    meshes_b = meshes_a if solids_b is None else [_as_manifold(s, tolerance) for s in solids_b]
    pairs = _near_pairs(meshes_a, meshes_b, solids_b is None, 0.0)

    def block_volumes(block: NDArray[np.int64]) -> list[float]:
        return [(meshes_a[i] ^ meshes_b[j]).volume() for i, j in block]

    # manifold3d's booleans release the GIL: blocks of pairs on threads, gathered in order
    blocks = np.array_split(pairs, max(1, min(len(pairs) // 32, 4 * parallel.thread_count())))
    volumes = np.array(
        [v for done in parallel.map_blocks(block_volumes, blocks) for v in done], dtype=np.float64
    )
    return Interference(pairs, volumes)


@dataclass(frozen=True)
class Clearances:
    """Distances between solids that come close (:func:`clearances`).

    pairs : (K, 2) int, solids closer than the search distance.
    distances : (K,) float, mm.
    """

    pairs: NDArray[np.int64]
    distances: NDArray[np.float64]

    @property
    def min_distance(self) -> float:
        return float(self.distances.min()) if self.distances.size else math.inf


def clearances(
    solids: Sequence[bd.Shape | manifold3d.Manifold],
    search_mm: float,
    tolerance: float = CAD_INTERFERENCE_DEFLECTION_MM,
) -> Clearances:
    """Every pair of ``solids`` closer than ``search_mm`` and its distance (manifold3d's
    ``min_gap`` between their tessellations, ``tolerance`` as in :func:`to_manifold`)."""
    meshes = [_as_manifold(s, tolerance) for s in solids]
    pairs = _near_pairs(meshes, meshes, True, search_mm)
    distances = np.array(
        [meshes[i].min_gap(meshes[j], search_mm) for i, j in pairs], dtype=np.float64
    )
    close = distances < search_mm
    return Clearances(pairs[close], distances[close])


def face_openings(
    solid: bd.Shape, point: NDArray[np.float64], normal: NDArray[np.float64], tol: float = 1e-6
) -> list[tuple[NDArray[np.float64], float]]:
    """Holes in the planar face(s) of ``solid`` lying in the plane (``point``, ``normal``).

    Returns
    -------
    list of (centre (3,) float mm, mean radius float mm), one per inner wire.
    """
    unit = np.asarray(normal, dtype=np.float64) / np.linalg.norm(normal)
    found = []
    for face in _near_plane_faces(solid, np.asarray(point, dtype=np.float64), unit, tol):
        centre = np.array(tuple(face.center()))
        face_normal = np.array(tuple(face.normal_at()))
        if abs(abs(face_normal @ unit) - 1.0) > 1e-6 or abs((centre - point) @ unit) > tol:
            continue
        for wire in face.inner_wires():
            middle = np.array(tuple(wire.center(bd.CenterOf.MASS)))
            samples = np.array(
                [tuple(wire.position_at(t)) for t in np.linspace(0.0, 1.0, 24, endpoint=False)]
            )
            radius = float(np.linalg.norm(samples - middle, axis=1).mean())
            found.append((middle, radius))
    return found


def _near_plane_faces(
    solid: bd.Shape, point: NDArray[np.float64], unit: NDArray[np.float64], tol: float
) -> list[bd.Face]:
    """The planar faces of ``solid``, in ``solid.faces()``'s order, that may lie in the plane
    (``point``, ``unit``) as :func:`face_openings` asks it (normal within 1e-6, centre within
    ``tol``), found from each face's plane alone: no face's centre of mass is computed for
    the many that lie elsewhere.

    A face that passes :func:`face_openings`' test has a normal ``n`` within ``sqrt(2e-6)``
    of ``+-unit`` and a centre ``c`` on its plane, so its plane passes within ``tol +
    |point - c| sqrt(2e-6)`` of ``point``; ``|point - c|`` is at most the distance from
    ``point`` to the far corner of the solid's bounding box.  The bounds kept here are
    looser still, so no such face is left out."""
    box = Bnd_Box()
    BRepBndLib.Add_s(solid.wrapped, box, False)  # encloses the solid, maybe loosely
    low, high = np.array([box.CornerMin().Coord(), box.CornerMax().Coord()])
    reach = float(np.linalg.norm(np.maximum(np.abs(point - low), np.abs(high - point))))
    within = tol + 2e-3 * reach + 1e-6
    (ux, uy, uz), (px, py, pz) = unit.tolist(), point.tolist()
    faces = []
    for face in unique_subshapes(solid.wrapped, TopAbs_FACE):
        surface = BRepAdaptor_Surface(TopoDS.Face(face))
        if surface.GetType() != GeomAbs_Plane:
            continue
        plane = surface.Plane()
        ax, ay, az = plane.Axis().Direction().Coord()
        if abs(abs(ax * ux + ay * uy + az * uz) - 1.0) > 1e-4:
            continue
        ox, oy, oz = plane.Location().Coord()
        if abs((px - ox) * ax + (py - oy) * ay + (pz - oz) * az) > within:
            continue
        faces.append(bd.Face(face))
    return faces


#: Depth (mm) under a side face's centroid at which :func:`_opening` probes for a channel whose
#: opening a trim cut away.
_OPEN_PROBE_MM = 0.05


def _opening(
    solid: bd.Shape,
    tile: NDArray[np.float64],
    side: int,
    radius: float,
    trimmed_open: bool = False,
) -> NDArray[np.float64] | None:
    """Centre of the hole in side face ``side`` whose radius is closest to ``radius`` (None
    where there is none, or the kernel raises while looking).

    With ``trimmed_open`` (string channels, which start at the face's centroid): only holes
    within a quarter of ``radius`` of it count, and where none is left in the face because a
    trim (``--hinges top``) cut the face away around it, the
    centroid counts as the opening when the solid is open just under it; the channel runs on
    from the trimmed pocket, and the string passes.
    """
    centroids, normals = face_planes(tile)
    try:
        holes = face_openings(solid, centroids[side], normals[side])
        if trimmed_open:  # only a hole of the channel's size is the channel's
            holes = [h for h in holes if abs(h[1] - radius) <= 0.25 * radius]
        if not holes and trimmed_open:
            probe = centroids[side] - _OPEN_PROBE_MM * normals[side]
            if not solid.is_inside(bd.Vector(*(float(c) for c in probe))):
                return np.asarray(centroids[side])
    except Exception:  # the kernel failing on the solid: the opening counts as missing
        return None
    if not holes:
        return None
    centre, _ = min(holes, key=lambda h: abs(h[1] - radius))
    return centre


@dataclass(frozen=True)
class OpeningMatch:
    """Distances (mm) between openings that should meet in the assembled pose.

    links : (K, 4) int ``(tile_a, side_a, tile_b, side_b)``.
    distances : (K,) float, mm; ``inf`` where an opening was not found on the solid.
    """

    links: NDArray[np.int64]
    distances: NDArray[np.float64]

    @property
    def max_distance(self) -> float:
        return float(self.distances.max()) if self.distances.size else 0.0


def _match(
    tile_solids: Sequence[bd.Shape],
    tiles_flat: NDArray[np.float64],
    transforms: NDArray[np.float64],
    links: NDArray[np.int64],
    radius: float,
    trimmed_open: bool = False,
) -> OpeningMatch:
    distances = np.full(len(links), np.inf)
    for index, (tile_a, side_a, tile_b, side_b) in enumerate(links):
        centre_a = _opening(tile_solids[tile_a], tiles_flat[tile_a], side_a, radius, trimmed_open)
        centre_b = _opening(tile_solids[tile_b], tiles_flat[tile_b], side_b, radius, trimmed_open)
        if centre_a is None or centre_b is None:
            continue
        placed_a = apply_transform(transforms[tile_a], centre_a)
        placed_b = apply_transform(transforms[tile_b], centre_b)
        distances[index] = float(np.linalg.norm(placed_a - placed_b))
    return OpeningMatch(np.asarray(links, dtype=np.int64).reshape(-1, 4), distances)


def channel_continuity(
    tile_solids: Sequence[bd.Shape],
    tiles_flat: NDArray[np.float64],
    transforms: NDArray[np.float64],
    route_steps: NDArray[np.int64],
    profile: Profile,
) -> OpeningMatch:
    """Distance between each channel exit and the next tile's entry in the assembled pose.

    Openings are measured on the flat solids (the hole in the side face, or where a trim cut
    the face away around it the face's centroid, see :func:`_opening`) and moved by the
    tiles' rigid flat-to-assembled transforms (``CadResult.transforms``).
    """
    links = route_links(route_steps)
    return _match(tile_solids, tiles_flat, transforms, links, channel_radius(profile), True)


def pockets_paired(
    tile_solids: Sequence[bd.Shape],
    tiles_flat: NDArray[np.float64],
    transforms: NDArray[np.float64],
    magnets: Sequence[MagnetPair],
) -> tuple[OpeningMatch, NDArray[np.float64]]:
    """Distance between the two pockets of each magnet pair in the assembled pose, and the dot
    product of their face normals there (-1 when the pockets face each other)."""
    links = np.array([(m.tile_a, m.side_a, m.tile_b, m.side_b) for m in magnets], dtype=np.int64)
    links = links.reshape(-1, 4)
    radius = magnets[0].diameter_mm / 2 if magnets else 0.0
    match = _match(tile_solids, tiles_flat, transforms, links, radius)
    facing = np.zeros(len(links))
    for index, (tile_a, side_a, tile_b, side_b) in enumerate(links):
        normal_a = transforms[tile_a, :3, :3] @ face_planes(tiles_flat[tile_a])[1][side_a]
        normal_b = transforms[tile_b, :3, :3] @ face_planes(tiles_flat[tile_b])[1][side_b]
        facing[index] = float(normal_a @ normal_b)
    return match, facing
