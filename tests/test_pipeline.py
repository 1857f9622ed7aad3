"""Pipeline helpers measured on known geometry.

The tiling ladder, co-optimization and hinge tests lay out the paper's assembled shape
(``fit="paper"``), on which their cases were found; ``tests/test_fit.py`` covers ``--fit close``.
"""

from __future__ import annotations

import copy
import math
import multiprocessing
import os
import re
from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from drawstring.app.commands import design_summary
from drawstring.fabrication.profiles import load_profile
from drawstring.geometry.core import parallel
from drawstring.geometry.core.parallel import can_fork
from drawstring.geometry.route.plan import plan_route
from drawstring.geometry.tiling.linkage import build_linkage, gap_centroids, rotating_squares_layout
from drawstring.pipeline import close_fit, co_rounds, layout_stage, shapes
from drawstring.pipeline.layout_stage import split_bound
from drawstring.pipeline.measure import channel_turn_assembled
from drawstring.pipeline.policy import DEFAULT_POLICY, LayoutPolicy
from drawstring.pipeline.record import DesignOptions, Progress
from drawstring.pipeline.run import cad_problems, cad_warnings, design


def flat_boxes(link, side: float = 10.0, thickness: float = 3.0) -> np.ndarray:
    """Assembled tiles of a planar grid: boxes, top face at z = 0, bottom at -thickness."""
    offsets = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], dtype=float)
    corners = (link.tile_cells[:, None, :] + offsets[None]) * side
    top = np.concatenate([corners, np.zeros((link.n_tiles, 4, 1))], axis=2)
    bottom = top - np.array([0.0, 0.0, thickness])
    return np.concatenate([top, bottom], axis=1)


def test_channel_turn_of_a_planar_loop_is_at_least_one_full_turn() -> None:
    link = build_linkage(np.ones((5, 4), dtype=bool))
    layout = rotating_squares_layout(link, math.radians(30))
    route = plan_route(link, gap_centroids(link, layout))
    turn = channel_turn_assembled(route, flat_boxes(link))
    # A closed loop in a plane turns by at least 2 pi; the channels bend only at the corners
    # of the ring and where the route steps in and out, each by a right angle.
    assert turn >= 2 * math.pi - 1e-9
    assert math.isclose(turn / (math.pi / 2), round(turn / (math.pi / 2)), abs_tol=1e-9)


def test_cad_problems_name_each_fault_of_the_solids() -> None:
    clean = {
        "solids_valid": True,
        "interference_tiles_max_mm3": 0.0,
        "interference_tiles_pads_max_mm3": 0.007,
        "interference_tiles_pads_max_rel": 0.0005,  # tessellation of shared pin walls
        "channel_opening_distance_max_mm": 0.0,
        "channel_openings_missing": 0,
    }
    assert cad_problems(clean) == []
    faults = {
        "solids_valid": False,
        "interference_tiles_max_mm3": 0.000234,
        "interference_tiles_pads_max_mm3": 5.7,
        "interference_tiles_pads_max_rel": 0.4,  # an uncut pin hole
        "channel_opening_distance_max_mm": 0.2,
        "channel_openings_missing": 1,
        "channel_worst_links": [
            {"tiles": [10, 11], "distance_mm": None},
            {"tiles": [3, 4], "distance_mm": 0.2},
            {"tiles": [4, 5], "distance_mm": 0.01},
        ],
        "print_clearance_mm": 0.4,
        "tile_gap_min_mm": 0.12,
        "tile_pairs_closer": 3,
    }
    found = cad_problems(faults)
    assert len(found) == 5
    assert any(
        p.startswith(
            "3 pairs of printed tiles come closer than the nozzle width (0.4 mm; down to 0.12 mm)"
        )
        for p in found
    )
    assert any(
        "(1 opening(s) missing, up to 0.2 mm apart; tiles 10 -> 11: an opening is missing on "
        "the solids; tiles 3 -> 4: 0.2 mm apart;" in p
        for p in found
    )
    assert any("40 % of its volume inside a tile" in p for p in found)
    assert any("interfere in the print pose (0.000234" in p for p in found)


def test_magnet_pockets_breaking_out_are_a_warning() -> None:
    profile = load_profile("fdm-dual")
    assert cad_warnings({"magnet_pairs": 12, "magnet_pockets_breaking_out": 0}, profile) == []
    (warning,) = cad_warnings({"magnet_pairs": 12, "magnet_pockets_breaking_out": 2}, profile)
    assert warning.startswith("2 of 12 magnet pairs have pockets breaking out of their side faces")
    assert f"smaller magnets than {profile.magnet_diameter_mm:g} mm" in warning


def test_a_part_whose_flat_layout_misses_is_tiled_again_and_a_miss_is_never_silent() -> None:
    # The 200-tile seashell stays one part under the default bound (ratio 1.37 < 1.66), yet
    # with the plain co-optimization its one-part layout misses the 1e-3 mm targets: by
    # 0.023 mm in the plane with numpy's AVX2 kernels, 0.024 mm in depth with AVX-512 ones.
    # It is tiled again; whether two parts win depends on those last bits (with AVX2 they
    # meet the targets, with AVX-512 they gain too little and the first tiling is kept; the
    # rule itself is tested on set accuracies below).  Either way the note gives the miss,
    # and what is kept either meets the targets or says in a warning by how much it misses.
    plain = LayoutPolicy(conical_weights=())  # the plain co-optimization, never conical
    options = DesignOptions(tiles=200, size_mm=200.0, simulate=False, cad=False, fit="paper")
    result = design("seashell", options, policy=plain)
    default_bound = split_bound(result.options)
    metrics = result.metrics()
    assert result.tiling.scale_factor_max_unsplit < default_bound  # no split at the default
    (note,) = [n for n in result.notes if n.startswith("tiling:")]
    missed = float(note.split("only to ")[1].split(" mm")[0])
    assert missed > 1e-3
    assert re.search(r"tighter splits gave \d+ parts at bound [\d.]+: [\d.e-]+ mm", note)
    parts = result.tiling.linkage.n_components
    assert note.endswith("kept the first tiling" if parts == 1 else f"kept {parts} parts")
    assert metrics["flat_edge_error_max_mm"] <= 1e-3 or any(
        w.startswith("flat edge error") for w in result.warnings
    )
    assert metrics["hinge_gap_max_mm"] <= 1e-3 or any(
        w.startswith("hinge gap") for w in result.warnings
    )
    assert result.problems == ()


def test_a_part_whose_hinges_miss_only_in_depth_is_split_further() -> None:
    # The 100-tile chair in one part: its conical co-optimization misses the flat target, so
    # (laid out in full, not paused for the split, prefer_split_at_first_weight) it is
    # co-optimized without, and its bottom hinges then meet seen from above (1.3e-4 mm) but
    # not in depth (0.020 mm with numpy's AVX2 kernels, 0.005 mm with AVX-512 ones).  The
    # tiling is judged by the whole hinge gap: split once more, the conical co-optimization
    # succeeds and the hinges meet in 3D.
    policy = LayoutPolicy(prefer_split_at_first_weight=False)
    options = DesignOptions(tiles=100, size_mm=200.0, simulate=False, cad=False, fit="paper")
    result = design("chair", options, policy=policy)
    metrics = result.metrics()
    assert result.tiling.linkage.n_components == 2
    (note,) = [n for n in result.notes if n.startswith("tiling:")]
    assert float(note.split("only to ")[1].split(" mm")[0]) > 1e-3
    assert note.endswith("kept 2 parts")
    assert not any("without the conical condition" in n for n in result.notes)
    assert metrics["hinges_bottom"] > 0
    assert metrics["hinge_gap_max_mm"] <= 1e-3
    assert metrics["flat_edge_error_max_mm"] <= 1e-3
    assert result.problems == ()
    # the summary line says why the bound is below what one part can absorb
    summary = design_summary(result)
    bound = metrics["split_bound"]
    assert f"exceeds {bound:.3g}, tightened from {split_bound(result.options):.3g}" in summary


