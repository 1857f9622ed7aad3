"""Minimum lift points from the gaps' gravitational potential energy (paper section 5.2).

:func:`select_lift_points` clusters the energy peaks of
:mod:`~drawstring.geometry.route.energy` by their coupling and sweeps the threshold ``tau = tau0,
tau0 + step, ... , 1.0`` and past 1.0 every peak on its own, stopping at the first ``tau`` whose
deployment check passes.  Each cluster's root is a lift point, moved off split and boundary gaps
onto the interior gap next to it (:func:`interior_lift_gaps`).

The deployment check is a callable: the design loop plugs in the deployment simulation; without
it ``geometric_deploy_check`` stands in, and its name says so in the result.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
from numpy.typing import ArrayLike

from drawstring.geometry.core.errors import InternalError
from drawstring.geometry.core.tolerances import LIFT_SHARE_MIN, LIFT_SUPPORT_MIN
from drawstring.geometry.core.types import FloatArray, IntArray
from drawstring.geometry.route.energy import (
    cluster_peaks,
    gap_adjacency,
    gap_potential_energy,
    morse_smale_basins,
    peak_barriers,
    peak_coupling,
    unit_direction,
)
from drawstring.geometry.tiling.linkage import Linkage

log = logging.getLogger(__name__)


class DeployCheck(Protocol):
    """A deployment check: ``check(lift_gaps) -> bool`` with a human-readable ``name``."""

    @property
    def name(self) -> str: ...

    def __call__(self, lift_gaps: IntArray) -> bool: ...


@dataclass(frozen=True)
class LiftPoints:
    """Selected lift points and the analysis behind them.

    Attributes
    ----------
    lift_gaps : (k,) int, gap id of each lift point (sorted from highest energy down).
    peaks : (p,) int, gap ids of the energy peaks (sorted from highest down).
    basin : (G,) int, index into ``peaks`` of the basin each gap belongs to.
    gap_energy : (G,) float, J, gravitational potential energy of each gap.
    coupling : (p, p) float, ``coupling[i, j] = barrier(i, j) / g_j`` when peak i is higher
        than peak j, else 0.
    clusters : (p,) int, cluster id of each peak; cluster ``c`` is lifted at ``lift_gaps[c]``.
    tau : float, the coupling threshold used (``inf`` when every peak is its own lift point).
    positions : (k, 3) float, mm, position of each lift point.
    pull_directions : (k, 3) float, unit pull direction at each lift point.
    check_name : str, which deployment check accepted (or last rejected) the selection.
    check_passed : bool, whether the check passed at ``tau``.
    sweep : list of ``(tau, n_lift, passed)`` for every threshold tried.
    """

    lift_gaps: IntArray
    peaks: IntArray
    basin: IntArray
    gap_energy: FloatArray
    coupling: FloatArray
    clusters: IntArray
    tau: float
    positions: FloatArray
    pull_directions: FloatArray
    check_name: str
    check_passed: bool
    sweep: tuple[tuple[float, int, bool], ...]

    def to_json(self) -> dict[str, Any]:
        """Plain-JSON summary: per lift point its gap, position (mm) and pull direction."""
        return {
            "count": int(len(self.lift_gaps)),
            "tau": None if not np.isfinite(self.tau) else float(self.tau),
            "check": self.check_name,
            "check_passed": bool(self.check_passed),
            "peaks": [int(p) for p in self.peaks],
            "sweep": [
                {"tau": None if not np.isfinite(t) else float(t), "lift_points": n, "passed": ok}
                for t, n, ok in self.sweep
            ],
            "points": [
                {
                    "gap": int(g),
                    "position_mm": [float(c) for c in p],
                    "pull_direction": [float(c) for c in d],
                }
                for g, p, d in zip(
                    self.lift_gaps, self.positions, self.pull_directions, strict=True
                )
            ],
        }


# --------------------------------------------------------------------------------------------
# deployment check stand-in


@dataclass(frozen=True)
class _RidgeSupportCheck:
    """Callable behind ``geometric_deploy_check``."""

    name: str
    peaks: IntArray
    peak_energy: FloatArray
    basin_share: FloatArray
    barrier: FloatArray
    share_min: float
    support_min: float

    def __call__(self, lift_gaps: IntArray) -> bool:
        lifted = np.isin(self.peaks, np.asarray(lift_gaps))
        if not lifted.any():
            return len(self.peaks) == 0
        support = self.barrier[:, lifted].max(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(self.peak_energy > 0, support / self.peak_energy, 1.0)
        significant = self.basin_share >= self.share_min
        ok = lifted | ~significant | (ratio >= self.support_min)
        return bool(ok.all())


def geometric_deploy_check(
    linkage: Linkage,
    gap_energy: ArrayLike,
    *,
    share_min: float = LIFT_SHARE_MIN,
    support_min: float = LIFT_SUPPORT_MIN,
) -> DeployCheck:
    """A geometric STAND-IN for the deployment simulation (named as such in the output).

    Criterion ("ridge support"): every peak whose basin holds at least ``share_min`` of the
    total gap potential energy must either be a lift point or be joined to some lift point by a
    ridge whose lowest energy (the barrier on the maximum spanning tree) is at least
    ``support_min`` times the peak's own energy.

    Why this is defensible: pulling a lift point raises the region around it, and the load
    reaches another heavy region only through the gaps between them; if every path to the
    nearest lift point dips into a valley far below the heavy peak (a slack region in between)
    that region has to be raised by the boundary string alone, which is what the paper's
    simulation reports as a stuck deployment for heavy structures.  Light basins are ignored
    because the boundary string alone assembles light structures (paper section 5.1).  It is a
    proxy: it knows nothing of friction, hinge stiffness or dynamics.

    Parameters
    ----------
    linkage : topology.
    gap_energy : (G,) float, J, from ``gap_potential_energy``.
    share_min : fraction of the total energy above which a basin counts as heavy.
    support_min : required ridge height as a fraction of the peak's energy.

    Returns
    -------
    A callable ``check(lift_gaps) -> bool`` with a ``name``.
    """
    energy = np.asarray(gap_energy, dtype=np.float64)
    edges = gap_adjacency(linkage)
    peaks, basin = morse_smale_basins(energy, edges)
    total = float(energy.sum())
    share = np.bincount(basin, weights=energy, minlength=len(peaks)) / (total if total else 1.0)
    return _RidgeSupportCheck(
        name=(
            f"geometric stand-in (ridge support >= {support_min:g} of peak energy for basins "
            f">= {share_min:.0%} of total energy; not a simulation)"
        ),
        peaks=peaks,
        peak_energy=energy[peaks],
        basin_share=share,
        barrier=peak_barriers(energy, edges, peaks),
        share_min=share_min,
        support_min=support_min,
    )


# --------------------------------------------------------------------------------------------
# selection


def _check_name(check: Callable[[IntArray], bool]) -> str:
    return str(getattr(check, "name", getattr(check, "__name__", type(check).__name__)))


def select_lift_points(
    linkage: Linkage,
    tile_centroids: ArrayLike,
    tile_masses: ArrayLike,
    *,
    up: ArrayLike = (0.0, 0.0, 1.0),
    tau0: float = 0.8,
    tau_step: float = 0.1,
    deploy_check: Callable[[IntArray], bool] | None = None,
    gap_positions: ArrayLike | None = None,
    gap_normals: ArrayLike | None = None,
) -> LiftPoints:
    """Minimum set of lift points by energetic coupling of the gap energy peaks.

    Parameters
    ----------
    linkage : topology.
    tile_centroids : (T, 3) float, mm, assembled tile centres of mass.
    tile_masses : (T,) float, kg.
    up : (3,) resting up axis of the assembled shape.
    tau0, tau_step : threshold sweep: ``tau0, tau0 + tau_step, ...`` up to 1.0 inclusive; if
        the check still fails every peak becomes its own lift point (``tau = inf``) and the
        result reports whether that passed.  A split linkage that fails even then tries the
        peaks of each part on its own (no ascent through seam gaps), every one lifted; that
        set is kept only if it passes.
    deploy_check : ``check(lift_gaps) -> bool``; default ``geometric_deploy_check`` (a stand-in).
    gap_positions : (G, 3) float, mm, optional lift-point positions (e.g. mean of the tiles'
        top-face centroids); default: mean of the surrounding tiles' centroids.
    gap_normals : (G, 3) float, optional outward normals; if given the pull direction is the
        normalized normal of the lift gap, else the ``up`` axis.

    Returns
    -------
    LiftPoints
    """
    up_axis = unit_direction(up, "up axis")
    if not 0.0 < tau_step:
        raise InternalError(f"tau step {tau_step} must be positive; the paper uses 0.1")
    energy = gap_potential_energy(linkage, tile_centroids, tile_masses, up=up_axis)
    edges = gap_adjacency(linkage)
    peaks, basin = morse_smale_basins(energy, edges)
    barrier = peak_barriers(energy, edges, peaks)
    coupling = peak_coupling(energy, peaks, barrier)
    check = deploy_check or geometric_deploy_check(linkage, energy)
    name = _check_name(check)
    sweep: list[tuple[float, int, bool]] = []
    chosen = _sweep_thresholds(
        linkage, energy, edges, peaks, basin, coupling, check, _thresholds(tau0, tau_step), sweep
    )
    if not chosen.passed and linkage.n_components > 1:
        chosen = _peaks_part_by_part(linkage, energy, edges, check, chosen, sweep)
    if not chosen.passed:
        # returned in ``sweep``; the pipeline lists it where the user reads it
        log.info("lift points: deployment check '%s' failed for every threshold", name)
    positions, pulls = _lift_pulls(
        linkage, tile_centroids, chosen.lift_gaps, up_axis, gap_positions, gap_normals
    )
    return LiftPoints(
        lift_gaps=chosen.lift_gaps.astype(np.int64),
        peaks=chosen.peaks,
        basin=chosen.basin,
        gap_energy=energy,
        coupling=chosen.coupling,
        clusters=chosen.clusters,
        tau=chosen.tau,
        positions=np.asarray(positions, dtype=np.float64),
        pull_directions=np.asarray(pulls, dtype=np.float64),
        check_name=name,
        check_passed=chosen.passed,
        sweep=tuple(sweep),
    )


@dataclass(frozen=True)
class _Selection:
    """One candidate set of lift points: the peaks it clusters, and whether the check passed."""

    lift_gaps: IntArray
    peaks: IntArray
    basin: IntArray
    coupling: FloatArray
    clusters: IntArray
    tau: float
    passed: bool


def _thresholds(tau0: float, tau_step: float) -> list[float]:
    """The coupling thresholds ``tau0, tau0 + tau_step, ...`` up to 1.0, then ``inf``."""
    taus: list[float] = []
    t = float(tau0)
    while t <= 1.0 + 1e-9:
        taus.append(round(t, 10))
        t += tau_step
    taus.append(float("inf"))
    return taus


def _sweep_thresholds(
    linkage: Linkage,
    energy: FloatArray,
    edges: IntArray,
    peaks: IntArray,
    basin: IntArray,
    coupling: FloatArray,
    check: Callable[[IntArray], bool],
    taus: list[float],
    sweep: list[tuple[float, int, bool]],
) -> _Selection:
    """The lift points of the first threshold whose check passes, else of the last; every
    threshold tried is appended to ``sweep``."""
    for tau in taus:
        clusters, roots = cluster_peaks(coupling, tau)
        lift_gaps = interior_lift_gaps(linkage, energy, edges, peaks[roots])
        passed = bool(check(lift_gaps))
        sweep.append((tau, int(len(lift_gaps)), passed))
        log.info("lift points: tau=%s -> %d lift points, check passed=%s", tau, len(roots), passed)
        if passed:
            break
    return _Selection(lift_gaps, peaks, basin, coupling, clusters, tau, passed)


def _peaks_part_by_part(
    linkage: Linkage,
    energy: FloatArray,
    edges: IntArray,
    check: Callable[[IntArray], bool],
    failed: _Selection,
    sweep: list[tuple[float, int, bool]],
) -> _Selection:
    """Last try on a split linkage: the peaks of every part on its own, every one lifted.

    Split parts share no hinge, so each must rise on its own; but one peak's basin can reach
    across a seam (the 1600-tile dome: its one peak lies just right of the cut and drains the
    left part too).  Kept only when the check passes (and then appended to ``sweep``)."""
    seam = np.asarray(linkage.gap_kind) == "split"
    field = energy.copy()
    field[seam] = energy.min() - 1.0  # nothing climbs through a seam gap
    part_peaks, part_basin = morse_smale_basins(field, edges)
    part_lifts = interior_lift_gaps(linkage, energy, edges, part_peaks)
    if set(part_lifts.tolist()) == set(failed.lift_gaps.tolist()):
        return failed
    part_passed = bool(check(part_lifts))
    sweep.append((float("inf"), int(len(part_lifts)), part_passed))
    log.info(
        "lift points: peaks part by part -> %d lift points, check passed=%s",
        len(part_lifts),
        part_passed,
    )
    if not part_passed:
        return failed
    n_peaks = len(part_peaks)
    return _Selection(
        part_lifts,
        part_peaks,
        part_basin,
        np.zeros((n_peaks, n_peaks)),
        np.arange(n_peaks, dtype=np.int64),
        float("inf"),
        True,
    )


def _lift_pulls(
    linkage: Linkage,
    tile_centroids: ArrayLike,
    lift_gaps: IntArray,
    up_axis: FloatArray,
    gap_positions: ArrayLike | None,
    gap_normals: ArrayLike | None,
) -> tuple[FloatArray, FloatArray]:
    """Position ``(k, 3)`` and pull direction ``(k, 3)`` of every lift point (see
    :func:`select_lift_points`)."""
    if gap_positions is None:
        tiles = linkage.gap_sides[:, :, 0]
        cent = np.asarray(tile_centroids, dtype=np.float64)
        valid = tiles >= 0
        pos_all = (cent[np.maximum(tiles, 0)] * valid[..., None]).sum(1) / valid.sum(1)[:, None]
    else:
        pos_all = np.asarray(gap_positions, dtype=np.float64)
    positions = pos_all[lift_gaps]
    if gap_normals is None:
        pulls = np.tile(up_axis, (len(lift_gaps), 1))
    else:
        nrm = np.asarray(gap_normals, dtype=np.float64)[lift_gaps]
        pulls = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    return positions, pulls


def interior_lift_gaps(
    linkage: Linkage,
    energy: FloatArray,
    edges: IntArray,
    gaps: IntArray,
) -> IntArray:
    """Move lift points off split and boundary gaps onto the best interior gap next to them.

    The string reaches a lift point from the boundary through interior gaps and may not enter
    through a split gap (paper sec. 5.3), and a gap on a split seam joins two separate parts, so
    a peak that falls on a split (or boundary) gap is lifted at the highest-energy horizontal or
    vertical gap sharing a tile with it.  Order is kept; duplicates are dropped.
    """
    interior = np.array([k in ("horizontal", "vertical") for k in linkage.gap_kind], dtype=bool)
    neighbours: dict[int, list[int]] = {}
    for a, b in edges.tolist():
        neighbours.setdefault(a, []).append(b)
        neighbours.setdefault(b, []).append(a)
    moved: list[int] = []
    for gap in np.asarray(gaps, dtype=np.int64).tolist():
        if not interior[gap]:
            options = [n for n in neighbours.get(gap, []) if interior[n]]
            if options:
                gap = max(options, key=lambda n: (energy[n], -n))
        if gap not in moved:
            moved.append(gap)
    return np.array(moved, dtype=np.int64)


def nearby_lift_gaps(linkage: Linkage, gap: int, positions: ArrayLike, steps: int = 2) -> IntArray:
    """Interior gaps of ``gap``'s part within ``steps`` hops of it (a hop joins two gaps that
    share a tile), nearest first: where a lift point may move when the string cannot reach it.

    Parameters
    ----------
    linkage : topology.
    gap : the lift gap.
    positions : (G, d) float, gap positions that decide "nearest" (ties: lower gap id).
    steps : largest number of hops.

    Returns
    -------
    (c,) int, without ``gap`` itself.
    """
    pos = np.asarray(positions, dtype=np.float64)
    interior = np.array([k in ("horizontal", "vertical") for k in linkage.gap_kind], dtype=bool)
    parts = {int(linkage.tile_component[t]) for t in linkage.gap_tiles(gap)}
    neighbours: dict[int, set[int]] = {}
    for a, b in gap_adjacency(linkage).tolist():
        neighbours.setdefault(a, set()).add(b)
        neighbours.setdefault(b, set()).add(a)
    seen, frontier = {int(gap)}, {int(gap)}
    for _ in range(steps):
        frontier = {n for f in frontier for n in neighbours.get(f, ())} - seen
        seen |= frontier
    found = [
        g
        for g in seen - {int(gap)}
        if interior[g] and {int(linkage.tile_component[t]) for t in linkage.gap_tiles(g)} <= parts
    ]
    dist = [float(np.linalg.norm(pos[g] - pos[gap])) for g in found]
    order = sorted(range(len(found)), key=lambda i: (dist[i], found[i]))
    return np.array([found[i] for i in order], dtype=np.int64)
