"""Fabrication features cut into (or added next to) the tiles, each dimensioned from a Profile.

Every function takes tile vertices ((8, 3) float, mm, contract order; see :mod:`.tiles`) and
returns build123d solids: *tools* to subtract from a tile, or separate parts (hinge pads, rubber
strips).  Tools poke ``TOOL_OVERSHOOT_MM`` out of the faces they open so that no boolean meets a
coplanar face.

Route sides: ``0..3`` are the tile's side faces; ``SIDE_TOP_FACE`` (4) means the top face (a lift
point, where the string leaves the linkage upward).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Literal

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.kernel import bounding_box, clean_solid, cut, fuse, polyhedron_solid
from drawstring.cad.paths import (
    FACE_BOTTOM,
    FACE_TOP,
    SIDE_TOP_FACE,
    ChannelPath,
    LiftPath,
    arc_samples,
    channel_path,
    check_side,
    face_planes,
    lift_path,
    unit_vector,
)
from drawstring.cad.tiles import convex_solid, tile_solid
from drawstring.geometry.errors import InputError

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile

log = logging.getLogger(__name__)

HingeSide = Literal["top", "bottom"]

#: Length (mm) by which a cutting tool extends past the face it opens.
TOOL_OVERSHOOT_MM = 0.3
#: A bend this little (mm) below the profile's minimum radius is not reported (rounding).
BEND_RADIUS_SLACK_MM = 1e-6
#: Labels: text fits inside this fraction of the bottom face's inscribed radius.
LABEL_FILL = 0.6
#: Labels: digit width and spacing over digit height; stroke over height.
_DIGIT_WIDTH, _DIGIT_SPACING, _DIGIT_STROKE = 0.55, 0.22, 0.18
#: Glue recess depth as a fraction of the rubber strip thickness.
GLUE_RECESS_DEPTH_FRACTION = 0.5
#: A TPU hinge pin cut shorter than this many of its radii (to clear a channel or another pin)
#: is left out: a stub that short does not key the pad.
MIN_PIN_LENGTH_RADII = 1.0


# --------------------------------------------------------------------------------------------
# small geometry helpers


def _vec(point: NDArray[np.float64]) -> bd.Vector:
    return bd.Vector(float(point[0]), float(point[1]), float(point[2]))


def _plane(origin: NDArray[np.float64], normal: NDArray[np.float64]) -> bd.Plane:
    return bd.Plane(origin=_vec(origin), z_dir=_vec(unit_vector(normal)))


def channel_radius(profile: Profile) -> float:
    """Radius (mm) of a string channel: half of string diameter plus clearance."""
    return 0.5 * (profile.string_diameter_mm + profile.channel_clearance_mm)


def feature_wall_mm(profile: Profile) -> float:
    """Thinnest wall (mm) left between a feature and a tile face or another feature: a nozzle
    width, two kerfs, and at least 0.3 mm (the label strokes' limit too)."""
    return max(profile.nozzle_mm, 2.0 * profile.kerf_mm, 0.3)


def channel_min_face_mm(profile: Profile) -> float:
    """Narrowest side face (mm, edge length at mid-thickness) a string channel can open through:
    the bore and a :func:`feature_wall_mm` either side of it."""
    return 2.0 * (channel_radius(profile) + feature_wall_mm(profile))


def hinge_sink_depth(profile: Profile) -> float:
    """How deep (mm) the hinge features reach into a tile from its hinge face, pins aside (they
    are cut short around the channels): the TPU recess, the dovetail key, the glue recess or the
    screw and staple holes."""
    if profile.hinge_interlock == "through-holes":
        return profile.hinge_thickness_mm
    if profile.hinge_interlock == "dovetail":
        return 2.0 * profile.hinge_thickness_mm
    if profile.hinge_interlock == "glue-recess":
        return GLUE_RECESS_DEPTH_FRACTION * profile.hinge_thickness_mm
    return 0.25 * profile.thickness_mm


def channel_min_thickness_mm(profile: Profile) -> float:
    """Thinnest tile (mm) whose mid-thickness string channel keeps a :func:`feature_wall_mm`
    from the hinge features and the label sunk into its top and bottom faces."""
    sunk = max(hinge_sink_depth(profile), label_depth(profile))
    return 2.0 * (channel_radius(profile) + feature_wall_mm(profile) + sunk)


def _tube(path: ChannelPath, radius: float) -> bd.Solid:
    """Circular tube of ``radius`` around ``path``, extended straight past both openings."""
    overshoot = radius + TOOL_OVERSHOOT_MM
    start, end = path.control[0], path.control[3]
    outer_start = start - overshoot * path.start_tangent
    outer_end = end + overshoot * path.end_tangent
    offsets = path.control - start
    chord = unit_vector(end - start)
    if np.abs(offsets - np.outer(offsets @ chord, chord)).max() < 1e-9:
        # Straight: a plain cylinder (sweeping along a straight line has no defined frame).
        length = float(np.linalg.norm(outer_end - outer_start))
        return bd.Solid.make_cylinder(radius, length, _plane(outer_start, chord))
    edges = [
        bd.Edge.make_line(_vec(outer_start), _vec(start)),
        bd.Edge.make_bezier(*[_vec(p) for p in path.control]),
        bd.Edge.make_line(_vec(end), _vec(outer_end)),
    ]
    section = bd.Wire([bd.Edge.make_circle(radius, _plane(outer_start, path.start_tangent))])
    tube = bd.Solid.sweep(section, bd.Wire(edges), transition=bd.Transition.ROUND)
    return clean_solid(tube)


def string_channel(
    tile: NDArray[np.float64], enter_side: int, leave_side: int, profile: Profile
) -> bd.Solid:
    """Tool: the string channel through one tile.

    Parameters
    ----------
    tile : (8, 3) float, mm.
    enter_side, leave_side : side faces 0..3 the string enters and leaves through.
    profile : gives the bore diameter (string diameter + clearance).

    Returns
    -------
    Solid tube of diameter ``string + clearance`` swept along :func:`channel_path`; a bend
    tighter than ``profile.min_bend_radius_mm`` is logged (the tile is too small for it).
    """
    check_side(enter_side, "enter_side")
    check_side(leave_side, "leave_side")
    path = channel_path(tile, enter_side, leave_side)
    if path.min_radius < profile.min_bend_radius_mm - BEND_RADIUS_SLACK_MM:
        log.debug(
            "channel bend radius %.2f mm < profile minimum %.2f mm",
            path.min_radius,
            profile.min_bend_radius_mm,
        )
    return _tube(path, channel_radius(profile))


def lift_bore_depth_mm(
    tile: NDArray[np.float64], side: int, profile: Profile
) -> tuple[float, float]:
    """How deep ``tile`` is from side face ``side`` inward, and how deep it would have to be
    for the lift bore from that side (:func:`lift_path`) to keep a :func:`feature_wall_mm`
    from every other side face (mm).

    The bore's bend rises from mid-thickness to the top face, so it reaches about half the
    tile's thickness in from its side face whatever the tile's size: on a small tile it breaks
    out through the far side face.
    """
    tile = np.asarray(tile, dtype=np.float64)
    path = lift_path(tile, side)
    centroids, normals = face_planes(tile)
    points = np.vstack([path.entry[None], arc_samples(path.arc)])
    others = [k for k in range(4) if k != side]
    beyond = np.einsum("pd,kd->pk", points, normals[others]) - np.einsum(
        "kd,kd->k", centroids[others], normals[others]
    )
    overshoot = float(beyond.max()) + channel_radius(profile) + feature_wall_mm(profile)
    opposite = (side + 2) % 4
    depth = float((centroids[opposite] - path.entry) @ normals[opposite])
    return depth, depth + overshoot


def lift_chamfer(tile: NDArray[np.float64], path: LiftPath, profile: Profile) -> float:
    """Depth (mm) of the 45-degree chamfer at a lift bore's exit: ``max(radius, 0.5 mm)``, or 0
    (no chamfer) where its rim would come nearer than :func:`feature_wall_mm` to the top face's
    edges.  Not a shallower one: a chamfer whose cone starts in the bore's bend (under about
    0.55 mm for the shipped FDM profiles, measured on a 4.4 mm tile) gives a solid that OCCT
    meshes with open seams."""
    radius = channel_radius(profile)
    chamfer = max(radius, 0.5)
    top = np.asarray(tile, dtype=np.float64)[:4]
    margin = _footprint_margin(np.concatenate([top, top]), path.arc[2], path.end_tangent)
    return chamfer if margin >= radius + chamfer + feature_wall_mm(profile) else 0.0


#: How much thinner (mm, radius) a lift bore is cut where a string channel opens through the
#: same side face: the two tubes would otherwise share their cylinder just outside the face, and
#: OCCT then leaves seams that mesh open (saddle, 47 mm, 200 tiles: tile 98).
SHARED_OPENING_INSET_MM = 0.02


def lift_bore(
    tile: NDArray[np.float64], side: int, profile: Profile, *, shared: bool = False
) -> bd.Solid:
    """Tool: a channel from side ``side`` that leaves upward through the top face.

    Follows :func:`lift_path`.  The exit is chamfered at 45 degrees (depth
    :func:`lift_chamfer`) so the string, pulled upward, does not run over a sharp edge.
    ``shared``: a string channel opens through the same side face; the bore is then
    :data:`SHARED_OPENING_INSET_MM` thinner, inside that channel where they overlap.
    """
    tile = np.asarray(tile, dtype=np.float64)
    radius = channel_radius(profile) - (SHARED_OPENING_INSET_MM if shared else 0.0)
    path = lift_path(tile, side)
    if path.radius < profile.min_bend_radius_mm - BEND_RADIUS_SLACK_MM:
        log.debug(
            "lift bore bend radius %.2f mm < profile minimum %.2f mm",
            path.radius,
            profile.min_bend_radius_mm,
        )
    overshoot = radius + TOOL_OVERSHOOT_MM
    outer_start = path.entry - overshoot * path.start_tangent
    exit_point = path.arc[2]
    outer_end = exit_point + overshoot * path.end_tangent
    edges = [bd.Edge.make_line(_vec(outer_start), _vec(path.arc[0]))]
    edges.append(bd.Edge.make_three_point_arc(*[_vec(p) for p in path.arc]))
    edges.append(bd.Edge.make_line(_vec(exit_point), _vec(outer_end)))
    section = bd.Wire([bd.Edge.make_circle(radius, _plane(outer_start, path.start_tangent))])
    tube = clean_solid(bd.Solid.sweep(section, bd.Wire(edges), transition=bd.Transition.ROUND))
    chamfer = lift_chamfer(tile, path, profile)
    if chamfer <= 0.0:
        return tube
    cone_base = exit_point - chamfer * path.end_tangent
    height = chamfer + TOOL_OVERSHOOT_MM
    cone = bd.Solid.make_cone(radius, radius + height, height, _plane(cone_base, path.end_tangent))
    return clean_solid(fuse(tube, [cone]))


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


def _side_quad(tile: NDArray[np.float64], side: int) -> NDArray[np.float64]:
    """(4, 3): top k, top k+1, bottom k, bottom k+1 of side ``side``."""
    nxt = (side + 1) % 4
    return np.asarray(tile[[side, nxt, 4 + side, 4 + nxt]])


def _bilinear(quad: NDArray[np.float64], u: float, v: float) -> NDArray[np.float64]:
    """Point at (u along the top edge, v from top to bottom) of a side quad."""
    top = (1 - u) * quad[0] + u * quad[1]
    bottom = (1 - u) * quad[2] + u * quad[3]
    return np.asarray((1 - v) * top + v * bottom)


def _invert_bilinear(quad: NDArray[np.float64], point: NDArray[np.float64], u: float, v: float):
    """(u, v) of the point of a side quad nearest ``point`` (Gauss-Newton from a guess)."""
    for _ in range(20):
        residual = _bilinear(quad, u, v) - point
        du = (1 - v) * (quad[1] - quad[0]) + v * (quad[3] - quad[2])
        dv = ((1 - u) * quad[2] + u * quad[3]) - ((1 - u) * quad[0] + u * quad[1])
        jac = np.stack([du, dv], axis=1)
        step = np.linalg.lstsq(jac, -residual, rcond=None)[0]
        u, v = u + float(step[0]), v + float(step[1])
        if np.linalg.norm(step) < 1e-14:
            break
    return u, v


def _pocket(
    centre: NDArray[np.float64], outward: NDArray[np.float64], radius: float, depth: float
) -> bd.Solid:
    origin = centre + TOOL_OVERSHOOT_MM * outward
    return bd.Solid.make_cylinder(radius, depth + TOOL_OVERSHOOT_MM, _plane(origin, -outward))


def _pocket_fits(quad: NDArray[np.float64], u: float, v: float, radius: float) -> bool:
    """Whether a pocket circle at (u, v) stays inside the side face (mid-lines test)."""
    centre = _bilinear(quad, u, v)
    edges = (
        (_bilinear(quad, 0, 0), _bilinear(quad, 1, 0)),
        (_bilinear(quad, 0, 1), _bilinear(quad, 1, 1)),
        (_bilinear(quad, 0, 0), _bilinear(quad, 0, 1)),
        (_bilinear(quad, 1, 0), _bilinear(quad, 1, 1)),
    )
    for a, b in edges:
        direction = unit_vector(b - a)
        offset = centre - a
        distance = np.linalg.norm(offset - (offset @ direction) * direction)
        if distance < radius:
            return False
    return True


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

    Returns
    -------
    tool_a, tool_b : pocket cylinders for tile a and tile b.
    record : the pair, its assembled centre and polarity (tile a north out, tile b south out).
    """
    check_side(side_a, "side_a")
    check_side(side_b, "side_b")
    tile_a = np.asarray(tile_a, dtype=np.float64)
    tile_b = np.asarray(tile_b, dtype=np.float64)
    quad_a, quad_b = _side_quad(tile_a, side_a), _side_quad(tile_b, side_b)
    width = float(np.linalg.norm(_bilinear(quad_a, 1, 0.5) - _bilinear(quad_a, 0, 0.5)))
    u_a, v_a = 0.5 + offset_mm / width, 0.5
    centre = _bilinear(quad_a, u_a, v_a)
    u_b, v_b = _invert_bilinear(quad_b, centre, 1.0 - u_a, v_a)
    radius = 0.5 * profile.magnet_diameter_mm + profile.magnet_clearance_mm
    depth = profile.magnet_height_mm + profile.magnet_clearance_mm
    fits = _pocket_fits(quad_a, u_a, v_a, radius) and _pocket_fits(quad_b, u_b, v_b, radius)
    tools = []
    for flat, side, u, v in (
        (flat_a if flat_a is not None else tile_a, side_a, u_a, v_a),
        (flat_b if flat_b is not None else tile_b, side_b, u_b, v_b),
    ):
        flat = np.asarray(flat, dtype=np.float64)
        _, normals = face_planes(flat)
        tools.append(_pocket(_bilinear(_side_quad(flat, side), u, v), normals[side], radius, depth))
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


def _segment_rectangles(text: str, height: float) -> list[NDArray[np.float64]]:
    """Seven-segment outlines of ``text`` ((4, 2) rectangles, mm), centred on the origin.

    Segments of a digit are separated by small gaps, so the rectangles never touch.
    """
    width, stroke = _DIGIT_WIDTH * height, _DIGIT_STROKE * height
    gap = 0.2 * stroke
    spacing = _DIGIT_SPACING * height
    total = len(text) * width + (len(text) - 1) * spacing
    half = 0.5 * height
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
                np.array([[x0 + a, c], [x0 + b, c], [x0 + b, d], [x0 + a, d]]) - [0.0, half]
            )
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
    if np.cross(axis_x, axis_y) @ direction * _signed_area(outline) < 0:
        faces = [list(reversed(f)) for f in faces]
    return polyhedron_solid(points, faces)


def _cross2(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """z component of the cross product of 2D vectors (..., 2)."""
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def _signed_area(outline: NDArray[np.float64]) -> float:
    x, y = outline[:, 0], outline[:, 1]
    return float(0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def label_depth(profile: Profile) -> float:
    """Engraving depth (mm) of tile labels: 7 % of the tile thickness, within 0.3 .. 2 mm."""
    return float(np.clip(0.07 * profile.thickness_mm, 0.3, 2.0))


#: Per tile of a hinge (a, b): the other corners of its hinge face that hold hinge strips, or
#: None for all of them (see :func:`strip_room`).
StripNeighbours = tuple[Sequence[int] | None, Sequence[int] | None]

#: A footprint on a tile face: a polyline ((k, 3) float, mm; one point for a disc) and the
#: radius (mm) it is thickened by.
Footprint = tuple[NDArray[np.float64], float]


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


def hinge_face_footprints(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    pins: HingePins | None = None,
    neighbours: StripNeighbours = (None, None),
) -> tuple[list[Footprint], list[Footprint]]:
    """What a hinge puts on the bottom faces of tile a and of tile b (where tile numbers are
    engraved): a bottom hinge's strip (its recess, or the strip glued or screwed on; the holes
    under it lie inside) and the pins whose holes open there (a bottom hinge's pins, a top
    hinge's pins that run through)."""
    tile_a, tile_b = np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64)
    found: tuple[list[Footprint], list[Footprint]] = ([], [])
    if side == "bottom":
        frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
        for kept in found:
            kept.append((frame.points, 0.5 * profile.hinge_width_mm))
    for kept, pin in zip(found, pins or (None, None), strict=True):
        if pin is None:
            continue
        if side == "bottom":
            kept.append((pin.point[None], pin_radius(profile)))
        elif pin.through:
            kept.append(((pin.point - pin.depth * pin.normal)[None], pin_radius(profile)))
    return found


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
    cover or cut the digits, and whose recesses overlapping an engraving made OCCT's cut fail).
    Returns ``None`` (and logs) when the strokes would be thinner than the machine can make
    (:func:`feature_wall_mm`: ``max(nozzle, 2 kerf, 0.3 mm)``).
    """
    if tile_id < 0:
        raise InputError(f"tile_id = {tile_id} must be >= 0")
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
    inradius = float(np.min(np.abs(_cross2(edge, -corners2d)) / np.linalg.norm(edge, axis=1)))
    text = str(tile_id)
    width_over_height = len(text) * _DIGIT_WIDTH + (len(text) - 1) * _DIGIT_SPACING
    height = LABEL_FILL * inradius / float(np.hypot(0.5 * width_over_height, 0.5))
    min_stroke = feature_wall_mm(profile)
    if keep_out:
        footprints = []
        for points, radius in keep_out:
            rel = np.asarray(points, dtype=np.float64).reshape(-1, 3) - centre
            footprints.append((np.stack([rel @ axis_x, rel @ axis_y], axis=1), float(radius)))
        height = _label_clear_height(height, width_over_height, footprints, min_stroke)
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


# --------------------------------------------------------------------------------------------
# hinges


@dataclass(frozen=True)
class HingeParts:
    """What one hinge adds: a separate part (TPU pad or rubber strip) and tools for its tiles.

    Attributes
    ----------
    pad : the part, or None when only the tools were asked for.
    tools_a, tools_b : tools to subtract from tile a and from tile b.
    notes : interlock parts that did not fit and were left out.
    """

    pad: bd.Solid | None
    tools_a: tuple[bd.Solid, ...]
    tools_b: tuple[bd.Solid, ...]
    notes: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class _HingeFrame:
    """Layout of a hinge strip on the hinge face plane (mm).

    points : (k, 3) polyline: end inside tile a, corner a, [corner b], end inside tile b.
    normal : (3,) outward normal of the hinge face (up for "top", down for "bottom").
    halves : per tile, (corner point, unit direction from the corner into the tile).
    lengths : per tile, how far (mm) the strip runs from the corner into the tile.
    """

    points: NDArray[np.float64]
    normal: NDArray[np.float64]
    halves: tuple[tuple[NDArray[np.float64], NDArray[np.float64]], ...]
    lengths: tuple[float, float]


def strip_room(
    profile: Profile,
    ring: NDArray[np.float64] | None = None,
    corner: int = 0,
    others: Sequence[int] | None = None,
) -> float:
    """How far (mm) a hinge strip's end stays from the centre of its tile's hinge face, so that
    the strips of the face's corners, which all run towards that centre, keep a
    :func:`feature_wall_mm` between them: half the strip width and a wall, and, given the
    face's corners ``ring`` ((4, 3), mm), at least ``(width + wall) / (2 sin(angle / 2))``,
    where ``angle`` is the smallest one at the centre between ``corner`` and another corner of
    the face that holds a strip (``others``; None: any corner).  Two strips ending that far out
    on rays that far apart are a width and a wall apart; on a square face that is 0.71 (width
    + wall), more than half a width and a wall for any strip over 1.41 walls wide.  Recesses of
    neighbouring corners' strips overlapping in thin slivers made OCCT's cut of a tile fail."""
    width, wall = profile.hinge_width_mm, feature_wall_mm(profile)
    room = 0.5 * width + wall
    if ring is None:
        return room
    spokes = np.asarray(ring, dtype=np.float64) - np.asarray(ring, dtype=np.float64).mean(axis=0)
    lengths = np.linalg.norm(spokes, axis=1)
    if lengths.min() < 1e-12:
        return float("inf")
    units = spokes / lengths[:, None]
    crowd = [k for k in (range(4) if others is None else others) if k != corner]
    if not crowd:
        return room
    cosines = units[crowd] @ units[corner]
    half_angle = 0.5 * float(np.arccos(np.clip(cosines.max(), -1.0, 1.0)))
    if half_angle < 1e-9:
        return float("inf")
    return max(room, (width + wall) / (2.0 * np.sin(half_angle)))


def strip_min_reach_mm(
    profile: Profile,
    ring: NDArray[np.float64] | None = None,
    corner: int = 0,
    others: Sequence[int] | None = None,
) -> float:
    """Shortest distance (mm) from a hinged corner to its face's centre that still leaves the
    strip half a width of its own in the tile (see :func:`strip_room`)."""
    return strip_room(profile, ring, corner, others) + 0.5 * profile.hinge_width_mm


def hinge_strip_lengths(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> tuple[float, float]:
    """How far (mm) a hinge's strip runs into tile a and into tile b: half the profile's pad
    length, less where the strip's end would come within :func:`strip_room` of the centre of
    the tile's hinge face (never under half the strip width).  ``neighbours``: per tile, the
    other corners of its hinge face that hold strips (None: all of them)."""
    frame = _hinge_frame(
        np.asarray(tile_a, dtype=np.float64),
        corner_a,
        np.asarray(tile_b, dtype=np.float64),
        corner_b,
        side,
        profile,
        neighbours,
    )
    return frame.lengths


def _hinge_frame(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> _HingeFrame:
    """The strip of a hinge: half the profile's pad length into each tile, less where its end
    would come within :func:`strip_room` of the centre of the tile's hinge face (the strips of
    neighbouring corners met there: their recesses overlapping in thin slivers made OCCT's
    cut of a tile fail)."""
    if side not in ("top", "bottom"):
        raise InputError(f"hinge side {side!r} must be 'top' or 'bottom'")
    for corner, name in ((corner_a, "corner_a"), (corner_b, "corner_b")):
        if corner not in (0, 1, 2, 3):
            raise InputError(f"{name} = {corner} must be a corner index 0..3")
    face = FACE_TOP if side == "top" else FACE_BOTTOM
    shift = 0 if side == "top" else 4
    normal = unit_vector(face_planes(tile_a)[1][face] + face_planes(tile_b)[1][face])
    point_a, point_b = tile_a[shift + corner_a], tile_b[shift + corner_b]
    level = 0.5 * (point_a + point_b) @ normal
    half_length = 0.5 * profile.hinge_pad_length_mm
    halves = []
    lengths = []
    for tile, corner, point, others in zip(
        (tile_a, tile_b), (corner_a, corner_b), (point_a, point_b), neighbours, strict=True
    ):
        point = point - (point @ normal - level) * normal
        ring = tile[shift : shift + 4]
        towards = ring.mean(axis=0) - point
        towards = towards - (towards @ normal) * normal
        halves.append((point, unit_vector(towards)))
        reach = float(np.linalg.norm(towards)) - strip_room(profile, ring, corner, others)
        lengths.append(max(min(half_length, reach), 0.5 * profile.hinge_width_mm))
    (pa, da), (pb, db) = halves
    points = [pa + lengths[0] * da]
    for candidate in (pa, pb, pb + lengths[1] * db):
        if np.linalg.norm(candidate - points[-1]) > 1e-6:
            points.append(candidate)
    kept = [points[0]]  # drop interior points where the polyline runs straight on
    for i in range(1, len(points) - 1):
        turn = np.cross(unit_vector(points[i] - kept[-1]), unit_vector(points[i + 1] - points[i]))
        if np.linalg.norm(turn) > 1e-6:
            kept.append(points[i])
    kept.append(points[-1])
    return _HingeFrame(np.array(kept), normal, (halves[0], halves[1]), (lengths[0], lengths[1]))


def _strip_outline(points: NDArray[np.float64], width: float, normal: NDArray) -> bd.Face:
    """Planar face: the polyline ``points`` thickened to ``width`` with round ends and joints."""
    points = _merge_short_segments(points, width)
    if len(points) == 2:
        return _stadium(points[0], points[1], width, normal)
    wire = bd.Wire.make_polygon([_vec(p) for p in points], close=False)
    outline = wire.offset_2d(0.5 * width, kind=bd.Kind.ARC, side=bd.Side.BOTH)
    return bd.Face(outline)


def _merge_short_segments(points: NDArray[np.float64], width: float) -> NDArray[np.float64]:
    """Join interior polyline points closer than ``width`` into their midpoint.

    OCCT's 2D offset fails on a polyline whose middle segment is shorter than the offset (a
    hinge whose two corners are a fraction of a millimetre apart); at that scale the pad is
    the same with the two joints merged.
    """
    pts = [np.asarray(p, dtype=np.float64) for p in points]
    k = 1
    while k < len(pts) - 2:
        if np.linalg.norm(pts[k + 1] - pts[k]) < width:
            pts[k : k + 2] = [0.5 * (pts[k] + pts[k + 1])]
        else:
            k += 1
    return np.array(pts)


def _stadium(
    a: NDArray[np.float64], b: NDArray[np.float64], width: float, normal: NDArray[np.float64]
) -> bd.Face:
    """Planar face: segment ``a``-``b`` thickened to ``width`` with round ends."""
    along = unit_vector(b - a)
    across = 0.5 * width * unit_vector(np.cross(normal, along))
    cap = 0.5 * width * along
    edges = [
        bd.Edge.make_line(_vec(a - across), _vec(b - across)),
        bd.Edge.make_three_point_arc(_vec(b - across), _vec(b + cap), _vec(b + across)),
        bd.Edge.make_line(_vec(b + across), _vec(a + across)),
        bd.Edge.make_three_point_arc(_vec(a + across), _vec(a - cap), _vec(a - across)),
    ]
    return bd.Face(bd.Wire(edges))


def _slab(
    frame: _HingeFrame, points: NDArray[np.float64], width: float, start: float, stop: float
) -> bd.Solid:
    """The strip outline between depths ``start`` and ``stop`` (mm, positive into the tiles)."""
    face = _strip_outline(points - start * frame.normal, width, frame.normal)
    return clean_solid(bd.Solid.extrude(face, _vec(-(stop - start) * frame.normal)))


def _footprint_margin(
    tile: NDArray[np.float64],
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    depth: float | None = None,
) -> float:
    """Smallest signed distance (mm) from the line through ``point`` along ``normal`` to the
    edges of the tile's top and bottom faces (negative: outside a face).

    With ``depth``, only the part of the tile within ``depth`` mm under the face that
    ``point`` lies on counts (a blind hole): the edges of that face and of the tile's section
    ``depth`` below it (the side faces are planar, so the margin in between is no smaller).
    """
    helper = [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0]
    axis_u = unit_vector(np.cross(normal, helper))
    axis_v = np.cross(normal, axis_u)
    rings = [tile[0:4], tile[4:8]]
    if depth is not None:
        heights = [abs(float((ring.mean(axis=0) - point) @ normal)) for ring in rings]
        face = int(np.argmin(heights))
        span = abs(float((rings[1 - face].mean(axis=0) - rings[face].mean(axis=0)) @ normal))
        share = min(1.0, depth / span) if span > 0 else 1.0
        rings = [rings[face], rings[face] + share * (rings[1 - face] - rings[face])]
    margins = []
    for ring in rings:
        rel = ring - point
        poly = np.stack([rel @ axis_u, rel @ axis_v], axis=1)
        edge = np.roll(poly, -1, axis=0) - poly
        signed = _cross2(edge, -poly) / np.linalg.norm(edge, axis=1)
        margins.append(float(np.min(signed * np.sign(_signed_area(poly)))))
    return min(margins)


def _depth_to_opposite(
    tile: NDArray[np.float64], side: HingeSide, point: NDArray[np.float64], normal: NDArray
) -> tuple[float, bool]:
    """Distance (mm) along ``-normal`` from ``point`` on the hinge face to the opposite face,
    shortest over a pin's rim when the faces are not parallel, and whether they are parallel."""
    centroids, normals = face_planes(tile)
    face = FACE_BOTTOM if side == "top" else FACE_TOP
    cosine = float(-normal @ normals[face])
    distance = float((centroids[face] - point) @ normals[face] / cosine)
    return distance, abs(abs(cosine) - 1.0) < 1e-12