def test_the_summary_names_the_gap_angle_bound_where_no_retiling_tightened_it() -> None:
    # The 8 x 8 dome is split at the default bound (1.65575 in design.json, to 6 digits, of
    # 2 / (1 + sin 12 deg) = 1.6557502): the rounding alone once read as a tightened bound.
    result = design(
        "dome", DesignOptions(grid=(8, 8), resolution=1500, simulate=False, cad=False, fit="paper")
    )
    assert result.tiling.linkage.n_components == 2
    assert not any(n.startswith("tiling:") for n in result.notes)
    summary = design_summary(result)
    assert "exceeds 1.66, what one part's gaps can absorb opening within [12, 90] deg" in summary
    assert "tightened" not in summary


def test_a_conical_round_that_loses_ground_does_not_end_the_co_optimization() -> None:
    # The CLI-default three-shell's conical rounds once went 0.020, 0.060, 1.1e-3, 3.9e-4,
    # 1.4e-4 mm.  Judged by the rate of the lost second round they were given up, and the
    # design co-optimized without the condition kept a 0.033 mm hinge gap in depth.  (With
    # other last bits the three-shell's rounds go otherwise; the rule is tested here on those
    # numbers, the real design below.)
    judge = co_rounds.RoundJudge(0.13, conical=True)
    rounds = [0.020, 0.060, 1.1e-3, 3.9e-4, 1.4e-4]
    verdicts = [judge.judge(error, 1e-6) for error in rounds]
    assert verdicts == [(True, False), (False, False), (True, False), (True, False), (True, True)]
    assert judge.best_mm == 1.4e-4 and not judge.cut_short
    # A plain run that may still be split is given up at the lost round: at its rate the
    # rounds left would not reach the tolerance.
    plain = co_rounds.RoundJudge(0.13, give_up_slow=True)
    assert [plain.judge(error, 1e-6) for error in rounds[:2]] == [(True, False), (False, True)]
    assert plain.cut_short
    # A conical first round above the plain layout waits for the next one too (AVX-512
    # three-shell: 0.197 mm against a plain 0.117 mm, then 6.7e-3, 4.0e-4 mm); a plain one
    # that may be split is given up (at its rate it would not reach the tolerance).
    conical = co_rounds.RoundJudge(0.117, conical=True, give_up_slow=True)
    assert [conical.judge(e, 1e-4) for e in (0.197, 6.7e-3, 4.0e-4)] == [
        (True, False),
        (True, False),
        (True, False),
    ]
    assert not conical.cut_short
    plain = co_rounds.RoundJudge(0.117, give_up_slow=True)
    assert plain.judge(0.197, 1e-4) == (True, True) and plain.cut_short


def test_co_optimization_rounds_stop_where_they_no_longer_pay() -> None:
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    # a first round far above the plain layout is given up at once (one-part chair: 6.5x)
    judge = co_rounds.RoundJudge(0.69)
    assert judge.judge(4.5, 0.1) == (True, True)
    # two rounds in a row that do not get below the plain layout
    judge = co_rounds.RoundJudge(0.69)
    assert [judge.judge(e, 0.1) for e in (1.0, 0.9)] == [(True, False), (True, True)]
    # within the tolerance and gaining less than 10 % on the best round
    judge = co_rounds.RoundJudge(0.1)
    assert [judge.judge(e, 1e-6) for e in (5e-4, 4.6e-4)] == [(True, False), (True, True)]
    # ... but not where it is within the tolerance by less than co_stop_near: the hinge
    # layout can add to it (the AVX-512 wave stopped at 9.4e-4 mm and missed at 1.2e-3 mm)
    judge = co_rounds.RoundJudge(0.1)
    assert [judge.judge(e, 1e-6) for e in (9.4e-4, 9.8e-4)] == [(True, False), (False, False)]
    # well inside the tolerance at once
    assert co_rounds.RoundJudge(0.1).judge(0.25 * tol, 1e-6) == (True, True)
    # within the tolerance and near the joint solve (conical: only within 0.35 of it)
    assert co_rounds.RoundJudge(0.1).judge(0.5 * tol, 0.1 * tol) == (True, True)
    assert co_rounds.RoundJudge(0.1, conical=True).judge(0.5 * tol, 0.1 * tol) == (
        True,
        False,
    )


#: The default policy with every co-optimization run in this process (none run ahead).
IN_TURN = LayoutPolicy(co_speculate=False)
#: The conical weights the ladder tries first and next.
FIRST, RETRY = DEFAULT_POLICY.conical_weights[:2]


def _conical_runs(
    monkeypatch, refused: set[float], missed_mm: float | None = None, joint: bool = False
) -> list[tuple[bool, float | None, bool]]:
    """Record the co-optimizations ``_shaped`` runs as ``(conical, weight, fallback)``; a
    conical one with a weight in ``refused`` comes back refused (``joint``: for its first
    joint solve), or with ``missed_mm`` used but that far off the flat targets.  Only the
    calls made in this process are recorded: the design runs with :data:`IN_TURN` (or
    another policy with ``co_speculate=False``) to make every co-optimization here."""
    calls: list[tuple[bool, float | None, bool]] = []
    real = layout_stage._co_optimized_with_fallback

    def recorded(*args, **kwargs):
        conical, weight = args[8], args[9] if len(args) > 9 else None
        calls.append((conical, weight, args[7]))
        out = real(*args, **kwargs)
        if conical and weight in refused:
            if missed_mm is not None:
                block = {**out[2], "accepted": True, "reason": ""}
                return out[0], replace(out[1], edge_error_max_mm=missed_mm), block, out[3]
            block = {**out[2], "accepted": False, "reason": f"refused at weight {weight:g}"}
            if joint:
                block["joint_refused"] = True
            return out[0], out[1], block, out[3]
        return out

    monkeypatch.setattr(layout_stage, "_co_optimized_with_fallback", recorded)
    return calls


def test_a_conical_co_optimization_that_misses_is_tried_with_the_next_weight(monkeypatch) -> None:
    # The 60-tile saddle has bottom hinges: its co-optimization is conical.  Refused at the
    # first weight, it runs again at the retry weight, and only where that is refused too
    # without the condition, with a note giving the last reason.  (Laid out in full: a
    # tiling that may still be split pauses for its split after the first weight.)
    policy = replace(IN_TURN, prefer_split_at_first_weight=False)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    first, retry = FIRST, RETRY
    calls = _conical_runs(monkeypatch, {first})
    result = design("saddle", options, policy=policy)
    assert [c[:2] for c in calls[:2]] == [(True, first), (True, retry)]
    without = [n for n in result.notes if "without the conical condition" in n]
    if [c[:2] for c in calls[2:3]] == [
        (False, None)
    ]:  # the retry weight missed the flat targets itself
        assert without and f"refused at weight {first:g}" not in without[0]
    else:
        assert not without
    calls = _conical_runs(monkeypatch, {first, retry})
    result = design("saddle", options, policy=policy)
    assert [c[:2] for c in calls[:3]] == [(True, first), (True, retry), (False, None)]
    (note,) = [n for n in result.notes if "without the conical condition" in n]
    assert f"(refused at weight {retry:g} with it)" in note


def test_a_tiling_that_may_still_be_split_tries_no_second_weight_after_a_far_miss(
    monkeypatch,
) -> None:
    # The 60-tile saddle is made a tiling that may be split again; its conical
    # co-optimization is used but misses by 0.5 mm at the first weight: it goes without the
    # condition at once.  A miss within co_slow_reach of the tolerance still gets the retry
    # weight, and so does the same far miss in a tiling that is laid out in full.
    policy = replace(
        IN_TURN,
        retile_min_share=0.0,
        retile_ahead=False,
        prefer_split_at_first_weight=False,  # (no pause)
    )
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    first, retry = FIRST, RETRY
    calls = _conical_runs(monkeypatch, {first}, missed_mm=0.5)
    design("saddle", options, policy=policy)
    assert calls[:2] == [(True, first, False), (False, None, False)]
    near = 0.5 * policy.co_slow_reach * layout_stage.FLAT_EDGE_ERROR_TOL_MM
    calls = _conical_runs(monkeypatch, {first}, missed_mm=near)
    design("saddle", options, policy=policy)
    assert calls[:2] == [(True, first, False), (True, retry, False)]
    in_full = replace(policy, retile_min_share=10.0)  # laid out in full
    calls = _conical_runs(monkeypatch, {first}, missed_mm=0.5)
    design("saddle", options, policy=in_full)
    assert calls[:2] == [(True, first, True), (True, retry, True)]


