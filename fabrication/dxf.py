"""Flat parts for laser cutters and routers: outlines, kerf offset, nesting, DXF and SVG.

A :class:`Part2D` is a closed outline (counter-clockwise, mm) with holes, round holes and
engraving strokes, in its own coordinates.  :func:`nest_parts` offsets cut contours by half the
kerf (outlines grow, holes shrink), turns each part to its smallest bounding rectangle and packs
the rectangles on sheets with a shelf packer.  :func:`write_sheets_dxf` writes one layer and one
colour per operation (Boxes.py convention: inner cut blue, outer cut black, engrave green,
annotation red), units mm, labels as single-stroke paths (no TEXT entities), inner contours
before outer ones, and fixed header metadata so the bytes repeat.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import ezdxf
import numpy as np
from numpy.typing import NDArray

from drawstring.geometry.core.errors import InputError, InternalError

LAYER_ENGRAVE = "ENGRAVE"
LAYER_CUT_INNER = "CUT_INNER"
LAYER_CUT_OUTER = "CUT_OUTER"
LAYER_SHEET = "SHEET"
#: Round holes narrower than the router's tool, or for screws: drilled, not cut.
LAYER_DRILL = "DRILL"
#: ACI colour per layer: engrave green, inner cut blue, outer cut black (7), annotation red.
LAYER_COLOURS = {
    LAYER_ENGRAVE: 3,
    LAYER_CUT_INNER: 5,
    LAYER_CUT_OUTER: 7,
    LAYER_SHEET: 1,
    LAYER_DRILL: 6,
}
#: Layers a cutter cuts through (only closed polylines there).
CUT_LAYERS = (LAYER_CUT_INNER, LAYER_CUT_OUTER)
#: Free border (mm) around each sheet and gap between sheets in the DXF.
SHEET_MARGIN_MM = 5.0
SHEET_GAP_MM = 50.0


# --------------------------------------------------------------------------------------------
# single-stroke font (digits, a few letters and signs), glyph cell 0.6 wide x 1.0 high

_GLYPHS: dict[str, tuple[tuple[tuple[float, float], ...], ...]] = {
    "0": (((0, 0), (0.6, 0), (0.6, 1), (0, 1), (0, 0), (0.6, 1)),),
    "1": (((0.15, 0.8), (0.35, 1), (0.35, 0)), ((0.1, 0), (0.6, 0))),
    "2": (((0, 1), (0.6, 1), (0.6, 0.5), (0, 0.5), (0, 0), (0.6, 0)),),
    "3": (((0, 1), (0.6, 1), (0.6, 0), (0, 0)), ((0.15, 0.5), (0.6, 0.5))),
    "4": (((0, 1), (0, 0.45), (0.6, 0.45)), ((0.45, 0.75), (0.45, 0))),
    "5": (((0.6, 1), (0, 1), (0, 0.55), (0.6, 0.55), (0.6, 0), (0, 0)),),
    "6": (((0.6, 1), (0, 1), (0, 0), (0.6, 0), (0.6, 0.5), (0, 0.5)),),
    "7": (((0, 1), (0.6, 1), (0.2, 0)),),
    "8": (((0, 0), (0.6, 0), (0.6, 1), (0, 1), (0, 0)), ((0, 0.5), (0.6, 0.5))),
    "9": (((0.6, 0.5), (0, 0.5), (0, 1), (0.6, 1), (0.6, 0), (0, 0)),),
    "-": (((0.1, 0.5), (0.5, 0.5)),),
    ".": (((0.25, 0), (0.35, 0), (0.35, 0.1), (0.25, 0.1), (0.25, 0)),),
    "T": (((0, 1), (0.6, 1)), ((0.3, 1), (0.3, 0))),
    "B": (
        ((0, 0), (0, 1), (0.45, 1), (0.55, 0.85), (0.45, 0.5), (0, 0.5)),
        ((0.45, 0.5), (0.6, 0.3), (0.6, 0.15), (0.45, 0), (0, 0)),
    ),
    "S": (((0.6, 1), (0, 1), (0, 0.5), (0.6, 0.5), (0.6, 0), (0, 0)),),
    "H": (((0, 0), (0, 1)), ((0.6, 0), (0.6, 1)), ((0, 0.5), (0.6, 0.5))),
    "J": (((0.6, 1), (0.6, 0), (0, 0), (0, 0.3)),),
    "P": (((0, 0), (0, 1), (0.6, 1), (0.6, 0.5), (0, 0.5)),),
    "#": (
        ((0.2, 0), (0.2, 1)),
        ((0.4, 0), (0.4, 1)),
        ((0, 0.35), (0.6, 0.35)),
        ((0, 0.65), (0.6, 0.65)),
    ),
    " ": (),
}
#: Advance between glyphs as a fraction of the text height.
GLYPH_ADVANCE = 0.85
GLYPH_WIDTH = 0.6


def text_width(text: str, height: float) -> float:
    """Width (mm) of ``text`` set at ``height`` in the stroke font."""
    return height * (GLYPH_ADVANCE * (len(text) - 1) + GLYPH_WIDTH) if text else 0.0


def text_strokes(
    text: str, height: float, centre: NDArray[np.float64], angle: float = 0.0
) -> list[NDArray[np.float64]]:
    """Single-stroke paths of ``text`` centred on ``centre`` and turned by ``angle`` (rad).

    Returns
    -------
    list of (k, 2) float polylines, mm.
    """
    unknown = sorted(set(text) - set(_GLYPHS))
    if unknown:
        raise InternalError(f"the stroke font has no glyph for {''.join(unknown)!r}")
    width = text_width(text, height)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    strokes = []
    for index, char in enumerate(text):
        x0 = index * GLYPH_ADVANCE * height - 0.5 * width
        for stroke in _GLYPHS[char]:
            local = np.array(stroke, dtype=np.float64) * height + [x0, -0.5 * height]
            strokes.append(local @ rotation.T + centre)
    return strokes


# --------------------------------------------------------------------------------------------
# polygons


def signed_area(polygon: NDArray[np.float64]) -> float:
    """Signed area (mm^2) of a closed (k, 2) polygon; positive when counter-clockwise."""
    x, y = polygon[:, 0], polygon[:, 1]
    return float(0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def offset_polygon(polygon: NDArray[np.float64], distance: float) -> NDArray[np.float64]:
    """Mitre offset of a simple polygon: outward by ``distance`` mm (inward when negative).

    Exact for straight edges; arcs given as many short segments stay arcs to within the chord.
    Collinear vertices are kept.  The orientation of the input does not matter.
    """
    points = np.asarray(polygon, dtype=np.float64)
    if distance == 0.0:
        return points.copy()
    ccw = signed_area(points) > 0
    edge = np.roll(points, -1, axis=0) - points
    length = np.linalg.norm(edge, axis=1)
    keep = length > 1e-9
    points, edge, length = points[keep], edge[keep], length[keep]
    direction = edge / length[:, None]
    outward = np.stack([direction[:, 1], -direction[:, 0]], axis=1)  # right normal
    if not ccw:
        outward = -outward
    previous = np.roll(outward, 1, axis=0)
    bisector = outward + previous
    scale = 1.0 + np.einsum("ij,ij->i", outward, previous)
    scale = np.maximum(scale, 0.05)  # near-reversals: cap the mitre at ~6 x the distance
    return np.asarray(points + distance * bisector / scale[:, None])


def min_area_rotation(polygon: NDArray[np.float64]) -> float:
    """Angle (rad) that turns ``polygon`` so its bounding rectangle is smallest, long side on x.

    Tries the directions of the polygon's convex hull edges.
    """
    from scipy.spatial import ConvexHull

    points = np.asarray(polygon, dtype=np.float64)
    hull = points[ConvexHull(points).vertices]
    edges = np.roll(hull, -1, axis=0) - hull
    angles = -np.arctan2(edges[:, 1], edges[:, 0])
    best_angle, best_area = 0.0, np.inf
    for angle in np.round(angles, 12):
        turned = rotate(hull, float(angle))
        size = np.ptp(turned, axis=0)
        area = float(size[0] * size[1])
        if area < best_area - 1e-9:
            best_area, best_angle = area, float(angle)
            if size[1] > size[0]:
                best_angle += 0.5 * np.pi
    return best_angle


def rotate(points: NDArray[np.float64], angle: float) -> NDArray[np.float64]:
    """(k, 2) points turned counter-clockwise by ``angle`` (rad) about the origin."""
    c, s = np.cos(angle), np.sin(angle)
    return np.asarray(points @ np.array([[c, s], [-s, c]]))


# --------------------------------------------------------------------------------------------
# parts and nesting


@dataclass
class Part2D:
    """A flat part in its own coordinates (mm).

    name : what the part is (``hinge_12``, ``tile_3_top``).
    outline : (k, 2) closed outer contour, counter-clockwise.
    holes : (k, 2) closed inner contours.
    circles : (c, 3) round holes ``(x, y, radius)``, cut.
    strokes : engraving polylines (k, 2), open.
    drills : (d, 3) round holes ``(x, y, radius)`` drilled (on the DRILL layer, no kerf).
    text_angle : reading direction (rad) of the part's engraved text, None without text; the
        nesting keeps it reading left to right (or upwards), so that a 6 is not a 9.
    """

    name: str
    outline: NDArray[np.float64]
    holes: list[NDArray[np.float64]] = field(default_factory=list)
    circles: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    strokes: list[NDArray[np.float64]] = field(default_factory=list)
    drills: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 3)))
    text_angle: float | None = None

    @property
    def area(self) -> float:
        """Area (mm^2) of the outline minus its holes and round holes."""
        holes = sum(abs(signed_area(h)) for h in self.holes)
        circles = float(np.pi * np.sum(self.circles[:, 2] ** 2))
        circles += float(np.pi * np.sum(self.drills[:, 2] ** 2))
        return abs(signed_area(self.outline)) - holes - circles

    def moved(self, angle: float, shift: NDArray[np.float64]) -> Part2D:
        """A copy turned by ``angle`` about the origin, then shifted by ``shift``."""
        circles, drills = self.circles.copy(), self.drills.copy()
        for round_holes in (circles, drills):
            if len(round_holes):
                round_holes[:, :2] = rotate(round_holes[:, :2], angle) + shift
        return Part2D(
            self.name,
            rotate(self.outline, angle) + shift,
            [rotate(h, angle) + shift for h in self.holes],
            circles,
            [rotate(s, angle) + shift for s in self.strokes],
            drills,
            None if self.text_angle is None else self.text_angle + angle,
        )

    def kerf_compensated(self, kerf: float) -> Part2D:
        """Outline grown and holes shrunk by half the kerf (the beam's centre path)."""
        half = 0.5 * kerf
        circles = self.circles.copy()
        if len(circles):
            circles[:, 2] = np.maximum(circles[:, 2] - half, 1e-3)
        return Part2D(
            self.name,
            offset_polygon(self.outline, half),
            [offset_polygon(h, -half) for h in self.holes],
            circles,
            list(self.strokes),
            self.drills.copy(),
            self.text_angle,
        )


@dataclass(frozen=True)
class Nesting:
    """Parts placed on sheets.

    sheet_size : (2,) float, mm.
    sheets : per sheet, the parts in sheet coordinates (origin at the sheet's lower left).
    utilisation : (S,) float, area of the parts (holes taken out) over the sheet's area.
    """

    sheet_size: NDArray[np.float64]
    sheets: tuple[tuple[Part2D, ...], ...]
    utilisation: NDArray[np.float64]


def shelf_pack(
    sizes: NDArray[np.float64],
    sheet: tuple[float, float],
    spacing: float,
    margin: float,
    turn: bool = True,
    long_side_x: bool = True,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.bool_]]:
    """Pack rectangles on sheets in shelves (tallest first, left to right, bottom to top),
    each into the first sheet with room, on its open shelf or a new shelf above it.

    Parameters
    ----------
    sizes : (n, 2) float, mm, rectangle widths and heights.
    sheet : (width, height) of a sheet, mm.
    spacing : gap between rectangles, mm.
    margin : free border of each sheet, mm.
    turn : whether a rectangle may be turned by 90 degrees.
    long_side_x : turn every rectangle that fits so that its long side lies along x; without
        it a rectangle is turned only when it fits no other way.

    Returns
    -------
    sheet_index : (n,) int.
    position : (n, 2) float, mm, lower-left corner of each rectangle on its sheet.
    turned : (n,) bool, rectangle turned by 90 degrees (width and height swapped).

    Raises
    ------
    InputError
        When a rectangle does not fit an empty sheet in either orientation.
    """
    width, height = sheet[0] - 2 * margin, sheet[1] - 2 * margin
    sizes = np.asarray(sizes, dtype=np.float64).reshape(-1, 2)
    n = len(sizes)
    turned = np.zeros(n, dtype=bool)
    placed = sizes.copy()
    for i, (w, h) in enumerate(sizes):
        fits_flat = w <= width and h <= height
        fits_turned = turn and h <= width and w <= height
        if not (fits_flat or fits_turned):
            raise InputError(
                f"a part of {w:.1f} x {h:.1f} mm does not fit the {sheet[0]:.0f} x {sheet[1]:.0f} "
                "mm sheet; use larger sheets (machine.bed_x_mm / bed_y_mm)"
            )
        if not fits_flat or (long_side_x and h > w and fits_turned):
            turned[i] = True
            placed[i] = (h, w)
    order = np.lexsort((-placed[:, 0], -placed[:, 1]))
    sheet_index = np.zeros(n, dtype=np.int64)
    position = np.zeros((n, 2))
    shelves: list[list[float]] = []  # per sheet: x, y and height of its open shelf
    for i in order:
        w, h = placed[i]
        number = len(shelves)  # a new sheet unless one has room
        x = y = shelf = 0.0
        for index, (open_x, open_y, open_h) in enumerate(shelves):
            if open_x + w <= width and open_y + h <= height:  # beside the others on its shelf
                number, x, y, shelf = index, open_x, open_y, open_h
                break
            if open_y + open_h + spacing + h <= height:  # on a new shelf above
                number, x, y, shelf = index, 0.0, open_y + open_h + spacing, 0.0
                break
        if number == len(shelves):
            shelves.append([0.0, 0.0, 0.0])
        sheet_index[i] = number
        position[i] = (margin + x, margin + y)
        shelves[number] = [x + w + spacing, y, max(shelf, h)]
    return sheet_index, position, turned


