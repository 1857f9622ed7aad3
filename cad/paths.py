"""Centre lines of the string inside the tiles, and the route's length along them.

Pure geometry on tile vertices ((8, 3) float, mm; top corners 0..3 counter-clockwise seen from
above, bottom corners 4..7 under them): the faces' best-fit planes, the channel through a tile
from side to side (a cubic Bezier), the lift bore from a side face up to the top face (a
straight run and one circular arc), and the closed route's length through them.  The CAD
features (:mod:`.features`) sweep their tools along these lines; the design's measurements use
them without building any solid, so they need no B-rep kernel.

Route sides: ``0..3`` are the tile's side faces; ``SIDE_TOP_FACE`` (4) means the top face (a lift
point, where the string leaves the linkage upward).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.memo import Memo, content_key
from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tile import CAD_FACE_ORDER, TILE_FACES, Face

#: A tile's faces as vertex indices in the CAD layer's order (sides 0..3, then top and bottom:
#: a side's face index is its side index), taken from the one definition of the faces.
SOLID_FACES: tuple[tuple[int, int, int, int], ...] = tuple(
    (int(a), int(b), int(c), int(d)) for a, b, c, d in TILE_FACES[list(CAD_FACE_ORDER)]
)
#: :data:`SOLID_FACES` as an array.
FACE_INDICES = np.array(SOLID_FACES, dtype=np.int64)
#: Index of the top face in :data:`SOLID_FACES`.
FACE_TOP = CAD_FACE_ORDER.index(Face.TOP)
#: Index of the bottom face in :data:`SOLID_FACES`.
FACE_BOTTOM = CAD_FACE_ORDER.index(Face.BOTTOM)


def face_planes(vertices: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Best-fit plane of each of the six faces.

    Parameters
    ----------
    vertices : (8, 3) float, mm.

    Returns
    -------
    centroids : (6, 3) float, mm, mean of each face's four vertices.
    normals : (6, 3) float, unit outward normals (Newell's method, exact for planar faces).
    """
    quads = np.asarray(vertices, dtype=np.float64)[FACE_INDICES]  # (6, 4, 3)
    centroids = quads.mean(axis=1)
    following = np.roll(quads, -1, axis=1)
    normals = np.cross(quads, following).sum(axis=1)
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    if np.any(lengths < 1e-300):
        raise InternalError("a tile has a face of zero area")
    return centroids, normals / lengths


SIDE_TOP_FACE = FACE_TOP
#: Handle lengths tried for the channel's cubic Bezier, as fractions of the chord.
_HANDLE_FRACTIONS = np.linspace(0.15, 0.85, 15)


def unit_vector(vector: NDArray[np.float64]) -> NDArray[np.float64]:
    length = float(np.linalg.norm(vector))
    if length < 1e-12:
        raise InternalError("degenerate feature geometry (zero-length direction)")
    return np.asarray(vector / length)


def check_side(side: int, name: str) -> None:
    if side not in (0, 1, 2, 3):
        raise InternalError(f"{name} = {side} is not a side index 0..3")


def bezier_points(control: NDArray[np.float64], samples: int = 65) -> NDArray[np.float64]:
    s = np.linspace(0.0, 1.0, samples)[:, None]
    basis = np.hstack([(1 - s) ** 3, 3 * s * (1 - s) ** 2, 3 * s**2 * (1 - s), s**3])
    return np.asarray(basis @ control)


def bezier_min_radius(control: NDArray[np.float64], samples: int = 65) -> float:
    """Smallest radius of curvature (mm) of a cubic Bezier; ``inf`` for a straight one."""
    s = np.linspace(0.0, 1.0, samples)[:, None]
    d1 = 3 * (
        (1 - s) ** 2 * (control[1] - control[0])
        + 2 * s * (1 - s) * (control[2] - control[1])
        + s**2 * (control[3] - control[2])
    )
    d2 = 6 * (
        (1 - s) * (control[2] - 2 * control[1] + control[0])
        + s * (control[3] - 2 * control[2] + control[1])
    )
    speed = np.linalg.norm(d1, axis=1)
    curvature = np.linalg.norm(np.cross(d1, d2), axis=1) / np.maximum(speed, 1e-300) ** 3
    peak = float(curvature.max())
    return float("inf") if peak < 1e-12 else 1.0 / peak


@dataclass(frozen=True)
class ChannelPath:
    """Centre line of a string channel inside one tile.

    Attributes
    ----------
    control : (4, 3) float, mm, cubic Bezier control points from the entry to the exit opening.
    start_tangent, end_tangent : (3,) float, unit directions at the openings (into the tile at
        the entry, out of the tile at the exit).
    min_radius : float, mm, smallest radius of curvature (``inf`` when straight).
    """

    control: NDArray[np.float64]
    start_tangent: NDArray[np.float64]
    end_tangent: NDArray[np.float64]
    min_radius: float

    def points(self, samples: int = 65) -> NDArray[np.float64]:
        """(samples, 3) float, mm, points along the centre line."""
        return bezier_points(self.control, samples)


