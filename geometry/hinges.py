"""Hinge placement on the flat tiles T2D (paper section 4.4).

Hinge side
----------
Every tile corner has a top vertex ``P`` and the bottom vertex ``Q`` under it; in T3D the four
tiles around a grid vertex share ``P`` and ``Q`` (contact faces are shared).  Flattening keeps
each tile rigid, so near a hinge each tile occupies, below its top corner, whatever its side
faces reach.  For tile ``a`` at hinge corner ``c`` let ``d = Q - P`` projected on ``a``'s top
plane and ``m1, m2`` the inward unit normals (in that plane) of ``a``'s two top sides at ``c``.
The *bottom overhang* of ``a`` at the hinge is ``max(0, -min(d.m1, d.m2))``: how far the bottom
corner pokes out of the top face's corner wedge.  The *top overhang* is the same with roles
swapped (``P - Q`` against the bottom face's sides).  With a top hinge the two tiles touch at
``P``; overhanging bottoms of both tiles then overlap near the hinge, and vice versa.  We place
the hinge at the **bottom when the summed bottom overhang of both tiles exceeds their summed top
overhang** (by more than ``HINGE_SIDE_TOL_REL`` times the thickness), otherwise at the top.

This is the paper's criterion made measurable: the bottom overhangs when the side faces at the
corner lean outward, i.e. the dihedral angle between the top face and the contact face exceeds
90 deg, which happens exactly where the target's normal curvature across that face is negative
(concave seen from the top).  Outside of a cylinder: no overhang below, all top; inside of a
cylinder: bottoms overhang along the curved direction at every corner, all bottom.

Strategies
----------
``top``: all hinges at the top.  The region where two hinged tiles overlap in the flat pose is
computed exactly (convex hulls intersected with manifold3d); it is to be removed from the tile
with the larger id, and the side-face (contact) area it takes away is reported.
``dual``: sides as above, then the rigid-tile layout ``w_rigid E_rigid + w_collision E_collision
+ w_conn E_conn`` (18 edges per tile; conservative non-interpenetration: every vertex of a
hinged pair stays on its side of a vertical plane through the hinge along the gap's bisector;
paired hinge vertices to their midpoint), then every hinge pair is merged into one vertex.
"""

from __future__ import annotations

import json
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
from drawstring.geometry.constraints import HalfPlane3D, HingeConnection
from drawstring.geometry.errors import InputError
from drawstring.geometry.flat import FlatResult
from drawstring.geometry.linkage import Linkage
from drawstring.geometry.solver import EdgeLength, LocalGlobalSolver
from drawstring.geometry.tolerances import HINGE_GAP_TOL_MM
from drawstring.geometry.verify import (
    RIGID_EDGES,
    TILE_FACES,
    hinge_gaps,
    polygon_in_convex_polyhedron_area,
)
from numpy.typing import ArrayLike, NDArray

logger = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
IntArray = NDArray[np.int64]
HingeStrategy = Literal["dual", "top"]
HingeSide = Literal["top", "bottom"]

#: A hinge goes to the bottom only when the bottom overhang exceeds the top overhang by more
#: than this fraction of the tile thickness (ties, e.g. flat targets, stay on top).
HINGE_SIDE_TOL_REL = 1e-9

__all__ = [
    "HingeLayout",
    "HingeTrim",
    "draw_flat",
    "hinge_overhangs",
    "hinge_sides",
    "hinge_vertex_json",
    "layout_hinges",
    "rigid_hinge_polish",
    "top_hinge_trims",
    "write_flat_obj",
]


