"""Built-in parametric target surfaces (analogues of the shapes in the paper's Fig. 1, 10, 11).

Every target is a smooth disk-topology patch generated in code: a structured grid over a rectangular
parameter domain, triangulated with alternating diagonals, mapped to 3D by a closed-form surface. z
is up and faces are oriented so that the area-weighted normal points +z. The coordinates are in
arbitrary units; :func:`drawstring.geometry.target.surface.load_target` scales them to the requested
size in millimetres. Everything is deterministic.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from drawstring.geometry.core.types import FloatArray, IntArray

#: A surface map: parameters ``u, v`` (same shape, each in [0, 1]) to coordinates ``x, y, z``.
XYZ = tuple[FloatArray, FloatArray, FloatArray]
SurfaceMap = Callable[[FloatArray, FloatArray], XYZ]

#: Fewest grid cells along a parameter direction, whatever the requested resolution.
_MIN_CELLS = 2
#: Samples per line when measuring the parameter lines' 3D lengths to choose the grid shape.
_LENGTH_SAMPLES = 257


@dataclass(frozen=True)
class BuiltinTarget:
    """A named parametric target surface.

    Attributes
    ----------
    name : str
        Name used on the command line (``drawstring design NAME``).
    description : str
        One line for ``drawstring targets``.
    make : Callable[[int], tuple[NDArray, NDArray]]
        ``make(n_triangles) -> (V, F)``: ``V : (n, 3) float`` (arbitrary units, z up),
        ``F : (m, 3) int`` with ``m`` about ``n_triangles``, one boundary loop.
    """

    name: str
    description: str
    make: Callable[[int], tuple[FloatArray, IntArray]]


def grid_shape(n_triangles: int, aspect: float) -> tuple[int, int]:
    """Choose grid cell counts for about ``n_triangles`` triangles and a cell aspect near 1.

    Parameters
    ----------
    n_triangles : int
        Requested triangle count (two triangles per grid cell).
    aspect : float
        Length of the u parameter lines divided by the length of the v lines (3D).

    Returns
    -------
    n_u, n_v : int
        Cells along u and along v, each at least 2; ``2 * n_u * n_v`` is about ``n_triangles``.
    """
    cells = max(n_triangles / 2.0, float(_MIN_CELLS * _MIN_CELLS))
    n_u = max(_MIN_CELLS, round(float(np.sqrt(cells * aspect))))
    n_v = max(_MIN_CELLS, round(cells / n_u))
    return n_u, n_v


def alternating_grid(n_u: int, n_v: int) -> tuple[FloatArray, IntArray]:
    """Triangulate the unit square with a structured grid and alternating diagonals.

    Cell ``(i, j)`` is split along its ``(i, j)-(i+1, j+1)`` diagonal when ``i + j`` is even and
    along the other diagonal otherwise, so vertices alternate between 4 and 8 neighbours and the
    triangulation has no preferred direction.

    Parameters
    ----------
    n_u, n_v : int
        Number of cells along u and v.

    Returns
    -------
    UV : (n, 2) float
        Parameters in [0, 1]^2, vertex ``i + j * (n_u + 1)`` at ``(i / n_u, j / n_v)``.
    F : (2 * n_u * n_v, 3) int
        Triangles, counter-clockwise in the (u, v) plane.
    """
    u = np.linspace(0.0, 1.0, n_u + 1)
    v = np.linspace(0.0, 1.0, n_v + 1)
    uu, vv = np.meshgrid(u, v)
    uv = np.column_stack([uu.ravel(), vv.ravel()])
    cell_i, cell_j = np.meshgrid(np.arange(n_u), np.arange(n_v))
    i = cell_i.ravel()
    j = cell_j.ravel()
    a = i + j * (n_u + 1)
    b = a + 1
    c = b + n_u + 1
    d = a + n_u + 1
    even = (i + j) % 2 == 0
    first = np.where(even[:, None], np.column_stack([a, b, c]), np.column_stack([a, b, d]))
    second = np.where(even[:, None], np.column_stack([a, c, d]), np.column_stack([b, c, d]))
    faces = np.concatenate([first, second]).astype(np.int64)
    return uv, faces


def _line_length(surface: SurfaceMap, u: FloatArray, v: FloatArray) -> float:
    """3D length of the polyline ``surface(u, v)`` sampled along one parameter line."""
    x, y, z = surface(u, v)
    points = np.column_stack([x, y, z])
    return float(np.linalg.norm(np.diff(points, axis=0), axis=1).sum())


def parametric_patch(surface: SurfaceMap, n_triangles: int) -> tuple[FloatArray, IntArray]:
    """Mesh a parametric surface over [0, 1]^2 with about ``n_triangles`` triangles.

    The grid shape follows the ratio of the mean 3D lengths of the u and v parameter lines so
    that cells are close to square on the surface. Faces are flipped if needed so that the
    area-weighted normal has a positive z component.

    Parameters
    ----------
    surface : SurfaceMap
        ``(u, v) -> (x, y, z)``, vectorized.
    n_triangles : int
        Approximate number of triangles.

    Returns
    -------
    V : (n, 3) float
        Vertex positions, in the surface's units.
    F : (m, 3) int
        Triangles, one boundary loop (the image of the square's boundary).
    """
    t = np.linspace(0.0, 1.0, _LENGTH_SAMPLES)
    levels = (0.25, 0.5, 0.75)
    length_u = np.mean([_line_length(surface, t, np.full_like(t, s)) for s in levels])
    length_v = np.mean([_line_length(surface, np.full_like(t, s), t) for s in levels])
    n_u, n_v = grid_shape(n_triangles, float(length_u / length_v))
    uv, faces = alternating_grid(n_u, n_v)
    x, y, z = surface(uv[:, 0], uv[:, 1])
    vertices = np.column_stack([x, y, z]).astype(np.float64)
    return vertices, orient_up(vertices, faces)


def orient_up(vertices: FloatArray, faces: IntArray) -> IntArray:
    """Flip all faces if the area-weighted normal points down.

    Parameters
    ----------
    vertices : (n, 3) float
    faces : (m, 3) int, consistently oriented

    Returns
    -------
    faces : (m, 3) int
        The same triangles, oriented so that the summed normal has z >= 0.
    """
    p0, p1, p2 = (vertices[faces[:, k]] for k in range(3))
    normal_sum = np.cross(p1 - p0, p2 - p0).sum(axis=0)
    if normal_sum[2] < 0.0:
        return faces[:, [0, 2, 1]].copy()
    return faces


def _smoothstep(edge0: float, edge1: float, x: FloatArray) -> FloatArray:
    """C1 ramp from 0 (x <= edge0) to 1 (x >= edge1)."""
    t = np.clip((x - edge0) / (edge1 - edge0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# --- the surfaces -------------------------------------------------------------------------


def _saddle(u: FloatArray, v: FloatArray) -> XYZ:
    """Hyperbolic paraboloid z = c (x^2 - y^2) over a square."""
    x = 2.0 * u - 1.0
    y = 2.0 * v - 1.0
    return x, y, 0.45 * (x * x - y * y)


#: Half-side of the square that the dome's stereographic chart covers (1 = the equator).
_DOME_CHART_HALF_SIDE = 0.7


def _dome(u: FloatArray, v: FloatArray) -> XYZ:
    """Deep spherical cap: inverse stereographic image of a square (conformal, so the grid
    cells stay square on the sphere).

    The cap reaches about 62 degrees from the pole at the edge midpoints and 81 degrees at the
    corners, deep enough that its conformal area scale ratio is about 2.5 (> 2).
    """
    px = _DOME_CHART_HALF_SIDE * (2.0 * u - 1.0)
    py = _DOME_CHART_HALF_SIDE * (2.0 * v - 1.0)
    rho2 = px * px + py * py
    denominator = 1.0 + rho2
    return 2.0 * px / denominator, 2.0 * py / denominator, (1.0 - rho2) / denominator


def _peanut(u: FloatArray, v: FloatArray) -> XYZ:
    """Two domes joined by a saddle-shaped waist, over a peanut-shaped footprint.

    The footprint is the union of two overlapping ellipses, rounded at the waist. Towards the
    ends the distance along the axis saturates (a cubic with zero end slope), so the tips are
    narrow but the grid lines still meet the end edges square.
    """
    half_length = 2.1
    saturation_start = 1.3
    lobe_centre = 0.9
    x = half_length * (2.0 * u - 1.0)
    s = 2.0 * v - 1.0
    ax = np.sqrt(x * x + 0.12**2)  # smooth |x|: a rounded waist
    excess = np.clip(ax - saturation_start, 0.0, None)
    ax = ax - excess**3 / (3.0 * (half_length - saturation_start) ** 2)
    half_width = np.sqrt(np.clip(1.0 - 0.8 * (ax - lobe_centre) ** 2, 0.05, None))
    lobes = np.exp(-(((ax - lobe_centre) / 0.9) ** 2))
    z = 0.7 * half_width * lobes * (1.0 - s * s)
    return x, s * half_width, z


def _seashell(u: FloatArray, v: FloatArray) -> XYZ:
    """Scallop fan: log-polar grid, radial ribs deepening towards a rising, convex rim.

    The fan starts at 0.45 of its outer radius: a narrower hinge end makes tiles there so
    small that the flat layout of a 200-tile linkage folds over.
    """
    r_hinge = 0.45
    half_opening = np.deg2rad(62.0)
    n_ribs = 9
    r = r_hinge ** (1.0 - u)  # log-polar: square cells everywhere
    phi = half_opening * (2.0 * v - 1.0)
    t = (r - r_hinge) / (1.0 - r_hinge)
    x = r * np.sin(phi)
    y = r * np.cos(phi)
    crown = 0.38 * np.sin(np.pi * t) ** 0.8 * (1.0 - 0.6 * (phi / half_opening) ** 2)
    rim = 0.14 * t**4
    ribs = 0.035 * t * np.cos(n_ribs * np.pi * phi / half_opening)
    return x, y, crown + rim + ribs


def _three_shell(u: FloatArray, v: FloatArray) -> XYZ:
    """Three overlapping shell vaults around a centre (trefoil pavilion), as a height field.

    Each lobe is a paraboloid vault that flattens out beyond its footprint circle; a smooth
    maximum merges them, so creases between neighbouring lobes become rounded saddles.
    """
    centre_distance = 0.5
    radius = 0.7
    reach = 0.6  # footprint: a box this far beyond the lobe centres
    sharpness = 14.0
    x = (centre_distance * np.cos(np.pi / 6.0) + reach) * (2.0 * u - 1.0)
    y = -0.5 * centre_distance - reach + (1.5 * centre_distance + 2.0 * reach) * v
    lobes = []
    for angle in np.deg2rad([90.0, 210.0, 330.0]):
        dx = x - centre_distance * np.cos(angle)
        dy = y - centre_distance * np.sin(angle)
        q = 1.0 - (dx * dx + dy * dy) / radius**2
        lobes.append(np.where(q > 0.0, q, q / (1.0 - q)))  # C1 flattening outside the circle
    stacked = np.stack(lobes)
    top = stacked.max(axis=0)
    smooth_max = top + np.log(np.exp(sharpness * (stacked - top)).sum(axis=0)) / sharpness
    return x, y, 0.6 * smooth_max


#: Bumps of the cloud height field: (centre x, centre y, height, width).
_CLOUD_BUMPS = np.array(
    [
        (-0.8, -0.2, 0.55, 0.55),
        (-0.1, 0.4, 0.45, 0.5),
        (0.6, -0.1, 0.65, 0.55),
        (1.0, 0.6, 0.3, 0.4),
        (-1.0, 0.6, 0.25, 0.4),
        (0.1, -0.6, 0.3, 0.45),
    ]
)


def _cloud(u: FloatArray, v: FloatArray) -> XYZ:
    """Irregular height field: soft bumps of different heights and widths (mixed curvature)."""
    x = 2.8 * u - 1.4
    y = 2.0 * v - 1.0
    z = np.zeros_like(x)
    for cx, cy, height, width in _CLOUD_BUMPS:
        z = z + height * np.exp(-((x - cx) ** 2 + (y - cy) ** 2) / width**2)
    return x, y, z


def _wave(u: FloatArray, v: FloatArray) -> XYZ:
    """Sinusoidal wave sheet with gently bent crests (curvature changing sign across x)."""
    x = 2.6 * u - 1.3
    y = 2.0 * v - 1.0
    z = 0.22 * np.sin(2.0 * np.pi * (x / 1.7 + 0.12 * y * y)) * (1.0 + 0.15 * y)
    return x, y, z


def _chair_profile(
    n_samples: int = 2049,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Arc-length parametrized J profile of the chair in the (y, z) plane.

    Starts at the front edge of the seat (which rolls down), runs back along a slightly
    reclined seat, bends up into a backrest reclined about 12 degrees past vertical.

    Returns
    -------
    s : (k,) float
        Arc length, from 0 to the profile length.
    points : (k, 2) float
        (y, z) positions.
    normals : (k, 2) float
        Unit normals towards the sitter (up on the seat, forward on the back).
    """
    length = 2.1
    s = np.linspace(0.0, length, n_samples)
    # tangent angle above the backwards direction (-y), in radians
    front_roll = np.deg2rad(40.0) * (1.0 - _smoothstep(0.0, 0.22, s))
    seat_tilt = np.deg2rad(-6.0) * _smoothstep(0.1, 0.3, s)
    bend = np.deg2rad(108.0) * _smoothstep(0.8, 1.25, s)
    lumbar = np.deg2rad(-8.0) * _smoothstep(1.3, 2.1, s)
    angle = front_roll + seat_tilt + bend + lumbar
    tangent = np.column_stack([-np.cos(angle), np.sin(angle)])
    ds = np.diff(s)
    mid = 0.5 * (tangent[1:] + tangent[:-1])
    points = np.concatenate([np.zeros((1, 2)), np.cumsum(mid * ds[:, None], axis=0)])
    # the tangent turned by -90 degrees: up on the seat, forward on the back
    normals = np.column_stack([tangent[:, 1], -tangent[:, 0]])
    return s, points, normals


def _chair(u: FloatArray, v: FloatArray) -> XYZ:
    """Seat and backrest as one sheet: J profile swept across the width, dished sideways."""
    s_table, points, normals = _chair_profile()
    s = u * s_table[-1]
    py = np.interp(s, s_table, points[:, 0])
    pz = np.interp(s, s_table, points[:, 1])
    ny = np.interp(s, s_table, normals[:, 0])
    nz = np.interp(s, s_table, normals[:, 1])
    half_width = 0.5
    x = half_width * (2.0 * v - 1.0)
    dish = 0.09 * (x / half_width) ** 2  # sides come up on the seat and forward on the back
    return x, py + dish * ny, pz + dish * nz


def _maker(surface: SurfaceMap) -> Callable[[int], tuple[FloatArray, IntArray]]:
    """Bind a surface map into a ``make(n_triangles)`` function."""

    def make(n_triangles: int) -> tuple[FloatArray, IntArray]:
        return parametric_patch(surface, int(n_triangles))

    return make


#: Built-in targets in the order ``drawstring targets`` lists them.
BUILTIN_TARGETS: dict[str, BuiltinTarget] = {
    target.name: target
    for target in (
        BuiltinTarget(
            "saddle",
            "hyperbolic paraboloid over a square (negative curvature everywhere)",
            _maker(_saddle),
        ),
        BuiltinTarget(
            "dome",
            "deep spherical cap (124 degrees across); conformal scale ratio above 2, needs a split",
            _maker(_dome),
        ),
        BuiltinTarget(
            "peanut",
            "elongated two-lobed bump: two domes joined by a saddle-shaped waist",
            _maker(_peanut),
        ),
        BuiltinTarget(
            "seashell",
            "scallop-like fan shell with radial ribs and a rising rim",
            _maker(_seashell),
        ),
        BuiltinTarget(
            "three-shell",
            "three overlapping shell lobes around a centre, like a trefoil pavilion",
            _maker(_three_shell),
        ),
        BuiltinTarget(
            "cloud",
            "irregular height field of soft bumps of different heights (mixed curvature)",
            _maker(_cloud),
        ),
        BuiltinTarget(
            "wave",
            "sinusoidal wave sheet with gently bent crests (curvature changing sign)",
            _maker(_wave),
        ),
        BuiltinTarget(
            "chair",
            "seat curving up into a backrest: a J profile swept across the width, dished",
            _maker(_chair),
        ),
    )
}