def _place_holes(
    tile: NDArray[np.float64],
    corner: NDArray[np.float64],
    direction: NDArray[np.float64],
    normal: NDArray[np.float64],
    stations: tuple[float, ...],
    radius: float,
    wall: float,
    limit: float = np.inf,
    depth: float | None = None,
) -> tuple[list[NDArray[np.float64]], int]:
    """Hole axes along one half of a strip, each slid inward (up to ``limit`` mm from the
    corner) until it keeps ``wall`` from the tile's side faces (within ``depth`` of the face
    for a blind hole, see :func:`_footprint_margin`), and how many stations never fit."""
    placed, missing = [], 0
    for station in stations:
        candidates = np.linspace(station, station + 4.0 * radius, 17)
        for distance in candidates[candidates <= limit + 1e-9]:
            point = corner + distance * direction
            if _footprint_margin(tile, point, normal, depth) >= radius + wall:
                placed.append(point)
                break
        else:
            missing += 1
    return placed, missing


def _cylinder_between(
    point: NDArray[np.float64],
    normal: NDArray[np.float64],
    radius: float,
    start: float,
    stop: float,
) -> bd.Solid:
    """Cylinder on the axis through ``point`` along ``-normal`` between two depths (mm)."""
    return bd.Solid.make_cylinder(radius, stop - start, _plane(point - start * normal, -normal))


