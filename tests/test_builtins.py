"""Built-in parametric targets: valid disks of the requested size, resolution and character."""

from __future__ import annotations

import igl
import numpy as np
import pytest
from numpy.typing import NDArray

from drawstring.geometry.target.builtins import (
    BUILTIN_TARGETS,
    alternating_grid,
    grid_shape,
)
from drawstring.geometry.target.surface import load_target, validate_disk_mesh

NAMES = list(BUILTIN_TARGETS)
REQUIRED = ["saddle", "dome", "peanut", "seashell", "three-shell", "cloud", "wave", "chair"]
RESOLUTION = 2000


def min_angle_deg(vertices: NDArray[np.float64], faces: NDArray[np.int64]) -> float:
    corners = vertices[faces]
    smallest = np.inf
    for k in range(3):
        u = corners[:, (k + 1) % 3] - corners[:, k]
        w = corners[:, (k + 2) % 3] - corners[:, k]
        cosine = (u * w).sum(1) / np.linalg.norm(u, axis=1) / np.linalg.norm(w, axis=1)
        smallest = min(smallest, float(np.degrees(np.arccos(np.clip(cosine, -1, 1))).min()))
    return smallest


def free_conformal_map(
    vertices: NDArray[np.float64], faces: NDArray[np.int64]
) -> tuple[float, float]:
    """LSCM with two far-apart boundary vertices pinned (a free-boundary conformal map).

    Returns
    -------
    area_ratio : float
        max / min over vertices of the flat-to-3D area ratio (incident faces pooled).
    aspect : float
        Long side over short side of the flat map's principal-axis bounding box.
    """
    loop = igl.boundary_loop(faces)
    points = vertices[loop]
    distances = np.linalg.norm(points[:, None] - points[None], axis=2)
    i, j = np.unravel_index(distances.argmax(), distances.shape)
    uv, _ = igl.lscm(
        vertices, faces, np.array([loop[i], loop[j]]), np.array([[0.0, 0.0], [1.0, 0.0]])
    )
    area_3d = igl.doublearea(vertices, faces)
    e1 = uv[faces[:, 1]] - uv[faces[:, 0]]
    e2 = uv[faces[:, 2]] - uv[faces[:, 0]]
    area_2d = np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    flat_sum = np.bincount(faces.ravel(), np.repeat(area_2d, 3), minlength=len(vertices))
    curved_sum = np.bincount(faces.ravel(), np.repeat(area_3d, 3), minlength=len(vertices))
    ratio = flat_sum / curved_sum
    centred = uv - uv.mean(axis=0)
    _, _, axes = np.linalg.svd(centred, full_matrices=False)
    extent = np.ptp(centred @ axes.T, axis=0)
    return float(ratio.max() / ratio.min()), float(extent.max() / extent.min())


@pytest.fixture(scope="module")
def meshes() -> dict[str, tuple[NDArray[np.float64], NDArray[np.int64]]]:
    return {name: BUILTIN_TARGETS[name].make(RESOLUTION) for name in NAMES}


def test_required_targets_are_listed_with_one_line_descriptions():
    assert set(REQUIRED) <= set(NAMES)
    for name, builtin in BUILTIN_TARGETS.items():
        assert builtin.name == name == name.lower().strip()
        assert " " not in name
        assert builtin.description and "\n" not in builtin.description
        assert len(builtin.description) < 100


@pytest.mark.parametrize("name", NAMES)
def test_builtin_is_a_valid_disk_of_about_the_requested_size(meshes, name):
    vertices, faces = meshes[name]
    assert RESOLUTION / 1.5 <= len(faces) <= RESOLUTION * 1.5
    clean_vertices, clean_faces, notes = validate_disk_mesh(vertices, faces)
    assert notes == ()
    assert len(clean_faces) == len(faces) and len(clean_vertices) == len(vertices)
    assert len(igl.boundary_loop_all(faces)) == 1


@pytest.mark.parametrize("name", NAMES)
def test_builtin_faces_up_and_has_good_triangles(meshes, name):
    vertices, faces = meshes[name]
    corners = vertices[faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    total = normals.sum(axis=0)
    assert total[2] > 0.3 * np.linalg.norm(total)  # mostly +z
    assert min_angle_deg(vertices, faces) > 15.0


@pytest.mark.parametrize("name", NAMES)
def test_load_builtin_scales_exactly(name):
    target = load_target(name.upper(), 240.0, resolution=RESOLUTION)
    assert target.name == name and target.source == "builtin"
    low, high = target.vertices.min(axis=0), target.vertices.max(axis=0)
    assert (high - low).max() == pytest.approx(240.0, rel=1e-12)
    assert low[2] == pytest.approx(0.0, abs=1e-9)
    assert (low + high)[:2] == pytest.approx([0.0, 0.0], abs=1e-9)


def test_builtins_are_deterministic():
    for builtin in BUILTIN_TARGETS.values():
        v1, f1 = builtin.make(500)
        v2, f2 = builtin.make(500)
        np.testing.assert_array_equal(v1, v2)
        np.testing.assert_array_equal(f1, f2)


@pytest.mark.parametrize("resolution", [32, 300, 10_000])
def test_resolution_is_followed(resolution):
    for builtin in BUILTIN_TARGETS.values():
        n_faces = len(builtin.make(resolution)[1])
        assert resolution / 1.5 <= n_faces <= resolution * 1.5


@pytest.mark.parametrize("name", NAMES)
def test_flat_domain_aspect_fits_a_rectangle_grid(meshes, name):
    _, aspect = free_conformal_map(*meshes[name])
    assert aspect < 2.6


def test_conformal_scale_ratios_match_the_intent(meshes):
    ratio = {name: free_conformal_map(*meshes[name])[0] for name in NAMES}
    assert ratio["dome"] > 2.2  # the deep cap needs a split even with a free boundary
    for name in ("saddle", "wave", "chair"):
        assert ratio[name] < 2.0  # gentle sheets do not
    assert ratio["wave"] < 1.2  # nearly developable


def test_saddle_has_negative_and_dome_positive_curvature(meshes):
    for name, sign in (("saddle", -1.0), ("dome", 1.0)):
        vertices, faces = meshes[name]
        defect = igl.gaussian_curvature(vertices, faces)
        interior = np.ones(len(vertices), dtype=bool)
        interior[igl.boundary_loop(faces)] = False
        assert np.all(sign * defect[interior] > 0.0)


def test_grid_shape_known_answers():
    assert grid_shape(2000, 1.0) == (32, 31)
    n_u, n_v = grid_shape(10_000, 2.0)
    assert n_u == 100 and n_v == 50
    assert grid_shape(1, 1.0) == (2, 2)


def test_alternating_grid():
    uv, faces = alternating_grid(3, 2)
    assert uv.shape == (12, 2) and faces.shape == (12, 3)
    e1 = uv[faces[:, 1]] - uv[faces[:, 0]]
    e2 = uv[faces[:, 2]] - uv[faces[:, 0]]
    signed = 0.5 * (e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
    assert np.all(signed > 0) and signed.sum() == pytest.approx(1.0)
    # diagonals alternate: cell (0, 0) uses (0,0)-(1,1), cell (1, 0) uses (2,0)-(1,1)
    edges = {tuple(sorted(e)) for f in faces.tolist() for e in zip(f, f[1:] + f[:1], strict=True)}
    assert (0, 5) in edges and (2, 5) in edges and (1, 4) not in edges
