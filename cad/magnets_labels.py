"""Magnet pockets across split contacts (:func:`magnet_pockets`) and the tile numbers
engraved on the bottom faces (:func:`label_engraving`), each dimensioned from a Profile."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from scipy.spatial import ConvexHull

from drawstring.cad.engraving_fill import fill_engraving as fill_engraving
from drawstring.cad.feature_common import (
    TOOL_OVERSHOOT_MM,
    Footprint,
    bd_plane,
    cross2,
    feature_wall_mm,
    signed_area,
)
from drawstring.cad.hinge_frame import cut_margin, outside_margin
from drawstring.cad.kernel import polyhedron_solid
from drawstring.cad.paths import FACE_BOTTOM, check_side, face_planes, unit_vector
from drawstring.cad.side_faces import (
    bilinear,
    invert_bilinear,
    pocket_fits,
    pocket_place,
    side_quad,
)
from drawstring.geometry.core.errors import InternalError

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)


#: Labels: text fits inside this fraction of the bottom face's inscribed radius.
LABEL_FILL = 0.6
#: Labels: digit width and spacing over digit height; stroke over height.
_DIGIT_WIDTH, _DIGIT_SPACING, _DIGIT_STROKE = 0.55, 0.22, 0.18


# --------------------------------------------------------------------------------------------
# magnets


@dataclass(frozen=True)
class MagnetPair:
    """Two pockets facing each other across a split contact in the assembled pose.

    ``polarity_a`` is the pole of tile a's magnet that faces out of its face; tile b's magnet
    shows the other pole, so the pair attracts.
    """

    tile_a: int
    side_a: int
    tile_b: int
    side_b: int
    centre: NDArray[np.float64]
    diameter_mm: float
    depth_mm: float
    polarity_a: Literal["N", "S"]
    polarity_b: Literal["N", "S"]
    fits: bool

    def flat_points(
        self, assembled: NDArray[np.float64], flat: NDArray[np.float64]
    ) -> tuple[tuple[int, int, NDArray[np.float64]], tuple[int, int, NDArray[np.float64]]]:
        """``(tile, side, centre)`` of both pockets on the tiles of another pose (``flat``,
        (T, 8, 3)): each keeps its place on its face (bilinear face coordinates, as cut)."""
        ends = []
        for tile, side in ((self.tile_a, self.side_a), (self.tile_b, self.side_b)):
            u, v = invert_bilinear(side_quad(assembled[tile], side), self.centre, 0.5, 0.5)
            ends.append((tile, side, bilinear(side_quad(flat[tile], side), u, v)))
        return ends[0], ends[1]

    def to_json(self) -> dict[str, object]:
        return {
            "tile_a": self.tile_a,
            "side_a": self.side_a,
            "tile_b": self.tile_b,
            "side_b": self.side_b,
            "centre_mm": [round(float(c), 6) for c in self.centre],
            "diameter_mm": self.diameter_mm,
            "depth_mm": self.depth_mm,
            "polarity_a": self.polarity_a,
            "polarity_b": self.polarity_b,
            "fits": self.fits,
        }


def _pocket(
    centre: NDArray[np.float64], outward: NDArray[np.float64], radius: float, depth: float
) -> bd.Solid:
    origin = centre + TOOL_OVERSHOOT_MM * outward
    return bd.Solid.make_cylinder(radius, depth + TOOL_OVERSHOOT_MM, bd_plane(origin, -outward))


def magnet_pockets(
    tile_a: NDArray[np.float64],
    side_a: int,
    tile_b: NDArray[np.float64],
    side_b: int,
    profile: Profile,
    *,
    flat_a: NDArray[np.float64] | None = None,
    flat_b: NDArray[np.float64] | None = None,
    offset_mm: float = 0.0,
    tile_ids: tuple[int, int] = (-1, -1),
    cuts: tuple[NDArray[np.float64] | None, NDArray[np.float64] | None] = (None, None),
    hollows: tuple[Sequence[NDArray[np.float64]], Sequence[NDArray[np.float64]]] = ((), ()),
) -> tuple[bd.Solid, bd.Solid, MagnetPair]:
    """Tools: one cylindrical magnet pocket in each of two faces that touch across a split.

    Parameters
    ----------
    tile_a, tile_b : (8, 3) float, mm, the two tiles in the assembled pose (faces touching).
    side_a, side_b : the touching side faces.
    profile : magnet diameter and height; pocket diameter ``d + 2 clearance``, depth
        ``height + clearance``.
    flat_a, flat_b : (8, 3) float, mm, the same tiles in the pose to cut (default: assembled).
        The pocket keeps its place on the face (bilinear face coordinates).
    offset_mm : shift of the pocket along the face from its centre (to clear a channel).
    tile_ids : tile numbers written into the record.
    cuts : per tile, planes ``(n, d)`` (flat pose) that cut it (hinge reliefs, see
        :func:`~drawstring.cad.hinge_frame.place_holes`): a pocket one of them would open is
        moved along the face (:func:`pocket_place`).
    hollows : per tile, convex polyhedra ``(k, 3)`` (flat pose) cut out of it (hinge reliefs
        where no plane serves): a pocket that would enter one is moved the same way.

    Returns
    -------
    tool_a, tool_b : pocket cylinders for tile a and tile b.
    record : the pair, its assembled centre and polarity (tile a north out, tile b south out).
    """
    check_side(side_a, "side_a")
    check_side(side_b, "side_b")
    tile_a = np.asarray(tile_a, dtype=np.float64)
    tile_b = np.asarray(tile_b, dtype=np.float64)
    quad_a, quad_b = side_quad(tile_a, side_a), side_quad(tile_b, side_b)
    width = float(np.linalg.norm(bilinear(quad_a, 1, 0.5) - bilinear(quad_a, 0, 0.5)))
    radius = 0.5 * profile.magnet_diameter_mm + profile.magnet_clearance_mm
    depth = profile.magnet_height_mm + profile.magnet_clearance_mm
    flats = (
        np.asarray(flat_a if flat_a is not None else tile_a, dtype=np.float64),
        np.asarray(flat_b if flat_b is not None else tile_b, dtype=np.float64),
    )

    hulls = [[ConvexHull(points).equations for points in tile] for tile in hollows]

    def clear(at_u: float, at_v: float, wall: float) -> bool:
        u_b, v_b = invert_bilinear(quad_b, bilinear(quad_a, at_u, at_v), 1.0 - at_u, at_v)
        for flat, side, u, v, cut, hull in zip(
            flats, (side_a, side_b), (at_u, u_b), (at_v, v_b), cuts, hulls, strict=True
        ):
            if (cut is None or not len(cut)) and not hull:
                continue
            point = bilinear(side_quad(flat, side), u, v)
            normal = face_planes(flat)[1][side]
            if cut_margin(flat, point, normal, radius, cut, depth) < wall:
                return False
            if any(outside_margin(point, normal, radius, depth, h) < wall for h in hull):
                return False
        return True

    start = 0.5 + offset_mm / width
    u_a, v_a = pocket_place(quad_a, quad_b, start, radius, profile, clear)
    centre = bilinear(quad_a, u_a, v_a)
    u_b, v_b = invert_bilinear(quad_b, centre, 1.0 - u_a, v_a)
    fits = (
        pocket_fits(quad_a, u_a, v_a, radius)
        and pocket_fits(quad_b, u_b, v_b, radius)
        and clear(u_a, v_a, 0.0)
    )
    tools = []
    for flat, side, u, v in (
        (flat_a if flat_a is not None else tile_a, side_a, u_a, v_a),
        (flat_b if flat_b is not None else tile_b, side_b, u_b, v_b),
    ):
        flat = np.asarray(flat, dtype=np.float64)
        _, normals = face_planes(flat)
        tools.append(_pocket(bilinear(side_quad(flat, side), u, v), normals[side], radius, depth))
    record = MagnetPair(
        tile_ids[0], side_a, tile_ids[1], side_b, centre, 2 * radius, depth, "N", "S", fits
    )
    return tools[0], tools[1], record


# --------------------------------------------------------------------------------------------
# labels

_SEGMENTS_OF_DIGIT = {
    "0": "abcdef",
    "1": "bc",
    "2": "abged",
    "3": "abgcd",
    "4": "fgbc",
    "5": "afgcd",
    "6": "afgedc",
    "7": "abc",
    "8": "abcdefg",
    "9": "abcdfg",
}


#: The digit each seven-segment digit shows when turned half a turn (3, 4 and 7 show none).
_TURNED_DIGIT = {"0": "0", "1": "1", "2": "2", "5": "5", "6": "9", "8": "8", "9": "6"}
#: An underline (a stroke's gap, then a stroke) adds this many digit heights below a label.
_UNDERLINE_ROWS = 2.0 * _DIGIT_STROKE


def reads_as_another(text: str) -> bool:
    """Whether ``text`` in seven-segment digits turned half a turn shows another number (6 and
    9, 16 and 91): such labels are underlined, as on dice.  Tiles of a loose print are turned
    every way on the bed."""
    if not all(char in _TURNED_DIGIT for char in text):
        return False
    return "".join(_TURNED_DIGIT[char] for char in reversed(text)) != text


def _label_rows(text: str) -> float:
    """Height of ``text``'s label, digits and any underline, in digit heights."""
    return 1.0 + (_UNDERLINE_ROWS if reads_as_another(text) else 0.0)


