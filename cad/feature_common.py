"""Shared pieces of the fabrication features (:mod:`.features`, :mod:`.magnets_labels`,
:mod:`.hinge_frame`, :mod:`.hinge_pins`, :mod:`.hinge_parts`): the tool overshoot, the channel
radius and feature wall every feature is sized from, and small geometry helpers (build123d
vectors and planes, 2D cross products and areas, a hole's margin from a tile's face edges)."""

from __future__ import annotations

from typing import TYPE_CHECKING

import build123d as bd
import numpy as np
from numpy.typing import NDArray

from drawstring.cad.paths import unit_vector

if TYPE_CHECKING:  # profiles live in the fabrication layer; cad only reads fields
    from drawstring.cad.dimensions import FeatureDimensions as Profile


#: Length (mm) by which a cutting tool extends past the face it opens.
TOOL_OVERSHOOT_MM = 0.3


#: A footprint on a tile face: a polyline ((k, 3) float, mm; one point for a disc) and the
#: radius (mm) it is thickened by.
Footprint = tuple[NDArray[np.float64], float]


# --------------------------------------------------------------------------------------------
# small geometry helpers


def vector3(point: NDArray[np.float64]) -> bd.Vector:
    return bd.Vector(float(point[0]), float(point[1]), float(point[2]))


def bd_plane(origin: NDArray[np.float64], normal: NDArray[np.float64]) -> bd.Plane:
    return bd.Plane(origin=vector3(origin), z_dir=vector3(unit_vector(normal)))


def channel_radius(profile: Profile) -> float:
    """Radius (mm) of a string channel: half of string diameter plus clearance."""
    return 0.5 * (profile.string_diameter_mm + profile.channel_clearance_mm)


def feature_wall_mm(profile: Profile) -> float:
    """Thinnest wall (mm) left between a feature and a tile face or another feature: a nozzle
    width, two kerfs, and at least 0.3 mm (the label strokes' limit too)."""
    return max(profile.nozzle_mm, 2.0 * profile.kerf_mm, 0.3)


def cross2(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """z component of the cross product of 2D vectors (..., 2)."""
    return np.asarray(a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0])


def signed_area(outline: NDArray[np.float64]) -> float:
    x, y = outline[:, 0], outline[:, 1]
    return float(0.5 * (x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def footprint_margin(
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
        signed = cross2(edge, -poly) / np.linalg.norm(edge, axis=1)
        margins.append(float(np.min(signed * np.sign(signed_area(poly)))))
    return min(margins)
