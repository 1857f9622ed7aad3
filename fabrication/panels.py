"""Plywood box tiles: each frustum tile as six flat panels with butt or finger joints.

Construction (``panel_thickness_mm = p``).  Face ``f`` of a tile has its outer plane
``n_f . x = d_f`` and its inner plane ``n_f . x = d_f - p``.  Along the edge shared by faces
``f`` and ``g`` one panel *owns* the joint region (it reaches ``g``'s outer plane) and the other
stops at the owner's inner plane.  Ends of every edge belong to the face with the lower index
(sides 0..3, top 4, bottom 5), a total order, so the panels neither overlap nor leave holes at
the tile corners.  Butt joints: the whole edge follows that rule.  Finger joints: the edge is cut
into an odd number of fingers that alternate owners, with dog-bone relief of the router's radius
on every inside corner.

Panels are cut square on a 3-axis machine.  Where a joint's dihedral angle is not 90 degrees the
edge is laid at the larger of its two face positions (the panel is slightly proud and is sanded
or bevelled flush); ``cutlist.csv`` lists the dihedral and bevel angle of every edge for a
tilting saw or a 5-axis machine.  Panels are drawn as seen from *inside* the tile: cut them with
the inner face up, so the engraved labels end up hidden inside the box.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from drawstring.cad.feature_common import channel_radius
from drawstring.cad.hinge_plans import strip_hole_plans
from drawstring.cad.paths import SIDE_TOP_FACE, SOLID_FACES, channel_path, face_planes, lift_path
from drawstring.fabrication.dxf import Part2D, signed_area, text_strokes, text_width
from drawstring.geometry.core.tile import HingeSide

if TYPE_CHECKING:
    from drawstring.cad.design import CadResult
    from drawstring.fabrication.profiles import Profile

FACE_NAMES = ("S0", "S1", "S2", "S3", "T", "B")
#: Finger width as a multiple of the panel thickness (at least twice the tool diameter).
FINGER_WIDTH_FACTOR = 3.0
#: Points per dog-bone half circle.
DOGBONE_SEGMENTS = 12


@dataclass(frozen=True)
class PanelEdge:
    """One edge of a panel: the neighbouring face and the joint angles."""

    neighbour: str
    dihedral_deg: float
    bevel_deg: float
    fingers: int


@dataclass(frozen=True)
class Panel:
    """A flat panel of one tile.

    tile, face : tile id and face (``S0``..``S3``, ``T``, ``B``).
    part : the 2D part (outline with fingers and dog-bones, drilled holes, engraved label).
    edges : the four edges in outline order.
    thickness : mm.
    """

    tile: int
    face: str
    part: Part2D
    edges: tuple[PanelEdge, ...]
    thickness: float

    @property
    def name(self) -> str:
        return f"{self.tile}{self.face}"

    @property
    def area(self) -> float:
        """Area (mm^2) of the outline minus its holes."""
        return self.part.area


def _face_edges() -> list[list[tuple[int, int]]]:
    """Per face, its four edges in order as (neighbour face, index of the edge's first vertex)."""
    edge_face: dict[tuple[int, int], int] = {}
    for face, ring in enumerate(SOLID_FACES):
        for i in range(4):
            edge_face[(ring[i], ring[(i + 1) % 4])] = face
    result = []
    for ring in SOLID_FACES:
        result.append([(edge_face[(ring[(i + 1) % 4], ring[i])], i) for i in range(4)])
    return result


_EDGES = _face_edges()


def _frame(normal: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """In-plane axes (a, b) with a x b = -normal (the face seen from inside)."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(normal[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    axis_a = np.cross(helper, normal)
    axis_a /= np.linalg.norm(axis_a)
    axis_b = np.cross(normal, axis_a)  # a x b = -n ... check below
    if np.cross(axis_a, axis_b) @ normal > 0:
        axis_b = -axis_b
    return axis_a, axis_b


def _dogbones(outline: NDArray[np.float64], radius: float) -> NDArray[np.float64]:
    """Replace each inside (right-turn) corner of a counter-clockwise outline by a dog-bone."""
    points = []
    n = len(outline)
    for i in range(n):
        corner = outline[i]
        before, after = outline[i - 1], outline[(i + 1) % n]
        d_in, d_out = before - corner, after - corner
        len_in, len_out = np.linalg.norm(d_in), np.linalg.norm(d_out)
        u, v = corner - before, after - corner
        turn = u[0] * v[1] - u[1] * v[0]
        if turn >= -1e-9 or len_in < 1e-9 or len_out < 1e-9:
            points.append(corner)
            continue
        d_in, d_out = d_in / len_in, d_out / len_out
        bisector = d_in + d_out
        if np.linalg.norm(bisector) < 1e-9:
            points.append(corner)
            continue
        bisector /= np.linalg.norm(bisector)
        centre = corner + radius * bisector
        start = corner + 2 * radius * (bisector @ d_in) * d_in
        end = corner + 2 * radius * (bisector @ d_out) * d_out
        a0 = np.arctan2(*(start - centre)[::-1])
        a1 = np.arctan2(*(end - centre)[::-1])
        through = np.arctan2(*(corner - centre)[::-1])
        # Sweep from start to end through the corner (clockwise for a concave corner).
        sweep = (a1 - a0) % (2 * np.pi)
        if not ((through - a0) % (2 * np.pi) < sweep):
            sweep -= 2 * np.pi
        angles = a0 + sweep * np.linspace(0.0, 1.0, DOGBONE_SEGMENTS + 1)
        points.extend(centre + radius * np.stack([np.cos(angles), np.sin(angles)], axis=1))
    return np.array(points)


def tile_panels(
    tile_id: int,
    vertices: NDArray[np.float64],
    profile: Profile,
    drill_points: Sequence[tuple[int, NDArray[np.float64]]] = (),
    holes: Sequence[tuple[int, NDArray[np.float64], float]] = (),
    pilots: Sequence[tuple[int, NDArray[np.float64], float]] = (),
) -> list[Panel]:
    """The six panels of one tile.

    Parameters
    ----------
    tile_id : tile number (for labels).
    vertices : (8, 3) float, mm, the tile (any pose).
    profile : ``panel_thickness_mm``, ``joint``, ``tool_diameter_mm``, string and clearance.
    drill_points : (face, (3,) point) where the cable passes through a panel; a hole of the
        channel diameter goes through it there, perpendicular to the panel.
    holes : (face, (3,) point, radius) further round holes through a panel (magnets).
    pilots : (face, (3,) point, radius) pilot holes of the hinge strips' screws: drilled.

    A round hole at least as wide as the router's tool is cut (CUT_INNER); a narrower one is
    drilled (the DRILL layer), as the pilot holes are.
    """
    centroids, normals = face_planes(vertices)
    box = _Box(vertices, centroids, normals, np.einsum("fd,fd->f", centroids, normals), profile)
    return [box.panel(tile_id, face, drill_points, holes, pilots) for face in range(6)]


@dataclass(frozen=True)
class _EdgeLine:
    """One edge of a panel as a 2D line: ``c`` the unit normal pointing out of the panel (the
    neighbour's normal in the panel's frame), ``positions`` along it where the owner of the
    joint reaches (the neighbour's outer plane) and where the other stops (its inner plane),
    ``owner_ends`` whether this panel owns the edge's ends, the edge's two ends in 2D, the
    neighbouring face and the dihedral angle (degrees)."""

    c: NDArray[np.float64]
    positions: tuple[float, float]
    owner_ends: bool
    start: NDArray[np.float64]
    end: NDArray[np.float64]
    neighbour: int
    dihedral: float


@dataclass(frozen=True)
class _Box:
    """A tile as a box of panels: its vertices, face planes (centroids, outward normals and
    offsets ``n . x``) and the profile's panel dimensions."""

    vertices: NDArray[np.float64]
    centroids: NDArray[np.float64]
    normals: NDArray[np.float64]
    offsets: NDArray[np.float64]
    profile: Profile

    def panel(
        self,
        tile_id: int,
        face: int,
        drill_points: Sequence[tuple[int, NDArray[np.float64]]],
        holes: Sequence[tuple[int, NDArray[np.float64], float]],
        pilots: Sequence[tuple[int, NDArray[np.float64], float]],
    ) -> Panel:
        """Face ``face``'s panel: outline, holes and engraved label."""
        profile = self.profile
        axis_a, axis_b = _frame(self.normals[face])
        origin = self.centroids[face]

        def to2d(point: NDArray[np.float64]) -> NDArray:
            rel = point - origin
            return np.array([rel @ axis_a, rel @ axis_b])

        lines = [
            self._edge_line(face, neighbour, first, axis_a, axis_b, to2d)
            for neighbour, first in _EDGES[face]
        ]
        polygon, panel_edges = _outline(lines, profile)
        round_holes = [(point, channel_radius(profile)) for f, point in drill_points if f == face]
        round_holes += [(point, radius) for f, point, radius in holes if f == face]
        rows = np.array([[*to2d(point), r] for point, r in round_holes]).reshape(-1, 3)
        # a lift bore and the channel it leaves from open at the same place: one hole (the
        # holes then in the order of their coordinates)
        rows = rows[np.unique(np.round(rows, 6), axis=0, return_index=True)[1]]
        wide = 2 * rows[:, 2] >= profile.tool_diameter_mm
        circles = rows[wide]
        screw_rows = [[*to2d(point), r] for f, point, r in pilots if f == face]
        drills = np.vstack([rows[~wide], np.array(screw_rows).reshape(-1, 3)])
        label = f"{tile_id}{FACE_NAMES[face]}"
        strokes = _label_strokes(label, polygon, np.vstack([circles, drills]))
        part = Part2D(
            f"tile_{tile_id}_{FACE_NAMES[face]}", polygon, [], circles, strokes, drills, 0.0
        )
        return Panel(
            tile_id, FACE_NAMES[face], part, tuple(panel_edges), profile.panel_thickness_mm
        )

    def _edge_line(
        self,
        face: int,
        neighbour: int,
        first: int,
        axis_a: NDArray[np.float64],
        axis_b: NDArray[np.float64],
        to2d: Callable[[NDArray[np.float64]], NDArray],
    ) -> _EdgeLine:
        """The edge of face ``face``'s panel against ``neighbour``, from vertex ``first`` of
        the face's ring."""
        p = self.profile.panel_thickness_mm
        normal, origin = self.normals[face], self.centroids[face]
        ring = SOLID_FACES[face]
        start3, end3 = self.vertices[ring[first]], self.vertices[ring[(first + 1) % 4]]
        n_g = self.normals[neighbour]
        c = np.array([n_g @ axis_a, n_g @ axis_b])
        scale = float(np.linalg.norm(c))
        c /= scale
        cos_fg = float(normal @ n_g)
        positions = []
        for level in (self.offsets[neighbour], self.offsets[neighbour] - p):
            # Plane n_g.x = level cut with this panel's outer and inner plane: take the
            # larger extent (the panel is left proud rather than short).
            outer = (level - n_g @ origin) / scale
            inner = (level - n_g @ (origin - p * normal)) / scale
            positions.append(max(outer, inner))
        dihedral = float(np.degrees(np.pi - np.arccos(np.clip(cos_fg, -1.0, 1.0))))
        return _EdgeLine(
            c, (positions[0], positions[1]), face < neighbour, to2d(start3), to2d(end3),
            neighbour, dihedral,
        )  # fmt: skip


def _outline(
    lines: Sequence[_EdgeLine], profile: Profile
) -> tuple[NDArray[np.float64], list[PanelEdge]]:
    """A panel's outline (counter-clockwise seen from inside, with fingers and dog-bones for
    finger joints) and its edges."""
    finger = profile.joint == "finger"
    tool_radius = 0.5 * profile.tool_diameter_mm
    finger_width = max(FINGER_WIDTH_FACTOR * profile.panel_thickness_mm, 4.0 * tool_radius)
    # Base polygon: edge i at its end-owner position; corner i between edges i-1 and i.
    base_level = [line.positions[0 if line.owner_ends else 1] for line in lines]
    corners = []
    for i in range(4):
        matrix = np.array([lines[i - 1].c, lines[i].c])
        corners.append(np.linalg.solve(matrix, [base_level[i - 1], base_level[i]]))
    outline: list[NDArray[np.float64]] = []
    panel_edges = []
    for line, a in zip(lines, corners, strict=True):
        outline.append(a)
        length = float(np.linalg.norm(line.end - line.start))
        count = 1
        if finger and length >= 3 * finger_width:
            count = int(length // finger_width)
            count -= 1 - count % 2  # odd
        if count > 1:
            outline += _fingers(line, a, length, count)
        panel_edges.append(
            PanelEdge(
                FACE_NAMES[line.neighbour],
                round(line.dihedral, 3),
                round(line.dihedral - 90.0, 3),
                count,
            )
        )
    polygon = np.array(outline)
    # c points outward (the neighbour's normal), so the ring runs as the corners do;
    # make it counter-clockwise in the frame seen from inside.
    if signed_area(polygon) < 0:
        polygon = polygon[::-1]
    if finger and tool_radius > 0:
        polygon = _dogbones(polygon, tool_radius)
    return polygon, panel_edges


def _fingers(
    line: _EdgeLine, a: NDArray[np.float64], length: float, count: int
) -> list[NDArray[np.float64]]:
    """The outline's points along an edge from corner ``a`` cut into ``count`` fingers that
    alternate owners: two points (before and after the step) at each finger boundary."""
    points = []
    direction = (line.end - line.start) / length
    for k in range(1, count):
        t = float((line.start - a) @ direction) + k * length / count
        own_before = line.owner_ends if (k - 1) % 2 == 0 else not line.owner_ends
        own_after = line.owner_ends if k % 2 == 0 else not line.owner_ends
        for owned in (own_before, own_after):
            level = line.positions[0] if owned else line.positions[1]
            point = a + t * direction
            point = point + (level - line.c @ point) * line.c
            points.append(point)
    return points


def _label_strokes(
    label: str, polygon: NDArray[np.float64], round_holes: NDArray[np.float64]
) -> list[NDArray[np.float64]]:
    """The panel's name engraved at its centre, moved below a hole ``(x, y, r)`` it would
    cross."""
    span = np.ptp(polygon, axis=0)
    height = float(min(0.12 * span.min(), 25.0))
    height = min(height, 0.6 * span.max() / max(text_width(label, 1.0), 1e-9))
    centre = polygon.mean(axis=0)
    for x, y, r in round_holes:
        if np.all(
            np.abs(centre - [x, y]) < [0.5 * text_width(label, height) + r, 0.5 * height + r]
        ):
            centre = np.array([centre[0], y - r - height])
    return text_strokes(label, height, centre)


@dataclass(frozen=True)
class CableRun:
    """Where the cable passes one tile: drill points per face and the channel tube length."""

    tile: int
    drill_points: tuple[tuple[int, NDArray[np.float64]], ...]
    tube_length_mm: float


def cable_runs(
    tiles: NDArray[np.float64], route_steps: NDArray[np.int64], lift_tiles: NDArray[np.int64]
) -> list[CableRun]:
    """Holes and tube lengths of every route step and lift bore.

    Parameters
    ----------
    tiles : (T, 8, 3) float, mm.
    route_steps : (S, 4) int ``(gap, tile, enter, leave)``; side 4 is the top face.
    lift_tiles : (L, 2) int ``(tile, side)``: extra bores from a side to the top face.
    """
    runs = []
    items = [(int(t), int(e), int(lv)) for _, t, e, lv in route_steps]
    items += [(int(t), int(s), SIDE_TOP_FACE) for t, s in lift_tiles]
    for tile, enter, leave in items:
        vertices = tiles[tile]
        if SIDE_TOP_FACE in (enter, leave):
            side = leave if enter == SIDE_TOP_FACE else enter
            path = lift_path(vertices, side)
            radius = path.radius
            turn = float(np.arccos(np.clip(path.start_tangent @ path.end_tangent, -1, 1)))
            length = float(np.linalg.norm(path.arc[0] - path.entry)) + radius * turn
            points = ((side, path.entry), (SIDE_TOP_FACE, path.arc[2]))
        else:
            channel = channel_path(vertices, enter, leave)
            samples = channel.points()
            length = float(np.linalg.norm(np.diff(samples, axis=0), axis=1).sum())
            points = ((enter, channel.control[0]), (leave, channel.control[3]))
        runs.append(CableRun(tile, points, length))
    return runs


#: A round hole through a panel: ``(tile, face, (3,) point, radius)``, mm.
PanelHole = tuple[int, int, NDArray[np.float64], float]


def plywood_panels(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    steps: NDArray[np.int64],
    lifts: NDArray[np.int64],
    holes: Sequence[PanelHole] = (),
    pilots: Sequence[PanelHole] = (),
) -> tuple[list[Panel], list[CableRun]]:
    """The six panels of every tile, with the cable holes of the route, and the runs;
    ``holes`` (magnets) and ``pilots`` (hinge strip screws) are ``(tile, face, point,
    radius)`` in the pose of ``tiles_flat`` (see :func:`panel_holes`)."""
    drill: dict[int, list[tuple[int, NDArray[np.float64]]]] = {}
    runs = cable_runs(tiles_flat, steps, lifts)
    for run in runs:
        drill.setdefault(run.tile, []).extend(run.drill_points)
    panels: list[Panel] = []
    for tile in range(len(tiles_flat)):
        panels += tile_panels(
            tile, tiles_flat[tile], profile, drill.get(tile, []),
            [(f, p, r) for t, f, p, r in holes if t == tile],
            [(f, p, r) for t, f, p, r in pilots if t == tile],
        )  # fmt: skip
    return panels, runs


def panel_holes(
    profile: Profile,
    tiles_flat: NDArray[np.float64],
    tiles_assembled: NDArray[np.float64],
    hinges: NDArray[np.int64],
    hinge_side: Sequence[str],
    cad_flat: CadResult,
) -> tuple[list[PanelHole], list[PanelHole]]:
    """Magnet holes (through the side panels, where the solids have their pockets) and the
    hinge strips' pilot holes (through the top or bottom panels, as
    :func:`~drawstring.cad.hinge_plans.strip_hole_plans` places them on the solids), each
    ``(tile, face, point, radius)`` on the flat tiles."""
    magnets = []
    for pair in cad_flat.magnets:
        for tile, side, point in pair.flat_points(tiles_assembled, tiles_flat):
            magnets.append((int(tile), int(side), point, 0.5 * pair.diameter_mm))
    pilots = []
    if profile.hinge_interlock in ("screws", "staples"):
        rows = np.asarray(hinges, dtype=np.int64).reshape(-1, 4)
        sides = [str(side) for side in hinge_side]
        for (a, _, b, _), side, plan in zip(
            rows, sides, strip_hole_plans(tiles_flat, rows, sides, profile), strict=True
        ):
            face = 4 if side == HingeSide.TOP else 5
            for tile, points in zip((a, b), plan.points, strict=True):
                pilots += [(int(tile), face, point, plan.radius) for point in points]
    return magnets, pilots