def _segment_rectangles(text: str, height: float) -> list[NDArray[np.float64]]:
    """Seven-segment outlines of ``text`` ((4, 2) rectangles, mm), centred on the origin
    (``height`` the digits' height; a label that turned reads as another number gets an
    underline below them, :func:`reads_as_another`).

    Segments of a digit are separated by small gaps, so the rectangles never touch.
    """
    width, stroke = _DIGIT_WIDTH * height, _DIGIT_STROKE * height
    gap = 0.2 * stroke
    spacing = _DIGIT_SPACING * height
    total = len(text) * width + (len(text) - 1) * spacing
    half = 0.5 * height
    rise = 0.5 * (_label_rows(text) - 1.0) * height  # the digits move up to make room
    boxes = {
        "a": (stroke + gap, width - stroke - gap, height - stroke, height),
        "g": (stroke + gap, width - stroke - gap, half - stroke / 2, half + stroke / 2),
        "d": (stroke + gap, width - stroke - gap, 0.0, stroke),
        "f": (0.0, stroke, half + gap, height - gap),
        "b": (width - stroke, width, half + gap, height - gap),
        "e": (0.0, stroke, gap, half - gap),
        "c": (width - stroke, width, gap, half - gap),
    }
    rectangles = []
    for index, char in enumerate(text):
        x0 = -0.5 * total + index * (width + spacing)
        for segment in _SEGMENTS_OF_DIGIT[char]:
            a, b, c, d = boxes[segment]
            rectangles.append(
                np.array([[x0 + a, c], [x0 + b, c], [x0 + b, d], [x0 + a, d]]) - [0.0, half - rise]
            )
    if rise > 0:
        low = -half - rise
        rectangles.append(
            np.array([[-0.5 * total, low], [0.5 * total, low], [0.5 * total, low + stroke],
                      [-0.5 * total, low + stroke]])
        )  # fmt: skip
    return rectangles