def smooth_path(
    start: NDArray[np.float64],
    start_tangent: NDArray[np.float64],
    end: NDArray[np.float64],
    end_tangent: NDArray[np.float64],
) -> ChannelPath:
    """The cubic Bezier from ``start`` to ``end`` with the given end tangents whose smallest
    radius of curvature is largest among a few handle lengths."""
    chord = float(np.linalg.norm(end - start))
    if chord < 1e-9:
        raise InternalError("channel entry and exit coincide")
    best: ChannelPath | None = None
    for fraction in _HANDLE_FRACTIONS:
        handle = fraction * chord
        control = np.stack([start, start + handle * start_tangent, end - handle * end_tangent, end])
        radius = bezier_min_radius(control)
        if best is None or radius > best.min_radius:
            best = ChannelPath(control, start_tangent, end_tangent, radius)
    assert best is not None
    return best


def channel_path(tile: NDArray[np.float64], enter_side: int, leave_side: int) -> ChannelPath:
    """Centre line of the channel from side ``enter_side`` to ``leave_side`` (or the top face).

    Openings sit at the face centroids (mid-thickness on a side face), and the line meets each
    face along its normal, so the channels of two tiles whose faces touch line up across the
    contact.
    """
    if enter_side == leave_side:
        raise InternalError(f"route enters and leaves tile through the same side {enter_side}")
    for side, name in ((enter_side, "enter_side"), (leave_side, "leave_side")):
        if side not in (0, 1, 2, 3, SIDE_TOP_FACE):
            raise InternalError(
                f"{name} = {side} must be a side 0..3 or {SIDE_TOP_FACE} (top face)"
            )
    centroids, normals = face_planes(np.asarray(tile, dtype=np.float64))
    return smooth_path(
        centroids[enter_side], -normals[enter_side], centroids[leave_side], normals[leave_side]
    )


@dataclass(frozen=True)
class LiftPath:
    """Centre line of a lift bore: straight in from a side face, one circular arc, up and out.

    Attributes
    ----------
    entry : (3,) float, mm, centroid of the side face.
    arc : (3, 3) float, mm, start, middle and end of the arc; the arc ends on the top face.
    start_tangent, end_tangent : (3,) unit directions (into the tile; out of the top face).
    radius : float, mm, the arc radius (the tightest bend of the bore).
    """

    entry: NDArray[np.float64]
    arc: NDArray[np.float64]
    start_tangent: NDArray[np.float64]
    end_tangent: NDArray[np.float64]
    radius: float


def lift_path(tile: NDArray[np.float64], side: int) -> LiftPath:
    """The lift bore's centre line from side ``side`` to the top face.

    The arc turns from the side's inward normal to the top's outward normal with the largest
    radius that still ends on the top face; a straight run before it brings the exit near the
    top face's centroid.
    """
    check_side(side, "side")
    centroids, normals = face_planes(np.asarray(tile, dtype=np.float64))
    entry, inward = centroids[side], -normals[side]
    up = normals[FACE_TOP]
    cos_turn = float(np.clip(inward @ up, -1.0, 1.0))
    across = unit_vector(up - cos_turn * inward)
    sin_turn = float(np.sqrt(1.0 - cos_turn**2))
    height = float((centroids[FACE_TOP] - entry) @ up)
    reach = float((centroids[FACE_TOP] - entry) @ inward)
    # A run along an inward direction that rises (a side face leaning out) climbs too: stop it
    # where half the rise is left for the bend, or on a large tile it would pass the top face.
    longest = 0.5 * height / cos_turn if cos_turn > 1e-9 else np.inf
    run = 0.0
    radius = height / sin_turn
    for _ in range(3):
        radius = (height - run * cos_turn) / sin_turn
        run = max(0.0, reach - radius * (1.0 - cos_turn * cos_turn) / sin_turn * sin_turn)
        run = min(run, longest)
    radius = (height - run * cos_turn) / sin_turn
    if radius <= 0.0:
        raise InternalError("tile too thin for a lift bore: no height above its side face's centre")
    start = entry + run * inward
    centre = start + radius * across

    def on_arc(angle: float) -> NDArray[np.float64]:
        return np.asarray(centre + radius * (np.sin(angle) * inward - np.cos(angle) * across))

    turn = float(np.arccos(cos_turn))
    arc = np.stack([on_arc(0.0), on_arc(0.5 * turn), on_arc(turn)])
    return LiftPath(entry, arc, inward, up, radius)


