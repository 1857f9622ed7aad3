"""Grid overlay, cropping, lifting and splitting, on targets whose flattening is known."""

from __future__ import annotations

import igl
import numpy as np
import pytest

from drawstring.geometry.core.errors import InputError
from drawstring.geometry.tiling.grid import grid_shape_for, lift_points, tile_surface


def plane_patch(width: float, height: float, n: int = 21) -> tuple[np.ndarray, np.ndarray]:
    uv, faces = igl.triangulated_grid(n, n)
    vertices = np.c_[uv[:, 0] * width, uv[:, 1] * height, np.zeros(len(uv))]
    return vertices, faces.astype(np.int64)


def test_grid_shape_is_close_to_request_with_square_cells() -> None:
    assert grid_shape_for(200, 100, 200) == (20, 10)
    n_i, n_j = grid_shape_for(160, 90, 1600)
    assert abs(n_i * n_j - 1600) < 80
    assert abs((160 / n_i) / (90 / n_j) - 1) < 0.05
    with pytest.raises(InputError, match="--tiles"):
        grid_shape_for(1, 1, 0)


def test_planar_target_gives_the_plain_grid() -> None:
    vertices, faces = plane_patch(200, 100)
    tiling = tile_surface(vertices, faces, vertices[:, :2], grid=(8, 4))
    assert tiling.linkage.n_tiles == 32
    assert tiling.cell_size == pytest.approx(25.0)
    # Lifting the plane onto itself is the identity; every tile keeps its area.
    assert np.allclose(tiling.vertices[:, :2], tiling.uv, atol=1e-9)
    assert np.allclose(tiling.tile_area_scale, 1.0)
    assert tiling.scale_factor_max == pytest.approx(1.0)
    assert not tiling.linkage.splits


def test_lift_reproduces_a_linear_map_exactly() -> None:
    """A piecewise-linear map that is globally affine is reproduced exactly at any point."""
    uv, faces = igl.triangulated_grid(9, 9)
    affine = np.array([[2.0, 0.5, 1.0], [-0.3, 1.5, 0.2]])
    vertices = uv @ affine + np.array([1.0, 2.0, 3.0])
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 1, size=(50, 2))
    lifted, dist, _ = lift_points(points, uv, vertices, faces.astype(np.int64))
    assert np.allclose(lifted, points @ affine + np.array([1.0, 2.0, 3.0]), atol=1e-12)
    assert np.allclose(dist, 0.0)


def test_disk_domain_crops_cells_outside() -> None:
    """A disk-shaped flat domain keeps only cells entirely inside it."""
    uv, faces = igl.triangulated_grid(41, 41)
    uv = uv * 2 - 1
    inside = np.linalg.norm(uv, axis=1) <= 1.0 + 1e-9
    # Keep faces fully inside the unit disk.
    keep = inside[faces].all(axis=1)
    faces = faces[keep]
    used = np.unique(faces)
    remap = -np.ones(len(uv), dtype=np.int64)
    remap[used] = np.arange(len(used))
    uv, faces = uv[used], remap[faces]
    vertices = np.c_[uv * 100, np.zeros(len(uv))]
    tiling = tile_surface(vertices, faces, vertices[:, :2], grid=(8, 8))
    corners = tiling.uv[tiling.quads]
    assert np.all(np.linalg.norm(corners, axis=2) <= 100 + 1e-6)
    assert tiling.linkage.n_tiles < 64
    assert tiling.linkage.n_components == 1


def dome(radius: float, height_ratio: float, n: int = 41) -> tuple[np.ndarray, np.ndarray]:
    """Spherical cap over a square; flat domain = orthographic projection (not conformal)."""
    uv, faces = igl.triangulated_grid(n, n)
    xy = (uv - 0.5) * 2 * radius * height_ratio
    z = np.sqrt(radius**2 - (xy**2).sum(axis=1))
    return np.c_[xy, z], faces.astype(np.int64)


def test_splits_bring_every_component_within_the_bound() -> None:
    vertices, faces = dome(100.0, 0.66)
    tiling = tile_surface(vertices, faces, vertices[:, :2], grid=(12, 12), max_scale_factor=1.3)
    assert tiling.scale_factor_max_unsplit > 1.3
    assert tiling.linkage.splits
    link = tiling.linkage
    for c in range(link.n_components):
        scale = tiling.tile_area_scale[link.tile_component == c]
        assert scale.max() / scale.min() <= 1.3 + 1e-12
    assert tiling.scale_factor_max <= 1.3 + 1e-12
    # Components share no hinge.
    for ta, _, tb, _ in link.hinges:
        assert link.tile_component[ta] == link.tile_component[tb]


def test_first_split_goes_through_the_highest_curvature() -> None:
    """On a cap centred in the domain the first cut passes through the middle grid line."""
    vertices, faces = dome(100.0, 0.66)
    tiling = tile_surface(vertices, faces, vertices[:, :2], grid=(12, 12), max_scale_factor=1.3)
    first = tiling.linkage.splits[0]
    assert first.line == 6


def test_no_split_when_disabled_reports_ratio() -> None:
    vertices, faces = dome(100.0, 0.66)
    tiling = tile_surface(
        vertices, faces, vertices[:, :2], grid=(12, 12), max_scale_factor=1.3, split=False
    )
    assert not tiling.linkage.splits
    assert tiling.scale_factor_max == pytest.approx(tiling.scale_factor_max_unsplit)


def test_every_split_part_keeps_a_tile_on_the_outer_boundary() -> None:
    """The string enters a part only from the outer boundary, never through a cut, so no split
    may enclose a part.  On the 1600-tile three-shell a cut that would enclose one of its seven
    parts (which the string route would then miss) is passed over for another with the same
    largest ratio."""
    import math

    from drawstring.geometry.flatten.conformal import flatten
    from drawstring.geometry.target.surface import load_target

    target = load_target("three-shell", size_mm=200.0)
    uv = flatten(target.vertices, target.faces).uv
    bound = 2.0 / (1.0 + math.sin(math.radians(12.0)))  # the fdm-dual default
    tiling = tile_surface(target.vertices, target.faces, uv, tiles=1600, max_scale_factor=bound)
    link = tiling.linkage
    assert link.n_components == 7
    for c in range(link.n_components):
        assert link.boundary_tile[link.tile_component == c].any(), f"part {c} is enclosed"
    assert tiling.scale_factor_max == pytest.approx(1.573, abs=1e-3)
    assert not tiling.notes