def _prism(
    outline: NDArray[np.float64],
    origin: NDArray[np.float64],
    axis_x: NDArray[np.float64],
    axis_y: NDArray[np.float64],
    direction: NDArray[np.float64],
    start: float,
    stop: float,
) -> bd.Solid:
    """Straight prism over a planar convex outline ((k, 2) in the (axis_x, axis_y) frame)."""
    base = origin + outline[:, :1] * axis_x + outline[:, 1:] * axis_y
    k = len(outline)
    points = np.vstack([base + stop * direction, base + start * direction])
    ring = list(range(k))
    faces = [ring, [k + i for i in reversed(ring)]]
    faces += [[i, k + i, k + (i + 1) % k, (i + 1) % k] for i in ring]
    # Orient: the cap at ``stop`` must be counter-clockwise seen from ``direction``.
    if np.cross(axis_x, axis_y) @ direction * signed_area(outline) < 0:
        faces = [list(reversed(f)) for f in faces]
    return _prism_solid(points, faces)


def _prism_solid(points: NDArray[np.float64], faces: list[list[int]]) -> bd.Solid:
    """:func:`~drawstring.cad.kernel.polyhedron_solid` of a prism over a quadrilateral (six
    faces of four corners, planar by construction), the faces' planes computed together."""
    rings = points[np.asarray(faces)]  # (6, 4, 3)
    normals = np.cross(rings, np.roll(rings, -1, axis=1)).sum(axis=1)
    return polyhedron_solid(points, faces, (normals, rings.mean(axis=1)))


