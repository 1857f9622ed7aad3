"""Rubber hinge strips as flat parts, the 1:1 placement template, and cable lengths."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRepAdaptor import BRepAdaptor_Curve
from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
from OCP.GCPnts import GCPnts_QuasiUniformDeflection
from OCP.TopAbs import TopAbs_REVERSED

from drawstring.cad.magnets_labels import reads_as_another
from drawstring.cad.paths import face_planes
from drawstring.fabrication.dxf import (
    Part2D,
    new_dxf,
    save_dxf,
    signed_area,
    svg_document,
    text_strokes,
    text_width,
)
from drawstring.geometry.core.tile import HingeSide

#: Chordal deviation (mm) when round ends of strips become polyline points.
OUTLINE_DEFLECTION_MM = 0.01
#: Smallest engraved text height (mm); smaller labels are left out.
MIN_LABEL_MM = 0.6


@dataclass(frozen=True)
class HingeStyle:
    """How the placement template draws the hinges of one face.

    layer : DXF layer.  colour : SVG colour and DXF true colour.  aci : the nearest AutoCAD
    colour index (for DXF readers without true colour).  marker : ``circle`` or ``square``.
    """

    layer: str
    colour: str
    aci: int
    marker: str

    @property
    def rgb(self) -> tuple[int, int, int]:
        return int(self.colour[1:3], 16), int(self.colour[3:5], 16), int(self.colour[5:7], 16)


#: Placement template hinges, as in every picture (``pictures.TOP_HINGE`` / ``BOTTOM_HINGE``,
#: not imported: that module loads matplotlib): top-face strips blue with a circle,
#: bottom-face strips orange with a square, the markers filled and black-edged.
PLACEMENT_HINGES = {
    HingeSide.TOP: HingeStyle("HINGE_TOP", "#0072B2", 5, "circle"),
    HingeSide.BOTTOM: HingeStyle("HINGE_BOTTOM", "#E69F00", 30, "square"),
}
#: Marker size (mm, radius or half side) as a fraction of the strip width, and its bounds.
MARKER_FRACTION, MARKER_MIN_MM, MARKER_MAX_MM = 0.3, 0.5, 2.5


def planar_outline(solid: bd.Shape) -> tuple[NDArray[np.float64], float]:
    """Outline of a flat part lying in a horizontal plane: its largest face with a vertical
    normal, as a counter-clockwise (k, 2) polygon (mm) seen from above, and the face's z."""
    best = None
    best_area = -1.0
    for face in solid.faces():
        if face.geom_type != bd.GeomType.PLANE:
            continue
        normal = face.normal_at()
        if abs(normal.Z) < 0.999:
            continue
        if face.area > best_area + 1e-9:
            best, best_area = face, face.area
    if best is None:
        raise RuntimeError("hinge part has no horizontal planar face")
    wire = BRepTools.OuterWire_s(best.wrapped)
    explorer = BRepTools_WireExplorer(wire, best.wrapped)
    points: list[tuple[float, float]] = []
    z = 0.0
    while explorer.More():
        edge = explorer.Current()
        curve = BRepAdaptor_Curve(edge)
        sampler = GCPnts_QuasiUniformDeflection(curve, OUTLINE_DEFLECTION_MM)
        values = [curve.Value(sampler.Parameter(i)) for i in range(1, sampler.NbPoints() + 1)]
        coords = [(v.X(), v.Y()) for v in values]
        z = values[0].Z()
        if edge.Orientation() == TopAbs_REVERSED:
            coords.reverse()
        points.extend(coords[:-1])
        explorer.Next()
    polygon = np.array(points, dtype=np.float64)
    if signed_area(polygon) < 0:
        polygon = polygon[::-1]
    return polygon, float(z)


def hinge_halves(
    tiles: NDArray[np.float64], hinge: NDArray[np.int64], side: str
) -> list[tuple[int, NDArray[np.float64], NDArray[np.float64]]]:
    """Per tile of a hinge: (tile, corner point (2,), unit direction (2,) into the tile), flat
    pose seen from above."""
    shift = 0 if side == HingeSide.TOP else 4
    halves = []
    for tile, corner in ((int(hinge[0]), int(hinge[1])), (int(hinge[2]), int(hinge[3]))):
        point = tiles[tile, shift + corner, :2]
        towards = tiles[tile, shift : shift + 4, :2].mean(axis=0) - point
        halves.append((tile, point, towards / np.linalg.norm(towards)))
    return halves


#: A strip number that turned reads as another is underlined this many text heights below
#: its centre line (inside the strip: the text is at most half the strip's width high).
STRIP_UNDERLINE_DROP = 0.8