#: The 60-tile saddle's first tiling may still be split; every co-optimization runs here.
PAUSING = replace(IN_TURN, retile_min_share=0.0, retile_ahead=False)


def _two_parts_meet(shaped: layout_stage.ShapedLayout) -> float:
    return 1.4e-3 if shaped.tiling.linkage.n_components == 1 else 9.5e-4


def _every_tiling_misses(_shaped: layout_stage.ShapedLayout) -> float:
    return 1.0


@pytest.fixture(scope="module")
def _paused_saddles():
    """The 60-tile saddle under :data:`PAUSING` whose first conical weight misses the flat
    targets by twice the tolerance, so its first tiling pauses for the split: where the split
    meets the targets (:func:`_two_parts_meet`) and where it misses too
    (:func:`_every_tiling_misses`); each with the co-optimizations it ran (``_conical_runs``).
    They see two cores, as the designs they are compared with that run work ahead."""
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    made = {}
    for accuracy in (_two_parts_meet, _every_tiling_misses):
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(parallel, "thread_count", lambda: 2)
            patch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(accuracy))
            calls = _conical_runs(patch, {FIRST}, missed_mm=2.0 * tol)
            made[accuracy] = design("saddle", options, policy=PAUSING), list(calls)
    return made


@pytest.fixture
def paused_saddle(_paused_saddles):
    """A copy of a design of :func:`_paused_saddles`, and its co-optimizations, by accuracy."""
    return lambda accuracy: copy.deepcopy(_paused_saddles[accuracy])


def test_a_split_meeting_the_targets_is_kept_before_the_first_tiling_tries_more(
    monkeypatch, paused_saddle
) -> None:
    # The 60-tile saddle as a tiling that may still be split: its first conical weight misses
    # the flat targets, so its ladder pauses and the first tighter tiling is laid out; that
    # meets every target, so it is kept and the first tiling tries no further co-optimization
    # (prefer_split_at_first_weight).
    # (calls are counted here: nothing is laid out or co-optimized ahead)
    first = FIRST
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    result, calls = paused_saddle(_two_parts_meet)
    assert result.tiling.linkage.n_components == 2
    assert [c for c in calls if not c[2]] == [(True, first, False)]  # the first tiling's
    assert calls[1] == (True, first, True)  # then the split, laid out in full
    (note,) = [n for n in result.notes if n.startswith("tiling:")]
    assert f"(1 part) the conical co-optimization (weight {first:g}) missed" in note
    assert f"{2.0 * tol:.3g} mm exceeds" in note
    assert "2 parts at bound" in note and "0.00095 mm" in note
    assert note.endswith(
        "without trying the first tiling with another weight or without the condition"
    )
    # with no tighter tiling to try, nothing pauses: the first tiling runs its whole ladder
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(_two_parts_meet))
    calls = _conical_runs(monkeypatch, {first}, missed_mm=2.0 * tol)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    result = design("saddle", options, policy=replace(PAUSING, retile_attempts=0))
    assert result.tiling.linkage.n_components == 1
    assert calls[:2] == [(True, first, False), (True, RETRY, False)]


def test_a_paused_first_tiling_goes_on_where_the_split_misses(monkeypatch, paused_saddle) -> None:
    # Where the split misses too, the first tiling's ladder goes on from its next weight (the
    # first is not run again) and the design is bitwise the one laid out without the pause.
    first, retry = FIRST, RETRY
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    paused, calls = paused_saddle(_every_tiling_misses)
    ones = [c for c in calls if not c[2]]  # the first tiling's, in this process
    assert ones[:2] == [(True, first, False), (True, retry, False)]
    assert calls.index((True, retry, False)) > calls.index((True, first, True))  # after the split
    assert paused.tiling.linkage.n_components == 1
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(_every_tiling_misses))
    calls = _conical_runs(monkeypatch, {first}, missed_mm=2.0 * tol)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    policy = replace(PAUSING, prefer_split_at_first_weight=False)
    straight = design("saddle", options, policy=policy)
    assert [c for c in calls if not c[2]] == ones
    assert paused.notes == straight.notes
    for a, b in zip(_design_arrays(paused), _design_arrays(straight), strict=True):
        assert np.array_equal(a, b)


def test_after_a_pause_each_tighter_tiling_is_laid_out_once(monkeypatch) -> None:
    # The 60-tile saddle pauses in one part; its two parts halve the accuracy figure but miss
    # the targets, so the first tiling goes on, the two parts (laid out once) are kept over
    # it, and the next split (four parts) is laid out in its own right and meets them.
    # (calls are counted here: nothing is laid out or co-optimized ahead)
    policy = replace(IN_TURN, retile_min_share=0.0, retile_ahead=False)
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    _conical_runs(monkeypatch, {FIRST}, missed_mm=2.0 * tol)
    by_parts = {1: 1.0, 2: 0.4}
    monkeypatch.setattr(
        layout_stage.ShapedLayout,
        "accuracy_mm",
        property(lambda s: by_parts.get(s.tiling.linkage.n_components, 1e-4)),
    )
    laid: list[tuple[int, bool]] = []  # parts of each tiling laid out, and whether it paused
    shaped = layout_stage._shaped

    def recorded(tiling, *args, **kwargs):
        out = shaped(tiling, *args, **kwargs)
        laid.append((tiling.linkage.n_components, out.unfinished))
        return out

    monkeypatch.setattr(layout_stage, "_shaped", recorded)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    result = design("saddle", options, policy=policy)
    assert laid == [(1, True), (2, False), (1, False), (4, False)]
    assert result.tiling.linkage.n_components == 4
    (note,) = [n for n in result.notes if n.startswith("tiling:")]
    assert re.search(
        r"gave 2 parts at bound [\d.]+: 0\.4 mm; 4 parts at bound [\d.]+: 0\.0001 mm", note
    )
    assert note.endswith("kept 4 parts")


def test_the_pause_gives_the_design_laid_out_in_turn_where_work_runs_ahead(
    monkeypatch, paused_saddle
) -> None:
    # With the split laid out ahead and the run without the condition run ahead, the paused
    # first tiling gives the serial design (laid out in turn: PAUSING) bitwise, where the
    # split is kept and where the first tiling goes on, and no child is left behind.
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)  # ahead even on one core
    run_ahead = replace(PAUSING, retile_ahead=True, co_speculate=True)
    if not can_fork():
        pytest.skip("processes cannot fork here")
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    _conical_runs(monkeypatch, {FIRST}, missed_mm=2.0 * tol)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    for accuracy, parts in ((_two_parts_meet, 2), (_every_tiling_misses, 1)):
        monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(accuracy))
        serial, _ = paused_saddle(accuracy)
        ahead = design("saddle", options, policy=run_ahead)
        assert ahead.tiling.linkage.n_components == serial.tiling.linkage.n_components == parts
        assert ahead.notes == serial.notes
        for a, b in zip(_design_arrays(ahead), _design_arrays(serial), strict=True):
            assert np.array_equal(a, b)
        assert multiprocessing.active_children() == []


def test_no_larger_conical_weight_follows_a_joint_solve_above_the_plain_layout(
    monkeypatch,
) -> None:
    # Refused for its first joint solve, the conical co-optimization is run without the
    # condition next: a larger weight would pull the joint solve further off.
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    calls = _conical_runs(monkeypatch, {FIRST}, joint=True)
    result = design("saddle", options, policy=IN_TURN)
    assert [c[:2] for c in calls[:2]] == [(True, FIRST), (False, None)]
    (note,) = [n for n in result.notes if "without the conical condition" in n]
    assert f"(refused at weight {FIRST:g} with it)" in note