def label_depth(profile: Profile) -> float:
    """Engraving depth (mm) of tile labels: 7 % of the tile thickness, within 0.3 .. 2 mm."""
    return float(np.clip(0.07 * profile.thickness_mm, 0.3, 2.0))


def _box_point_distance(half: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray:
    """Distance (mm) from each 2D point ((k, 2)) to the box ``[-half, half]`` (0 inside)."""
    return np.asarray(np.linalg.norm(np.maximum(np.abs(points) - half, 0.0), axis=-1))


def _box_segment_distance(
    half: NDArray[np.float64], a: NDArray[np.float64], b: NDArray[np.float64]
) -> float:
    """Distance (mm) from the 2D segment ``a``-``b`` to the box ``[-half, half]`` (0 where
    they meet): between disjoint convex shapes it is reached at a vertex of one of them."""
    direction = b - a
    low, high = 0.0, 1.0  # Liang-Barsky: the part of the segment inside the box
    for axis in range(2):
        if abs(direction[axis]) < 1e-15:
            if abs(a[axis]) > half[axis]:
                low, high = 1.0, 0.0
                break
            continue
        t0 = (-half[axis] - a[axis]) / direction[axis]
        t1 = (half[axis] - a[axis]) / direction[axis]
        low, high = max(low, min(t0, t1)), min(high, max(t0, t1))
    if low <= high:
        return 0.0
    corners = np.array([[-1.0, -1.0], [1.0, -1.0], [1.0, 1.0], [-1.0, 1.0]]) * half
    length2 = float(direction @ direction)
    t = np.clip((corners - a) @ direction / max(length2, 1e-300), 0.0, 1.0)
    to_corners = np.linalg.norm(a + t[:, None] * direction - corners, axis=1)
    ends = _box_point_distance(half, np.stack([a, b]))
    return float(min(to_corners.min(), ends.min()))


def _label_clear_height(
    height: float,
    aspect: float,
    footprints: Sequence[tuple[NDArray[np.float64], float]],
    wall: float,
) -> float:
    """The largest text height (mm, at most ``height``) whose box (``aspect`` times as wide as
    high, centred on the origin) keeps ``wall`` from every 2D footprint (polyline, radius)."""

    def clear(h: float) -> bool:
        half = 0.5 * h * np.array([aspect, 1.0])
        for points, radius in footprints:
            if len(points) == 1:
                gap = float(_box_point_distance(half, points)[0])
            else:
                gap = min(
                    _box_segment_distance(half, p, q)
                    for p, q in zip(points[:-1], points[1:], strict=True)
                )
            if gap < radius + wall:
                return False
        return True

    if clear(height):
        return height
    low, high = 0.0, height
    for _ in range(40):  # a nanometre on a 10 mm label
        middle = 0.5 * (low + high)
        low, high = (middle, high) if clear(middle) else (low, middle)
    return low


def label_engraving(
    tile: NDArray[np.float64],
    tile_id: int,
    profile: Profile,
    keep_out: Sequence[Footprint] = (),
) -> bd.Compound | None:
    """Tool: the tile number engraved in seven-segment digits on the bottom face.

    The text reads correctly when the bottom face is seen from outside, runs along side 0, is
    centred on the face and fits inside ``LABEL_FILL`` of the face's inscribed radius.  It is
    made smaller where it would come within :func:`feature_wall_mm` of a ``keep_out`` footprint
    on the bottom face (:func:`hinge_face_footprints`: hinge strips and pin holes, which would
    cover or cut the digits, and whose recesses overlapping an engraving make OCCT's cut fail).
    Returns ``None`` (and logs) when the strokes would be thinner than the machine can make
    (:func:`feature_wall_mm`: ``max(nozzle, 2 kerf, 0.3 mm)``).
    """
    if tile_id < 0:
        raise InternalError(f"tile_id = {tile_id} must be >= 0")
    tile = np.asarray(tile, dtype=np.float64)
    centroids, normals = face_planes(tile)
    centre, outward = centroids[FACE_BOTTOM], normals[FACE_BOTTOM]
    axis_x = unit_vector(tile[5] - tile[4])
    axis_x = unit_vector(axis_x - (axis_x @ outward) * outward)
    axis_y = np.cross(outward, axis_x)
    corners = tile[4:8] - centre
    corners2d = np.stack([corners @ axis_x, corners @ axis_y], axis=1)
    nxt = np.roll(corners2d, -1, axis=0)
    edge = nxt - corners2d
    inradius = float(np.min(np.abs(cross2(edge, -corners2d)) / np.linalg.norm(edge, axis=1)))
    text = str(tile_id)
    rows = _label_rows(text)
    width_over_height = len(text) * _DIGIT_WIDTH + (len(text) - 1) * _DIGIT_SPACING
    height = LABEL_FILL * inradius / float(np.hypot(0.5 * width_over_height, 0.5 * rows))
    min_stroke = feature_wall_mm(profile)
    if keep_out:
        footprints = []
        for points, radius in keep_out:
            rel = np.asarray(points, dtype=np.float64).reshape(-1, 3) - centre
            footprints.append((np.stack([rel @ axis_x, rel @ axis_y], axis=1), float(radius)))
        block = _label_clear_height(height * rows, width_over_height / rows, footprints, min_stroke)
        height = block / rows
    if _DIGIT_STROKE * height < min_stroke:
        # debug: the design lists the tiles without numbers in one note
        log.debug(
            "tile %d: label strokes %.2f mm too thin; no label", tile_id, _DIGIT_STROKE * height
        )
        return None
    depth = label_depth(profile)
    solids = [
        _prism(rect, centre, axis_x, axis_y, -outward, -TOOL_OVERSHOOT_MM, depth)
        for rect in _segment_rectangles(text, height)
    ]
    return bd.Compound(solids)


def pairs_left_out(pairs: Sequence[MagnetPair], parts: NDArray[np.int64]) -> list[MagnetPair]:
    """The magnet ``pairs`` whose pockets fit nowhere on their faces and that another pair,
    whose pockets fit, joins across the same split (between the same two of the tiles'
    ``parts``): those are left out; a split no fitting pair joins keeps its pairs."""

    def split(pair: MagnetPair) -> tuple[int, int]:
        ends = sorted((int(parts[pair.tile_a]), int(parts[pair.tile_b])))
        return ends[0], ends[1]

    joined = {split(pair) for pair in pairs if pair.fits}
    return [pair for pair in pairs if not pair.fits and split(pair) in joined]
