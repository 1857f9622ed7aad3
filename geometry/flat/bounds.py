"""The hard rows of the flat layout: gap-angle bounds on the top faces (and the bottom faces
of T3D where they differ), narrowed where a dual layout's hinge faces need it, and the
orientation of every gap junction.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.rigid import rigid_fit
from drawstring.geometry.core.tolerances import FLAT_GAP_ANGLE_TOL_DEG, FLAT_ORIENTATION_MIN_RAD
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.flat.junctions import GapJunctions
from drawstring.geometry.flat.pose import HingeFaces, hinge_points
from drawstring.geometry.solve.constrained_lsq import AngleRows, SeparationRows
from drawstring.geometry.solve.constraints import signed_angles
from drawstring.geometry.tiling.linkage import Linkage, slit_ends

logger = logging.getLogger(__name__)


def face_offsets(
    plane_tiles: FloatArray,
    tiles_3d: FloatArray,
    junctions: GapJunctions,
    anchor_3d: FloatArray | None = None,
) -> FloatArray:
    """Top- and bottom-face minus node opening angle ``(2, E)`` in rad at every slit end.

    The nodes carry each tile's anchor polygon (its top face, or with ``anchor_3d`` its hinge
    points): a rigid tile turns its anchor, top and bottom sides together, so the opening
    measured on a face differs from the one measured on the nodes by a constant per slit end,
    the turn from each arm's anchor side to its face side (tiles posed rigidly on their flat
    anchor polygons ``plane_tiles``).
    """
    anchor = tiles_3d[:, :4] if anchor_3d is None else anchor_3d
    dst = np.concatenate([plane_tiles, np.zeros((len(plane_tiles), 4, 1))], axis=2)
    rot, trans = rigid_fit(anchor, dst)
    posed = (np.einsum("kij,kvj->kvi", rot, tiles_3d) + trans[:, None, :])[..., :2]
    t = junctions.tiles[junctions.is_end]
    s = junctions.sides[junctions.is_end]
    t0, t1, s0, s1 = t[:, 0], t[:, 1], s[:, 0], s[:, 1]

    def arm(pts: FloatArray, tile: IntArray, a: IntArray, b: IntArray) -> FloatArray:
        return np.asarray(pts[tile, a] - pts[tile, b])

    u_node = arm(plane_tiles, t1, s1, (s1 + 1) % 4)
    v_node = arm(plane_tiles, t0, (s0 + 1) % 4, s0)
    out = []
    for face in (0, 4):
        u = arm(posed, t1, face + s1, face + (s1 + 1) % 4)
        v = arm(posed, t0, face + (s0 + 1) % 4, face + s0)
        out.append(signed_angles(v_node, v) - signed_angles(u_node, u))
    return np.asarray(out)


def _clear_bounds(hinges: HingeFaces, ends_hinge: IntArray, lo: FloatArray, hi: FloatArray) -> None:
    """Narrow the opening bounds ``lo``, ``hi`` ``(2, E)`` (top, bottom face rows; rad) in place
    to the openings at which each slit end's tiles clear each other on its hinge face."""
    face = hinges.bottom[ends_hinge].astype(np.int64)
    k = np.arange(len(face))
    new_lo, new_hi, fits = hinges.window(lo[face, k], hi[face, k])
    # where clearing needs openings outside the gap-angle bounds, the bounds stay as they are
    # (holding such a pair at the nearest bound would make the joint solve jump where the
    # interval shifts between rounds); the hinge stage trims such pairs' overlap
    lo[face[fits], k[fits]] = new_lo[fits]
    hi[face[fits], k[fits]] = new_hi[fits]
    if not fits.all():
        logger.info(
            "flat: %d slit ends cannot clear on their hinge face within the gap-angle bounds",
            int((~fits).sum()),
        )


def flat_constraints(
    linkage: Linkage,
    junctions: GapJunctions,
    plane: FloatArray,
    tiles_3d: ArrayLike | None,
    theta_min: float,
    side: float,
    bounds: bool,
    collision: bool,
    theta_max: float = 0.5 * np.pi,
    hinges: HingeFaces | None = None,
) -> list[AngleRows | SeparationRows]:
    """The hard rows of the flat layout: gap-angle bounds on the top faces (and, with T3D, on
    the bottom faces where they differ) and the orientation of every gap junction.

    With ``hinges`` (a dual layout's hinge faces, needs T3D) the nodes carry the hinge points
    (:func:`~drawstring.geometry.flat.pose.hinge_points`), both faces' angles are bounded through
    their offsets from the nodes' angles, and each slit end's opening on its hinge face is kept
    where its two tiles clear each other (:func:`~drawstring.geometry.flat.pose.free_openings`,
    ``FLAT_FREE_MARGIN_DEG`` inside)."""
    constraints: list[AngleRows | SeparationRows] = []
    ends = junctions.ends
    if len(ends) and bounds:
        n_ends = len(ends)
        lo = np.full((2, n_ends), theta_min)
        hi = np.full((2, n_ends), theta_max)
        off = np.zeros((2, n_ends))
        if tiles_3d is not None:
            t3 = np.asarray(tiles_3d, dtype=np.float64)
            if t3.shape != (linkage.n_tiles, 8, 3):
                raise InternalError(f"tiles_3d has shape {t3.shape}; pass (T, 8, 3) T3D tiles")
            anchor = None if hinges is None else hinge_points(linkage, t3, hinges.bottom)
            off = face_offsets(plane, t3, junctions, anchor)
            if hinges is not None:
                _clear_bounds(hinges, slit_ends(linkage).hinge, lo, hi)
        for face in (0, 1):
            rows = np.arange(n_ends)
            if face == 1:
                # bottom rows only where they differ from the top ones
                differ = np.abs(off[1] - off[0]) > np.radians(FLAT_GAP_ANGLE_TOL_DEG)
                rows = np.flatnonzero(differ | (lo[1] != lo[0]) | (hi[1] != hi[0]))
            if len(rows):
                constraints.append(
                    AngleRows(ends[rows], off[face, rows], lo[face, rows], hi[face, rows],
                               np.full(len(rows), side))
                )  # fmt: skip
    if len(junctions.elements) and collision:
        k = len(junctions.elements)
        constraints.append(
            AngleRows(junctions.elements, np.zeros(k), np.full(k, FLAT_ORIENTATION_MIN_RAD),
                       np.full(k, 1.5 * np.pi), np.full(k, side), branch=-0.5 * np.pi)
        )  # fmt: skip
    return constraints
