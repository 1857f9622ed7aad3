"""Rubber hinge strips as flat parts, the 1:1 placement template, and cable lengths."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import build123d as bd
import numpy as np
from numpy.typing import NDArray
from OCP.BRepAdaptor import BRepAdaptor_Curve
from OCP.BRepTools import BRepTools, BRepTools_WireExplorer
from OCP.GCPnts import GCPnts_QuasiUniformDeflection
from OCP.TopAbs import TopAbs_REVERSED

from drawstring.cad.features import SIDE_TOP_FACE, channel_path, lift_path
from drawstring.cad.tiles import face_planes
from drawstring.fabrication.exports_dxf import (
    Part2D,
    new_dxf,
    save_dxf,
    signed_area,
    svg_document,
    text_strokes,
    text_width,
)

#: Chordal deviation (mm) when round ends of strips become polyline points.
OUTLINE_DEFLECTION_MM = 0.01
#: Smallest engraved text height (mm); smaller labels are left out.
MIN_LABEL_MM = 0.6


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
    shift = 0 if side == "top" else 4
    halves = []
    for tile, corner in ((int(hinge[0]), int(hinge[1])), (int(hinge[2]), int(hinge[3]))):
        point = tiles[tile, shift + corner, :2]
        towards = tiles[tile, shift : shift + 4, :2].mean(axis=0) - point
        halves.append((tile, point, towards / np.linalg.norm(towards)))
    return halves


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
    for tile, corner, direction in hinge_halves(tiles, hinge, side):
        text = str(tile)
        start, stop = 0.5 * width, half_length
        height = min(0.5 * width, 0.9 * (stop - start) / text_width(text, 1.0))
        if height < MIN_LABEL_MM:
            fits = False
            continue
        angle = float(np.arctan2(direction[1], direction[0]))
        if not -0.5 * np.pi < angle <= 0.5 * np.pi:
            angle += np.pi if angle <= -0.5 * np.pi else -np.pi
        centre = corner + 0.5 * (start + stop) * direction
        strokes += text_strokes(text, height, centre, angle)
    return Part2D(f"hinge_{hinge_id}", outline, [], np.zeros((0, 3)), strokes), fits


def write_placement(
    dxf_path: Path,
    svg_path: Path,
    tiles: NDArray[np.float64],
    strips: Sequence[tuple[int, str, NDArray[np.float64]]],
) -> NDArray[np.float64]:
    """1:1 template of the flat layout: tile outlines (top faces solid, bottom faces on their own
    layer), numbers, and every hinge strip where it goes (top / bottom hinges on their own
    layers and colours).  Returns the (2,) template size, mm."""
    margin = 10.0
    points = tiles[:, :, :2].reshape(-1, 2)
    low = points.min(axis=0) - margin
    size = points.max(axis=0) + margin - low
    size[1] += margin  # title line
    doc = new_dxf()
    layers = {"TILE_TOP": 7, "TILE_BOTTOM": 8, "HINGE_TOP": 5, "HINGE_BOTTOM": 6, "LABEL": 3}
    for name, colour in layers.items():
        doc.layers.add(name, color=colour)
    msp = doc.modelspace()
    svg_colours = {
        "TILE_TOP": "#000000",
        "TILE_BOTTOM": "#999999",
        "HINGE_TOP": "#1f4fd0",
        "HINGE_BOTTOM": "#c02090",
        "LABEL": "#108020",
    }
    svg_paths: list[tuple[NDArray[np.float64], bool, str, float]] = []

    def add(points_2d: NDArray[np.float64], layer: str, closed: bool) -> None:
        local = np.round(points_2d - low, 4) + 0.0
        msp.add_lwpolyline(
            [tuple(p) for p in local.tolist()],
            close=closed,
            dxfattribs={"layer": layer, "color": layers[layer]},
        )
        svg_paths.append((local, closed, svg_colours[layer], 0.2))

    edge = np.linalg.norm(tiles[:, 1, :2] - tiles[:, 0, :2], axis=1)
    for tile, vertices in enumerate(tiles):
        add(vertices[4:8, :2], "TILE_BOTTOM", True)
        add(vertices[0:4, :2], "TILE_TOP", True)
        height = 0.25 * float(edge[tile])
        for stroke in text_strokes(str(tile), height, vertices[:4, :2].mean(axis=0)):
            add(stroke, "LABEL", False)
    for _, side, outline in strips:
        add(outline, "HINGE_TOP" if side == "top" else "HINGE_BOTTOM", True)
    # Scale bar: 50 mm (or the template width) to check the print is 1:1.
    bar = min(50.0, float(size[0]) - 2 * margin)
    start = np.array([low[0] + margin, low[1] + size[1] - 0.6 * margin])
    add(np.array([start, start + [bar, 0.0]]), "LABEL", False)
    for x in (0.0, bar):
        add(np.array([start + [x, -1.5], start + [x, 1.5]]), "LABEL", False)
    for stroke in text_strokes(f"{bar:.0f}", 3.0, start + [0.5 * bar, 3.5]):
        add(stroke, "LABEL", False)
    save_dxf(doc, dxf_path)
    svg_path.write_text(svg_document(float(size[0]), float(size[1]), svg_paths), encoding="utf-8")
    return size


def route_openings(
    tiles: NDArray[np.float64], steps: NDArray[np.int64]
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Entry and exit points of the string in each route step and the length inside the tile.

    Returns
    -------
    entry, exit : (S, 3) float, mm.
    inside : (S,) float, mm.
    """
    entries, exits, inside = [], [], []
    for _, tile, enter, leave in steps:
        vertices = tiles[tile]
        if SIDE_TOP_FACE in (enter, leave):
            side = int(leave if enter == SIDE_TOP_FACE else enter)
            path = lift_path(vertices, side)
            turn = float(np.arccos(np.clip(path.start_tangent @ path.end_tangent, -1.0, 1.0)))
            length = float(np.linalg.norm(path.arc[0] - path.entry)) + path.radius * turn
            side_point, top_point = path.entry, path.arc[2]
            a, b = (top_point, side_point) if enter == SIDE_TOP_FACE else (side_point, top_point)
        else:
            channel = channel_path(vertices, int(enter), int(leave))
            samples = channel.points()
            length = float(np.linalg.norm(np.diff(samples, axis=0), axis=1).sum())
            a, b = channel.control[0], channel.control[3]
        entries.append(a)
        exits.append(b)
        inside.append(length)
    return np.array(entries).reshape(-1, 3), np.array(exits).reshape(-1, 3), np.array(inside)