def pin_radius(profile: Profile) -> float:
    """Radius (mm) of a through-holes hinge's TPU pin: ``max(0.75 width, 1.5 nozzle)``."""
    return max(0.75 * profile.hinge_width_mm, 1.5 * profile.nozzle_mm)


@dataclass(frozen=True)
class KeepOut:
    """Solids a hinge pin keeps a wall away from, as a union of balls.

    Attributes
    ----------
    centres : (k, 3) float, mm, sampled densely (:data:`_KEEP_OUT_SPACING_MM`) along channels,
        lift bores, hinge strips and pins.
    radii : (k,) float, mm.
    """

    centres: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    radii: NDArray[np.float64] = field(default_factory=lambda: np.zeros(0))

    def __add__(self, other: KeepOut) -> KeepOut:
        return KeepOut(
            np.vstack([self.centres, other.centres]), np.concatenate([self.radii, other.radii])
        )


#: Spacing (mm) of the balls of a :class:`KeepOut` along a centre line: the union of balls of
#: radius >= 0.3 mm this far apart falls short of the tube by under 0.005 mm.
_KEEP_OUT_SPACING_MM = 0.1


def _resample(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """A polyline ((k, 3) mm) with points added so that none are more than
    :data:`_KEEP_OUT_SPACING_MM` apart."""
    out = [points[:1]]
    for a, b in zip(points[:-1], points[1:], strict=True):
        count = max(1, int(np.ceil(np.linalg.norm(b - a) / _KEEP_OUT_SPACING_MM)))
        out.append(a + np.linspace(0.0, 1.0, count + 1)[1:, None] * (b - a))
    return np.vstack(out)


def _tube_keep_out(points: NDArray[np.float64], radius: float) -> KeepOut:
    centres = _resample(np.asarray(points, dtype=np.float64))
    return KeepOut(centres, np.full(len(centres), radius))


def channel_keep_out(
    tile: NDArray[np.float64], enter_side: int, leave_side: int, profile: Profile
) -> KeepOut:
    """The string channel of one route step through ``tile`` ((8, 3), mm) as balls, or its lift
    bore when a side is ``SIDE_TOP_FACE`` (the chamfered exit as balls of the chamfer's top
    radius)."""
    tile = np.asarray(tile, dtype=np.float64)
    radius = channel_radius(profile)
    if SIDE_TOP_FACE not in (enter_side, leave_side):
        return _tube_keep_out(channel_path(tile, enter_side, leave_side).points(129), radius)
    side = enter_side if leave_side == SIDE_TOP_FACE else leave_side
    path = lift_path(tile, side)
    chamfer = lift_chamfer(tile, path, profile)
    exit_point = path.arc[2]
    bore = _tube_keep_out(
        np.vstack([path.entry[None], arc_samples(path.arc), exit_point[None]]), radius
    )
    top = exit_point + (radius + TOOL_OVERSHOOT_MM) * path.end_tangent
    flare = _tube_keep_out(np.stack([exit_point - chamfer * path.end_tangent, top]), radius)
    return bore + KeepOut(flare.centres, flare.radii + chamfer)


@dataclass(frozen=True)
class HingePin:
    """One TPU pin of a through-holes hinge and the hole it fills.

    Attributes
    ----------
    point : (3,) float, mm, where the pin's axis meets the hinge face plane.
    normal : (3,) float, the hinge face's outward normal; the pin runs along its opposite.
    depth : float, mm, how far below the hinge face the pin ends (it starts at the recess floor,
        ``hinge_thickness_mm`` deep).
    through : whether it ends on the opposite face (its hole is then cut on past that face).
    """

    point: NDArray[np.float64]
    normal: NDArray[np.float64]
    depth: float
    through: bool


#: Per tile half (tile a, tile b) of a hinge: its pin, or None where it has none.
HingePins = tuple[HingePin | None, HingePin | None]


@dataclass(frozen=True)
class PinPlan:
    """The pins of one through-holes hinge (:func:`plan_pins`).

    Attributes
    ----------
    pins : per tile (a, b), the pin or None where none fits.
    short : per tile, whether the pin was cut short to clear another feature.
    notes : one line per pin that does not fit, for the hinge's record.
    """

    pins: HingePins
    short: tuple[bool, bool]
    notes: tuple[str, ...] = field(default=())


def pin_keep_out(pin: HingePin, profile: Profile) -> KeepOut:
    """A planned pin as balls along its axis."""
    start = pin.point - profile.hinge_thickness_mm * pin.normal
    return _tube_keep_out(
        np.stack([start, pin.point - pin.depth * pin.normal]), pin_radius(profile)
    )


def strip_keep_outs(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> tuple[KeepOut, KeepOut]:
    """A TPU hinge's strip (the recess it sits in) as balls, the half in tile a and in tile b:
    from each hinged corner inward as far as the strip runs, half the strip thickness deep."""
    tile_a, tile_b = np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64)
    frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = 0.5 * profile.hinge_thickness_mm
    radius = float(np.hypot(0.5 * profile.hinge_width_mm, depth))
    found = []
    for (corner, direction), length in zip(frame.halves, frame.lengths, strict=True):
        start = corner - depth * frame.normal
        found.append(_tube_keep_out(np.stack([start, start + length * direction]), radius))
    return found[0], found[1]


def _clear_depth(
    point: NDArray[np.float64],
    axis: NDArray[np.float64],
    radius: float,
    start: float,
    stop: float,
    keep_out: KeepOut,
    wall: float,
) -> float:
    """The deepest end (mm, at most ``stop``) of a cylinder of ``radius`` on the axis
    ``point + t axis`` from ``t = start`` that stays ``wall`` away from every ball of
    ``keep_out``; below ``start`` when no length does."""
    if not len(keep_out.radii):
        return stop
    rel = keep_out.centres - point
    along = rel @ axis
    off_axis = np.linalg.norm(rel - along[:, None] * axis, axis=1)
    reach = keep_out.radii + wall
    lateral = np.maximum(off_axis - radius, 0.0)
    near = lateral < reach
    # Axial half-extent of each inflated ball where it meets the infinite cylinder.
    half = np.sqrt(np.maximum(reach[near] ** 2 - lateral[near] ** 2, 0.0))
    low, high = along[near] - half, along[near] + half
    below = high > start  # balls wholly on the hinge face's side of the pin are no obstacle
    if not np.any(below):
        return stop
    if np.any(low[below] <= start):
        return start - 1.0
    return float(min(stop, low[below].min()))


def plan_pins(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    keep_out: tuple[KeepOut | None, KeepOut | None] = (None, None),
    neighbours: StripNeighbours = (None, None),
) -> PinPlan:
    """Where the TPU pins of a through-holes hinge go, one per tile (a "lollipop").

    Each pin sits at the inner end of the strip, slid inward until it keeps a wall from the
    tile's side faces, and runs from the recess floor to the opposite face (blind, one diameter
    short of it, when that face is tilted).  Where side faces leaning in leave no such room
    through the whole tile, the pin is blind: half the tile deep, or the shortest that keys
    the pad, whichever keeps its wall down to its end.  ``keep_out`` per tile (channels, lift
    bores, other hinges' strips and pins, see :class:`KeepOut`) cuts a pin short to keep a wall
    from them; a pin shorter than ``MIN_PIN_LENGTH_RADII`` radii is left out.

    ``keep_out`` entries are None for no other features (only the tile's edges limit the pin).
    """
    tiles = (np.asarray(tile_a, dtype=np.float64), np.asarray(tile_b, dtype=np.float64))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    radius = pin_radius(profile)
    wall = max(profile.nozzle_mm, 0.3)
    floor = profile.hinge_thickness_mm
    pins: list[HingePin | None] = []
    short = [False, False]
    notes: list[str] = []
    for index, (tile, (corner, direction), length, keep, name) in enumerate(
        zip(tiles, frame.halves, frame.lengths, keep_out, ("a", "b"), strict=True)
    ):
        # the axis stays under the strip: a pin beyond its end would not hold it
        points, _ = _place_holes(
            tile, corner, direction, frame.normal, (length - radius,), radius, wall, length
        )
        blind = None
        if not points:
            # Side faces leaning in under the hinge corner (a curved design's tiles) leave no
            # room for a pin through the whole tile; a blind one keeps its wall only as deep
            # as it goes: half the tile, else the shortest pin that still keys the pad.
            span = abs(float((tile[4:8].mean(axis=0) - tile[0:4].mean(axis=0)) @ frame.normal))
            for tried in (0.5 * span, floor + 2.0 * MIN_PIN_LENGTH_RADII * radius):
                points, _ = _place_holes(
                    tile, corner, direction, frame.normal, (length - radius,), radius, wall,
                    length, tried,
                )  # fmt: skip
                if points:
                    blind = tried
                    break
        if not points:
            notes.append(f"pin in tile {name} left out: it does not fit under the strip")
            pins.append(None)
            continue
        point = points[0]
        depth, through = _depth_to_opposite(tile, side, point, frame.normal)
        if not through:
            depth -= radius * 2.0  # tilted opposite face: keep the hole blind
        if blind is not None and blind < depth:
            depth, through = blind, False
        if keep is not None:
            clear = _clear_depth(point, -frame.normal, radius, floor, depth, keep, wall)
            if clear < depth:
                depth, through, short[index] = clear, False, True
        if depth - floor < MIN_PIN_LENGTH_RADII * radius:
            short[index] = False
            notes.append(f"pin in tile {name} left out: no room clear of the tile's other features")
            pins.append(None)
            continue
        pins.append(HingePin(point, frame.normal, float(depth), through))
    return PinPlan((pins[0], pins[1]), (short[0], short[1]), tuple(notes))


def _tpu_pad(
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]],
    frame: _HingeFrame,
    corners: tuple[int, int],
    side: HingeSide,
    profile: Profile,
    build_pad: bool,
    pins: HingePins | None,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Dual-material FDM pad: a TPU strip sunk into both tiles, keyed by pins or a dovetail."""
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    wall = max(profile.nozzle_mm, 0.3)
    recess = _slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, thickness)
    tools: tuple[list[bd.Solid], list[bd.Solid]] = ([recess], [recess])
    keys: list[bd.Solid] = []
    notes: list[str] = []
    if profile.hinge_interlock == "through-holes":
        if pins is None:
            plan = plan_pins(
                tiles[0], corners[0], tiles[1], corners[1], side, profile, neighbours=neighbours
            )
            pins = plan.pins
            notes += plan.notes
        radius = pin_radius(profile)
        for index, pin in enumerate(pins):
            if pin is None:
                continue
            stop = pin.depth + (TOOL_OVERSHOOT_MM if pin.through else 0.0)
            # the hole starts at the recess floor, like the pin: cutting it from above the
            # surface through the recess left it uncut on some hinges (OCCT)
            tools[index].append(_cylinder_between(pin.point, frame.normal, radius, thickness, stop))
            # The pin starts at the strip's underside: starting it inside the strip (which
            # the union makes no different where the strip covers it) left OCCT's fuse
            # non-manifold on some hinges.
            keys.append(_cylinder_between(pin.point, frame.normal, radius, thickness, pin.depth))
    else:
        for index, (tile, (corner, direction), half) in enumerate(
            zip(tiles, frame.halves, frame.lengths, strict=True)
        ):
            # Dovetail: a key 1.8 x wider than the strip just above it, held by the narrow neck.
            key_width = 1.8 * width
            inner = next(
                (
                    distance
                    for distance in np.linspace(0.0, half, 41)
                    if _footprint_margin(tile, corner + distance * direction, frame.normal)
                    >= 0.5 * key_width + wall
                ),
                None,
            )
            if inner is None or half - inner < 0.5 * width:
                notes.append("dovetail key does not fit in the pad length")
                continue
            segment = np.stack([corner + inner * direction, corner + half * direction])
            key = _slab(frame, segment, key_width, 0.5 * thickness, 2.0 * thickness)
            tools[index].append(key)
            keys.append(key)
    pad = None
    if build_pad:
        pad = clean_solid(fuse(_slab(frame, frame.points, width, 0.0, thickness), keys))
    return HingeParts(pad, tuple(tools[0]), tuple(tools[1]), tuple(notes))


def glue_recess(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Laser-cut rubber hinge: a shallow recess where the strip is glued, and the strip itself.

    The recess is ``GLUE_RECESS_DEPTH_FRACTION`` of the strip thickness deep and follows the
    strip outline (``hinge_width_mm`` wide, ``hinge_pad_length_mm`` long, shorter on small tiles:
    :func:`hinge_strip_lengths`); the strip (``pad``) sits in it and stands proud by the rest of
    its thickness.
    """
    tile_a, tile_b = np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float)
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
    depth = GLUE_RECESS_DEPTH_FRACTION * thickness
    recess = (_slab(frame, frame.points, width, -TOOL_OVERSHOOT_MM, depth),)
    pad = _slab(frame, frame.points, width, depth - thickness, depth) if build_pad else None
    return HingeParts(pad, recess, recess)