def _corner_overhang(tiles: FloatArray, tile: IntArray, corner: IntArray) -> tuple[FloatArray, ...]:
    """Bottom and top overhang ``(k,)`` of tile corners (see module docstring)."""
    t = tiles[tile]  # (k, 8, 3)
    top, bottom = t[:, :4], t[:, 4:]
    normal = np.cross(top[:, 2] - top[:, 0], top[:, 3] - top[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    k = np.arange(len(tile))
    nxt, prv = (corner + 1) % 4, (corner + 3) % 4

    def overhang(face: FloatArray, other: FloatArray) -> FloatArray:
        p = face[k, corner]
        d = other[k, corner] - p
        d -= np.einsum("ki,ki->k", d, normal)[:, None] * normal
        e1 = face[k, nxt] - p  # side leaving the corner
        e2 = p - face[k, prv]  # side arriving at the corner
        m1 = np.cross(normal, e1)
        m2 = np.cross(normal, e2)
        m1 /= np.maximum(np.linalg.norm(m1, axis=1, keepdims=True), 1e-300)
        m2 /= np.maximum(np.linalg.norm(m2, axis=1, keepdims=True), 1e-300)
        inside = np.minimum(np.einsum("ki,ki->k", d, m1), np.einsum("ki,ki->k", d, m2))
        return np.asarray(np.maximum(0.0, -inside))

    return overhang(top, bottom), overhang(bottom, top)


def hinge_overhangs(linkage: Linkage, tiles_3d: ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Summed bottom and top overhang ``(H,)`` of both tiles of every hinge, mm (T3D)."""
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    h = linkage.hinges
    bot_a, top_a = _corner_overhang(tiles, h[:, 0], h[:, 1])
    bot_b, top_b = _corner_overhang(tiles, h[:, 2], h[:, 3])
    return bot_a + bot_b, top_a + top_b


def hinge_sides(linkage: Linkage, tiles_3d: ArrayLike) -> NDArray[np.bool_]:
    """Whether each hinge goes to the bottom (criterion in the module docstring).

    Parameters
    ----------
    linkage : Linkage
    tiles_3d : (T, 8, 3) float, mm
        T3D tiles.

    Returns
    -------
    (H,) bool
        True: bottom hinge; False: top hinge.
    """
    tiles = np.asarray(tiles_3d, dtype=np.float64)
    if tiles.ndim != 3 or tiles.shape[1:] != (8, 3) or len(tiles) != linkage.n_tiles:
        raise InputError(f"tiles_3d has shape {tiles.shape}; pass (T, 8, 3) T3D tiles")
    bottom, top = hinge_overhangs(linkage, tiles)
    thickness = float(np.mean(np.linalg.norm(tiles[:, :4] - tiles[:, 4:], axis=2)))
    return np.asarray(bottom - top > HINGE_SIDE_TOL_REL * max(thickness, 1e-300))


@dataclass(frozen=True)
class HingeTrim:
    """Overlap of two top-hinged tiles in the flat pose, removed from ``tile``.

    Attributes
    ----------
    hinge : int
    tile : int
        The tile trimmed (the larger id of the pair).
    vertices : (p, 3) float, mm
        Vertices of the convex overlap polyhedron (CAD subtracts their hull).
    volume_mm3 : float
    contact_area_lost_mm2 : float
        Area of the trimmed tile's side faces inside the overlap.
    """

    hinge: int
    tile: int
    vertices: FloatArray
    volume_mm3: float
    contact_area_lost_mm2: float


@dataclass(frozen=True)
class HingeLayout:
    """Flat tiles with their hinges.

    Attributes
    ----------
    strategy : "dual" | "top"
    tiles : (T, 8, 3) float, mm
        Final flat tiles (hinge pairs merged for ``dual``).
    bottom : (H,) bool
        Hinge side (True: bottom).
    hinge_vertices : (H, 2) int
        ``8 * tile + vertex`` of both tiles' hinge vertex.
    hinge_points : (H, 3) float, mm
        Hinge positions (after merging).
    hinge_gap_max_mm : float
        Max paired-vertex distance before merging.
    trims : tuple of HingeTrim
        ``top`` strategy only.
    contact_area_lost_mm2 : float
    iterations : int
    time_s : float
    problems : tuple of str
    """

    strategy: HingeStrategy
    tiles: FloatArray
    bottom: NDArray[np.bool_]
    hinge_vertices: IntArray
    hinge_points: FloatArray
    hinge_gap_max_mm: float
    trims: tuple[HingeTrim, ...] = field(default=())
    contact_area_lost_mm2: float = 0.0
    iterations: int = 0
    time_s: float = 0.0
    problems: tuple[str, ...] = field(default=())

    @property
    def sides(self) -> tuple[HingeSide, ...]:
        return tuple("bottom" if b else "top" for b in self.bottom)


def _hinge_vertex_ids(linkage: Linkage, bottom: NDArray[np.bool_]) -> IntArray:
    h = linkage.hinges
    off = np.where(bottom, 4, 0)
    return np.stack([8 * h[:, 0] + h[:, 1] + off, 8 * h[:, 2] + h[:, 3] + off], axis=1)


def top_hinge_trims(linkage: Linkage, tiles_2d: ArrayLike) -> tuple[HingeTrim, ...]:
    """Exact overlap of every top-hinged tile pair in the flat pose.

    Parameters
    ----------
    linkage : Linkage
    tiles_2d : (T, 8, 3) float, mm

    Returns
    -------
    tuple of HingeTrim
        Only hinges whose tiles overlap with positive volume.
    """
    import manifold3d as m3d

    tiles = np.asarray(tiles_2d, dtype=np.float64)
    trims: list[HingeTrim] = []
    for index, (ta, _, tb, _) in enumerate(linkage.hinges):
        a, b = int(ta), int(tb)
        overlap = m3d.Manifold.hull_points(tiles[a]) ^ m3d.Manifold.hull_points(tiles[b])
        volume = float(overlap.volume())
        if volume <= 0:
            continue
        mesh = overlap.to_mesh64()
        verts = np.asarray(mesh.vert_properties, dtype=np.float64)[:, :3]
        tris = np.asarray(mesh.tri_verts, dtype=np.int64)
        p0, p1, p2 = verts[tris[:, 0]], verts[tris[:, 1]], verts[tris[:, 2]]
        normals = np.cross(p1 - p0, p2 - p0)
        keep = np.linalg.norm(normals, axis=1) > 0
        normals = normals[keep] / np.linalg.norm(normals[keep], axis=1, keepdims=True)
        trimmed = max(a, b)
        lost = sum(
            polygon_in_convex_polyhedron_area(tiles[trimmed][face], p0[keep], normals)
            for face in TILE_FACES[2:]
        )
        trims.append(HingeTrim(index, trimmed, verts, volume, float(lost)))
    return tuple(trims)


def _separating_normals(linkage: Linkage, flat: FlatResult, tiles: FloatArray) -> FloatArray:
    """Horizontal unit normal ``(H, 3)`` of a plane through each hinge separating its tiles.

    The plane runs along the bisector of the gap whose slit ends at the hinge (the two tiles'
    corner wedges lie on either side of it); without such a gap, across the centre line.
    """
    h = linkage.hinges
    node = linkage.corner_node[h[:, 0], h[:, 1]]
    centre_dir = tiles[h[:, 2], :4, :2].mean(axis=1) - tiles[h[:, 0], :4, :2].mean(axis=1)
    normal = centre_dir.copy()
    ends = flat.junctions.ends
    apex_to_end = {int(a): i for i, a in enumerate(ends[:, 0])}
    nodes = flat.nodes
    for k, nd in enumerate(node):
        i = apex_to_end.get(int(nd))
        if i is None:
            continue
        apex, q, p = ends[i]
        u = nodes[q] - nodes[apex]
        v = nodes[p] - nodes[apex]
        bis = u / np.linalg.norm(u) + v / np.linalg.norm(v)
        if np.linalg.norm(bis) < 1e-12:
            continue
        n = np.array([-bis[1], bis[0]])
        normal[k] = n if n @ centre_dir[k] >= 0 else -n
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    return np.concatenate([normal, np.zeros((len(normal), 1))], axis=1)


def _skew_neg(r: FloatArray) -> FloatArray:
    """``-[r]_x`` for many vectors ``(k, 3) -> (k, 3, 3)``: ``-[r]_x w = w x r``."""
    z = np.zeros(len(r))
    return np.stack(
        [
            np.stack([z, r[:, 2], -r[:, 1]], -1),
            np.stack([-r[:, 2], z, r[:, 0]], -1),
            np.stack([r[:, 1], -r[:, 0], z], -1),
        ],
        -2,
    )


def _rotation_from_vectors(w: FloatArray) -> FloatArray:
    """Rodrigues: rotation matrices ``(k, 3, 3)`` of rotation vectors ``(k, 3)``."""
    theta = np.linalg.norm(w, axis=1)
    axis = w / np.maximum(theta, 1e-300)[:, None]
    k = -_skew_neg(axis)  # [axis]_x
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    eye = np.eye(3)[None]
    return np.asarray(eye + s * k + (1 - c) * np.einsum("kij,kjl->kil", k, k))


def rigid_hinge_polish(
    tiles_flat: FloatArray,
    tiles_now: FloatArray,
    pairs: IntArray,
    *,
    planes: tuple[IntArray, FloatArray] | None = None,
    w_collision: float = 100.0,
    steps: int = 20,
    step_tol: float = 1e-10,
) -> FloatArray:
    """Exactly rigid, still flat tiles placed so paired hinge vertices meet.

    Each tile keeps the shape of ``tiles_flat`` (its T2D pose: top face horizontal) and may only
    turn about the vertical axis and translate in the plane.  Its pose is first fitted to
    ``tiles_now`` (2D Procrustes), then Levenberg-Marquardt minimizes
    ``sum |x_a - x_b|^2`` over hinge pairs plus ``w_collision`` times the squared violation of
    the separating half-planes.  This is the limit ``w_rigid -> infinity`` of the paper's hinge
    energy, used as the precise finish of the local-global solve.

    Parameters
    ----------
    tiles_flat : (T, 8, 3) float, mm
        Rigid shapes in the flat pose (T2D).
    tiles_now : (T, 8, 3) float, mm
        Start layout.
    pairs : (H, 2) int
        Flat vertex ids ``8 * tile + vertex``.
    planes : ((k, 2) int, (k, 3) float), optional
        Half-plane elements ``(vertex, anchor)`` and horizontal unit normals.

    Returns
    -------
    (T, 8, 3) float, mm
    """
    import scipy.sparse as sp
    import scipy.sparse.linalg as spla

    n_t = len(tiles_flat)
    centre = tiles_flat[:, :, :2].mean(axis=1)
    local = tiles_flat[:, :, :2] - centre[:, None]
    target = tiles_now[:, :, :2] - tiles_now[:, :, :2].mean(axis=1, keepdims=True)
    cross = np.sum(local[..., 0] * target[..., 1] - local[..., 1] * target[..., 0], axis=1)
    phi = np.arctan2(cross, np.sum(local * target, axis=(1, 2)))
    trans = tiles_now[:, :, :2].mean(axis=1)
    z = tiles_flat[:, :, 2]

    def positions(phi: FloatArray, trans: FloatArray) -> FloatArray:
        c, s = np.cos(phi)[:, None], np.sin(phi)[:, None]
        x = c * local[..., 0] - s * local[..., 1] + trans[:, :1]
        y = s * local[..., 0] + c * local[..., 1] + trans[:, 1:]
        return np.stack([x, y], axis=-1)

    def point_jac(x: FloatArray, ids: IntArray, trans: FloatArray) -> FloatArray:
        """d(xy of vertex ids) / d(phi, tx, ty): (k, 2, 3)."""
        t = ids // 8
        r = x[t, ids % 8] - trans[t]
        k = len(ids)
        out = np.zeros((k, 2, 3))
        out[:, 0, 0], out[:, 1, 0] = -r[:, 1], r[:, 0]
        out[:, 0, 1] = out[:, 1, 2] = 1.0
        return out

    def residual_jac(phi: FloatArray, trans: FloatArray) -> tuple[FloatArray, sp.csr_matrix]:
        x = positions(phi, trans)
        flat = x.reshape(-1, 2)
        res_parts = [(flat[pairs[:, 0]] - flat[pairs[:, 1]]).reshape(-1)]
        h = len(pairs)
        ja, jb = point_jac(x, pairs[:, 0], trans), point_jac(x, pairs[:, 1], trans)
        rows = np.repeat(np.arange(2 * h).reshape(h, 2, 1), 3, axis=2)
        ca = np.broadcast_to(3 * (pairs[:, 0] // 8)[:, None, None] + np.arange(3), (h, 2, 3))
        cb = np.broadcast_to(3 * (pairs[:, 1] // 8)[:, None, None] + np.arange(3), (h, 2, 3))
        vals = [ja.ravel(), -jb.ravel()]
        rr = [rows.ravel(), rows.ravel()]
        cc = [ca.ravel(), cb.ravel()]
        n_rows = 2 * h
        if planes is not None and w_collision > 0 and len(planes[0]):
            el, nrm = planes
            nrm2 = nrm[:, :2]
            side = np.einsum("ki,ki->k", flat[el[:, 0]] - flat[el[:, 1]], nrm2)
            act = np.flatnonzero(side < 0)
            if act.size:
                sw = np.sqrt(w_collision)
                res_parts.append(sw * side[act])
                jv = np.einsum("kij,ki->kj", point_jac(x, el[act, 0], trans), nrm2[act])
                jn = np.einsum("kij,ki->kj", point_jac(x, el[act, 1], trans), nrm2[act])
                r_act = n_rows + np.arange(act.size)
                for ids, jj, sign in ((el[act, 0], jv, sw), (el[act, 1], jn, -sw)):
                    vals.append((sign * jj).ravel())
                    rr.append(np.repeat(r_act, 3))
                    cc.append((3 * (ids // 8)[:, None] + np.arange(3)).ravel())
                n_rows += act.size
        jac = sp.csr_matrix(
            (np.concatenate(vals), (np.concatenate(rr), np.concatenate(cc))),
            shape=(n_rows, 3 * n_t),
        )
        return np.concatenate(res_parts), jac

    res, jac = residual_jac(phi, trans)
    cost = float(res @ res)
    lam = 1e-6
    for _ in range(steps):
        if cost == 0.0:
            break
        jtj = (jac.T @ jac).tocsc()
        mu = lam * max(float(jtj.diagonal().mean()), 1e-300)
        step = spla.splu(
            (jtj + mu * sp.identity(3 * n_t, format="csc")).tocsc(),
            permc_spec="MMD_AT_PLUS_A",
            diag_pivot_thresh=0.0,
            options={"SymmetricMode": True},
        ).solve(-(jac.T @ res))
        step = step.reshape(n_t, 3)
        phi_new, trans_new = phi + step[:, 0], trans + step[:, 1:]
        res_new, jac_new = residual_jac(phi_new, trans_new)
        cost_new = float(res_new @ res_new)
        if cost_new < cost:
            done = cost - cost_new <= 1e-12 * cost or float(np.abs(step).max()) < step_tol
            phi, trans, res, jac, cost = phi_new, trans_new, res_new, jac_new, cost_new
            lam = max(0.5 * lam, 1e-12)
            if done:
                break
        else:
            lam *= 8.0
            if lam > 1e3:
                break
    return np.concatenate([positions(phi, trans), z[..., None]], axis=2)


def layout_hinges(
    linkage: Linkage,
    flat: FlatResult,
    tiles_2d: ArrayLike,
    tiles_3d: ArrayLike,
    *,
    strategy: HingeStrategy = "dual",
    w_rigid: float = 100.0,
    w_collision: float = 100.0,
    w_conn: float = 1.0,
    max_iter: int = 100,
    anderson: int = 5,
    polish_steps: int = 20,
) -> HingeLayout:
    """Place hinges and lay the rigid tiles out so paired hinge vertices meet.

    Parameters
    ----------
    linkage : Linkage
    flat : FlatResult
        K2D (used for the gap bisectors of the collision planes).
    tiles_2d : (T, 8, 3) float, mm
        T2D from :func:`~drawstring.geometry.flat.extrude_flat`.
    tiles_3d : (T, 8, 3) float, mm
        T3D (rigidity targets and hinge sides).
    strategy : "dual" | "top"
    w_rigid, w_collision, w_conn : float
        ``dual`` weights (paper defaults 100, 100, 1).
    max_iter, anderson : local-global solver options.
    polish_steps : int
        Levenberg-Marquardt steps of :func:`rigid_hinge_polish` after the local-global solve
        (tiles exactly rigid, hinge pairs least-squares); 0 to skip.

    Returns
    -------
    HingeLayout
    """
    start = time.perf_counter()
    t2 = np.asarray(tiles_2d, dtype=np.float64)
    t3 = np.asarray(tiles_3d, dtype=np.float64)
    if t2.shape != t3.shape or t2.shape[1:] != (8, 3) or len(t2) != linkage.n_tiles:
        raise InputError("tiles_2d and tiles_3d must both be (T, 8, 3) for the linkage's tiles")
    if strategy not in ("dual", "top"):
        raise InputError(f"--hinges {strategy!r} is not known; use dual or top")
    problems: list[str] = []
    if strategy == "top":
        bottom = np.zeros(linkage.n_hinges, dtype=bool)
        ids = _hinge_vertex_ids(linkage, bottom)
        gap = float(hinge_gaps(t2, ids).max(initial=0.0))
        trims = top_hinge_trims(linkage, t2)
        lost = float(sum(tr.contact_area_lost_mm2 for tr in trims))
        if trims:
            problems.append(
                f"top hinges: {len(trims)} hinged pairs overlap in the flat pose; trimmed "
                f"{sum(tr.volume_mm3 for tr in trims):.3g} mm^3, losing {lost:.3g} mm^2 of contact"
            )
        points = t2.reshape(-1, 3)[ids].mean(axis=1)
        return HingeLayout(
            strategy, t2.copy(), bottom, ids, points, gap, trims, lost, 0,
            time.perf_counter() - start, tuple(problems),
        )  # fmt: skip

    bottom = hinge_sides(linkage, t3)
    ids = _hinge_vertex_ids(linkage, bottom)
    n_vert = 8 * linkage.n_tiles
    rigid_pairs = (8 * np.arange(linkage.n_tiles)[:, None, None] + RIGID_EDGES[None]).reshape(-1, 2)
    flat3 = t3.reshape(-1, 3)
    targets = np.linalg.norm(flat3[rigid_pairs[:, 1]] - flat3[rigid_pairs[:, 0]], axis=1)
    groups: list = [
        EdgeLength(rigid_pairs, targets, weight=w_rigid, name="rigid"),
        HingeConnection(ids, weight=w_conn, name="conn"),
    ]
    planes: tuple[IntArray, FloatArray] | None = None
    if w_collision > 0 and linkage.n_hinges:
        normals = _separating_normals(linkage, flat, t2)
        elements: list[FloatArray] = []
        plane_n: list[FloatArray] = []
        h = linkage.hinges
        for side, (ta, tb), sign in (("b", (2, 0), 1.0), ("a", (0, 2), -1.0)):
            del side
            tile = h[:, ta]
            anchor = ids[:, 1 if ta == 0 else 0]
            verts = 8 * tile[:, None] + np.arange(8)[None, :]
            own = ids[:, 0 if ta == 0 else 1]
            for v in range(8):
                keep = verts[:, v] != own
                elements.append(np.stack([verts[keep, v], anchor[keep]], axis=1))
                plane_n.append(sign * normals[keep])
            del tb
        el = np.concatenate(elements)
        nm = np.concatenate(plane_n)
        # Only constrain vertices that start on the correct side (the rest is the overlap the
        # hinge side choice could not avoid; pushing them would fight rigidity).
        x0 = t2.reshape(-1, 3)
        ok = np.einsum("ki,ki->k", x0[el[:, 0]] - x0[el[:, 1]], nm) >= -1e-9
        planes = (el[ok], nm[ok])
        groups.append(HalfPlane3D(el[ok], nm[ok], weight=w_collision, name="collision"))
    solver = LocalGlobalSolver(n_vert, groups)
    result = solver.solve(t2.reshape(-1, 3), max_iter=max_iter, anderson=anderson)
    x = result.X
    if polish_steps > 0:
        x = rigid_hinge_polish(
            t2, x.reshape(-1, 8, 3), ids, planes=planes, w_collision=w_collision,
            steps=polish_steps,
        ).reshape(-1, 3)  # fmt: skip
    gaps = hinge_gaps(x.reshape(-1, 8, 3), ids)
    gap_max = float(gaps.max(initial=0.0))
    if gap_max > HINGE_GAP_TOL_MM:
        problems.append(
            f"hinge gap {gap_max:.3g} mm before merging exceeds {HINGE_GAP_TOL_MM:g} mm"
        )
    mid = 0.5 * (x[ids[:, 0]] + x[ids[:, 1]])
    merged = x.copy()
    merged[ids[:, 0]] = mid
    merged[ids[:, 1]] = mid
    return HingeLayout(
        strategy, merged.reshape(-1, 8, 3), bottom, ids, mid, gap_max, (), 0.0,
        result.iterations, time.perf_counter() - start, tuple(problems),
    )  # fmt: skip


def write_flat_obj(path: str | Path, tiles: ArrayLike) -> None:
    """Write tiles as closed outward-oriented quad meshes (8 vertices, 6 faces each).

    Vertex order per tile: top BL, BR, TR, TL, then the bottom vertices under them (same as
    ``assembled.obj``); tile ``t`` uses OBJ vertices ``8 t + 1 .. 8 t + 8`` and group ``tile_t``.

    Parameters
    ----------
    path : output file
    tiles : (T, 8, 3) float, mm
    """
    t = np.asarray(tiles, dtype=np.float64)
    lines = ["# drawstring flat configuration (T2D), mm"]
    lines += [f"v {x:.9g} {y:.9g} {z:.9g}" for x, y, z in t.reshape(-1, 3)]
    for k in range(len(t)):
        lines.append(f"g tile_{k}")
        for face in TILE_FACES:
            lines.append("f " + " ".join(str(8 * k + int(i) + 1) for i in face))
    Path(path).write_text("\n".join(lines) + "\n")


def hinge_vertex_json(layout: HingeLayout, linkage: Linkage) -> dict[str, Any]:
    """Hinge list for design.json: tiles, corners, side, 0-based OBJ vertex ids, position."""
    rows = []
    for k, (ta, ca, tb, cb) in enumerate(linkage.hinges):
        rows.append(
            {
                "tiles": [int(ta), int(tb)],
                "corners": [int(ca), int(cb)],
                "side": "bottom" if layout.bottom[k] else "top",
                "vertices": [int(layout.hinge_vertices[k, 0]), int(layout.hinge_vertices[k, 1])],
                "point_mm": [float(v) for v in layout.hinge_points[k]],
            }
        )
    out: dict[str, Any] = {"strategy": layout.strategy, "hinges": rows}
    if layout.trims:
        out["trims"] = [
            {
                "hinge": tr.hinge,
                "tile": tr.tile,
                "volume_mm3": tr.volume_mm3,
                "contact_area_lost_mm2": tr.contact_area_lost_mm2,
                "vertices_mm": tr.vertices.tolist(),
            }
            for tr in layout.trims
        ]
    json.dumps(out)  # fail early on anything not serializable
    return out


def draw_flat(
    ax: Any,
    linkage: Linkage,
    layout: HingeLayout,
    flat: FlatResult | None = None,
) -> None:
    """Draw the flat layout on a matplotlib axis.

    Tiles (top faces) coloured by component, bottom outlines thin, gaps shaded by opening angle,
    hinges as filled dots (top) or hollow circles (bottom).
    """
    from matplotlib import colormaps
    from matplotlib.collections import PolyCollection

    tiles = layout.tiles
    comp_cmap = colormaps["tab10"]
    colours = [comp_cmap(int(c) % 10) for c in linkage.tile_component]
    if flat is not None and flat.junctions.elements.size:
        nodes = flat.nodes
        gap_polys: list[FloatArray] = []
        gap_vals: list[float] = []
        ang = dict(zip(flat.junctions.gap[flat.junctions.is_end], flat.opening_deg, strict=True))
        for g in range(linkage.n_gaps):
            sides = linkage.gap_sides[g]
            sides = sides[sides[:, 0] >= 0]
            ring: list[FloatArray] = []
            for t, s in sides:
                ring.append(nodes[linkage.corner_node[t, (s + 1) % 4]])
                ring.append(nodes[linkage.corner_node[t, s]])
            gap_polys.append(np.array(ring))
            gap_vals.append(float(ang.get(g, 0.0)))
        pc = PolyCollection(gap_polys, array=np.array(gap_vals), cmap="viridis", alpha=0.6)
        pc.set_clim(0.0, 90.0)
        ax.add_collection(pc)
        ax.figure.colorbar(pc, ax=ax, label="gap opening angle (deg)", shrink=0.7)
    ax.add_collection(
        PolyCollection(list(tiles[:, 4:, :2]), facecolors="none", edgecolors="0.5", linewidths=0.3)
    )
    ax.add_collection(
        PolyCollection(list(tiles[:, :4, :2]), facecolors=colours, edgecolors="k", linewidths=0.5)
    )
    pts = layout.hinge_points
    top = ~layout.bottom
    ax.plot(pts[top, 0], pts[top, 1], "o", ms=3, color="k", label="top hinge")
    ax.plot(pts[~top, 0], pts[~top, 1], "o", ms=4, mfc="none", mec="r", label="bottom hinge")
    ax.set_aspect("equal")
    ax.autoscale_view()
    ax.legend(loc="upper right", fontsize=7)
