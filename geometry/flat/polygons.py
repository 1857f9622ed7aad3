"""Exact geometry of convex pieces: polygon areas, reflex corners and the convex pieces of a
tile, clipping of convex polygons (in the plane and by a convex polyhedron), and the
penetration depth of two convex polyhedra.  The measurements of
:mod:`drawstring.geometry.flat.verify` and the hinge stage are built on them.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial import ConvexHull

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray


def polygon_area(poly: FloatArray) -> float:
    """Signed shoelace area of one 2D polygon ``(k, 2)`` (positive counter-clockwise), mm^2."""
    if len(poly) < 3:
        return 0.0
    x, y = poly[:, 0], poly[:, 1]
    return float(0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def reflex_corners(quads: ArrayLike, *, in_plane: bool = False) -> IntArray:
    """Index ``(T,)`` of the reflex corner of every simple quad, or -1 where it is convex.

    Orientation is taken from the quad's signed area, so either winding works; a quad with more
    than one non-convex corner (self-intersecting) reports its most reflex one.

    Parameters
    ----------
    quads : (T, 4, 2+) float
    in_plane : bool
        False: the corners' (x, y) are used (flat tiles).  True: (T, 4, 3) corners in any
        orientation; each corner's turn is measured about the quad's own normal (the cross
        product of its diagonals), which for quads in the (x, y) plane gives the same answer.
    """
    q = np.asarray(quads, dtype=np.float64)
    if in_plane:
        p = q[..., :3]
        normal = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
        e_in3 = p - np.roll(p, 1, axis=1)
        e_out3 = np.roll(p, -1, axis=1) - p
        turn3 = np.einsum("kci,ki->kc", np.cross(e_in3, e_out3), normal)
        worst3 = np.argmin(turn3, axis=1)
        reflex3 = np.take_along_axis(turn3, worst3[:, None], axis=1)[:, 0] < 0
        return np.asarray(np.where(reflex3, worst3, -1), dtype=np.int64)
    q = q[..., :2]
    e_in = q - np.roll(q, 1, axis=1)  # edge arriving at each corner
    e_out = np.roll(q, -1, axis=1) - q
    turn = e_in[..., 0] * e_out[..., 1] - e_in[..., 1] * e_out[..., 0]  # (T, 4)
    area2 = np.sum(q[..., 0] * np.roll(q[..., 1], -1, axis=1) - np.roll(q[..., 0], -1, axis=1)
                   * q[..., 1], axis=1)  # fmt: skip
    turn = turn * np.where(area2 < 0, -1.0, 1.0)[:, None]
    worst = np.argmin(turn, axis=1)
    reflex = np.take_along_axis(turn, worst[:, None], axis=1)[:, 0] < 0
    return np.asarray(np.where(reflex, worst, -1), dtype=np.int64)


def convex_pieces(tiles: ArrayLike, *, in_plane: bool = False) -> BoolArray:
    """Vertex masks ``(T, 2, 8)`` of the convex pieces of every 8-vertex tile.

    A tile whose top face (x, y) is convex is one piece (second mask all False).  A tile with
    a reflex top corner ``k`` (a dart-shaped quad, which strongly distorted targets can give)
    is split along the diagonal plane through corners ``k``, ``k + 2`` and the bottom corners
    under them into two convex pieces, each holding both diagonal corners.  The tile is the
    union of its pieces; its convex hull is not (it fills the notch at the reflex corner), so
    overlap and collision tests must use the pieces.  ``in_plane``: find the reflex corner in the
    top face's own plane (assembled tiles in any orientation, see :func:`reflex_corners`).
    """
    t = np.asarray(tiles, dtype=np.float64)
    n = len(t)
    masks = np.zeros((n, 2, 8), dtype=bool)
    masks[:, 0] = True
    k = reflex_corners(t[:, :4], in_plane=in_plane)
    rows = np.flatnonzero(k >= 0)
    if rows.size:
        kk = k[rows]
        keep_1 = np.stack([kk, (kk + 1) % 4, (kk + 2) % 4], axis=1)
        keep_2 = np.stack([kk, (kk + 2) % 4, (kk + 3) % 4], axis=1)
        masks[rows, 0] = False
        for piece, keep in ((0, keep_1), (1, keep_2)):
            for c in range(3):
                masks[rows, piece, keep[:, c]] = True
                masks[rows, piece, keep[:, c] + 4] = True
    return masks


def clip_convex_polygons(subject: FloatArray, clip: FloatArray) -> FloatArray:
    """Intersection of two convex counter-clockwise polygons (Sutherland-Hodgman).

    Parameters
    ----------
    subject, clip : (k, 2), (m, 2) float

    Returns
    -------
    (p, 2) float
        The intersection polygon (possibly empty).
    """
    out = np.asarray(subject, dtype=np.float64)
    m = len(clip)
    for e in range(m):
        if len(out) == 0:
            break
        a, b = clip[e], clip[(e + 1) % m]
        edge = b - a
        side = edge[0] * (out[:, 1] - a[1]) - edge[1] * (out[:, 0] - a[0])  # >= 0 inside
        nxt = np.roll(out, -1, axis=0)
        side_n = np.roll(side, -1)
        pts: list[FloatArray] = []
        for i in range(len(out)):
            if side[i] >= 0:
                pts.append(out[i])
            if (side[i] >= 0) != (side_n[i] >= 0):
                t = side[i] / (side[i] - side_n[i])
                pts.append(out[i] + t * (nxt[i] - out[i]))
        out = np.array(pts).reshape(-1, 2)
    return out


def convex_polygon_overlap(a: FloatArray, b: FloatArray) -> float:
    """Exact overlap area of two convex polygons (either orientation), mm^2."""
    a = a if polygon_area(a) >= 0 else a[::-1]
    b = b if polygon_area(b) >= 0 else b[::-1]
    return max(polygon_area(clip_convex_polygons(a, b)), 0.0)


def polygon_in_convex_polyhedron_area(
    polygon: FloatArray,
    plane_points: FloatArray,
    plane_normals: FloatArray,
    tol: float = 1e-9,
) -> float:
    """Area of the part of a planar 3D polygon inside a convex polyhedron.

    Parameters
    ----------
    polygon : (k, 3) float, mm
        Planar convex polygon.
    plane_points, plane_normals : (f, 3) float
        The polyhedron as half-spaces ``(x - p) . n <= 0`` (outward normals).
    tol : float, mm
        Points within ``tol`` outside a plane count as inside, so polygons lying on the
        polyhedron's boundary (a contact face that is also a face of the overlap) are kept.

    Returns
    -------
    float, mm^2
    """
    out = np.asarray(polygon, dtype=np.float64)
    for p, n in zip(plane_points, plane_normals, strict=True):
        side = tol - (out - p) @ n  # >= 0 inside
        inside = side >= 0
        if inside.all():
            continue  # this plane cuts nothing off
        if not inside.any():
            return 0.0
        # Sutherland-Hodgman step: keep the inside corners, add a point where an edge crosses
        kept: list[FloatArray] = []
        count = len(out)
        for i in range(count):
            j = i + 1 if i + 1 < count else 0
            if inside[i]:
                kept.append(out[i])
            if inside[i] != inside[j]:
                t = side[i] / (side[i] - side[j])
                kept.append(out[i] + t * (out[j] - out[i]))
        out = np.array(kept)
    if len(out) < 3:
        return 0.0
    cross = np.cross(out - out[0], np.roll(out, -1, axis=0) - out[0]).sum(axis=0)
    return float(0.5 * np.linalg.norm(cross))


def convex_penetration_depth(a: ArrayLike, b: ArrayLike) -> float:
    """Penetration depth of two convex polyhedra given as vertex sets (separating-axis test).

    The depth is the shortest translation that separates them: the smallest overlap of their
    projections over all directions, which for convex polyhedra is attained on a face normal of
    either hull or on the cross product of an edge of each (all are tried).

    Parameters
    ----------
    a, b : (p, 3), (q, 3) float, mm
        Vertices; each set must span 3D.

    Returns
    -------
    float, mm
        0 when they are separated or only touch.
    """
    pa = np.asarray(a, dtype=np.float64)
    pb = np.asarray(b, dtype=np.float64)
    axes: list[FloatArray] = []
    edge_dirs: list[FloatArray] = []
    for pts in (pa, pb):
        hull = ConvexHull(pts)
        axes.append(hull.equations[:, :3])
        tri = hull.simplices
        e = np.unique(np.sort(np.concatenate([tri[:, [0, 1]], tri[:, [1, 2]], tri[:, [2, 0]]]),
                                axis=1), axis=0)  # fmt: skip
        d = pts[e[:, 1]] - pts[e[:, 0]]
        edge_dirs.append(d / np.linalg.norm(d, axis=1, keepdims=True))
    cross = np.cross(edge_dirs[0][:, None, :], edge_dirs[1][None, :, :]).reshape(-1, 3)
    norm = np.linalg.norm(cross, axis=1)
    axes.append(cross[norm > 1e-9] / norm[norm > 1e-9, None])
    ax = np.concatenate(axes)
    proj_a = pa @ ax.T
    proj_b = pb @ ax.T
    overlap = np.minimum(proj_a.max(axis=0) - proj_b.min(axis=0),
                         proj_b.max(axis=0) - proj_a.min(axis=0))  # fmt: skip
    return float(max(overlap.min(), 0.0))