def test_the_dual_hinged_three_shell_meets_its_hinges_in_3d() -> None:
    # Its conical co-optimization once gave up: after a lost second round on one machine,
    # after a first round above the plain layout (0.197 against 0.117 mm) with AVX-512
    # kernels on another, keeping 0.032 mm in depth.  Judged by the rounds after those, the
    # bottom hinges meet in 3D with AVX-512 and AVX2 kernels alike (3.8e-4, 3.5e-4 mm).
    # (--hinges dual: left unset, the close fit lays the three-shell out with top hinges.)
    result = design("three-shell", DesignOptions(simulate=False, cad=False, hinges="dual"))
    metrics = result.metrics()
    assert metrics["hinges_bottom"] > 0
    assert metrics["flat_edge_error_max_mm"] <= 1e-3
    assert metrics["hinge_gap_max_mm"] <= 1e-3
    assert not any("without the conical condition" in n for n in result.notes)
    assert result.problems == ()


def test_a_string_whose_channels_bend_too_much_is_warned_about(monkeypatch) -> None:
    # The warning follows the measured capstan factor of the assembled channels: none on a
    # small saddle at the default bound, one naming the factor and the fixes once the bound is
    # below it.
    from drawstring.pipeline import measure

    options = DesignOptions(grid=(6, 4), resolution=1500, simulate=False, cad=False, fit="paper")
    plain = design("saddle", options)
    factor = plain.metrics()["route"]["capstan_factor_channels_assembled"]
    assert 1.0 < factor < measure.CAPSTAN_FACTOR_WARN
    assert not any("the pull needs" in w for w in plain.warnings)
    monkeypatch.setattr(measure, "CAPSTAN_FACTOR_WARN", 0.5 * factor)
    (warning,) = [w for w in design("saddle", options).warnings if "the pull needs" in w]
    assert f"the pull needs {factor:.3g} times the tension" in warning
    assert "friction_coefficient" in warning and "far tiles may not close" in warning


def test_a_layout_that_meets_its_targets_keeps_the_default_split_bound(saddle60) -> None:
    result = saddle60
    assert result.metrics()["split_bound"] == round(split_bound(result.options), 6)
    assert not [n for n in result.notes if n.startswith("tiling:")]


def test_hinged_pairs_that_planes_through_the_hinge_hold_apart_are_laid_out_again() -> None:
    # At the ends of the three-shell's split lines three hinged pairs do not collide, yet no
    # plane through their hinge separates the two whole tiles: held to such planes they stay
    # 0.01 mm apart (two more stay just inside the tolerance, where T2D had them much closer:
    # laid out again too).  Separated on the hinge face only, they meet and nothing interpenetrates.
    # (With the bottom hinges' depths matched first the three-shell's pairs all meet without
    # this; the eq.-1 bottoms keep the case.)
    options = DesignOptions(
        tiles=200, size_mm=200.0, simulate=False, cad=False, fit="paper", hinges="dual"
    )
    result = design("three-shell", options, policy=LayoutPolicy(hinge_depths=False))
    metrics = result.metrics()
    assert metrics["hinge_gap_in_plane_max_mm"] <= 1e-3
    assert metrics["flat_interpenetration_mm3"] <= 1e-6
    assert metrics["flat_overlap_area_mm2"] == 0.0
    again = [re.search(r"laid out (\d+) pairs again", n) for n in result.notes]
    counts = [int(m.group(1)) for m in again if m]
    assert len(counts) == 1 and counts[0] >= 3
    # (without the depth matching the bottom hinges stay apart in depth, over the fabrication
    # tolerance: that is the one problem)
    assert [p for p in result.problems if not p.startswith("hinge gap in depth")] == []


def test_top_hinges_trim_unhinged_overlaps_instead_of_pulling_hinges_apart() -> None:
    # The 300-tile wave at the profile's size has 6 mm thick tiles 8.7 mm wide: four unhinged
    # pairs' bottoms overlap in the flat pose by about 0.01 mm^3 each.  Held apart by planes
    # through the whole tiles, they pulled hinges 6.7e-3 mm apart (a missed target); separated
    # on their top faces and trimmed, as top hinged pairs are, the layout keeps its accuracy.
    result = design(
        "wave", DesignOptions(tiles=300, hinges="top", simulate=False, cad=False, fit="paper")
    )
    metrics = result.metrics()
    assert metrics["hinge_gap_in_plane_max_mm"] <= 1e-3
    assert metrics["flat_edge_error_max_mm"] <= 1e-3
    assert metrics["flat_interpenetration_mm3"] <= 1e-6  # measured after every trim
    assert metrics["flat_overlap_area_mm2"] == 0.0
    unhinged = [tr for tr in result.hinge_layout.trims if tr.hinge < 0]
    hinged_pairs = {tuple(sorted(p)) for p in result.tiling.linkage.hinges[:, [0, 2]].tolist()}
    assert unhinged and all((tr.other, tr.tile) not in hinged_pairs for tr in unhinged)
    assert all(tr.other < tr.tile and 0 < tr.volume_mm3 < 0.1 for tr in unhinged)
    assert any("unhinged pairs overlap in the flat pose" in n for n in result.notes)
    assert result.problems == ()


@pytest.fixture(scope="module")
def _saddle60_shared():
    """The 60-tile saddle's design, its eq.-1 tiles, dual hinge faces and plain flat layout,
    made once for this module; tests get copies (:func:`saddle60`, :func:`before_co`)."""
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    shaped = design("saddle", options)  # for its tiling, target and resolved options
    eq1 = shapes.optimize_assembled(
        shaped.tiling.vertices,
        shaped.tiling.quads,
        shaped.target.vertices,
        shaped.target.faces,
        thickness=shaped.options.thickness_mm,
        w_planar=shaped.options.weights[0],
        w_square=shaped.options.weights[1],
        w_surface=shaped.options.weights[2],
    )
    linkage = shaped.tiling.linkage
    faces = layout_stage.dual_hinge_faces(linkage, eq1.tiles, shaped.options.min_gap_angle_deg)
    plain = co_rounds.flat_layout(linkage, shaped.tiling, eq1, shaped.options, faces)
    return shaped, eq1, faces, plain


@pytest.fixture
def before_co(_saddle60_shared):
    """A copy of the 60-tile saddle design, its eq.-1 tiles, dual hinge faces and plain flat
    layout (copied together: what one holds of another stays shared)."""
    return copy.deepcopy(_saddle60_shared)


@pytest.fixture
def saddle60(_saddle60_shared):
    """A copy of the 60-tile saddle's design (``tiles=60, size_mm=200``, no simulation or CAD)."""
    return copy.deepcopy(_saddle60_shared[0])