def arc_samples(arc: NDArray[np.float64], count: int = 33) -> NDArray[np.float64]:
    """Points along the circular arc through start, middle and end (``arc`` (3, 3), mm)."""
    a, m, b = arc
    u, v = m - a, b - a
    w = np.cross(u, v)
    if np.linalg.norm(w) < 1e-12:
        return np.linspace(a, b, count)
    centre = a + (u @ u * np.cross(v, w) + v @ v * np.cross(w, u)) / (2.0 * (w @ w))
    radius = float(np.linalg.norm(a - centre))
    e1 = (a - centre) / radius
    e2 = unit_vector((m - centre) - ((m - centre) @ e1) * e1)
    turn = 2.0 * float(np.arctan2((m - centre) @ e2, (m - centre) @ e1))
    angles = np.linspace(0.0, turn, count)[:, None]
    return np.asarray(centre + radius * (np.cos(angles) * e1 + np.sin(angles) * e2))


def route_openings(
    tiles: NDArray[np.float64], steps: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Entry and exit points of the string in each route step and the length inside the tile.

    Returns
    -------
    entry, exit : (S, 3) float, mm.
    inside : (S,) float, mm.

    Worked out once per content of ``tiles`` and ``steps`` (:class:`~.memo.Memo`: every
    length an output states and the pictures ask it of the same ones); the arrays are shared,
    read-only.
    """
    return _OPENINGS.get(content_key(tiles, steps), lambda: _route_openings(tiles, steps))


_OPENINGS: Memo[tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]] = Memo()


def _route_openings(
    tiles: NDArray[np.float64], steps: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    entries, exits, inside = [], [], []
    for _, tile, enter, leave in steps:
        vertices = tiles[tile]
        if SIDE_TOP_FACE in (enter, leave):
            side = int(leave if enter == SIDE_TOP_FACE else enter)
            length, side_point, top_point = _bore(vertices, side)
            a, b = (top_point, side_point) if enter == SIDE_TOP_FACE else (side_point, top_point)
        else:
            channel = channel_path(vertices, int(enter), int(leave))
            samples = channel.points()
            length = float(np.linalg.norm(np.diff(samples, axis=0), axis=1).sum())
            a, b = channel.control[0], channel.control[3]
        entries.append(a)
        exits.append(b)
        inside.append(length)
    found = (np.array(entries).reshape(-1, 3), np.array(exits).reshape(-1, 3), np.array(inside))
    for array in found:
        array.setflags(write=False)
    return found


def _bore(
    vertices: NDArray[np.float64], side: int
) -> tuple[float, NDArray[np.float64], NDArray[np.float64]]:
    """Length (mm) of a tile's lift bore from side ``side`` to the top face, and its ends
    there: (length, side point, top point)."""
    path = lift_path(vertices, side)
    turn = float(np.arccos(np.clip(path.start_tangent @ path.end_tangent, -1.0, 1.0)))
    length = float(np.linalg.norm(path.arc[0] - path.entry)) + path.radius * turn
    return length, path.entry, path.arc[2]


def route_length(
    tiles: NDArray[np.float64],
    steps: NDArray[np.int64],
    bores: NDArray[np.int64] | Sequence[Sequence[int]] = (),
) -> float:
    """Length (mm) of the closed string route in the given pose: inside the tiles plus the
    straight runs between consecutive openings.

    ``bores`` (L, 2) ``(tile, side)`` are the lift bores
    (:func:`~drawstring.pipeline.cad_stage.lift_bores`): where both tiles of a crossing
    have one on the contact face between them, the string comes up one bore, runs over the
    gap from top face to top face and goes down the other instead of straight across.  (A
    route passes each tile once, ``Route.tiles_passed_once``, so a contact face is crossed at
    most once and its two bores name one crossing.)
    """
    if len(steps) == 0:
        return 0.0
    entry, exit_, inside = route_openings(tiles, steps)
    between = np.linalg.norm(np.roll(entry, -1, axis=0) - exit_, axis=1)
    lifted = {(int(t), int(s)) for t, s in np.asarray(bores, dtype=np.int64).reshape(-1, 2)}
    count = len(steps)
    for k in range(count):
        before = (k - 1) % count
        out = (int(steps[before, 1]), int(steps[before, 3]))
        into = (int(steps[k, 1]), int(steps[k, 2]))
        if out in lifted and into in lifted and SIDE_TOP_FACE not in (out[1], into[1]):
            up, _, top_out = _bore(tiles[out[0]], out[1])
            down, _, top_in = _bore(tiles[into[0]], into[1])
            between[before] = up + float(np.linalg.norm(top_in - top_out)) + down
    return float(inside.sum() + between.sum())


def route_lengths(
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    steps: NDArray[np.int64],
    bores: NDArray[np.int64] | Sequence[Sequence[int]],
) -> tuple[float, float]:
    """(flat, assembled) length of the string route, mm rounded to 0.1 mm: the length every
    output reports (route.json, design.json, bom.csv, manifest.json, assembly.md).

    Measured along the string's centre line on the fabricated geometry (:func:`route_length`:
    through the channels and the lift bores ``bores`` the solids are cut with, straight across
    the other gaps), with ``tiles_flat`` the tiles as printed (the pose of ``flat.step``).
    """
    return (
        round(route_length(tiles_flat, steps, bores), 1),
        round(route_length(tiles_assembled, steps, bores), 1),
    )