@dataclass(frozen=True)
class StripHoles:
    """Pilot holes of a plywood hinge strip (:func:`strip_hole_plan`).

    Attributes
    ----------
    points : per tile (a, b), where each hole's axis meets the hinge face (mm).
    missing : per tile, how many of its holes found no room (they are left out).
    normal : (3,) float, the hinge face's outward normal (the holes run along ``-normal``).
    radius, depth : float, mm.
    kind : ``"screw"`` (one per hole) or ``"staple"`` (one per pair of holes across the strip).
    """

    points: tuple[tuple[NDArray[np.float64], ...], tuple[NDArray[np.float64], ...]]
    missing: tuple[int, int]
    normal: NDArray[np.float64]
    radius: float
    depth: float
    kind: Literal["screw", "staple"]

    @property
    def made(self) -> int:
        """How many holes the strip gets."""
        return len(self.points[0]) + len(self.points[1])

    @property
    def fasteners(self) -> int:
        """Screws, or staples (a staple needs both holes of its pair), the strip takes."""
        if self.kind == "screw":
            return self.made
        return sum(len(points) == 2 for points in self.points)


def _strip_holes_on(
    tiles: tuple[NDArray[np.float64], NDArray[np.float64]], frame: _HingeFrame, profile: Profile
) -> StripHoles:
    """The pilot holes of the strip laid out by ``frame`` (see :func:`strip_hole_plan`)."""
    width = profile.hinge_width_mm
    wall = max(profile.tool_diameter_mm, 1.0)
    depth = 0.25 * profile.thickness_mm
    screws = profile.hinge_interlock == "screws"
    radius = 0.5 * float(np.clip(0.12 * width, 2.0, 5.0)) if screws else 0.5
    points: list[tuple[NDArray[np.float64], ...]] = []
    missing: list[int] = []
    for tile, (corner, direction), half in zip(tiles, frame.halves, frame.lengths, strict=True):
        # every hole stays under the strip: one beyond its end would hold nothing
        if screws:
            found, lost = _place_holes(
                tile, corner, direction, frame.normal, (half / 3, 2 * half / 3), radius, wall,
                half - radius, depth,
            )  # fmt: skip
        else:
            across = 0.25 * width * unit_vector(np.cross(frame.normal, direction))
            found, lost = [], 0
            for shift in (across, -across):
                hole, miss = _place_holes(
                    tile, corner + shift, direction, frame.normal, (half / 2,), radius, wall,
                    half - radius, depth,
                )  # fmt: skip
                found += hole
                lost += miss
        points.append(tuple(found))
        missing.append(lost)
    return StripHoles(
        (points[0], points[1]),
        (missing[0], missing[1]),
        frame.normal,
        radius,
        depth,
        "screw" if screws else "staple",
    )