def test_co_optimization_is_judged_by_its_own_tiles_not_the_target_normals(
    monkeypatch, before_co
) -> None:
    # On a scan the one closest triangle at a tile's centre can face away from the tile
    # (``flipped_tiles``); that said nothing about the co-optimization and refused it on the
    # scanned face.  A tile is turned over only when its top turned by more than 90 deg.
    shaped, eq1, faces, plain = before_co
    reextrude, remeasured = co_rounds.reextrude, co_rounds.remeasured
    seen: list[int] = []

    def noisy_extrusion(*args: object, **kwargs: object):
        out = reextrude(*args, **kwargs)
        return None if out is None else replace(out, metrics={**out.metrics, "flipped_tiles": 3})

    def noisy_measure(*args: object, **kwargs: object):
        out = remeasured(*args, **kwargs)
        seen.append(1)
        return replace(out, metrics={**out.metrics, "flipped_tiles": 3})

    monkeypatch.setattr(co_rounds, "reextrude", noisy_extrusion)
    monkeypatch.setattr(co_rounds, "remeasured", noisy_measure)
    new, flat, block = co_rounds.co_optimized(
        shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert block["accepted"], block["reason"]
    assert seen and new.metrics["flipped_tiles"] == 3  # the kept round was measured so
    assert flat.edge_error_max_mm < plain.edge_error_max_mm
    # every top face kept its orientation
    before = co_rounds.quad_vector_areas(eq1.top, eq1.quads)
    after = co_rounds.quad_vector_areas(new.top, new.quads)
    assert np.all(np.einsum("ki,ki->k", before, after) > 0)


def test_a_required_co_optimization_is_refused_at_its_first_round_that_folds(
    monkeypatch, before_co
) -> None:
    # policy.co_required (the layouts pulled to the target): a round whose re-extruded shape
    # folds a tile ends the run there, refused, with the inputs back; without it the rounds
    # go on and the run is judged by the round it keeps.  Here only the first round folds.
    shaped, eq1, faces, plain = before_co
    reextrude = co_rounds.reextrude
    rounds: list[int] = []

    def first_folds(*args: object, **kwargs: object):
        out = reextrude(*args, **kwargs)
        rounds.append(1)
        if out is None or len(rounds) > 1:
            return out
        return replace(out, metrics={**out.metrics, "corner_margin_min": -0.01})

    monkeypatch.setattr(co_rounds, "reextrude", first_folds)
    args = (shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options)
    required = replace(DEFAULT_POLICY, co_required=True)
    new, flat, block = co_rounds.co_optimized(*args, faces, policy=required)
    assert not block["accepted"] and block["reason"] == co_rounds.FOLD_REASON
    assert new is eq1 and flat is plain and len(rounds) == 1
    rounds.clear()
    new, flat, block = co_rounds.co_optimized(*args, faces, policy=DEFAULT_POLICY)
    assert block["accepted"], block["reason"]
    assert len(rounds) > 1 and flat.edge_error_max_mm < plain.edge_error_max_mm


def test_co_optimization_can_hold_the_clear_openings_of_the_eq1_tiles(
    monkeypatch, before_co
) -> None:
    # The fallback when tracking the openings of the moved tiles strands the re-solve: with
    # track_openings=False no opening is recomputed, and the joint solve still makes the flat
    # tiles congruent.
    shaped, eq1, faces, plain = before_co
    linkage = shaped.tiling.linkage

    def no_recompute(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("clear openings recomputed")

    monkeypatch.setattr(co_rounds, "hinge_faces", no_recompute)
    _, flat, block = co_rounds.co_optimized(
        linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces,
        track_openings=False,
    )  # fmt: skip
    assert block["accepted"]
    assert flat.hinges is faces
    assert flat.edge_error_max_mm < 0.1 * plain.edge_error_max_mm


def test_a_part_whose_scale_hardly_varies_is_not_split_further(monkeypatch) -> None:
    # More splits help only where the area scale varies; a wave part (ratio about 1.03) that
    # misses its targets misses for another reason, and is tiled once.
    calls: list[float] = []
    tile_surface = layout_stage.tile_surface

    def counted(*args: object, max_scale_factor: float, **kwargs: object):
        calls.append(max_scale_factor)
        return tile_surface(*args, max_scale_factor=max_scale_factor, **kwargs)

    # (the first tiling is made where the design's refusing check runs, the tighter ones by
    # the tiling ladder)
    monkeypatch.setattr(close_fit, "tile_surface", counted)
    monkeypatch.setattr(layout_stage, "tile_surface", counted)
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(lambda _self: 1.0))
    options = DesignOptions(
        tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper", hinges="dual"
    )
    result = design("wave", options)
    assert result.tiling.scale_factor_max < 1.1
    assert calls == [split_bound(result.options)]
    # the same miss on the saddle, whose scale varies more, is tiled again
    calls.clear()
    result = design("saddle", options)
    bound = split_bound(result.options)
    assert result.tiling.scale_factor_max - 1 >= DEFAULT_POLICY.retile_min_share * (bound - 1)
    assert len(calls) == 2 and calls[1] < calls[0]
    assert any(n.startswith("tiling:") and "kept the first tiling" in n for n in result.notes)


def test_a_tighter_tiling_that_meets_the_targets_is_kept_without_halving_the_miss(
    monkeypatch,
) -> None:
    # A tighter tiling must halve the miss to be worth its extra parts, unless it meets the
    # accuracy targets: then it is kept whatever the gain (seashell: 1.4e-3 -> 9.5e-4 mm).
    def accuracy(shaped: layout_stage.ShapedLayout) -> float:
        return 1.4e-3 if shaped.tiling.linkage.n_components == 1 else 9.5e-4

    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(accuracy))
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    result = design("saddle", options)
    assert result.tiling.linkage.n_components > 1
    assert result.metrics()["split_bound"] < split_bound(result.options)
    assert any(n.startswith("tiling:") and "kept 2 parts" in n for n in result.notes)


def _design_arrays(result) -> list[np.ndarray]:
    layout = result.hinge_layout
    return [result.assembled.tiles, result.flat.nodes, layout.tiles, layout.hinge_vertices]


def test_the_co_optimization_run_ahead_gives_the_design_run_in_turn(monkeypatch) -> None:
    # Both conical weights refused: the co-optimization without the condition, run in a
    # forked child meanwhile, is taken from it, and the design is bitwise the serial one.
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)  # a spare core even on one
    in_turn = replace(IN_TURN, retile_min_share=10.0)  # one tiling, no other process
    if not can_fork():
        pytest.skip("processes cannot fork here")
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    first, retry = FIRST, RETRY
    calls = _conical_runs(monkeypatch, {first, retry})
    serial = design("saddle", options, policy=in_turn)
    assert [c[:2] for c in calls] == [(True, first), (True, retry), (False, None)]
    calls.clear()
    ahead = design("saddle", options, policy=replace(in_turn, co_speculate=True))
    assert [c[:2] for c in calls] == [(True, first), (True, retry)]  # the last in the child
    assert ahead.notes == serial.notes
    for a, b in zip(_design_arrays(ahead), _design_arrays(serial), strict=True):
        assert np.array_equal(a, b)
    assert ahead.metrics()["co_optimization"] == serial.metrics()["co_optimization"]


def test_the_tighter_tiling_laid_out_ahead_gives_the_design_laid_out_in_turn(
    monkeypatch,
) -> None:
    # The first tighter tiling is laid out in a forked process while the first tiling is; the
    # design must be the one the serial run gives, bitwise, and the child's stage times are
    # counted in this process's.
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(_two_parts_meet))
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)  # ahead even on one core
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    serial = design("saddle", options, policy=LayoutPolicy(retile_ahead=False))
    taken: list[bool] = []
    result_of = layout_stage._Ahead.result

    def result(self, progress):
        out = result_of(self, progress)
        if self._what == "the tiling laid out ahead":  # (not a co-optimization run ahead)
            taken.append(out is not None)
        return out

    monkeypatch.setattr(layout_stage._Ahead, "result", result)
    ahead = design("saddle", options, policy=LayoutPolicy(retile_ahead=True))
    assert taken == [True]
    assert ahead.tiling.linkage.n_components == serial.tiling.linkage.n_components == 2
    assert ahead.notes == serial.notes
    for a, b in zip(_design_arrays(ahead), _design_arrays(serial), strict=True):
        assert np.array_equal(a, b)
    assert ahead.timings_s["hinges"] > 0 and ahead.timings_s["co-optimize"] > 0


def test_a_failed_layout_ahead_is_laid_out_again_in_this_process(monkeypatch, caplog) -> None:
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(_two_parts_meet))
    monkeypatch.setattr(parallel, "thread_count", lambda: 2)
    parent = os.getpid()
    shaped = layout_stage._shaped

    def fails_in_a_child(*args, **kwargs):
        if os.getpid() != parent:
            raise RuntimeError("out of memory")
        return shaped(*args, **kwargs)

    monkeypatch.setattr(layout_stage, "_shaped", fails_in_a_child)
    result = design(
        "saddle", DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    )
    assert "laid out ahead failed (RuntimeError: out of memory)" in caplog.text
    assert result.tiling.linkage.n_components == 2
    assert any(n.startswith("tiling:") and "kept 2 parts" in n for n in result.notes)


