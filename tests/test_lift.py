"""Lift points: gap energy, Morse-Smale peaks, coupling clusters (paper section 5.2)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest
from numpy.typing import NDArray

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.route.energy import (
    cluster_peaks,
    gap_adjacency,
    gap_potential_energy,
    morse_smale_basins,
    peak_barriers,
    tile_masses_from_volumes,
)
from drawstring.geometry.route.lift import geometric_deploy_check, select_lift_points
from drawstring.geometry.tiling.linkage import Linkage, build_linkage

HeightField = Callable[[NDArray[np.float64], NDArray[np.float64]], NDArray[np.float64]]


def _height_field(n_i: int, n_j: int, f: HeightField) -> tuple[Linkage, NDArray[np.float64]]:
    """A full grid whose tile (i, j) sits at (i + 0.5, j + 0.5, f) (10 mm cells)."""
    linkage = build_linkage(np.ones((n_i, n_j), dtype=bool))
    xy = (linkage.tile_cells + 0.5) * 10.0
    z = f(xy[:, 0], xy[:, 1])
    return linkage, np.column_stack([xy, z])


def _gap_vertex_xy(linkage: Linkage) -> NDArray[np.float64]:
    return np.asarray(linkage.vertex_ij[linkage.gap_vertex] * 10.0, dtype=np.float64)


def test_dome_has_one_lift_point_at_its_apex() -> None:
    def cap(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        r2 = (x - 60.0) ** 2 + (y - 60.0) ** 2
        return np.sqrt(150.0**2 - r2)

    linkage, cent = _height_field(12, 12, cap)
    lift = select_lift_points(linkage, cent, np.full(linkage.n_tiles, 0.01))
    assert len(lift.peaks) == 1
    assert len(lift.lift_gaps) == 1
    apex = _gap_vertex_xy(linkage)[lift.lift_gaps[0]]
    np.testing.assert_allclose(apex, [60.0, 60.0])
    np.testing.assert_allclose(lift.pull_directions, [[0.0, 0.0, 1.0]])
    assert "stand-in" in lift.check_name and lift.check_passed
    assert lift.sweep[0][0] == pytest.approx(0.8)


def test_up_axis_option_follows_the_resting_pose() -> None:
    """The dome turned on its side (apex along +x) with ``up = +x`` lifts at the same apex and
    pulls along +x; with the default +z it does not."""

    def cap(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.sqrt(150.0**2 - (x - 60.0) ** 2 - (y - 60.0) ** 2)

    linkage, cent = _height_field(12, 12, cap)
    turned = cent[:, [2, 1, 0]]  # x <-> z: the apex now points along +x
    masses = np.full(linkage.n_tiles, 0.01)
    upright = select_lift_points(linkage, cent, masses)
    lift = select_lift_points(linkage, turned, masses, up=(1.0, 0.0, 0.0))
    assert lift.lift_gaps.tolist() == upright.lift_gaps.tolist()
    np.testing.assert_allclose(lift.pull_directions, [[1.0, 0.0, 0.0]])
    wrong = select_lift_points(linkage, turned, masses)
    assert wrong.lift_gaps.tolist() != upright.lift_gaps.tolist()


def test_two_far_bumps_with_a_deep_valley_need_two_lift_points() -> None:
    def bumps(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        a = np.exp(-((x - 35.0) ** 2 + (y - 55.0) ** 2) / 20.0**2)
        b = np.exp(-((x - 165.0) ** 2 + (y - 55.0) ** 2) / 20.0**2)
        return 100.0 * (a + b)

    linkage, cent = _height_field(20, 11, bumps)
    lift = select_lift_points(linkage, cent, np.full(linkage.n_tiles, 0.01))
    assert len(lift.lift_gaps) == 2
    xy = _gap_vertex_xy(linkage)[lift.lift_gaps]
    centres = np.array([[35.0, 55.0], [165.0, 55.0]])
    dist = np.linalg.norm(xy[:, None, :] - centres[None, :, :], axis=2)
    assert np.all(dist.min(axis=0) <= 10.0)  # one lift point on each bump


def test_chair_back_noise_peaks_merge_into_one() -> None:
    def ridge(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        across = np.exp(-(((y - 50.0) / 25.0) ** 2))
        along = 1.0 - 0.02 * (((x - 100.0) / 30.0) ** 2 - 1.0) ** 2  # two close maxima, 2% dip
        return 200.0 * across * along

    linkage, cent = _height_field(20, 10, ridge)
    lift = select_lift_points(linkage, cent, np.full(linkage.n_tiles, 0.01))
    assert len(lift.peaks) == 2
    assert len(lift.lift_gaps) == 1
    assert lift.coupling[0, 1] > 0.9
    assert lift.lift_gaps[0] == lift.peaks[0]


def test_energy_invariants_and_basins_partition() -> None:
    def wavy(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        return 20.0 * np.sin(x / 17.0) * np.cos(y / 13.0)

    linkage, cent = _height_field(15, 12, wavy)
    masses = np.linspace(0.01, 0.02, linkage.n_tiles)
    energy = gap_potential_energy(linkage, cent, masses)
    assert energy.shape == (linkage.n_gaps,)
    assert np.all(energy >= 0)
    lowest = int(np.argmin(cent[:, 2]))
    only_lowest = [
        g for g in range(linkage.n_gaps) if set(linkage.gap_tiles(g).tolist()) == {lowest}
    ]
    assert all(energy[g] == 0 for g in only_lowest)
    # Energy of a gap: a quarter of each of its tiles' m g h (mm -> m).
    h = cent[:, 2] - cent[:, 2].min()
    g0 = 7
    expect = sum(0.25 * masses[t] * 9.81 * h[t] * 1e-3 for t in linkage.gap_tiles(g0))
    assert energy[g0] == pytest.approx(expect)
    # Total: every tile counted once per gap around it.
    edges = gap_adjacency(linkage)
    peaks, basin = morse_smale_basins(energy, edges)
    assert basin.shape == (linkage.n_gaps,)
    assert basin.min() == 0 and basin.max() == len(peaks) - 1
    assert np.all(basin[peaks] == np.arange(len(peaks)))
    # Peaks are strict local maxima.
    for p in peaks:
        nb = edges[(edges[:, 0] == p) | (edges[:, 1] == p)].ravel()
        assert np.all(energy[nb[nb != p]] <= energy[p])
    # Every gap climbs to a peak at least as high as itself.
    assert np.all(energy[peaks[basin]] >= energy)


def test_barrier_and_clusters_on_a_path_graph() -> None:
    # Path 0-1-2-3-4 with energies 5, 1, 4, 3.9, 0: peaks 0 and 2, barrier 1.
    energy = np.array([5.0, 1.0, 4.0, 3.9, 0.0])
    edges = np.array([[0, 1], [1, 2], [2, 3], [3, 4]])
    peaks, basin = morse_smale_basins(energy, edges)
    assert peaks.tolist() == [0, 2]
    assert basin.tolist() == [0, 0, 1, 1, 1]
    barrier = peak_barriers(energy, edges, peaks)
    assert barrier[0, 1] == pytest.approx(1.0)
    coupling = np.array([[0.0, 0.25], [0.0, 0.0]])
    assert cluster_peaks(coupling, 0.8)[1].tolist() == [0, 1]
    assert cluster_peaks(coupling, 0.2)[1].tolist() == [0]


def test_sweep_raises_tau_until_the_check_passes() -> None:
    def ridge(x: NDArray[np.float64], y: NDArray[np.float64]) -> NDArray[np.float64]:
        across = np.exp(-(((y - 50.0) / 25.0) ** 2))
        along = 1.0 - 0.02 * (((x - 100.0) / 30.0) ** 2 - 1.0) ** 2
        return 200.0 * across * along

    linkage, cent = _height_field(20, 10, ridge)

    def needs_two(lift_gaps: NDArray[np.int64]) -> bool:
        return len(lift_gaps) >= 2

    lift = select_lift_points(linkage, cent, np.full(linkage.n_tiles, 0.01), deploy_check=needs_two)
    assert lift.check_name == "needs_two"
    assert [n for _, n, _ in lift.sweep][0] == 1
    assert lift.check_passed and len(lift.lift_gaps) == 2
    assert lift.sweep[-1][2] is True
    # The stand-in check is named and accepts one lift point on the ridge.
    energy = gap_potential_energy(linkage, cent, np.full(linkage.n_tiles, 0.01))
    check = geometric_deploy_check(linkage, energy)
    assert "stand-in" in check.name
    assert check(lift.peaks[:1])


def test_tile_mass_of_a_box_and_a_frustum() -> None:
    box = np.array(
        [
            [0, 0, 0],
            [10, 0, 0],
            [10, 20, 0],
            [0, 20, 0],
            [0, 0, 5],
            [10, 0, 5],
            [10, 20, 5],
            [0, 20, 5],
        ],
        dtype=float,
    )
    # Square frustum: bottom 10x10, top 6x6, height 3 -> V = h/3 (A1 + A2 + sqrt(A1 A2)).
    top = np.array([[2, 2, 3], [8, 2, 3], [8, 8, 3], [2, 8, 3]], dtype=float)
    frustum = np.vstack([box[:4, :] * [1, 0.5, 1], top])
    m = tile_masses_from_volumes(np.stack([box, frustum, box[[4, 5, 6, 7, 0, 1, 2, 3]]]), 1000.0)
    np.testing.assert_allclose(m[0], 1000 * 1000e-9)
    np.testing.assert_allclose(m[1], 1000 * (3 / 3 * (100 + 36 + 60)) * 1e-9)
    np.testing.assert_allclose(m[2], m[0])
    with pytest.raises(InternalError):
        tile_masses_from_volumes(np.zeros((2, 4, 3)), 1000.0)


def test_peak_on_a_split_is_lifted_at_the_next_interior_gap() -> None:
    """A dome split through its apex: the peak gap lies on the seam, the lift point next to it."""
    from drawstring.geometry.tiling.linkage import Split, build_linkage

    link = build_linkage(np.ones((8, 8), dtype=bool), (Split("y", 4, 0, 8),))
    centres = (link.tile_cells + 0.5).astype(float)
    xy = centres - 4.0
    z = 20.0 - (xy**2).sum(axis=1)
    tiles = np.c_[centres * 10.0, z]
    lift = select_lift_points(link, tiles, np.ones(link.n_tiles))
    assert len(lift.lift_gaps) == 1
    gap = int(lift.lift_gaps[0])
    assert link.gap_kind[gap] in ("horizontal", "vertical")
    # It is next to the apex: its grid vertex is one step from (4, 4).
    i, j = link.vertex_ij[link.gap_vertex[gap]]
    assert abs(int(i) - 4) + abs(int(j) - 4) == 1


def test_a_split_dome_that_fails_every_threshold_is_lifted_part_by_part() -> None:
    """The seam through the apex leaves one peak, lifted on one side only; a check that wants
    every part lifted fails every threshold, and the last try, peaks part by part, passes."""
    from drawstring.geometry.tiling.linkage import Split, build_linkage

    link = build_linkage(np.ones((8, 8), dtype=bool), (Split("y", 4, 0, 8),))
    centres = (link.tile_cells + 0.5).astype(float)
    z = 20.0 - ((centres - 4.0) ** 2).sum(axis=1)
    tiles = np.c_[centres * 10.0, z]
    sides = link.gap_sides[:, :, 0]

    def parts_of(gaps: NDArray[np.int64]) -> set[int]:
        tiles_of = sides[np.asarray(gaps)]
        return {int(link.tile_component[t]) for t in tiles_of[tiles_of >= 0]}

    def every_part_lifted(gaps: NDArray[np.int64]) -> bool:
        return parts_of(gaps) == {0, 1}

    lift = select_lift_points(link, tiles, np.ones(link.n_tiles), deploy_check=every_part_lifted)
    assert lift.check_passed and parts_of(lift.lift_gaps) == {0, 1}
    assert [n for _, n, ok in lift.sweep] == [1, 1, 1, 1, 2]
    assert [ok for _, _, ok in lift.sweep] == [False] * 4 + [True]
    assert all(link.gap_kind[g] in ("horizontal", "vertical") for g in lift.lift_gaps)
    assert len(lift.peaks) == 2 and len(lift.clusters) == 2 and not np.isfinite(lift.tau)
    # a check that passes at the first threshold never gets there
    plain = select_lift_points(link, tiles, np.ones(link.n_tiles), deploy_check=lambda g: True)
    assert len(plain.lift_gaps) == 1 and len(plain.sweep) == 1