def strip_part(
    hinge_id: int,
    pad: bd.Shape,
    tiles: NDArray[np.float64],
    hinge: NDArray[np.int64],
    side: str,
    width: float,
    half_length: float,
) -> tuple[Part2D, bool]:
    """A rubber strip as a flat part; each half engraved with the number of the tile it is
    glued to, away from the bending line.  Returns the part and whether labels fit."""
    outline, _ = planar_outline(pad)
    strokes: list[NDArray[np.float64]] = []
    fits = True
    reading: float | None = None
    for tile, corner, direction in hinge_halves(tiles, hinge, side):
        text = str(tile)
        start, stop = 0.5 * width, half_length
        height = min(0.5 * width, 0.9 * (stop - start) / text_width(text, 1.0))
        if height < MIN_LABEL_MM:
            fits = False
            continue
        angle = float(np.arctan2(direction[1], direction[0]))
        # both labels read the same way along the strip: within a quarter turn of the first
        # (which reads left to right here; the nesting keeps it so, see nest_parts)
        ref = 0.0 if reading is None else reading
        angle = ref + float(np.mod(angle - ref + 0.5 * np.pi, np.pi)) - 0.5 * np.pi
        centre = corner + 0.5 * (start + stop) * direction
        strokes += text_strokes(text, height, centre, angle)
        if reads_as_another(text):  # a loose strip turned over: 6 or 9? (underlined)
            along = np.array([np.cos(angle), np.sin(angle)])
            below = centre - STRIP_UNDERLINE_DROP * height * np.array([-along[1], along[0]])
            half = 0.5 * text_width(text, height) * along
            strokes.append(np.stack([below - half, below + half]))
        reading = angle if reading is None else reading  # the halves run along one line
    part = Part2D(f"hinge_{hinge_id}", outline, [], np.zeros((0, 3)), strokes, text_angle=reading)
    return part, fits