def test_a_tiling_that_may_be_split_again_skips_the_held_openings_run(monkeypatch) -> None:
    # A refused co-optimization of a tiling that may be split again is not run again holding
    # the eq.-1 openings (more splits are its cure); if that tiling is kept after all, it is.
    held: list[int] = []  # parts of each tiling whose co-optimization ran holding openings

    def refused(linkage, tiling, assembled, flat, *_args, track_openings=True, **_kwargs):
        if not track_openings:
            held.append(linkage.n_components)
        return assembled, flat, {"accepted": False, "reason": "refused", "steps": 0}

    monkeypatch.setattr(layout_stage, "co_optimized", refused)
    policy = replace(IN_TURN, retile_ahead=False)  # calls are counted here
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")

    def split_wins(shaped: layout_stage.ShapedLayout) -> float:
        return 1.0 if shaped.tiling.linkage.n_components == 1 else 1e-4

    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(split_wins))
    solved: list[int] = []  # quads of each eq.-1 solve
    solve = shapes.optimize_assembled

    def counted(vertices, quads, *args, **kwargs):
        solved.append(len(quads))
        return solve(vertices, quads, *args, **kwargs)

    monkeypatch.setattr(shapes, "optimize_assembled", counted)
    result = design("saddle", options, policy=policy)
    assert result.tiling.linkage.n_components == 2
    assert held == [2]  # the trial tiling ran it, the first one did not
    # the split tiling cuts the linkage, not the quad mesh: eq. 1 is solved once
    assert solved == [result.tiling.linkage.n_tiles]
    assert not result.assembled.tiles.flags.writeable
    held.clear()
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(lambda _s: 1.0))
    result = design("saddle", options, policy=policy)
    assert result.tiling.linkage.n_components == 1
    assert held == [2, 1]  # the first tiling, kept, ran it after all


def test_a_first_tiling_far_off_skips_the_hinge_stage_unless_kept(monkeypatch) -> None:
    # The rigid hinge layout cannot bring a flat layout many times the tolerance off within it,
    # so a tiling that may be split again skips it; kept after all, it is laid out in full.
    co_optimized = layout_stage.co_optimized

    def far_off_in_one_part(linkage, *args, **kwargs):
        new, flat, block = co_optimized(linkage, *args, **kwargs)
        if linkage.n_components == 1:
            flat = replace(flat, edge_error_max_mm=1.0)
        return new, flat, block

    hinged: list[int] = []  # parts of each tiling laid out by the hinge stage
    layout_hinges = layout_stage.layout_hinges

    def counted(linkage, *args, **kwargs):
        hinged.append(linkage.n_components)
        return layout_hinges(linkage, *args, **kwargs)

    monkeypatch.setattr(layout_stage, "co_optimized", far_off_in_one_part)
    monkeypatch.setattr(layout_stage, "layout_hinges", counted)
    # (its ladder goes on after the first weight's miss instead of pausing for the split;
    # calls are counted here)
    policy = replace(IN_TURN, prefer_split_at_first_weight=False, retile_ahead=False)
    options = DesignOptions(
        tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper", hinges="dual"
    )
    result = design("saddle", options, policy=policy)
    assert result.tiling.linkage.n_components == 2
    assert hinged == [2]
    note = next(n for n in result.notes if n.startswith("tiling:"))
    assert (
        "(1 part) the flat tiles met their hinges with their assembled shapes only to 1 mm" in note
    )
    hinged.clear()
    monkeypatch.setattr(layout_stage.ShapedLayout, "accuracy_mm", property(lambda _s: 1.0))
    result = design("saddle", options, policy=policy)
    assert result.tiling.linkage.n_components == 1
    assert hinged == [2, 1]  # the first tiling, kept, got its hinge stage after all
    assert result.hinge_layout.tiles.shape == (result.tiling.linkage.n_tiles, 8, 3)


def _re_solves_reporting(monkeypatch, error: float) -> list[float]:
    """Make every flat re-solve of the co-optimization report ``error`` as its edge error;
    the list returned collects one entry per re-solve."""
    flat_layout = co_rounds.flat_layout
    resolves: list[float] = []

    def reporting(*args: object, **kwargs: object):
        resolves.append(error)
        return replace(flat_layout(*args, **kwargs), edge_error_max_mm=error)

    monkeypatch.setattr(co_rounds, "flat_layout", reporting)
    return resolves


