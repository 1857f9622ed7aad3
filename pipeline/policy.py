"""The switches that steer the design loop: the tiling ladder, the co-optimization and the
work run ahead.

:class:`LayoutPolicy` holds them; :data:`DEFAULT_POLICY` is the one
:func:`~drawstring.pipeline.run.design` uses unless given another.  ``design`` hands it down
explicitly (:func:`~.layout_stage.shape_and_layout`, :class:`~.co_ladder.CoLadder`,
:func:`~.co_rounds.co_optimized`, :class:`~.ahead.Ahead`), so a test or a script changes a
switch by passing a policy, e.g. ``design(target, options, policy=LayoutPolicy(retile_ahead=
False))``.  The physical accuracy targets are not policy: they live in
:mod:`drawstring.geometry.core.tolerances`.
"""

from __future__ import annotations

from dataclasses import dataclass

from drawstring.geometry.flat.coflat import CO_CONICAL


@dataclass(frozen=True)
class LayoutPolicy:
    """How the layout stage searches for a design that meets the accuracy targets."""

    # -- the tiling ladder (pipeline/layout_stage.py) --

    #: Extra tilings tried, each with a tighter split bound, when the flat layout misses its
    #: accuracy targets (flat edge error or hinge gap above 1e-3 mm).  The scale bound of
    #: a split is necessary, not sufficient: a part whose area scale varies within it can still
    #: leave the tiles no flat layout that keeps their shape (the 200-tile chair: one part of
    #: ratio 1.55 < 1.66, 0.5 mm off; two parts of ratio 1.15, 1.5e-4 mm).
    retile_attempts: int = 2

    #: Each extra tiling keeps this share of the current largest part ratio's excess over 1.
    retile_shrink: float = 0.7

    #: Tiling again is tried only when the first tiling's largest part ratio uses at least this
    #: share of the bound's excess over 1 (of the 0.66 at 12 deg: 200-tile chair 0.84, seashell
    #: 0.58; the 1600-tile wave, whose miss has another cause, 0.05).
    retile_min_share: float = 0.5

    #: A first tiling that may still be split is co-optimized with the first conical weight
    #: alone at first; where that misses the flat targets, the first tighter tiling is laid out
    #: (ahead, where a core is spare) and kept if it meets every accuracy target, before the
    #: first tiling's further weights and its run without the condition are tried.  Those meet
    #: the targets, where they do, only by the last bits of the arithmetic (see
    #: ``conical_weights``) or with the bottom hinges apart in depth; a split
    #: that meets them with the first weight is the sounder design, at the cost of a part.
    #: Where the split misses, the first tiling's ladder goes on from its next step.  The
    #: 200-tile seashell in one part missed with weight 3 (2.9e-3 mm), then weight 10 (3.3e-3 mm)
    #: and then its hinges in depth (0.011 mm) without the condition, where its two parts meet
    #: the targets (8.3e-4 mm): 3.0 s of layout, 1.9 s now (the same design).
    prefer_split_at_first_weight: bool = True

    #: A tighter tiling is kept only when it at least halves the accuracy figure or meets the
    #: accuracy targets (more parts cost a longer route and more assembly, so a marginal gain that
    #: still misses them does not pay for them); one that does neither ends the search.
    retile_gain: float = 0.5

    #: Pull the bottom hinges' corners to equal depths before the flat layout (dual hinges; see
    #: ``layout_stage._bottom_hinge_depths``).
    hinge_depths: bool = True

    #: Lay out the first tighter tiling in a second process while the first tiling is laid out
    #: (:class:`~drawstring.pipeline.ahead.Ahead`), where the machine has two cores or more
    #: and processes can be forked.
    #: Its result is the one the serial run would compute: it is used only if the first tiling
    #: misses the targets, and thrown away otherwise.
    retile_ahead: bool = True

    #: Gauss-Newton steps after which the flat layout that only seeds the co-optimization (which
    #: moves it anyway) stops, at the end of the first augmented-Lagrangian round whose bounds all
    #: hold (a seed that breaks them would make the co-optimization's "keeps every hard bound"
    #: test meaningless).  The 200-tile built-ins' plain layouts settle within 125 steps, both
    #: hinge strategies, except the three-shell's with dual hinges: its bounds hold after 120
    #: steps and it then polished its 0.27 mm least-squares optimum up to the 400-step cap
    #: (1.2 s); it now stops at 251 steps and still meets the targets (7 parts; flat edge error
    #: 6.2e-5 mm, was 5.7e-5; in-plane hinge gap 7.4e-4 mm as before).  The other fifteen rows
    #: are bitwise unchanged.  At 1600 tiles the wave's plain layout stops at 262 steps instead
    #: of 308, and its hinges meet within 1.9e-4 mm.  (Those step counts were measured before the
    #: flat solver's line search, with which the 1600-tile wave's seed settles after 113.)  Where
    #: the co-optimization is not used, the seed is finished.
    flat_seed_steps: int = 150

    # -- the co-optimization ladder (pipeline/co_ladder.py) --

    #: Weights of the conical condition a design with bottom hinges is co-optimized with, in
    #: turn, where the last one missed the flat targets, before it goes without the condition
    #: (the first is ``coflat.CO_CONICAL``; none: never conical).  Which weight reaches them
    #: depends on the design and on the last bits of the arithmetic: on an AMD EPYC machine
    #: (200 tiles, dual hinges) 3 left the seashell 0.024 mm apart in depth with OpenBLAS's
    #: AVX-512 kernels, the wave 4.2e-3 mm with its AVX2 ones, where 10 met them; 10 alone
    #: missed the seashell with AVX2 (0.011 mm), where 3 met it.
    conical_weights: tuple[float, ...] = (CO_CONICAL, 10.0)
    #: ... except in a tiling that may still be split (``fallback=False``), where a run that was
    #: used but missed by more than ``co_slow_reach`` times the tolerance
    #: (``CoLadder.run``'s ``far_mm``) ends the weights at once: splitting mends such misses,
    #: and the tiling is laid out in full, every weight tried, if it is kept after all.
    #: The 200-tile chair in one part missed by 0.68 mm with weight 3, then spent 1.5 s to miss
    #: by 0.029 mm with 10, while its two-part tiling, laid out ahead, met the targets with 3.
    conical_retry_far: bool = True
    #: Whether the next weight is tried after one whose first joint solve, in its own model,
    #: already ended no lower than the plain layout (``co_optimized`` refuses it at once).  It is
    #: not: a larger weight holds the conical condition tighter against the flat tiles'
    #: congruence.  The 1600-tile wave: weight 3 ended at 0.30 mm against a plain 0.13 mm,
    #: weight 10 at 0.35 mm, 2.8 s for nothing.
    conical_retry_joint_miss: bool = False
    #: Run the co-optimization without the conical condition, which follows where the conical
    #: ones miss, in a forked child process while they run, where a core is spare
    #: (:class:`~.co_ladder.CoLadder`).
    co_speculate: bool = True

    # -- the rounds of one co-optimization (pipeline/co_rounds.py) --

    #: Extra rounds of ``co_optimized`` on the extruded T3D when re-solving the flat layout
    #: with its true bounds loses most of what the joint solve gained.  Each round shrinks the
    #: error by about 3x where it converges (peanut at 200 tiles: 0.03, 0.01, 3e-3, 1e-3, 4e-4
    #: mm); two rounds in a row without a new best stop it, and so do the stop rules below, so
    #: more rounds run only where the error is still above them.  At 4 the 200-tile seashell's
    #: two parts ended at 1.2e-3 mm (met through the hinge layout, 4.2e-4 mm), and with numpy's
    #: AVX2 kernels instead of AVX-512 (other last bits) at 2.3e-3 mm, a miss (3.1e-3 mm
    #: measured); at 7 they reach 3.1e-4 and 6.0e-4 mm, and every 200-tile row meets the
    #: targets with either kernel set.
    co_refinements: int = 7
    #: ``co_optimized`` stops when the re-solved flat layout's edge error is within this share
    #: of the tolerance, or within the tolerance and ``co_stop_ratio`` of the joint solve's.
    #: At 0.1 the 200-tile saddle ran a third round from 1.1e-4 mm, and the 1600-tile wave ran
    #: on to 4e-5 mm and then missed by one hinge (2.1e-3 mm) in the rigid hinge layout; at 0.3
    #: they stop at 7.9e-5 and 1.8e-4 mm and their hinges meet within 2.1e-4 mm (the other
    #: 200-tile rows, both hinge strategies, and the 1600-tile dome are unchanged).
    co_stop_share: float = 0.3
    co_stop_ratio: float = 10.0
    #: ... (that second rule only within this share of the tolerance: the hinge layout can add
    #: to a re-solve that ends near the tolerance; the CLI-default three-shell with dual hinges
    #: stopped at 8.4e-4 mm and ended at 1.1e-3 mm, exit 4; with one more round, 8.3e-5 mm)
    co_stop_near: float = 0.6
    #: The same with bottom hinges, whose rounds pull the bottom corners to equal depths (see
    #: co_optimized): the re-solve then follows the moved hinge points, and rounds stopped at 0.6
    #: left the 200-tile cloud's hinged layout at 9.9e-4 mm; 0.35 leaves it at 5.8e-4.
    co_stop_near_conical: float = 0.35
    #: ... and once a re-solve within ``co_stop_near`` (``co_stop_near_conical``) of the
    #: tolerance gains less than this factor on the best before it: the 200-tile seashell's
    #: one-part tiling went 0.85, 0.68, 0.65, 0.67, 0.67 um (its joint solves 7e-5 .. 8e-6 mm)
    #: where released ends had taken its window drift away.  Within the whole tolerance, the
    #: 200-tile wave (AVX-512 kernels) stopped at 9.4e-4 mm, and its hinge layout missed at
    #: 1.2e-3 mm; within 0.6 of it, it goes on to 3.8e-4 mm, its hinges 4.9e-4 mm.
    co_stall_gain: float = 0.9
    #: A tiling that may still be split (``give_up_slow``) stops co-optimizing when, shrinking
    #: at the rate of its last round for the rounds left, its re-solved error would stay above
    #: this many times the tolerance (the rigid hinge layout takes off about 4x: 200-tile
    #: seashell 2e-3 -> 4.9e-4 mm).  The 200-tile seashell's first tiling (0.052, 0.039, 0.032,
    #: 0.012, 0.025 mm) and the one-part chair's (0.29, 0.42, 2.9 mm) were split in the end; the
    #: peanut's (0.031, 0.010, 3.1e-3, 1.1e-3, 3.4e-4 mm) goes on.
    co_slow_reach: float = 4.0
    #: ... and gives up after its first round when that re-solve is this many times worse than
    #: the plain layout.  Runs that never recovered: 200-tile wave 130x (1.55 mm against
    #: 0.012), one-part chair 6.5x, 1600-tile wave 9x; one that did: the 200-tile wave holding
    #: the eq.-1 openings, 2.8x (0.032 mm, then 2.3e-3, 2e-4, 9e-5).
    co_give_up_ratio: float = 5.0

    # -- the work run ahead (pipeline/ahead.py) --

    #: Scheduling niceness added in :class:`~.ahead.Ahead`'s child.  The child's result is
    #: often thrown away (the tiling laid out here meets the targets), so where the two
    #: processes and this one's worker threads want more cores than there are, the parent goes
    #: first; the child still gets every core the parent leaves idle.  Its result does not
    #: depend on it.
    ahead_niceness: int = 19


#: The policy :func:`~drawstring.pipeline.run.design` uses by default.
DEFAULT_POLICY = LayoutPolicy()