def _inside(polygon: NDArray[np.float64], points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Which of the (n, 2) ``points`` lie inside the (k, 2) ``polygon`` (even-odd rule)."""
    a, b = polygon, np.roll(polygon, -1, axis=0)
    x, y = points[:, None, 0], points[:, None, 1]
    spans = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        cross_x = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return np.asarray((spans & (x < cross_x)).sum(axis=1) % 2 == 1)


def _hinge_marker(
    outline: NDArray[np.float64], corners: NDArray[np.float64]
) -> tuple[NDArray[np.float64], float]:
    """Where a strip's marker goes and its size (mm, from the strip's width).

    The marker sits on the hinge: the mean of the tile corners (``corners``, (n, 2), of the
    strip's face) under the strip, else the outline's area centroid."""
    x, y = outline[:, 0], outline[:, 1]
    cross = x * np.roll(y, -1) - np.roll(x, -1) * y
    area = 0.5 * float(cross.sum())
    perimeter = float(np.linalg.norm(np.roll(outline, -1, axis=0) - outline, axis=1).sum())
    width = 2.0 * abs(area) / max(perimeter, 1e-12)  # a long strip: area / (perimeter / 2)
    size = float(np.clip(MARKER_FRACTION * width, MARKER_MIN_MM, MARKER_MAX_MM))
    low, high = outline.min(axis=0), outline.max(axis=0)
    near = corners[np.all((corners >= low) & (corners <= high), axis=1)]
    under = near[_inside(outline, near)] if len(near) else near
    if len(under):
        return under.mean(axis=0), size
    if abs(area) < 1e-12:
        return outline.mean(axis=0), size
    centre = np.array(
        [((x + np.roll(x, -1)) * cross).sum(), ((y + np.roll(y, -1)) * cross).sum()]
    ) / (6.0 * area)
    return centre, size


def _svg_marker(kind: str, centre: NDArray[np.float64], size: float, colour: str) -> str:
    """A filled, black-edged circle or square (SVG, centre already in SVG coordinates)."""
    style = f'fill="{colour}" stroke="#000000" stroke-width="0.2"'
    if kind == "circle":
        return f'<circle cx="{centre[0]:.3f}" cy="{centre[1]:.3f}" r="{size:.3f}" {style}/>'
    corner = np.round(centre - size, 3) + 0.0
    return (
        f'<rect x="{corner[0]:.3f}" y="{corner[1]:.3f}" width="{2 * size:.3f}" '
        f'height="{2 * size:.3f}" {style}/>'
    )


def write_placement(
    dxf_path: Path,
    svg_path: Path,
    tiles: NDArray[np.float64],
    strips: Sequence[tuple[int, str, NDArray[np.float64]]],
) -> NDArray[np.float64]:
    """1:1 template of the flat layout: tile outlines (top faces solid, bottom faces on their own
    layer), numbers, and every hinge strip where it goes, coloured and marked as in every
    picture (:data:`PLACEMENT_HINGES`: top blue with a circle, bottom orange with a square; in
    the DXF on layers HINGE_TOP and HINGE_BOTTOM).  Returns the (2,) template size, mm."""
    margin = 10.0
    points = tiles[:, :, :2].reshape(-1, 2)
    low = points.min(axis=0) - margin
    size = points.max(axis=0) + margin - low
    size[1] += margin  # title line
    doc = new_dxf()
    layers = {"TILE_TOP": 7, "TILE_BOTTOM": 8, "LABEL": 3}
    svg_colours = {"TILE_TOP": "#000000", "TILE_BOTTOM": "#999999", "LABEL": "#108020"}
    true_colours: dict[str, tuple[int, int, int]] = {}
    for style in PLACEMENT_HINGES.values():
        layers[style.layer] = style.aci
        svg_colours[style.layer] = style.colour
        true_colours[style.layer] = style.rgb
    for name, aci in layers.items():
        layer = doc.layers.add(name, color=aci)
        if name in true_colours:
            layer.rgb = true_colours[name]
    msp = doc.modelspace()
    svg_paths: list[tuple[NDArray[np.float64], bool, str, float]] = []
    svg_markers: list[str] = []

    def attributes(layer: str) -> dict[str, object]:
        found: dict[str, object] = {"layer": layer, "color": layers[layer]}
        if layer in true_colours:
            red, green, blue = true_colours[layer]
            found["true_color"] = (red << 16) | (green << 8) | blue
        return found

    def add(points_2d: NDArray[np.float64], layer: str, closed: bool) -> None:
        local = np.round(points_2d - low, 4) + 0.0
        msp.add_lwpolyline(
            [tuple(p) for p in local.tolist()], close=closed, dxfattribs=attributes(layer)
        )
        svg_paths.append((local, closed, svg_colours[layer], 0.2))

    edge = np.linalg.norm(tiles[:, 1, :2] - tiles[:, 0, :2], axis=1)
    for tile, vertices in enumerate(tiles):
        add(vertices[4:8, :2], "TILE_BOTTOM", True)
        add(vertices[0:4, :2], "TILE_TOP", True)
        height = 0.25 * float(edge[tile])
        for stroke in text_strokes(str(tile), height, vertices[:4, :2].mean(axis=0)):
            add(stroke, "LABEL", False)
    markers = []
    rings = {
        HingeSide.TOP: tiles[:, 0:4, :2].reshape(-1, 2),
        HingeSide.BOTTOM: tiles[:, 4:8, :2].reshape(-1, 2),
    }
    for _, side, outline in strips:
        face = HingeSide(side)
        style = PLACEMENT_HINGES[face]
        add(outline, style.layer, True)
        markers.append((style, *_hinge_marker(outline, rings[face])))
    # Markers after every strip, so no strip outline crosses one.
    for style, centre, radius in markers:
        local = np.round(centre - low, 4) + 0.0
        if style.marker == "circle":
            msp.add_circle(tuple(local.tolist()), radius, dxfattribs=attributes(style.layer))
        else:
            square = local + radius * np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]])
            msp.add_lwpolyline(
                [tuple(p) for p in square.tolist()],
                close=True,
                dxfattribs=attributes(style.layer),
            )
        flipped = np.array([local[0], size[1] - local[1]])
        svg_markers.append(_svg_marker(style.marker, flipped, radius, style.colour))
    # Scale bar: 50 mm (or the template width) to check the print is 1:1.
    bar = min(50.0, float(size[0]) - 2 * margin)
    start = np.array([low[0] + margin, low[1] + size[1] - 0.6 * margin])
    add(np.array([start, start + [bar, 0.0]]), "LABEL", False)
    for x in (0.0, bar):
        add(np.array([start + [x, -1.5], start + [x, 1.5]]), "LABEL", False)
    for stroke in text_strokes(f"{bar:.0f}", 3.0, start + [0.5 * bar, 3.5]):
        add(stroke, "LABEL", False)
    save_dxf(doc, dxf_path)
    svg = svg_document(float(size[0]), float(size[1]), svg_paths)
    if svg_markers:
        end = svg.rindex("</svg>")
        svg = svg[:end] + "<g>\n" + "\n".join(svg_markers) + "\n</g>\n" + svg[end:]
    svg_path.write_text(svg, encoding="utf-8")
    return size


def top_face_centres(tiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(T, 3) float, mm: centroids of the top faces."""
    return np.array([face_planes(t)[0][4] for t in tiles]).reshape(-1, 3)
