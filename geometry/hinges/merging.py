"""Merging the rigid layout's hinge pairs (:mod:`~drawstring.geometry.hinges.rigid_layout`):
every pair's shared point on its separating plane, the tiles with the merged vertices moved
there, and the merges to undo where they break a plane or a gap-angle bound.
"""

from __future__ import annotations

import logging

import numpy as np

from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.hinges.separating_planes import (
    RigidPose,
    SeparatingPlanes,
    plane_values,
    rotate2,
    select_planes,
)
from drawstring.geometry.tiling.linkage import Linkage, SlitEnds

logger = logging.getLogger(__name__)

__all__ = ["broken_merges", "hinges_of_ends", "merge_points", "merged_tiles"]


def merge_points(
    layout: RigidPose, planes: SeparatingPlanes, ids: IntArray, x: FloatArray
) -> FloatArray:
    """Shared point ``(H, 3)`` of every hinge pair: the midpoint moved horizontally onto the
    pair's separating plane (so both tiles stay on their own side after merging)."""
    flat = x.reshape(-1, 3)
    mid = 0.5 * (flat[ids[:, 0]] + flat[ids[:, 1]])
    pair_of = -np.ones(len(ids), dtype=np.int64)
    hinged = np.flatnonzero(planes.hinge >= 0)
    pair_of[planes.hinge[hinged]] = hinged
    out = mid.copy()
    ok = pair_of >= 0
    p = pair_of[ok]
    a = planes.a[p]
    w = rotate2(planes.normal[p, :2], layout.phi[a])
    nz = planes.normal[p, 2]
    origin = layout.origin()[a]
    value = np.einsum("ki,ki->k", mid[ok, :2] - origin, w) + nz * mid[ok, 2] - planes.offset[p]
    out[ok, :2] -= (value / np.maximum(np.einsum("ki,ki->k", w, w), 1e-300))[:, None] * w
    return out


def merged_tiles(
    x: FloatArray, ids: IntArray, points: FloatArray, is_merged: BoolArray
) -> FloatArray:
    """Tiles ``(T, 8, 3)`` with both vertices of every merged hinge moved to its point."""
    flat = x.reshape(-1, 3).copy()
    flat[ids[is_merged, 0]] = points[is_merged]
    flat[ids[is_merged, 1]] = points[is_merged]
    return flat.reshape(x.shape)


def hinges_of_ends(ends: SlitEnds, bad: BoolArray, ids: IntArray, faces: IntArray) -> BoolArray:
    """Hinges whose merged vertices enter the angle of any ``bad`` slit end."""
    t0, t1 = ends.tiles[bad, 0], ends.tiles[bad, 1]
    s0, s1 = ends.sides[bad, 0], ends.sides[bad, 1]
    verts = []
    for f in faces:
        verts += [
            8 * t1 + f + s1,
            8 * t1 + f + (s1 + 1) % 4,
            8 * t0 + f + s0,
            8 * t0 + f + (s0 + 1) % 4,
        ]
    used = np.unique(np.concatenate(verts)) if verts else np.zeros(0, dtype=np.int64)
    return np.asarray(np.isin(ids[:, 0], used) | np.isin(ids[:, 1], used))


def broken_merges(
    layout: RigidPose,
    linkage: Linkage,
    trim: BoolArray,
    planes: SeparatingPlanes,
    ends: SlitEnds,
    faces: IntArray,
    merged: FloatArray,
    ids: IntArray,
    is_merged: BoolArray,
    min_gap_angle_deg: float,
) -> BoolArray:
    """Merged hinges to undo: those whose moved vertices leave two tiles without a separating
    plane, or a gap angle out of its bounds (checked on the merged tiles)."""
    tol = 1e-9
    gb, ga, _ = plane_values(layout, planes, merged, layout.phi, layout.trans)
    assert ga is not None
    # Separation only (the clearance is a target of the layout, not a validity condition).
    gb = gb + np.where(np.isfinite(planes.delta_b), planes.delta_b, 0.0)
    ga = ga + np.where(np.isfinite(planes.delta_a), planes.delta_a, 0.0)
    suspect = np.flatnonzero(np.any(gb < -tol, axis=1) | np.any(ga < -tol, axis=1))
    undo = np.zeros(len(ids), dtype=bool)
    if suspect.size:
        pairs = np.stack([planes.a[suspect], planes.b[suspect]], axis=1)
        again = select_planes(layout, linkage, ids, trim, 0.0, 0.0, x=merged, pairs=pairs)
        broken = again.score < -tol
        tiles = np.concatenate([again.a[broken], again.b[broken]])
        undo |= is_merged & (np.isin(ids[:, 0] // 8, tiles) | np.isin(ids[:, 1] // 8, tiles))
        # only hinges that moved a vertex of a broken pair matter; undo them pairwise
        if broken.any():
            pair_tiles = np.stack([again.a[broken], again.b[broken]], axis=1)
            mine = np.zeros(len(ids), dtype=bool)
            for ta, tb in pair_tiles:
                mine |= np.isin(ids[:, 0] // 8, (ta, tb)) | np.isin(ids[:, 1] // 8, (ta, tb))
            undo &= mine
    bad = np.zeros(len(ends.hinge), dtype=bool)
    for f in faces:
        ang = np.degrees(ends.angles(merged, int(f)))
        bad |= (ang < min_gap_angle_deg) | (ang > 90.0)
    logger.debug(
        "merge check: %d suspect pairs, %d undone for separation, %d bad angles",
        suspect.size,
        int(undo.sum()),
        int(bad.sum()),
    )
    if bad.any():
        undo |= is_merged & hinges_of_ends(ends, bad, ids, faces)
    return undo