def route_length(tiles: NDArray[np.float64], steps: NDArray[np.int64]) -> float:
    """Length (mm) of the closed string route in the given pose: inside the tiles plus the
    straight runs between consecutive openings (across gaps and between lift points)."""
    if len(steps) == 0:
        return 0.0
    entry, exit_, inside = route_openings(tiles, steps)
    between = np.linalg.norm(np.roll(entry, -1, axis=0) - exit_, axis=1)
    return float(inside.sum() + between.sum())


def route_lengths(
    tiles_flat: NDArray[np.float64], tiles_assembled: NDArray[np.float64], steps: NDArray[np.int64]
) -> tuple[float, float]:
    """(flat, assembled) length of the string route, mm rounded to 0.1 mm: the length every
    output reports (route.json, design.json, bom.csv, manifest.json, assembly.md).

    Measured along the string's centre line on the fabricated geometry (:func:`route_length`:
    through the channels and lift bores the solids are cut with, straight across the gaps),
    with ``tiles_flat`` the tiles as printed (the pose of ``flat.step``).
    """
    return (
        round(route_length(tiles_flat, steps), 1),
        round(route_length(tiles_assembled, steps), 1),
    )


def top_face_centres(tiles: NDArray[np.float64]) -> NDArray[np.float64]:
    """(T, 3) float, mm: centroids of the top faces."""
    return np.array([face_planes(t)[0][4] for t in tiles]).reshape(-1, 3)
