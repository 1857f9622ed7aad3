"""Regular quad grid on the flat domain, lifted to 3D, split where the scale range is too large.

Paper section 4.1 (overlay a regular grid on the conformal domain, crop, lift through the inverse
map) and section 4.5 (split along grid lines through the point of highest Gaussian curvature until
every part's conformal area scale ratio is within the bound).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import igl
import numpy as np
from scipy import ndimage

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tolerances import MAX_SCALE_FACTOR
from drawstring.geometry.core.types import BoolArray, FloatArray, IntArray
from drawstring.geometry.flatten.conformal import flatten
from drawstring.geometry.tiling.linkage import Linkage, Split, build_linkage
from drawstring.geometry.tiling.splits import MIN_PART_CELLS, choose_splits

log = logging.getLogger(__name__)

#: Grid vertices farther than this fraction of a cell from the flattened mesh count as outside.
CROP_TOLERANCE_CELLS = 1e-6


@dataclass(frozen=True)
class Tiling:
    """The quad grid on the flat domain and its lift to the target surface.

    Attributes
    ----------
    linkage : topology (tiles, hinges, gaps, splits, components).
    uv : (n, 2) float, mm, grid vertex positions in the flattened domain.
    vertices : (n, 3) float, mm, grid vertices lifted onto the target (M3D).
    cell_size : float, mm, side of a grid cell in the flat domain.
    tile_area_scale : (T,) float, each tile's area scale in its part's own free-boundary
        conformal flattening, normalized to 1 at the part's largest (see ``part_area_scale``).
    tile_conformal_scale : (T,) float, lifted tile area over flat cell area in the global map.
    layout_uv : (T, 4, 2) float, mm, tile corners in their component's own free-boundary
        flattening: the start of the flat layout.
    vertex_gaussian_curvature : (n,) float, 1/mm^2, target Gaussian curvature at each grid vertex.
    scale_factor_max : float, max over components of (max / min tile area scale), each
        component measured in its own conformal flattening.
    scale_factor_max_unsplit : float, the same ratio for the whole grid before splitting.
    notes : human-readable remarks (e.g. a bound that could not be met).
    """

    linkage: Linkage
    uv: FloatArray
    vertices: FloatArray
    cell_size: float
    tile_area_scale: FloatArray
    tile_conformal_scale: FloatArray
    layout_uv: FloatArray
    vertex_gaussian_curvature: FloatArray
    scale_factor_max: float
    scale_factor_max_unsplit: float
    notes: tuple[str, ...]

    @property
    def quads(self) -> IntArray:
        """(T, 4) int, grid-vertex ids of each tile, counter-clockwise in the flat domain."""
        return self.linkage.tile_corners


def grid_shape_for(width: float, height: float, tiles: int) -> tuple[int, int]:
    """Columns and rows of square-ish cells whose count is close to ``tiles``.

    Parameters
    ----------
    width, height : float, mm, size of the rectangle domain.
    tiles : int, the approximate number of tiles wanted (>= 1).
    """
    if tiles < 1:
        raise InputError(
            f"--tiles must be at least 1 (got {tiles}); ask for about 50 to 2000 tiles"
        )
    cell = math.sqrt(width * height / tiles)
    n_i = max(1, round(width / cell))
    n_j = max(1, round(height / cell))
    return n_i, n_j


def lift_points(
    points_uv: FloatArray,
    uv: FloatArray,
    vertices: FloatArray,
    faces: IntArray,
    values: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray | None]:
    """Map flat-domain points to 3D through the piecewise-linear inverse of the flattening.

    Parameters
    ----------
    points_uv : (p, 2) float, points in the flat domain.
    uv : (n, 2) float, flattened target vertices.
    vertices : (n, 3) float, target vertices.
    faces : (m, 3) int, target triangles.
    values : (n,) float, optional per-vertex field to interpolate the same way.

    Returns
    -------
    lifted : (p, 3) float, the points on the target.
    distance : (p,) float, distance of each point to the flat domain (0 inside).
    interpolated : (p,) float or None, ``values`` at the points.
    """
    pad = np.zeros((len(points_uv), 1))
    query = np.hstack([points_uv, pad])
    domain = np.hstack([uv, np.zeros((len(uv), 1))])
    sqr_dist, face_ids, closest = igl.point_mesh_squared_distance(query, domain, faces)
    tri = faces[face_ids]
    bary = igl.barycentric_coordinates(
        closest, domain[tri[:, 0]], domain[tri[:, 1]], domain[tri[:, 2]]
    )
    bary = np.clip(bary, 0.0, None)
    total = bary.sum(axis=1, keepdims=True)
    # A triangle the flattening shrank to (numerically) nothing gives no barycentric
    # coordinates (NaN): such a point takes the triangle's nearest corner.
    bad = ~np.isfinite(total[:, 0]) | (total[:, 0] <= 0.0)
    if np.any(bad):
        corners = domain[tri[bad]] - closest[bad][:, None, :]
        nearest = np.argmin(np.einsum("pkd,pkd->pk", corners, corners), axis=1)
        bary[bad] = np.eye(3)[nearest]
        total[bad] = 1.0
    bary /= total
    lifted = np.einsum("pk,pkd->pd", bary, vertices[tri])
    interpolated = None if values is None else np.einsum("pk,pk->p", bary, values[tri])
    return lifted, np.sqrt(sqr_dist), interpolated


def quad_vector_area(vertices: FloatArray, quads: IntArray) -> FloatArray:
    """(T,) area of possibly non-planar quads: half the norm of the cross product of diagonals."""
    p = vertices[quads]
    return 0.5 * np.linalg.norm(np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1]), axis=1)


def part_flattening(vertices: FloatArray, quads: IntArray) -> tuple[FloatArray, FloatArray]:
    """A part of the lifted grid flattened on its own, and its per-tile area scale.

    The part (its lifted quads, each split into two triangles) is flattened with free-boundary
    BFF (the least area distortion); each tile's 3D area is divided by its flat area, and the
    scales are normalized so the part's largest is 1: the value is how much the flat layout must
    open locally around that tile (1 to the part's ratio).  A split part gets its own flat
    layout, so this, not the global rectangle map, decides whether it fits.

    Parameters
    ----------
    vertices : (n, 3) float, mm, lifted grid vertices.
    quads : (t, 4) int, the part's tiles.

    Returns
    -------
    corners_uv : (t, 4, 2) float, mm, the tiles' corners in the part's flattening.
    scale : (t,) float, normalized area scale.
    """
    used, local = np.unique(quads, return_inverse=True)
    local = local.reshape(-1, 4)
    tris = np.concatenate([local[:, [0, 1, 2]], local[:, [0, 2, 3]]])
    flat = flatten(vertices[used], tris, mode="free")
    uv3 = np.hstack([flat.uv, np.zeros((len(used), 1))])
    scale = quad_vector_area(vertices[used], local) / quad_vector_area(uv3, local)
    return flat.uv[local], np.asarray(scale / scale.max())


def part_area_scale(vertices: FloatArray, quads: IntArray) -> FloatArray:
    """(t,) normalized per-tile area scale of a part in its own flattening (see above)."""
    return part_flattening(vertices, quads)[1]


def component_flattenings(
    linkage: Linkage, vertices: FloatArray, grid_uv: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Flatten every component of a tile mesh on its own (see :func:`part_flattening`).

    Parameters
    ----------
    linkage : topology (components after splits).
    vertices : (n, 3) float, mm, grid vertices in 3D (the lifted grid, or K3D after its
        optimization: the flat layout should follow the tiles it lays out).
    grid_uv : (n, 2) float, mm, grid vertices in the global flat domain; each component's own
        flattening is moved onto it by the best similarity, so components keep their places.

    Returns
    -------
    layout_uv : (T, 4, 2) float, mm, tile corners in their component's flattening.
    area_scale : (T,) float, normalized area scale per tile (max 1 in each component).
    """
    area_scale = np.empty(linkage.n_tiles)
    layout_uv = np.empty((linkage.n_tiles, 4, 2))
    for c in range(linkage.n_components):
        members = np.nonzero(linkage.tile_component == c)[0]
        quads = linkage.tile_corners[members]
        own_uv, area_scale[members] = part_flattening(vertices, quads)
        layout_uv[members] = align_similarity(own_uv, grid_uv[quads])
    return layout_uv, area_scale


def _fit_similarity(
    source: FloatArray, target: FloatArray, *, scaling: bool = True
) -> tuple[float, FloatArray, FloatArray]:
    """Scale, rotation (2, 2) and translation (2,) that best map 2D points ``source`` onto
    ``target`` in the least-squares sense (Umeyama; reflections excluded; ``scaling=False``:
    a rigid motion)."""
    src = source.reshape(-1, 2)
    dst = target.reshape(-1, 2)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    u, sigma, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    fix = np.diag([1.0, d])
    rotation = u @ fix @ vt
    scale = float(np.trace(np.diag(sigma) @ fix) / max((a**2).sum(), 1e-300)) if scaling else 1.0
    return scale, rotation, mu_d - scale * rotation @ mu_s


def _apply_similarity(fit: tuple[float, FloatArray, FloatArray], points: FloatArray) -> FloatArray:
    scale, rotation, shift = fit
    return np.asarray(scale * points @ rotation.T + shift)


def align_similarity(source: FloatArray, target: FloatArray) -> FloatArray:
    """Move 2D points ``source`` by the rotation, uniform scale and translation that best fit
    them to ``target`` in the least-squares sense (Umeyama; reflections excluded).

    Both are (..., 2) arrays of the same shape; the result has the shape of ``source``.
    """
    src = source.reshape(-1, 2)
    dst = target.reshape(-1, 2)
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    a, b = src - mu_s, dst - mu_d
    u, sigma, vt = np.linalg.svd(b.T @ a)
    d = np.sign(np.linalg.det(u @ vt))
    fix = np.diag([1.0, d])
    rotation = u @ fix @ vt
    scale = float(np.trace(np.diag(sigma) @ fix) / max((a**2).sum(), 1e-300))
    return np.asarray((scale * a @ rotation.T + mu_d).reshape(source.shape))


def parts_in_place(linkage: Linkage, corners: FloatArray, grid_uv: FloatArray) -> FloatArray:
    """Flat tile corners with the parts of a split design moved together where they meet.

    A flat layout of several parts spreads them apart for cutting, so a gap on a split line
    (its sides on two parts) has no meaningful flat position there, and string segments
    between parts cut across other parts.  Here the largest part stays; every other part, in
    turn the one with most cut hinges to those placed, is moved rigidly so that the corners
    those hinges would join (the hinges the splits removed) best meet: each part keeps its
    own flat shape and size.  A part with fewer than two cut hinges to the placed ones is
    placed where ``grid_uv`` puts it relative to them (a similarity fit).  One part is
    returned unmoved.

    Parameters
    ----------
    linkage : topology (``tile_component``, ``tile_cells``, ``tile_corners``).
    corners : (T, 4, 2) float, mm, flat tile corners.
    grid_uv : (n, 2) float, mm, grid vertices in the flattened domain (``Tiling.uv``).
    """
    corners = np.asarray(corners, dtype=np.float64)
    count = linkage.n_components
    if count <= 1:
        return corners
    component = linkage.tile_component
    cells = np.zeros(linkage.grid_shape, dtype=bool)
    cells[linkage.tile_cells[:, 0], linkage.tile_cells[:, 1]] = True
    whole = build_linkage(cells).hinges  # same tile numbering, no splits
    cut = whole[component[whole[:, 0]] != component[whole[:, 2]]]
    # both directions: (tile, corner) in one part, (tile, corner) it would be hinged to
    ends = np.concatenate([cut, cut[:, [2, 3, 0, 1]]])
    placed = np.zeros(count, dtype=bool)
    placed[int(np.argmax(np.bincount(component, minlength=count)))] = True
    result = corners.copy()
    while not placed.all():
        to_placed = placed[component[ends[:, 2]]]
        part_of = component[ends[:, 0]]
        shared = np.bincount(part_of[to_placed], minlength=count) * ~placed
        part = int(np.argmax(np.where(placed, -1, shared)))  # most cut hinges, lowest index
        if shared[part] >= 2:
            rows = ends[to_placed & (part_of == part)]
            fit = _fit_similarity(
                corners[rows[:, 0], rows[:, 1]], result[rows[:, 2], rows[:, 3]], scaling=False
            )
        else:
            done = placed[component]
            frame = _fit_similarity(
                grid_uv[linkage.tile_corners[done]], result[done]
            )  # grid -> the placed parts' frame
            own = component == part
            fit = _fit_similarity(
                corners[own], _apply_similarity(frame, grid_uv[linkage.tile_corners[own]])
            )
        members = component == part
        result[members] = _apply_similarity(fit, corners[members].reshape(-1, 2)).reshape(-1, 4, 2)
        placed[part] = True
    return result


def _scale_ratio(scale: FloatArray) -> float:
    return float(scale.max() / scale.min()) if scale.size else 1.0


def _largest_component(cells: BoolArray) -> BoolArray:
    labels, count = ndimage.label(cells)
    if count <= 1:
        return cells
    sizes = ndimage.sum(cells, labels, index=np.arange(1, count + 1))
    return np.asarray(labels == (int(np.argmax(sizes)) + 1))


def tile_surface(
    vertices: FloatArray,
    faces: IntArray,
    uv: FloatArray,
    *,
    tiles: int | None = None,
    grid: tuple[int, int] | None = None,
    max_scale_factor: float = MAX_SCALE_FACTOR,
    split: bool = True,
) -> Tiling:
    """Overlay a regular grid on the flat domain, crop, lift, and split where needed.

    Parameters
    ----------
    vertices : (n, 3) float, mm, target mesh.
    faces : (m, 3) int, target triangles.
    uv : (n, 2) float, mm, conformal flattening of the target (a rectangle from corner (0, 0)).
    tiles : approximate tile count (used when ``grid`` is None).
    grid : (I, J) explicit number of cell columns and rows.
    max_scale_factor : bound on max/min tile area scale within each component (paper: 2).
    split : whether to split components that exceed the bound.
    """
    if grid is None and tiles is None:
        raise InputError("give either --tiles N or --grid I J")
    lo = uv.min(axis=0)
    hi = uv.max(axis=0)
    width, height = (hi - lo).tolist()
    if grid is None:
        assert tiles is not None
        grid = grid_shape_for(width, height, tiles)
    n_i, n_j = grid
    if n_i < 1 or n_j < 1:
        raise InputError(f"--grid needs at least 1 x 1 cells (got {n_i} x {n_j})")
    if max_scale_factor <= 1.0:
        raise InputError(f"the scale-factor bound must exceed 1 (got {max_scale_factor}); use 2")
    # Square cells, centred on the domain.
    cell = min(width / n_i, height / n_j)
    origin = lo + 0.5 * (np.array([width, height]) - cell * np.array([n_i, n_j]))
    gi, gj = np.meshgrid(np.arange(n_i + 1), np.arange(n_j + 1), indexing="ij")
    grid_uv = origin + cell * np.stack([gi.ravel(), gj.ravel()], axis=1)

    gauss = _vertex_gaussian_curvature(vertices, faces)
    lifted_all, dist, gauss_all = lift_points(grid_uv, uv, vertices, faces, gauss)
    assert gauss_all is not None
    inside = (dist <= CROP_TOLERANCE_CELLS * cell).reshape(n_i + 1, n_j + 1)
    cells = inside[:-1, :-1] & inside[1:, :-1] & inside[1:, 1:] & inside[:-1, 1:]
    cells = _largest_component(cells)
    if not cells.any():
        raise InputError(
            f"no grid cell of the {n_i} x {n_j} grid fits inside the flattened surface; "
            "ask for more tiles"
        )

    base = build_linkage(cells)
    used_ij = base.vertex_ij
    flat_index = used_ij[:, 0] * (n_j + 1) + used_ij[:, 1]
    tile_uv = grid_uv[flat_index]
    tile_xyz = lifted_all[flat_index]
    vertex_gauss = gauss_all[flat_index]
    conformal_scale = quad_vector_area(tile_xyz, base.tile_corners) / cell**2
    if np.any(conformal_scale <= 0):
        raise InputError("the lifted grid has degenerate tiles; the flattening folded")
    unsplit = _scale_ratio(part_area_scale(tile_xyz, base.tile_corners))

    notes: list[str] = []
    splits: tuple[Split, ...] = ()
    if split and unsplit > max_scale_factor:
        splits, unmet = choose_splits(
            cells,
            base,
            vertex_gauss,
            max_scale_factor,
            lambda quads: _scale_ratio(part_area_scale(tile_xyz, quads)),
        )
        if unmet:
            notes.append(
                f"{unmet} part(s) still exceed the scale-factor bound {max_scale_factor:g}: no "
                f"split leaves {MIN_PART_CELLS} or more cells on each side and every piece on the "
                "outer boundary (the string enters a part only from there); use more tiles, "
                "other --corners or a flatter target"
            )
    linkage = build_linkage(cells, splits) if splits else base
    layout_uv, area_scale = component_flattenings(linkage, tile_xyz, tile_uv)
    per_component = [
        _scale_ratio(area_scale[linkage.tile_component == c]) for c in range(linkage.n_components)
    ]
    return Tiling(
        linkage=linkage,
        uv=tile_uv,
        vertices=tile_xyz,
        cell_size=float(cell),
        tile_area_scale=area_scale,
        tile_conformal_scale=conformal_scale,
        layout_uv=layout_uv,
        vertex_gaussian_curvature=vertex_gauss,
        scale_factor_max=max(per_component),
        scale_factor_max_unsplit=unsplit,
        notes=tuple(notes),
    )


def _vertex_gaussian_curvature(vertices: FloatArray, faces: IntArray) -> FloatArray:
    """Pointwise Gaussian curvature: angle defect over Voronoi area, boundary vertices zero."""
    defect = igl.gaussian_curvature(vertices, faces)
    mass = igl.massmatrix(vertices, faces, igl.MASSMATRIX_TYPE_VORONOI)
    area = np.asarray(mass.diagonal())
    curvature = defect / np.maximum(area, 1e-300)
    boundary = igl.boundary_loop(faces)
    curvature[boundary] = 0.0
    return np.asarray(curvature, dtype=np.float64)
