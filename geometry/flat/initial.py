"""The start of the flat layout: tiles laid into their planes, opened locally as rotating
squares on the conformal grid and translated so that hinged corners meet (see the
"Initial layout" section of :mod:`drawstring.geometry.flat.layout`).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.types import FloatArray
from drawstring.geometry.tiling.linkage import Linkage


def tile_plane_coordinates(tile_top_3d: FloatArray) -> FloatArray:
    """Each top face rigidly laid into the plane (best-fit plane coordinates).

    Parameters
    ----------
    tile_top_3d : (T, 4, 3) float, mm
        Corners BL, BR, TR, TL.

    Returns
    -------
    (T, 4, 2) float, mm
        Counter-clockwise coordinates, centred, x along the tile's mean bottom/top side
        direction.
    """
    pts = np.asarray(tile_top_3d, dtype=np.float64)
    return shadow_coordinates(pts, pts)


def shadow_coordinates(corners_3d: FloatArray, tiles_3d: FloatArray) -> FloatArray:
    """Every tile's 8 vertices seen from above once it lies flat: ``(T, 8, 2)`` in the frame of
    :func:`tile_plane_coordinates` of ``corners_3d`` (its top corners or hinge points)."""
    pts = np.asarray(corners_3d, dtype=np.float64)
    centre = pts.mean(axis=1, keepdims=True)
    normal = np.cross(pts[:, 2] - pts[:, 0], pts[:, 3] - pts[:, 1])
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    ex = (pts[:, 1] - pts[:, 0]) + (pts[:, 2] - pts[:, 3])
    ex -= np.einsum("ki,ki->k", ex, normal)[:, None] * normal
    ex /= np.maximum(np.linalg.norm(ex, axis=1, keepdims=True), 1e-300)
    ey = np.cross(normal, ex)
    rel = np.asarray(tiles_3d, dtype=np.float64) - centre
    return np.stack([np.einsum("kvi,ki->kv", rel, ex), np.einsum("kvi,ki->kv", rel, ey)], axis=-1)


def polygon_signed_area(poly: FloatArray) -> FloatArray:
    """Shoelace area ``(k,)`` of polygons ``(k, s, 2)`` (positive when counter-clockwise)."""
    x, y = poly[..., 0], poly[..., 1]
    return np.asarray(
        0.5 * np.sum(x * np.roll(y, -1, axis=-1) - np.roll(x, -1, axis=-1) * y, axis=-1)
    )


def _rotations_2d(angle: FloatArray) -> FloatArray:
    c, s = np.cos(angle), np.sin(angle)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)


def _fit_rotation_2d(src: FloatArray, dst: FloatArray) -> FloatArray:
    """Angle ``(k,)`` of the rotation best mapping centred ``src (k, s, 2)`` onto ``dst``."""
    cross = np.sum(src[..., 0] * dst[..., 1] - src[..., 1] * dst[..., 0], axis=1)
    dot = np.sum(src * dst, axis=(1, 2))
    return np.asarray(np.arctan2(cross, dot))


def _average_nodes(linkage: Linkage, corners: FloatArray) -> FloatArray:
    """Mean position of the tile corners that share each node."""
    dim = corners.shape[-1]
    nodes = np.zeros((linkage.n_nodes, dim))
    count = np.zeros(linkage.n_nodes)
    np.add.at(nodes, linkage.corner_node.ravel(), corners.reshape(-1, dim))
    np.add.at(count, linkage.corner_node.ravel(), 1.0)
    return nodes / count[:, None]


def initial_flat_layout(
    linkage: Linkage,
    plane_tiles: FloatArray,
    uv: FloatArray,
    min_gap_angle: float,
) -> tuple[FloatArray, FloatArray, FloatArray, list[str]]:
    """Locally opened rotating-squares start (see the module docstring).

    Parameters
    ----------
    linkage : Linkage
    plane_tiles : (T, 4, 2) float, mm
        K3D top faces in their own plane coordinates (:func:`tile_plane_coordinates`).
    uv : (n, 2) float, mm
        Conformal grid positions of the grid vertices.
    min_gap_angle : float, rad

    Returns
    -------
    nodes : (n_nodes, 2) float, mm
    tile_scale : (T,) float
        ``s_t``.
    layout_scale : (C,) float
        ``c`` per component.
    problems : list of str
    """
    # Per-vertex grid positions, or per-tile corner positions (each component flattened alone).
    cell_uv = uv if uv.ndim == 3 else uv[linkage.tile_corners]  # (T, 4, 2)
    cell_centre = cell_uv.mean(axis=1)
    cell_area = np.abs(polygon_signed_area(cell_uv))
    tile_area = polygon_signed_area(plane_tiles)
    if np.any(tile_area <= 0) or np.any(cell_area <= 0):
        raise InternalError("a tile or grid cell has zero or negative area; check the K3D tiles")
    tile_scale = tile_area / cell_area
    problems: list[str] = []
    comp = linkage.tile_component
    layout_scale = np.zeros(linkage.n_components)
    opening = np.zeros(linkage.n_tiles)
    sin_min = np.sin(min_gap_angle)
    for c in range(linkage.n_components):
        sel = comp == c
        s_max, s_min = float(tile_scale[sel].max()), float(tile_scale[sel].min())
        layout_scale[c] = s_max * (1.0 + sin_min)
        ratio = s_max / s_min
        limit = 2.0 / (1.0 + sin_min)
        if ratio > limit * (1.0 + 1e-9):
            problems.append(
                f"component {c}: tile area ratio {ratio:.3f} exceeds {limit:.3f}, the most a quad "
                f"linkage with gap angles in [{np.degrees(min_gap_angle):.1f}, 90] deg can absorb; "
                "lower --min-gap-angle, use more tiles, or split the surface"
            )
        sin_t = np.clip(layout_scale[c] / tile_scale[sel] - 1.0, 0.0, 1.0)
        opening[sel] = np.arcsin(sin_t)
    # Align each tile's plane shape with its grid cell, then turn it by +-opening/2.
    cell_centred = cell_uv - cell_centre[:, None, :]
    align = _fit_rotation_2d(plane_tiles, cell_centred)
    parity = (linkage.tile_cells[:, 0] + linkage.tile_cells[:, 1]) % 2
    turn = np.where(parity == 0, -1.0, 1.0) * 0.5 * opening
    rot = _rotations_2d(align + turn)
    shapes = np.einsum("tij,tkj->tki", rot, plane_tiles)
    centres = _hinge_matching_translations(
        linkage, shapes, np.sqrt(layout_scale[comp])[:, None] * cell_centre
    )
    corners = centres[:, None, :] + shapes
    return _average_nodes(linkage, corners), tile_scale, layout_scale, problems


def _hinge_matching_translations(
    linkage: Linkage, shapes: FloatArray, guess: FloatArray, reg: float = 1e-6
) -> FloatArray:
    """Tile translations ``(T, 2)`` that best join the hinged corners of fixed tile shapes.

    Minimizes ``sum_h |(c_a + x_a) - (c_b + x_b)|^2 + reg sum_t |x_t - guess_t|^2`` (linear;
    the small pull to ``guess`` fixes each component's translation).

    Parameters
    ----------
    shapes : (T, 4, 2) float, mm
        Tile corners relative to the tile's translation.
    guess : (T, 2) float, mm
    """
    h = linkage.hinges
    n_t = linkage.n_tiles
    rows = np.arange(len(h))
    diff = sp.csr_matrix(
        (np.r_[np.ones(len(h)), -np.ones(len(h))], (np.r_[rows, rows], np.r_[h[:, 0], h[:, 2]])),
        shape=(len(h), n_t),
    )
    rhs = shapes[h[:, 2], h[:, 3]] - shapes[h[:, 0], h[:, 1]]  # x_a - x_b should equal this
    mat = (diff.T @ diff + reg * sp.identity(n_t)).tocsc()
    return np.asarray(spla.spsolve(mat, diff.T @ rhs + reg * guess))