def place_outlines(
    outlines: Sequence[NDArray[np.float64]],
    sheet: tuple[float, float],
    spacing: float,
    margin: float,
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Where each outline goes when it is turned to its smallest bounding rectangle
    (:func:`min_area_rotation`) and the rectangles are shelf-packed (:func:`shelf_pack`).

    Returns
    -------
    sheet_index : (n,) int.
    angle : (n,) float, rad; the outline's points go to ``rotate(points, angle) + shift``.
    shift : (n, 2) float, mm, on the sheet.
    size : (n, 2) float, mm, each placed outline's bounding rectangle.
    """
    angles = np.array([min_area_rotation(outline) for outline in outlines], dtype=np.float64)
    sizes = np.array(
        [np.ptp(rotate(outline, a), axis=0) for outline, a in zip(outlines, angles, strict=True)]
    ).reshape(-1, 2)
    sheet_index, position, turned = shelf_pack(sizes, sheet, spacing, margin)
    angles = angles + np.where(turned, 0.5 * np.pi, 0.0)
    shift = np.zeros((len(outlines), 2))
    for i, (outline, angle) in enumerate(zip(outlines, angles, strict=True)):
        shift[i] = position[i] - rotate(outline, float(angle)).min(axis=0)
    return sheet_index, angles, shift, np.where(turned[:, None], sizes[:, ::-1], sizes)


def reads_forwards(angle: float) -> bool:
    """Whether text whose baseline runs at ``angle`` (rad) reads left to right, or upwards
    where it runs vertically (within a thousandth of a radian), rather than upside down."""
    c, s = np.cos(angle), np.sin(angle)
    return bool(c > 1e-3 or (abs(c) <= 1e-3 and s > 0))


def nest_parts(
    parts: Sequence[Part2D], sheet: tuple[float, float], kerf: float, spacing: float
) -> Nesting:
    """Kerf-compensate, orient and shelf-pack parts on sheets (see :func:`place_outlines`)."""
    prepared = [part.kerf_compensated(kerf) for part in parts]
    sheet_index, angles, shift, _ = place_outlines(
        [part.outline for part in prepared], sheet, spacing, SHEET_MARGIN_MM
    )
    for i, part in enumerate(prepared):
        if part.text_angle is not None and not reads_forwards(part.text_angle + angles[i]):
            # half a turn keeps the bounding rectangle: the text then reads forwards
            before = rotate(part.outline, float(angles[i])).min(axis=0)
            angles[i] += np.pi
            shift[i] += before - rotate(part.outline, float(angles[i])).min(axis=0)
    n_sheets = int(sheet_index.max()) + 1 if len(parts) else 0
    sheets: list[list[Part2D]] = [[] for _ in range(n_sheets)]
    used = np.zeros(n_sheets)
    for i, part in enumerate(prepared):
        sheets[sheet_index[i]].append(part.moved(float(angles[i]), shift[i]))
        used[sheet_index[i]] += part.area
    return Nesting(
        np.array(sheet, dtype=np.float64),
        tuple(tuple(s) for s in sheets),
        used / float(sheet[0] * sheet[1]),
    )


# --------------------------------------------------------------------------------------------
# DXF and SVG


@contextlib.contextmanager
def _fixed_dxf_metadata() -> Iterator[None]:
    """ezdxf writes creation dates and GUIDs unless told to write fixed ones."""
    before = ezdxf.options.write_fixed_meta_data_for_testing
    ezdxf.options.write_fixed_meta_data_for_testing = True
    try:
        yield
    finally:
        ezdxf.options.write_fixed_meta_data_for_testing = before


def new_dxf() -> ezdxf.document.Drawing:
    """An R2010 drawing in mm with the operation layers."""
    with _fixed_dxf_metadata():  # the creation stamp is written here
        doc = ezdxf.new("R2010", setup=True, units=ezdxf.units.MM)
    doc.header["$MEASUREMENT"] = 1
    for name, colour in LAYER_COLOURS.items():
        doc.layers.add(name, color=colour)
    return doc


def save_dxf(doc: ezdxf.document.Drawing, path: Path) -> None:
    """Write ``doc`` with fixed metadata (byte-identical on repeat runs, in any process).

    ezdxf adds a CLASS for every entity type in use by iterating a set of type names, whose
    order follows Python's per-process string hash seed; the classes are written sorted by
    name instead (their order carries no meaning).
    """
    doc.classes.add_required_classes(doc.dxfversion)
    doc.classes.classes = dict(sorted(doc.classes.classes.items()))
    stream = io.StringIO()
    with _fixed_dxf_metadata():
        doc.write(stream)
    path.write_bytes(stream.getvalue().encode("utf-8"))


def _polyline(msp, points: NDArray[np.float64], layer: str, closed: bool) -> None:
    rounded = np.round(np.asarray(points, dtype=np.float64), 5) + 0.0
    msp.add_lwpolyline(
        [tuple(p) for p in rounded.tolist()],
        close=closed,
        dxfattribs={"layer": layer, "color": LAYER_COLOURS[layer]},
    )


def _circle_polyline(msp, circle: NDArray[np.float64], layer: str) -> None:
    """An exact circle as a closed two-arc LWPOLYLINE (bulge 1 = half circle)."""
    x, y, r = (round(float(v), 5) + 0.0 for v in circle)
    msp.add_lwpolyline(
        [(x - r, y, 0, 0, 1.0), (x + r, y, 0, 0, 1.0)],
        format="xyseb",
        close=True,
        dxfattribs={"layer": layer, "color": LAYER_COLOURS[layer]},
    )


def add_part(msp, part: Part2D, shift: NDArray[np.float64] | None = None) -> None:
    """Engraving, then inner contours, then the outline (cut inside first)."""
    moved = part if shift is None else part.moved(0.0, shift)
    for stroke in moved.strokes:
        _polyline(msp, stroke, LAYER_ENGRAVE, closed=False)
    for hole in moved.holes:
        _polyline(msp, hole, LAYER_CUT_INNER, closed=True)
    for circle in moved.circles:
        _circle_polyline(msp, circle, LAYER_CUT_INNER)
    for drill in moved.drills:
        _circle_polyline(msp, drill, LAYER_DRILL)
    _polyline(msp, moved.outline, LAYER_CUT_OUTER, closed=True)


def sheet_offsets(nesting: Nesting) -> NDArray[np.float64]:
    """(S, 2) float, mm: where each sheet sits in the DXF (side by side along x)."""
    step = nesting.sheet_size[0] + SHEET_GAP_MM
    return np.array([[k * step, 0.0] for k in range(len(nesting.sheets))]).reshape(-1, 2)


def write_sheets_dxf(path: Path, nesting: Nesting, title: str) -> None:
    """The nested sheets side by side, each with its outline on the annotation layer."""
    doc = new_dxf()
    msp = doc.modelspace()
    width, height = nesting.sheet_size
    for k, (parts, offset) in enumerate(zip(nesting.sheets, sheet_offsets(nesting), strict=True)):
        frame = np.array([[0, 0], [width, 0], [width, height], [0, height]]) + offset
        _polyline(msp, frame, LAYER_SHEET, closed=True)
        caption = f"{title}{k + 1}"
        for stroke in text_strokes(
            _font_safe(caption), 0.02 * height, offset + [0.5 * width, -0.03 * height]
        ):
            _polyline(msp, stroke, LAYER_SHEET, closed=False)
        for part in parts:
            add_part(msp, part, offset)
    save_dxf(doc, path)


def _font_safe(text: str) -> str:
    """Upper-cased text with characters missing from the stroke font dropped."""
    return "".join(c for c in text.upper() if c in _GLYPHS)


def svg_document(
    width: float, height: float, paths: Sequence[tuple[NDArray[np.float64], bool, str, float]]
) -> str:
    """A 1:1 SVG (mm) of polylines given in y-up coordinates with origin at the lower left.

    paths : (points (k, 2), closed, stroke colour, stroke width in mm).
    """
    lines = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.3f}mm" height="{height:.3f}mm" '
        f'viewBox="0 0 {width:.3f} {height:.3f}">',
        '<g fill="none" stroke-linecap="round" stroke-linejoin="round">',
    ]
    for points, closed, colour, stroke_width in paths:
        flipped = np.column_stack([points[:, 0], height - points[:, 1]])
        text = " ".join(f"{x:.3f},{y:.3f}" for x, y in np.round(flipped, 3) + 0.0)
        tag = "polygon" if closed else "polyline"
        lines.append(f'<{tag} points="{text}" stroke="{colour}" stroke-width="{stroke_width}"/>')
    lines += ["</g>", "</svg>"]
    return "\n".join(lines) + "\n"