def test_co_optimization_gives_up_when_its_first_re_solve_is_far_worse(
    monkeypatch, before_co
) -> None:
    # A first re-solve many times worse than the plain layout has never recovered: the run
    # stops after one round and is refused.
    shaped, eq1, faces, plain = before_co
    assert DEFAULT_POLICY.co_give_up_ratio < 100.0
    resolves = _re_solves_reporting(monkeypatch, 100.0 * plain.edge_error_max_mm)
    _, flat, block = co_rounds.co_optimized(
        shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert len(resolves) == 1
    assert not block["accepted"] and "did not drop" in block["reason"]
    assert flat is plain


def test_co_optimization_stops_when_its_first_joint_solve_ends_above_the_plain_layout(
    monkeypatch,
    before_co,
) -> None:
    # A first joint solve that, in its own model, ends no lower than the plain layout is not
    # re-extruded and re-solved (that re-solve did no better on the 1600-tile wave): the run
    # is refused at once with the two errors.
    shaped, eq1, faces, plain = before_co
    resolves = _re_solves_reporting(monkeypatch, 1e-9)
    joint = co_rounds.co_optimize_top
    solves: list[int] = []

    def no_better(*args: object, **kwargs: object):
        solves.append(1)
        return replace(joint(*args, **kwargs), edge_error_max_mm=2.0 * plain.edge_error_max_mm)

    def no_extrusion(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("re-extruded")

    monkeypatch.setattr(co_rounds, "co_optimize_top", no_better)
    monkeypatch.setattr(co_rounds, "reextrude", no_extrusion)
    new, flat, block = co_rounds.co_optimized(
        shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert resolves == [] and len(solves) == 2  # round 1's two joint solves, nothing after
    assert not block["accepted"] and "joint solve did not lower" in block["reason"]
    assert f"{2.0 * plain.edge_error_max_mm:.3g} mm" in block["reason"]
    assert new is eq1 and flat is plain


def test_the_held_openings_run_reuses_the_first_joint_solve(monkeypatch, before_co) -> None:
    # Round 1's first joint solve runs on the eq.-1 tiles and their openings whether the
    # openings are tracked or held: the held-openings run takes it from the tracked run and
    # comes out bitwise as it would on its own, with one joint solve fewer.
    shaped, eq1, faces, plain = before_co
    joint = co_rounds.co_optimize_top
    solves: list[int] = []

    def counted(*args: object, **kwargs: object):
        solves.append(1)
        return joint(*args, **kwargs)

    monkeypatch.setattr(co_rounds, "co_optimize_top", counted)
    args = (shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options)
    first: dict = {}
    co_rounds.co_optimized(*args, faces, first_solves=first)
    assert set(first) == {"eq1"}
    solves.clear()
    new, flat, block = co_rounds.co_optimized(
        *args, faces, track_openings=False, first_solves=first
    )
    reused = len(solves)
    solves.clear()
    new_alone, flat_alone, block_alone = co_rounds.co_optimized(*args, faces, track_openings=False)
    assert reused == len(solves) - 1
    assert np.array_equal(flat.nodes, flat_alone.nodes)
    assert np.array_equal(new.tiles, new_alone.tiles)
    assert block == block_alone


def test_the_design_hands_the_first_joint_solve_to_the_held_openings_run(monkeypatch) -> None:
    memos: list[tuple[bool, object]] = []

    def refused(linkage, tiling, assembled, flat, *_args, track_openings=True, **kwargs):
        memos.append((track_openings, kwargs.get("first_solves")))
        return assembled, flat, {"accepted": False, "reason": "refused", "steps": 0}

    monkeypatch.setattr(layout_stage, "co_optimized", refused)
    options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper")
    design("saddle", options, policy=replace(IN_TURN, retile_ahead=False))
    # per laid-out tiling: the tracked run, then (where held openings are tried) the held one
    # with the same dictionary
    tracked = [k for k, (track, _) in enumerate(memos) if track]
    assert any(k + 1 < len(memos) and not memos[k + 1][0] for k in tracked)
    for k in tracked:
        if k + 1 < len(memos) and not memos[k + 1][0]:
            assert memos[k + 1][1] is memos[k][1] and isinstance(memos[k][1], dict)


def test_co_optimization_stops_once_a_re_solve_is_well_inside_the_tolerance(
    monkeypatch, before_co
) -> None:
    # A re-solve at a quarter of the tolerance is kept without further rounds, even when the
    # joint solve reached far less (the rigid hinge layout has room to spare; the rounds that
    # followed only moved the bottom corners again: 1600-tile wave).
    shaped, eq1, faces, plain = before_co
    resolves = _re_solves_reporting(monkeypatch, 0.25 * layout_stage.FLAT_EDGE_ERROR_TOL_MM)
    joint = co_rounds.co_optimize_top

    def exact_joint(*args: object, **kwargs: object):
        return replace(joint(*args, **kwargs), edge_error_max_mm=1e-9)

    assert DEFAULT_POLICY.co_stop_share > 0.25
    monkeypatch.setattr(co_rounds, "co_optimize_top", exact_joint)
    _, flat, block = co_rounds.co_optimized(
        shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert len(resolves) == 1
    assert block["accepted"], block["reason"]
    assert flat.edge_error_max_mm == resolves[0]


def test_co_optimization_stops_when_rounds_inside_the_tolerance_stall(
    monkeypatch, before_co
) -> None:
    # Re-solves within co_stop_near of the tolerance but above the stop share: the rounds go
    # on while each gains more than co_stall_gain on the best before it, and stop at the first
    # that does not.
    shaped, eq1, faces, plain = before_co
    tol = layout_stage.FLAT_EDGE_ERROR_TOL_MM
    reported = [0.58 * tol, 0.5 * tol, 0.49 * tol, 0.35 * tol]
    policy = DEFAULT_POLICY
    assert reported[2] > policy.co_stall_gain * reported[1]
    assert reported[1] < policy.co_stall_gain * reported[0]
    assert min(reported[:3]) > policy.co_stop_share * tol
    assert max(reported[:3]) <= policy.co_stop_near * tol
    flat_layout, joint = co_rounds.flat_layout, co_rounds.co_optimize_top
    resolves: list[float] = []

    def reporting(*args: object, **kwargs: object):
        resolves.append(reported[len(resolves)])
        return replace(flat_layout(*args, **kwargs), edge_error_max_mm=resolves[-1])

    def exact_joint(*args: object, **kwargs: object):  # the ratio rule never stops it
        return replace(joint(*args, **kwargs), edge_error_max_mm=1e-9)

    monkeypatch.setattr(co_rounds, "flat_layout", reporting)
    monkeypatch.setattr(co_rounds, "co_optimize_top", exact_joint)
    _, flat, block = co_rounds.co_optimized(
        shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert resolves == reported[:3]
    assert block["accepted"], block["reason"]
    assert flat.edge_error_max_mm == reported[2]  # the best round


def test_slow_rounds_are_projected_from_their_last_gain() -> None:
    # Re-solved errors (mm) of real runs at 200 tiles: the seashell's first tiling shrank 1.3x
    # a round and was split in the end; the peanut's shrinks 3x a round and meets 1e-3 mm.
    left = DEFAULT_POLICY.co_refinements + 1
    assert co_rounds.too_slow(0.0516, 0.0386, left - 2)
    assert not co_rounds.too_slow(0.0306, 0.0102, left - 2)
    assert not co_rounds.too_slow(0.0102, 0.00306, left - 3)
    # no gain at all projects no shrinking; no rounds left is never "too slow"
    assert co_rounds.too_slow(0.01, 0.02, 1)
    assert not co_rounds.too_slow(0.0516, 0.0386, 0)


def test_a_tiling_that_may_be_split_again_stops_slow_co_optimization(
    monkeypatch, before_co
) -> None:
    # Re-solves that shrink only 1.25x a round from the plain layout cannot reach the
    # tolerance in the rounds left: a tiling that may be split again stops after one round
    # (and says so); one that is final runs every round.
    shaped, eq1, faces, plain = before_co
    flat_layout = co_rounds.flat_layout
    resolves: list[float] = []

    def slow(*args: object, **kwargs: object):
        out = flat_layout(*args, **kwargs)
        error = plain.edge_error_max_mm * 0.8 ** (len(resolves) + 1)
        resolves.append(error)
        return replace(out, edge_error_max_mm=error)

    monkeypatch.setattr(co_rounds, "flat_layout", slow)
    args = (shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options)
    _, flat, block = co_rounds.co_optimized(*args, faces, give_up_slow=True)
    assert len(resolves) == 1 and block["cut_short"]
    assert block["accepted"] and flat.edge_error_max_mm == resolves[0]
    resolves.clear()
    _, flat, block = co_rounds.co_optimized(*args, faces)
    assert len(resolves) == DEFAULT_POLICY.co_refinements + 1 and "cut_short" not in block
    assert flat.edge_error_max_mm == resolves[-1]


def test_refinement_rounds_start_from_the_re_solved_layout(monkeypatch, before_co) -> None:
    # each refinement round's joint solve starts from the layout re-solved on the extruded
    # tiles (which holds their bounds), not from the previous joint solve's nodes
    shaped, eq1, faces, plain = before_co
    co_optimize_top = co_rounds.co_optimize_top
    flat_layout = co_rounds.flat_layout
    starts: list[np.ndarray | None] = []
    resolved: list[np.ndarray] = []

    def recording_joint(*args: object, **kwargs: object):
        start = kwargs.get("start_nodes")
        starts.append(None if start is None else np.array(start))
        return co_optimize_top(*args, **kwargs)

    def slow(*args: object, **kwargs: object):
        out = flat_layout(*args, **kwargs)
        resolved.append(np.array(out.nodes))
        # shrinking slowly: every round runs
        return replace(out, edge_error_max_mm=plain.edge_error_max_mm * 0.8 ** len(resolved))

    monkeypatch.setattr(co_rounds, "co_optimize_top", recording_joint)
    monkeypatch.setattr(co_rounds, "flat_layout", slow)
    args = (shaped.tiling.linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options)
    co_rounds.co_optimized(*args, faces)
    # round 1 runs every stage, then its last one again; each later round one stage
    assert starts[0] is None
    assert len(starts) == 2 + DEFAULT_POLICY.co_refinements
    assert len(resolved) == 1 + DEFAULT_POLICY.co_refinements
    for start, before in zip(starts[2:], resolved[:-1], strict=True):
        assert start is not None and np.array_equal(start, before)


def test_clear_windows_closing_on_their_openings_are_released(monkeypatch, before_co) -> None:
    # A joint solve that presses an opening against its clear window, while its move of K3D
    # closes that window, strands every re-solve; from the next round on such a slit end is
    # laid out without its window (the hinge stage trims the pair), and stays released.
    from drawstring.geometry.core.tolerances import FLAT_FREE_MARGIN_DEG
    from drawstring.geometry.flat.layout import hinge_face_openings

    shaped, eq1, faces, plain = before_co
    linkage = shaped.tiling.linkage
    hinge_faces, flat_layout = co_rounds.hinge_faces, co_rounds.flat_layout
    given: list[tuple[object, np.ndarray]] = []
    chosen = np.arange(len(faces.clear_hi)) % 2 == 0

    def closing(*args: object, **kwargs: object):
        out = hinge_faces(*args, **kwargs)
        if not given:
            return out
        # the chosen ends' windows close 0.1 deg past where the last re-solve opened them
        shut = given[-1][1] + np.radians(FLAT_FREE_MARGIN_DEG - 0.1)
        return replace(out, clear_hi=np.where(chosen, np.minimum(out.clear_hi, shut), out.clear_hi))

    def slow(*args, **kwargs):
        out = flat_layout(*args, **kwargs)
        given.append((args[4], hinge_face_openings(linkage, out, args[2].tiles)))
        return replace(out, edge_error_max_mm=plain.edge_error_max_mm * 0.8 ** len(given))

    monkeypatch.setattr(co_rounds, "hinge_faces", closing)
    monkeypatch.setattr(co_rounds, "flat_layout", slow)
    _, flat, block = co_rounds.co_optimized(
        linkage, shaped.tiling, eq1, plain, shaped.target, shaped.options, faces
    )
    assert block["accepted"], block["reason"]
    # round 2 lays out in windows just closed on its openings; round 3 releases them
    assert given[0][0].released is None and given[1][0].released is None
    released = given[2][0].released
    assert released is not None and released.any()
    assert not released[~chosen].any()
    for later, _ in given[3:]:
        assert np.all(later.released[released])  # released for good
    assert flat.hinges is given[-1][0]  # the last round is the best here
    assert block["released_ends"] == int(flat.hinges.released.sum())


def test_the_flat_seed_of_a_refused_co_optimization_is_finished(monkeypatch) -> None:
    # The flat layout that seeds the co-optimization stops once its bounds hold after
    # flat_seed_steps; where the co-optimization is not used, that seed would be the design's
    # layout, so it is finished.
    calls: list[tuple[int | None, bool, object]] = []
    flat_layout = layout_stage.flat_layout

    def recorded(*args, initial_nodes=None, seed_steps=None, **kwargs):
        out = flat_layout(*args, initial_nodes=initial_nodes, seed_steps=seed_steps, **kwargs)
        calls.append((seed_steps, initial_nodes is not None, out))
        return out

    def refused(linkage, tiling, assembled, flat, *_args, **_kwargs):
        return assembled, flat, {"accepted": False, "reason": "refused", "steps": 0}

    monkeypatch.setattr(layout_stage, "flat_layout", recorded)
    monkeypatch.setattr(layout_stage, "co_optimized", refused)
    options = DesignOptions(
        tiles=60, size_mm=200.0, simulate=False, cad=False, fit="paper", hinges="dual"
    )
    result = design("saddle", options, policy=LayoutPolicy(flat_seed_steps=5))
    # every layout (the first tiling is laid out twice: see the held-openings test) is a seed
    # and then its finish
    assert len(calls) % 2 == 0
    for (seed_steps, seeded, seed), (finish_steps, from_seed, finished) in zip(
        calls[::2], calls[1::2], strict=True
    ):
        assert seed_steps == 5 and not seeded and seed.iterations >= 5
        # finished: stopped by convergence, not by optimize_flat's 400-step cap
        assert finish_steps is None and from_seed and 0 < finished.iterations < 400
    assert result.flat is calls[-1][2]


def test_time_waited_for_another_process_is_shared_among_its_stages(monkeypatch) -> None:
    # The child's stage times give the shares; the wait is what this process spent, so the
    # stages add up to its wall clock, and an enclosing stage does not count it again.  The
    # stages read a stand-in clock: the 2 s the outer stage lasts are the 2 s waited.
    from drawstring.pipeline import record

    readings = iter([100.0, 102.0])  # the outer stage's start and end
    monkeypatch.setattr(record, "time", SimpleNamespace(perf_counter=lambda: next(readings)))
    progress = Progress(quiet=True)
    progress.timings["flat"] = 1.0
    with progress.stage("outer"):
        progress.absorb({"flat": 1.0, "co-optimize": 3.0, "hinges": 0.0}, 2.0)
    assert progress.timings["flat"] == pytest.approx(1.5)
    assert progress.timings["co-optimize"] == pytest.approx(1.5)
    assert progress.timings["hinges"] == 0.0
    assert progress.timings["outer"] == 0.0


def test_an_error_inside_a_stage_starts_on_its_own_line(
    capsys: pytest.CaptureFixture[str],
) -> None:
    """On a terminal a stage's line stays open while it runs; an error or Ctrl-C inside it
    must not print its message on the end of that line."""
    progress = Progress()
    progress.enabled = True  # as on a terminal
    with pytest.raises(KeyboardInterrupt), progress.stage("assembled"):
        raise KeyboardInterrupt
    assert capsys.readouterr().err == "  assembled ...\n"
    with progress.stage("flat"):
        pass
    assert capsys.readouterr().err.startswith("  flat ... ")


def test_the_ahead_process_tags_its_log_lines_once() -> None:
    import logging

    record = logging.LogRecord(
        "drawstring.geometry.flat.layout", logging.INFO, "f.py", 1, "flat: %d", (3,), None
    )
    from drawstring.pipeline.ahead import tag_ahead

    assert tag_ahead(record) and tag_ahead(record)
    assert record.getMessage() == "(ahead) flat: 3"


def test_a_value_just_above_its_bound_reads_as_above_it() -> None:
    from drawstring.pipeline.record import above

    assert above(0.001005479, 0.001) == "0.00101"
    assert above(0.0010000004, 0.001) == "0.001"  # closer than six digits show
    assert above(0.0036, 0.001) == "0.0036"
    assert float(above(0.23, 0.001)) == 0.23


@pytest.mark.parametrize("fit", ["paper", "close"])
def test_surface_distance_warnings_agree_with_the_report(fit, request) -> None:
    # The report marks both surface-distance targets; a design that misses one says so in its
    # warnings too (and --strict then exits 4), and one that meets them says nothing.
    from drawstring.output.metric_rules import evaluate_metrics

    if fit == "paper":  # the module's 60-tile saddle
        result = request.getfixturevalue("saddle60")
    else:
        options = DesignOptions(tiles=60, size_mm=200.0, simulate=False, cad=False, fit=fit)
        result = design("saddle", options)
    failed = {row.name for row in evaluate_metrics(result.to_json()) if row.passed is False}
    warned = " ".join(result.warnings)
    assert ("surface_distance_max_mm" in failed) == ("of the target's diagonal" in warned)
    assert ("surface_distance_mean_mm" in failed) == ("on average" in warned)
    # the coarse saddle with the paper's weights misses both; fitted closely it meets both
    assert ("surface_distance_max_mm" in failed) == (fit == "paper")
    assert ("surface_distance_mean_mm" in failed) == (fit == "paper")


def test_a_tile_size_refusal_names_the_problems_a_new_size_may_not_mend() -> None:
    # The CAD stage asks the feature checks again before any solid (the pipeline asked them
    # right after the route, tests/test_auto.py): tiles too small for the lift bores are
    # refused in words; where the design has a problem besides, the one line names it (a new
    # --size alone may not give a design).
    from drawstring.geometry.core.errors import InputError
    from drawstring.pipeline.run import with_cad

    options = DesignOptions(
        grid=(10, 8), resolution=1500, size_mm=30.0, simulate=False, cad=False, fit="paper"
    )
    result = design("saddle", options)
    with pytest.raises(
        InputError,
        match=r"lift-point tiles .* mm deep.*; give the tiles more room with a larger --size or "
        r"fewer tiles$",
    ):
        with_cad(result, Progress(quiet=True))
    troubled = replace(result, problems=("flat tiles overlap by 2 mm^2", "another"))
    with pytest.raises(InputError) as refused:
        with_cad(troubled, Progress(quiet=True))
    line = str(refused.value)
    assert "\n" not in line and "tiles too small" in line
    assert line.endswith(
        "which --no-cad writes out to look at: flat tiles overlap by 2 mm^2 and 1 more"
    )