def strip_hole_plan(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    neighbours: StripNeighbours = (None, None),
) -> StripHoles:
    """Where a plywood hinge strip is screwed or stapled to its two tiles.

    Screws: two holes per tile at a third and two thirds of the half strip, diameter
    ``clip(0.12 width, 2, 5) mm``; staples: one pair of 1 mm holes per tile across the strip.
    Holes are a quarter of the tile thickness deep; each slides inward along the strip (staying
    under it) until it keeps ``max(tool diameter, 1 mm)`` from the tile's side faces down to
    that depth, and one that finds no room is left out (counted in ``missing``).
    """
    tiles = (np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    return _strip_holes_on(tiles, frame, profile)


def strip_holes(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """Plywood hinge: the rubber strip lying on the face and the pilot holes of
    :func:`strip_hole_plan` for screws or staples.  ``pad`` is the strip, touching the face.
    Holes left out are not noted here: the design counts them for all hinges at once."""
    tiles = (np.asarray(tile_a, dtype=float), np.asarray(tile_b, dtype=float))
    frame = _hinge_frame(tiles[0], corner_a, tiles[1], corner_b, side, profile, neighbours)
    holes = _strip_holes_on(tiles, frame, profile)
    tools = tuple(
        tuple(
            _cylinder_between(point, frame.normal, holes.radius, -TOOL_OVERSHOOT_MM, holes.depth)
            for point in points
        )
        for points in holes.points
    )
    thickness, width = profile.hinge_thickness_mm, profile.hinge_width_mm
    pad = _slab(frame, frame.points, width, -thickness, 0.0) if build_pad else None
    return HingeParts(pad, tools[0], tools[1])


def hinge_pad(
    tile_a: NDArray[np.float64],
    corner_a: int,
    tile_b: NDArray[np.float64],
    corner_b: int,
    side: HingeSide,
    profile: Profile,
    build_pad: bool = True,
    pins: HingePins | None = None,
    neighbours: StripNeighbours = (None, None),
) -> HingeParts:
    """The hinge part and tile tools for the profile's process.

    Parameters
    ----------
    tile_a, tile_b : (8, 3) float, mm, the two tiles in the fabrication (flat) pose; their hinge
        faces lie in one plane.
    corner_a, corner_b : hinged corners 0..3.
    side : ``"top"`` or ``"bottom"``: the face whose corners the hinge joins.
    profile : ``hinge_interlock`` picks the kind.  ``through-holes`` / ``dovetail``: a TPU pad
        ``hinge_thickness_mm`` thick and ``hinge_width_mm`` wide running ``hinge_pad_length_mm``
        / 2 from each corner into its tile (less on small tiles: :func:`hinge_strip_lengths`),
        sunk flush into both tiles, keyed by a TPU pin through each tile (diameter
        ``max(1.5 width, 3 nozzle)``, see :func:`plan_pins`) or by a key 1.8 x wider under the
        strip.  ``glue-recess``: :func:`glue_recess`.  ``screws`` / ``staples``:
        :func:`strip_holes`.
    build_pad : also build the part (tile jobs only need the tools).
    pins : ``through-holes`` only: the pins as :func:`plan_pins` placed them around the tiles'
        other features (default: planned here, clear of the tiles' edges only).
    neighbours : per tile, the other corners of its hinge face holding strips, which the strip
        stops short of (:func:`strip_room`; default: all of them).

    Returns
    -------
    HingeParts: the pad (touching the tiles once the tools are cut, not overlapping them) and
    the tools to subtract from tile a and from tile b.
    """
    tile_a = np.asarray(tile_a, dtype=np.float64)
    tile_b = np.asarray(tile_b, dtype=np.float64)
    if profile.hinge_interlock in ("through-holes", "dovetail"):
        frame = _hinge_frame(tile_a, corner_a, tile_b, corner_b, side, profile, neighbours)
        return _tpu_pad(
            (tile_a, tile_b),
            frame,
            (corner_a, corner_b),
            side,
            profile,
            build_pad,
            pins,
            neighbours,
        )
    if profile.hinge_interlock == "glue-recess":
        return glue_recess(tile_a, corner_a, tile_b, corner_b, side, profile, build_pad, neighbours)
    return strip_holes(tile_a, corner_a, tile_b, corner_b, side, profile, build_pad, neighbours)


# --------------------------------------------------------------------------------------------
# trims and the batched cut


def trim_tool(points: NDArray[np.float64]) -> bd.Solid:
    """Tool: the convex polyhedron spanned by ``points`` ((k, 3) float, mm), to subtract."""
    array = np.asarray(points, dtype=np.float64)
    if array.ndim != 2 or array.shape[1] != 3 or len(array) < 4:
        raise InputError(f"a trim polyhedron needs (k >= 4, 3) points, got shape {array.shape}")
    return convex_solid(array)


#: Shifts (mm) tried, in order, when a single feature's boolean cut fails.
_NUDGES_MM = ((0.0, 0.0, 0.0), (0.002, 0.0, 0.0), (0.0, 0.002, 0.0), (0.0, 0.0, 0.002))


def _plausible(pieces: list[bd.Solid] | None, base: bd.Solid) -> bool:
    """A cut result is plausible when its largest piece is a valid, manifold solid keeping at
    least half the volume: the features are small next to a tile, so anything less (or a
    non-manifold seam where two tools touch, or a kernel error while measuring it) is a failed
    boolean."""
    if not pieces:
        return False
    try:
        volumes = [p.volume for p in pieces]  # each volume integral once
        largest = pieces[int(np.argmax(volumes))]
        if max(volumes) < 0.5 * base.volume:
            return False
        return bool(largest.is_manifold and largest.is_valid)
    except Exception:  # OCCT's own failures (Standard_Failure) are not RuntimeErrors
        log.debug("checking a cut result failed", exc_info=True)
        return False


def _try_cut(base: bd.Solid, tools: Sequence[bd.Shape]) -> list[bd.Solid] | None:
    """:func:`~drawstring.cad.kernel.cut`, or None where the kernel fails or raises."""
    try:
        return cut(base, tools)
    except Exception:  # OCCT's own failures (Standard_Failure) are not RuntimeErrors
        log.debug("OCCT cut failed", exc_info=True)
        return None


def build_tile(
    tile: NDArray[np.float64] | bd.Solid,
    tools: list[bd.Shape],
    *,
    failed: list[int] | None = None,
) -> bd.Solid:
    """The tile minus the tools that touch it, in one boolean operation.

    Tools whose bounding box misses the tile's are skipped.  If the cut splits the tile, the
    largest piece is kept and a warning is logged.  Where the batched cut fails (or raises),
    the tools are cut one at a time; a tool whose cut fails even on its own and slightly
    shifted raises ``RuntimeError``, or, given a ``failed`` list, is left uncut and its index
    in ``tools`` appended there.
    """
    base = tile if isinstance(tile, bd.Solid) else tile_solid(np.asarray(tile))
    box = bounding_box(base)
    touching = []
    for index, tool in enumerate(tools):
        tool_box = bounding_box(tool)
        if np.all(tool_box[0] <= box[1] + 1e-6) and np.all(tool_box[1] >= box[0] - 1e-6):
            touching.append((index, tool))
    batched = _try_cut(base, [tool for _, tool in touching])
    if batched is not None and _plausible(batched, base):
        pieces = batched
    else:
        # OCCT's batched cut can fail where two tools share a face (a channel and a lift bore
        # leaving through the same opening); cutting one tool at a time avoids that.
        pieces = [base]
        for index, tool in touching:
            current = max(pieces, key=lambda s: s.volume)
            for nudge in _NUDGES_MM:
                # A coincident face can defeat the boolean; a micrometre shift does not change
                # what is printed.
                moved = tool if not any(nudge) else tool.moved(bd.Location(nudge))
                attempt = _try_cut(current, [moved])
                if attempt is not None and _plausible(attempt, current):
                    pieces = attempt
                    break
            else:
                if failed is None:
                    raise RuntimeError("a feature's cut failed even after shifting it slightly")
                failed.append(index)
    if not pieces:
        raise RuntimeError("cutting the features removed the whole tile")
    if len(pieces) > 1:
        log.warning("features split a tile into %d pieces; keeping the largest", len(pieces))
    return clean_solid(pieces[0] if len(pieces) == 1 else max(pieces, key=lambda s: s.volume))
