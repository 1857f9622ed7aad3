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

from drawstring.geometry.assembled.top import Eq1Weights
from drawstring.geometry.flat.coflat import CO_CONICAL


@dataclass(frozen=True)
class LayoutPolicy:
    """How the layout stage searches for a design that meets the accuracy targets."""

    # -- the tiling ladder (pipeline/layout_stage.py) --

    #: Extra tilings tried, each with a tighter split bound, while the flat layout misses its
    #: accuracy targets (flat edge error or hinge gap above 1e-3 mm).  The split bound is
    #: necessary, not sufficient: a part whose area scale varies within it can still leave
    #: the tiles no flat layout that keeps their shape, where smaller parts have one.
    retile_attempts: int = 2

    #: Each extra tiling keeps this share of the current largest part ratio's excess over 1.
    retile_shrink: float = 0.7

    #: Tiling again is tried only when the first tiling's largest part ratio uses at least this
    #: share of the bound's excess over 1: a part whose area scale hardly varies misses its
    #: targets for another reason, which more splits do not mend.
    retile_min_share: float = 0.5

    #: A first tiling that may still be split is co-optimized with the first conical weight
    #: alone at first; where that misses the flat targets, the first tighter tiling is laid out
    #: (ahead, where a core is spare) and kept if it meets every accuracy target, before the
    #: first tiling's further weights and its run without the condition are tried.  Those meet
    #: the targets, where they do, only by the last bits of the arithmetic (see
    #: ``conical_weights``) or with the bottom hinges apart in depth; a split that meets them
    #: with the first weight is the sounder design, at the cost of a part.  Where the split
    #: misses, the first tiling's ladder goes on from its next step, and the design is the one
    #: laid out without the pause.
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
    #: test meaningless).  A plain layout that settles sooner is not cut; one that would go on
    #: polishing its least-squares optimum up to the solver's step cap stops here.  Where the
    #: co-optimization is not used, the seed is finished.
    flat_seed_steps: int = 150

    # -- the co-optimization ladder (pipeline/co_ladder.py) --

    #: Weights of the conical condition (relative to planarity) a design with bottom hinges is
    #: co-optimized with, in turn while the last one missed the flat targets, before it goes
    #: without the condition; none: never conical.  The first is the joint solve's own default
    #: (``coflat.CO_CONICAL``).  Which weight reaches the targets depends on the design and on
    #: the last bits of the arithmetic (the BLAS kernels a machine runs), so a second one is
    #: tried before the condition is given up.
    conical_weights: tuple[float, ...] = (CO_CONICAL, 10.0)
    #: In a tiling that may still be split (``fallback=False``), a run that was used but missed
    #: by more than ``co_slow_reach`` times the tolerance (``CoLadder.run``'s ``far_mm``) ends
    #: the weights at once: splitting mends such misses, and the tiling is laid out in full,
    #: every weight tried, if it is kept after all.
    conical_retry_far: bool = True
    #: Whether the next weight is tried after one whose first joint solve, in its own model,
    #: already ended no lower than the plain layout (``co_optimized`` refuses it at once).  It
    #: is not: a larger weight holds the conical condition tighter against the flat tiles'
    #: congruence, so its joint solve ends no lower either.
    conical_retry_joint_miss: bool = False
    #: Run the co-optimization without the conical condition, which follows where the conical
    #: ones miss, in a forked child process while they run, where a core is spare
    #: (:class:`~.co_ladder.CoLadder`).
    co_speculate: bool = True

    # -- the rounds of one co-optimization (pipeline/co_rounds.py) --

    #: Extra rounds of ``co_optimized`` on the extruded T3D when re-solving the flat layout
    #: with its true bounds loses most of what the joint solve gained.  Each round shrinks the
    #: error by about 3x where it converges; two rounds in a row without a new best stop it,
    #: and so do the stop rules below, so more rounds run only where the error is still above
    #: them.
    co_refinements: int = 7
    #: ``co_optimized`` stops when the re-solved flat layout's edge error is within this share
    #: of the tolerance, or within ``co_stop_near`` of it and ``co_stop_ratio`` times the joint
    #: solve's: further rounds would gain little, and each moves the bottom corners again,
    #: which the rigid hinge layout has to absorb.
    co_stop_share: float = 0.3
    co_stop_ratio: float = 10.0
    #: ... (that second rule only within this share of the tolerance: the hinge layout can add
    #: to a re-solve that ends near the tolerance, so one there goes on)
    co_stop_near: float = 0.6
    #: The same with bottom hinges, whose rounds pull the bottom corners to equal depths (see
    #: ``co_optimized``): the re-solve then follows the moved hinge points, and the hinge layout
    #: needs a wider margin.
    co_stop_near_conical: float = 0.35
    #: ... and once a re-solve within ``co_stop_near`` (``co_stop_near_conical``) of the
    #: tolerance gains less than this factor on the best before it: the rounds have stalled.
    co_stall_gain: float = 0.9
    #: A tiling that may still be split (``give_up_slow``) stops co-optimizing when, shrinking
    #: at the rate of its last round for the rounds left, its re-solved error would stay above
    #: this many times the tolerance: about what the rigid hinge layout takes off, so such a
    #: tiling would miss the targets, and it is split instead.
    co_slow_reach: float = 4.0
    #: ... and gives up after its first round when that re-solve is this many times worse than
    #: the plain layout: such runs do not come back below it.
    co_give_up_ratio: float = 5.0

    # -- the close fit (pipeline/close_fit.py) --

    #: The eq.-1 weights of ``--fit close``'s assembled shape: the paper's planar and square
    #: weights, the surface weight raised from 0.1 to 10, and the quads' centres and edge
    #: midpoints pulled to the target with the same weight (a planar quad with its corners on
    #: a curved target has its interior off it by its sagitta).  The co-optimization keeps the
    #: paper's surface weight: raised there, it loses the flat layout on most built-ins.
    close_fit: Eq1Weights = Eq1Weights(1e4, 10.0, 10.0, 10.0)
    #: Largest mean conical defect (deg) of the close shape at the vertices next to its
    #: bottom hinges (``close_fit.conical_defect_deg``) for which its layout is tried; a
    #: shape further from conical would have its bottom hinges miss in depth, and the paper's
    #: shape is laid out at once.
    close_conical_defect_max_deg: float = 6.0
    #: The eq.-1 weights of the close shape laid out with every hinge on the top faces, which
    #: ask nothing of the shape in depth: the square weight lowered to 1 and the surface and
    #: face-sample weights raised to 100.  ``--hinges top`` lays it out; with ``--hinges``
    #: unset it is laid out where the close shape with dual hinges was not kept, then (where
    #: this one is not kept either) ``close_fit`` with top hinges, before the paper's shape.
    #: At 200 tiles its layout keeps every 1e-3 mm target on the five built-ins that come to
    #: it (peanut, wave, seashell, cloud, three-shell).
    close_fit_top: Eq1Weights = Eq1Weights(1e4, 1.0, 100.0, 100.0)

    #: Shapes between the close ones and the paper's, closest first, laid out (with top
    #: hinges where ``--hinges`` is unset) where no close shape was kept, before the paper's:
    #: the paper's planar and square weights with the surface and face-sample weights
    #: stepped down.  Where a close shape folds a tile, leaves tiles too small for the
    #: profile's features or misses the 1e-3 mm targets, one of these often keeps them and
    #: still sits far nearer the target than the paper's shape (the corpus's
    #: freeform_shell, nest_chair, ogre_face, minimal_surface, mountain).
    close_fit_rungs: tuple[Eq1Weights, ...] = (
        Eq1Weights(1e4, 10.0, 3.0, 3.0),
        Eq1Weights(1e4, 10.0, 1.0, 1.0),
        Eq1Weights(1e4, 10.0, 0.3, 0.3),
    )

    #: The co-optimization's pull to the target in its joint solves, at the vertices and at
    #: the quads' centres and edge midpoints (weights relative to its pull towards the
    #: starting shape); None: the eq.-1 surface weight of ``--weights`` (the paper's 0.1) at
    #: the vertices alone.
    co_surface: tuple[float, float] | None = None
    #: ``co_surface`` of the second layout of a close shape with top hinges whose design
    #: misses the fit level (mean distance 2 % of a tile side, largest 1 % of the target's
    #: diagonal): the co-optimization moves the tiles by millimetres to make them fold flat,
    #: and with the paper's 0.1 it takes the shape that far from the target (the 200-tile
    #: three-shell's eq.-1 shape sits 2.0 % of a tile side off, its layout 6.5 %); pulled
    #: there too, it stays near.  Kept only where closer (``close_fit.pulled_layout``).
    close_fit_top_co: tuple[float, float] = (30.0, 30.0)
    #: Whether a layout is wanted only with its co-optimization used, as the layouts pulled
    #: to the target are (``close_fit.pulled_layout``; without it such a layout is the plain
    #: one of a shape laid out already): the co-optimization is then refused at its first
    #: round whose re-extruded shape folds a tile or turns one over (each round starts from
    #: the last one's tiles; the 160 mm cloud's pulled rounds fold from the first of eight
    #: to the last), and a tiling whose co-optimization is refused goes without its flat
    #: layout finished and without hinges.
    co_required: bool = False
    #: ``co_surface`` of the polish that follows a pulled layout whose co-optimization was
    #: used (``close_fit.polished``): laid out again on its own tiling from its own assembled
    #: shape with a tenth of the pull, the joint solve settles nearer flat congruence (the
    #: 160 mm three-shell's pulled layout: 1.3e-3 mm, 3.3 % of a tile side; polished:
    #: 4.9e-4 mm, 1.9 %).
    close_fit_top_polish: tuple[float, float] = (3.0, 3.0)
    #: Layouts with ``close_fit_top_co`` at most, each from the assembled shape the last one
    #: kept, while the kept design misses the fit level, was split otherwise than the first
    #: tiling and was not polished (the 200-tile three-shell at 200 mm: 3.98 % of a tile side
    #: with the paper's pull, 2.09 % after one, on a tighter tiling, whose polish gains
    #: nothing, 1.56 % after two; a polished layout laid out again comes back unchanged).
    close_fit_top_passes: int = 2
    #: ... tried only where the close shape's eq.-1 solve on the first tiling, before its
    #: layout, sits within this many times the fit level: the pulled layouts come near that
    #: shape's own distance (the three-shell's sits 2.0 % of a side away, its design 1.6 %),
    #: and on shapes far from it (the corpus's crumpled_developable, 8.0 %) they cost minutes
    #: without getting closer.
    close_fit_top_pull_within: float = 2.0

    # -- the work run ahead (pipeline/ahead.py) --

    #: Scheduling niceness added in :class:`~.ahead.Ahead`'s child.  The child's result is
    #: often thrown away (the tiling laid out here meets the targets), so where the two
    #: processes and this one's worker threads want more cores than there are, the parent goes
    #: first; the child still gets every core the parent leaves idle.  Its result does not
    #: depend on it.
    ahead_niceness: int = 19


#: The policy :func:`~drawstring.pipeline.run.design` uses by default.
DEFAULT_POLICY = LayoutPolicy()
