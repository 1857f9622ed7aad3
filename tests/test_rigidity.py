"""Infinitesimal rigidity of assembled linkages with and without the boundary string."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from sim_scene import DeploymentScene, cylinder_scene

from drawstring.geometry.assembled.rigidity import (
    rigid_motion_basis,
    rigidity_matrix,
    rigidity_report,
)
from drawstring.geometry.simulate.inputs import route_snap_pairs


def generic(scene: DeploymentScene, seed: int = 0) -> np.ndarray:
    """The scene's assembled tiles moved into generic position (exact cylinders are special)."""
    rng = np.random.default_rng(seed)
    return scene.tiles_assembled + rng.normal(scale=0.3, size=scene.tiles_assembled.shape)


@pytest.mark.parametrize("n", [3, 4])
def test_boundary_string_makes_linkage_isostatic(n: int) -> None:
    scene = cylinder_scene(n, n)
    pairs, _ = route_snap_pairs(scene.route)
    tiles = generic(scene)
    with_string = rigidity_report(tiles, scene.hinge_vertices, pairs)
    without = rigidity_report(tiles, scene.hinge_vertices)
    assert with_string.null_dimension == 6 and with_string.isostatic
    assert with_string.internal_flexes == 0
    # Ball-jointed tiles: 6 T - 3 H motions; for an n x n grid that is 6 n.
    assert without.null_dimension == 6 * scene.linkage.n_tiles - 3 * scene.linkage.n_hinges
    assert without.null_dimension == 6 * n
    assert without.internal_flexes == without.null_dimension - 6


def test_rigid_motions_are_in_the_null_space() -> None:
    scene = cylinder_scene(3, 3)
    pairs, _ = route_snap_pairs(scene.route)
    mat = rigidity_matrix(scene.tiles_assembled, scene.hinge_vertices, pairs)
    basis = rigid_motion_basis(scene.tiles_assembled)
    assert np.abs(mat @ basis).max() < 1e-9
    assert np.allclose(basis.T @ basis, np.eye(6))


def test_flexes_are_orthogonal_to_rigid_motions_and_move_nothing() -> None:
    scene = cylinder_scene(3, 3)
    tiles = generic(scene, 1)
    rep = rigidity_report(tiles, scene.hinge_vertices)
    centred = (tiles - tiles.reshape(-1, 3).mean(axis=0)) / np.linalg.norm(
        tiles[:, 0] - tiles[:, 2], axis=1
    ).mean()
    basis = rigid_motion_basis(centred)
    assert np.abs(basis.T @ rep.flexes).max() < 1e-8
    mat = rigidity_matrix(centred, scene.hinge_vertices)
    assert np.abs(mat @ rep.flexes).max() < 1e-8


def test_exact_cylinder_special_position() -> None:
    """Odd grids on the exact cylinder are isostatic; even ones keep flexes (non-generic).

    Face contact (three points per contact) removes them on small grids.
    """
    s3 = cylinder_scene(3, 3)
    p3, _ = route_snap_pairs(s3.route)
    assert rigidity_report(s3.tiles_assembled, s3.hinge_vertices, p3).null_dimension == 6
    s4 = cylinder_scene(4, 4)
    p4, _ = route_snap_pairs(s4.route)
    assert rigidity_report(s4.tiles_assembled, s4.hinge_vertices, p4).internal_flexes > 0
    face = rigidity_report(s4.tiles_assembled, s4.hinge_vertices, p4, contact="face")
    assert face.null_dimension == 6


@pytest.mark.parametrize("with_string", [False, True])
def test_sparse_eigensolve_agrees_with_the_dense_svd(
    with_string: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Large linkages take the sparse path; on a small one both paths find the same motions."""
    from drawstring.geometry.assembled import rigidity

    scene = cylinder_scene(4, 4)
    pairs = route_snap_pairs(scene.route)[0] if with_string else np.zeros((0, 4), int)
    tiles = generic(scene, 2)
    dense = rigidity_report(tiles, scene.hinge_vertices, pairs)
    monkeypatch.setattr(rigidity, "DENSE_MAX_COLUMNS", 0)
    sparse = rigidity_report(tiles, scene.hinge_vertices, pairs)
    assert sparse.null_dimension == dense.null_dimension
    assert sparse.internal_flexes == dense.internal_flexes
    k = min(len(sparse.singular_values), len(dense.singular_values))
    assert np.allclose(sparse.singular_values[:k], dense.singular_values[:k], atol=1e-6)
    # The flexes span the same space.
    if dense.internal_flexes:
        proj = sparse.flexes @ (sparse.flexes.T @ dense.flexes)
        assert np.allclose(proj, dense.flexes, atol=1e-6)


def test_sparse_eigensolve_factors_a_gram_matrix_whose_shift_vanishes() -> None:
    """Two equal columns of norm 10 make ``R^T R`` singular, and a shift of ``tol ** 2``
    vanishes next to its entries (100), so that factor is exactly singular (as a 200-tile
    seashell design's can be).  A larger shift is tried then, and the null vector is still
    found."""
    import scipy.sparse.linalg as spla

    from drawstring.geometry.assembled import rigidity

    rng = np.random.default_rng(3)
    col = np.zeros((40, 1))
    col[0] = 10.0
    mat = sp.csr_matrix(np.hstack([rng.standard_normal((40, 30)), col, col]))
    s_max = float(np.linalg.svd(mat.toarray(), compute_uv=False).max())
    tol = 1e-10 * s_max
    gram = (mat.T @ mat).tocsc()
    with pytest.raises(RuntimeError, match="singular"):
        spla.splu(gram + tol**2 * sp.identity(32, format="csc"))
    sing, vecs = rigidity._smallest_singular_sparse(mat, tol, s_max)
    assert sing[0] <= tol < sing[1]
    assert abs(abs(vecs[-1, 0]) - np.sqrt(0.5)) < 1e-9 and abs(vecs[-1, 0] + vecs[-2, 0]) < 1e-9


def test_flex_count_ignores_eigensolver_noise_on_the_rigid_motions() -> None:
    # The sparse eigensolve returns the rigid motions only to about 1e-5 (the 1600-tile saddle);
    # such a null space with two true flexes has two internal flexes, not eight.
    from drawstring.geometry.assembled.rigidity import internal_flexes

    rng = np.random.default_rng(3)
    tiles = rng.normal(size=(30, 8, 3))
    rigid = rigid_motion_basis(tiles)
    flex = rng.normal(size=(rigid.shape[0], 2))
    flex -= rigid @ (rigid.T @ flex)
    mixed = np.hstack([rigid @ np.linalg.qr(rng.normal(size=(6, 6)))[0], flex])
    null, _ = np.linalg.qr(mixed + 1e-5 * rng.normal(size=mixed.shape))
    found = internal_flexes(null, rigid)
    assert found.shape == (rigid.shape[0], 2)
    # they span the true flexes
    q, _ = np.linalg.qr(flex)
    assert np.allclose(np.abs(np.linalg.svd(q.T @ found)[1]), 1.0, atol=1e-6)
    # without noise or flexes: none
    assert internal_flexes(rigid, rigid).shape[1] == 0
