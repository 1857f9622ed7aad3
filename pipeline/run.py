"""The design pipeline: target -> flattening -> tiling -> ... -> measured design.

``design(target, options)`` runs every stage in order, times each one and returns a
:class:`~drawstring.pipeline.record.Design`; :func:`drawstring.output.folder.write_design`
writes its output folder atomically.  The command line and the Python API (``from drawstring
import design, write_design``) both go through these two functions.
"""

from __future__ import annotations

import logging
import math
import os
from collections.abc import Callable
from dataclasses import replace
from typing import Any

from threadpoolctl import threadpool_limits

from drawstring.fabrication.printers import Printer, resolve_printer, with_printer
from drawstring.fabrication.profiles import Profile, load_profile
from drawstring.geometry.assembled.top import PAPER_WEIGHTS, Eq1Weights
from drawstring.geometry.core.errors import InputError, ThicknessError
from drawstring.geometry.core.tile import HingeStrategy
from drawstring.geometry.flatten.conformal import Flattening, flatten
from drawstring.geometry.hinges.placement import HingeLayout
from drawstring.geometry.route.result import Route
from drawstring.geometry.simulate.result import SimulationResult
from drawstring.geometry.target.surface import Target, load_target
from drawstring.pipeline.auto import (
    LaidOut,
    checked_feature_refusal,
    chooses_values,
    chosen_layout,
    routed_and_checked,
)
from drawstring.pipeline.cad_stage import FeatureShortfall, bed_refusal
from drawstring.pipeline.checks import check_grid, mesh_corners
from drawstring.pipeline.close_fit import fitted_layout
from drawstring.pipeline.layout_stage import ShapedLayout
from drawstring.pipeline.measure import cad_problems, cad_warnings, design_rigidity, measure_design
from drawstring.pipeline.policy import DEFAULT_POLICY, LayoutPolicy
from drawstring.pipeline.quality import quality_levels, tolerance_problems
from drawstring.pipeline.record import (
    Design,
    DesignOptions,
    Progress,
    ResolvedOptions,
    jsonable,
    rounded,
)
from drawstring.pipeline.retry import (
    Searched,
    checked_channel_refusal,
    checked_size_refusal,
    feature_check,
)
from drawstring.pipeline.routed import Deployment, routed_layout

log = logging.getLogger(__name__)


def resolve_options(
    options: DesignOptions, profile: Profile, printer: Printer | None = None
) -> ResolvedOptions:
    """Fill profile defaults into the options; ``printer`` is the one the tiles print on
    (:func:`~drawstring.fabrication.printers.resolve_printer`)."""
    options.validate()
    tiles = options.tiles
    if options.grid is None and tiles is None:
        tiles = profile.default_tiles
    resolved = ResolvedOptions(
        profile=profile.name if profile.source.endswith("(shipped)") else profile.source,
        tiles=tiles if options.grid is None else None,
        grid=tuple(options.grid) if options.grid is not None else None,
        size_mm=options.size_mm if options.size_mm is not None else profile.default_size_mm,
        resolution=options.resolution,
        thickness_mm=options.thickness_mm
        if options.thickness_mm is not None
        else profile.thickness_mm,
        min_gap_angle_deg=options.min_gap_angle_deg
        if options.min_gap_angle_deg is not None
        else profile.min_gap_angle_deg,
        max_scale_factor=options.max_scale_factor,
        corners=options.corners,
        hinges=HingeStrategy(options.hinges or HingeStrategy.DUAL),
        weights=PAPER_WEIGHTS if options.weights is None else tuple(options.weights),
        fit=options.fit,
        up=tuple(float(c) / math.hypot(*options.up) for c in options.up),
        simulate=options.simulate,
        cad=options.cad,
        co_optimize=options.co_optimize,
        seed=options.seed,
        repair=options.repair,
        printer=None
        if printer is None
        else printer.name
        if printer.origin.endswith("(shipped)")
        else printer.origin,
        slice=options.slice,
    )
    if resolved.cad:
        from drawstring.pipeline.cad_stage import thickness_refusal

        too_thin = thickness_refusal(profile, resolved.thickness_mm)
        if too_thin is not None:
            raise too_thin
    return resolved


#: BLAS threads while designing.  A multi-threaded BLAS sums in an order that depends on its
#: thread count, and the eq.-1 solve and the layouts amplify that rounding into a different
#: design; the BLAS calls here are small enough that one thread costs nothing measurable.
BLAS_THREADS = 1


def design(
    target: str | os.PathLike[str],
    options: DesignOptions | None = None,
    *,
    quiet: bool = True,
    progress: Progress | None = None,
    policy: LayoutPolicy = DEFAULT_POLICY,
) -> Design:
    """Run the design pipeline on a mesh path or built-in target name.

    BLAS runs on one thread meanwhile (:data:`BLAS_THREADS`), so the result does not depend on
    the machine's core count.  ``policy`` steers the tiling ladder, the co-optimization and
    the work run ahead (:class:`~drawstring.pipeline.policy.LayoutPolicy`).

    Raises
    ------
    InputError
        For bad input (the CLI prints its one-line message and exits with status 2).
    """
    with threadpool_limits(limits=BLAS_THREADS, user_api="blas"):
        return _design(target, options, quiet=quiet, progress=progress, policy=policy)


def _design(
    target: str | os.PathLike[str],
    options: DesignOptions | None,
    *,
    quiet: bool,
    progress: Progress | None,
    policy: LayoutPolicy,
) -> Design:
    options = options or DesignOptions()
    options.validate()
    profile = load_profile(options.profile)
    printer = resolve_printer(profile, options.printer)
    profile = with_printer(profile, printer)
    resolved = resolve_options(options, profile, printer)
    progress = progress or Progress(quiet=quiet)
    laid, chosen_values = _layout(os.fspath(target), options, resolved, profile, progress, policy)
    loaded, flat_map, shaped = laid.loaded, laid.flat_map, laid.shaped
    resolved, hinge_choice = laid.options, laid.hinge_choice
    notes = [*laid.notes, *shaped.notes]
    tiling, assembled, flat = shaped.tiling, shaped.assembled, shaped.flat
    hinge_layout = shaped.hinge_layout
    assert hinge_layout is not None  # only a tiling that was tiled again goes without
    # with CAD routed and checked with the layout (routed_and_checked)
    routed = laid.routed or routed_layout(shaped, resolved, profile, progress)
    deployment, lift, route, chosen = routed.deployment, routed.lift, routed.route, routed.chosen
    masses = routed.masses
    notes.extend(routed.notes)
    if resolved.cad:
        too_large = bed_refusal(profile, printer, deployment.fabricated)
        if too_large is not None:
            raise too_large
    # a close shape laid out with top hinges counts as top hinges tried
    top_tried = hinge_choice is not None or "close_top" in (shaped.fit or {})
    measured, problems, warnings = measure_design(
        resolved, profile, tiling, assembled, flat, hinge_layout, lift, route, masses,
        target_diagonal_mm=loaded.bbox_diagonal_mm, target=loaded, fit=shaped.fit,
        top_tried=top_tried,
    )  # fmt: skip
    measured["co_optimization"] = shaped.co_block
    if chosen_values is not None:
        measured["chosen_values"] = chosen_values
    if hinge_choice is not None:
        measured["hinge_choice"] = hinge_choice
    if shaped.fit is not None:
        measured["fit"] = jsonable(shaped.fit)
    measured["split_bound"] = rounded(shaped.split_bound, 6)
    notes.extend(f"flat stage: {p}" for p in flat.problems)
    notes.extend(f"hinge stage: {p}" for p in hinge_layout.problems)
    measured["rigidity"] = _rigidity(shaped, hinge_layout, route, progress, warnings)
    simulation = None
    if resolved.simulate:
        # the run of this route, already made by the sweep
        simulation = deployment.simulated(chosen)
        measured["simulation"] = _simulation_block(simulation, deployment, progress, problems)
    problems.extend(tolerance_problems(measured, profile.tolerance_mm))
    result = Design(
        options=resolved,
        profile=profile,
        target=loaded,
        flattening=flat_map,
        tiling=tiling,
        assembled=assembled,
        flat=flat,
        hinge_layout=hinge_layout,
        lift=lift,
        route=route,
        simulation=simulation,
        measured=measured,
        timings_s=progress.ordered_timings(),
        notes=tuple(notes),
        problems=tuple(problems),
        warnings=tuple(warnings),
        printer=printer,
        quality=quality_levels(measured, profile.tolerance_mm, loaded.bbox_diagonal_mm),
    )
    if resolved.cad:
        result = with_cad(result, progress)
    return result


def _layout(
    source: str,
    options: DesignOptions,
    resolved: ResolvedOptions,
    profile: Profile,
    progress: Progress,
    policy: LayoutPolicy,
) -> tuple[LaidOut, dict[str, Any] | None]:
    """Stages target to hinges at the options given, and ``metrics.chosen_values``: where the
    user gave none of --size, --thickness, --tiles and the defaults are refused or miss the
    fabrication tolerance, at values the tool chose (:func:`~.auto.chosen_layout`), else
    refused with a checked ``retry with:`` as :func:`_laid_out` refuses."""
    asked = (source, options)
    prepared = _target_and_flattening(source, resolved, progress)
    from_profile = options.tiles is None and options.grid is None
    check_grid(resolved, prepared[1], from_profile=from_profile)

    def lay_out(changed: ResolvedOptions) -> LaidOut:
        again = _target_and_flattening(source, changed, progress)
        check_grid(changed, again[1], from_profile=False)
        laid = _laid_out_at(changed, profile, progress, policy, asked, again, checked=False)
        return _routed_with_room(laid, profile, progress, policy, asked, again)

    if not chooses_values(options):
        laid = _laid_out_at(resolved, profile, progress, policy, asked, prepared)
        laid = _routed_with_room(laid, profile, progress, policy, asked, prepared)
        if laid.shortfall is not None:
            raise checked_feature_refusal(laid, source, options, resolved, profile, lay_out)
        return laid, None
    first: LaidOut | ThicknessError | FeatureShortfall
    try:
        first = _laid_out_at(resolved, profile, progress, policy, asked, prepared, checked=False)
    except (ThicknessError, FeatureShortfall) as refused:
        first = refused
    else:
        first = _routed_with_room(first, profile, progress, policy, asked, prepared)

    def refuse(exc: ThicknessError | FeatureShortfall, searched: Searched) -> InputError:
        if isinstance(exc, FeatureShortfall):
            return checked_channel_refusal(exc, source, options, resolved, profile, searched)
        return checked_size_refusal(exc, source, options, resolved, profile, searched)

    return chosen_layout(first, source, options, resolved, profile, lay_out, refuse)


def _routed_with_room(
    laid: LaidOut,
    profile: Profile,
    progress: Progress,
    policy: LayoutPolicy,
    asked: tuple[str, DesignOptions],
    prepared: tuple[Target, Flattening, list[str]],
) -> LaidOut:
    """``laid`` routed and checked (:func:`~.auto.routed_and_checked`); where a close shape's
    tiles are too small for the profile's features there, the paper's shape laid out, routed
    and checked at the same options instead, kept where it has room for them (the close fit
    can shrink tiles that the paper's squareness keeps whole)."""
    laid = routed_and_checked(laid, profile, progress)
    fit = laid.shaped.fit
    if laid.shortfall is None or fit is None or fit.get("used") != "close":
        return laid
    short = str(laid.shortfall)
    refused = {**fit, "used": "paper", "eq1": Eq1Weights.of(laid.options.weights).to_json()}
    refused["features"] = {"eq1": fit.get("eq1"), "refused": short}
    options = replace(laid.options, hinges=HingeStrategy(asked[1].hinges or HingeStrategy.DUAL))
    paper = _laid_out_at(
        options, profile, progress, policy, asked, prepared, checked=False, refused=refused
    )
    paper = routed_and_checked(paper, profile, progress)
    if paper.shortfall is not None:
        return laid
    note = (
        f"fit: the close shape's layout leaves tiles too small for the {profile.name} "
        f"profile's features ({short}); the paper's shape has room for them and is used"
    )
    return replace(paper, notes=(*paper.notes, note))


def _laid_out_at(
    options: ResolvedOptions,
    profile: Profile,
    progress: Progress,
    policy: LayoutPolicy,
    asked: tuple[str, DesignOptions],
    prepared: tuple[Target, Flattening, list[str]],
    *,
    checked: bool = True,
    refused: dict[str, Any] | None = None,
) -> LaidOut:
    """Stages tiling to hinges on the target and flattening ``prepared`` (:func:`_laid_out`),
    with the hinges :func:`hinges_chosen` picks; ``refused``: ``metrics.fit`` of close shapes
    refused on this design already, so that the paper's shape is laid out."""
    loaded, flat_map, notes = prepared
    shaped, options = _laid_out(
        loaded, flat_map, options, progress, policy, asked, checked=checked, refused=refused
    )
    # close shapes laid out with top hinges and refused are not laid out again
    if refused is None and shaped.fit is not None and "close_top" in shaped.fit:
        refused = shaped.fit
    shaped, options, hinge_choice = hinges_chosen(
        shaped, options, profile.tolerance_mm, lambda top: _laid_out(
            loaded, flat_map, top, progress, policy, asked, checked=False, refused=refused
        )[0], asked_hinges=asked[1].hinges,
    )  # fmt: skip
    return LaidOut(loaded, flat_map, tuple(notes), shaped, options, hinge_choice)


def _target_and_flattening(
    target: str | os.PathLike[str], options: ResolvedOptions, progress: Progress
) -> tuple[Target, Flattening, list[str]]:
    """Stages target and flatten: the loaded target, its conformal map onto a rectangle, and
    the design's notes so far."""
    notes: list[str] = []
    with progress.stage("target"):
        loaded = load_target(
            target, size_mm=options.size_mm, resolution=options.resolution,
            repair=options.repair,
        )  # fmt: skip
    with progress.stage("flatten"):
        try:
            flat_map = flatten(
                loaded.vertices, loaded.faces, mode="rectangle",
                corners=mesh_corners(loaded, options),
            )  # fmt: skip
        except InputError as unflattened:
            if loaded.source == "builtin":
                raise
            # a mesh the loader accepted but that cannot be flattened: name the file, as the
            # loader's own refusals do
            raise InputError(f"{loaded.source}: {unflattened}") from None
    if flat_map.flipped:
        notes.append(
            f"flattening: the conformal map turns {flat_map.flipped} of the target's "
            f"{len(loaded.faces)} triangles over (slivers or a coarse mesh where the surface "
            "bends sharply); the tiles are lifted from this map and checked as measured, and "
            "a finer, cleaner target mesh or other --corners avoids it"
        )
    return loaded, flat_map, notes


def _laid_out(
    loaded: Target,
    flat_map: Flattening,
    options: ResolvedOptions,
    progress: Progress,
    policy: LayoutPolicy,
    asked: tuple[str, DesignOptions],
    *,
    checked: bool = True,
    refused: dict[str, Any] | None = None,
) -> tuple[ShapedLayout, ResolvedOptions]:
    """Stages tiling to hinges on the shape ``--fit`` asks for (:func:`fitted_layout`, whose
    ``refused`` this is), and the options it was laid out with; tiles that turn inside out,
    or (with CAD) tiles too small for the string channel or the hinge strips, refused seconds
    in with a checked ``retry with:`` (:mod:`~drawstring.pipeline.retry`), or raised as they
    are when not ``checked``.  ``asked``: the target and the options as the user gave them."""
    source, given = asked
    profile = load_profile(options.profile)
    check = feature_check(profile, options) if options.cad else None
    try:
        return fitted_layout(
            loaded,
            flat_map,
            options,
            progress,
            policy=policy,
            weights_given=given.weights is not None,
            check_first=check,
            top_allowed=given.hinges is None,
            refused=refused,
        )
    except ThicknessError as exc:
        if not checked:
            raise
        raise checked_size_refusal(exc, source, given, options, profile) from exc
    except FeatureShortfall as exc:
        if not checked:
            raise
        raise checked_channel_refusal(exc, source, given, options, profile) from exc


def hinges_chosen(
    shaped: ShapedLayout,
    options: ResolvedOptions,
    tolerance_mm: float,
    lay_out: Callable[[ResolvedOptions], ShapedLayout],
    *,
    asked_hinges: HingeStrategy | None,
) -> tuple[ShapedLayout, ResolvedOptions, dict[str, Any] | None]:
    """With ``--hinges`` left unset, the dual layout ``shaped``, or where it misses the
    profile's fabrication tolerance (flat edge error or hinge gap over ``tolerance_mm``; in
    depth only bottom hinges can miss) the layout with every hinge on top, ``lay_out(options
    with top hinges)``, when that one meets it.  Returns the layout kept, its options, and
    ``metrics.hinge_choice`` (None where only one layout was made)."""
    if asked_hinges is not None or options.hinges != HingeStrategy.DUAL:
        return shaped, options, None
    dual = shaped.accuracy_mm
    if dual <= tolerance_mm:
        return shaped, options, None
    top_options = replace(options, hinges=HingeStrategy.TOP)
    choice: dict[str, Any] = {"dual_accuracy_mm": rounded(dual, 9)}
    try:
        top = lay_out(top_options)
    except (InputError, ThicknessError, FeatureShortfall) as refused:
        # the check that refuses does not depend on the hinges: not expected once dual passed
        choice.update(used="dual", top_refused=str(refused))
        return shaped, options, choice
    choice["top_accuracy_mm"] = rounded(top.accuracy_mm, 9)
    missed = f"with dual hinges the flat layout is {dual:.2g} mm off, over {tolerance_mm:g} mm"
    if top.accuracy_mm <= tolerance_mm:
        choice["used"] = "top"
        note = (
            f"hinges: {missed}; with every hinge on the top faces (the tiles' overlaps "
            f"trimmed) it is {top.accuracy_mm:.2g} mm off, so the design has top hinges "
            "(--hinges dual keeps the bottom ones)"
        )
        return replace(top, notes=(*top.notes, note)), top_options, choice
    choice["used"] = "dual"
    note = (
        f"hinges: {missed}; with every hinge on the top faces it is {top.accuracy_mm:.2g} mm "
        "off, so the dual design is kept"
    )
    return replace(shaped, notes=(*shaped.notes, note)), options, choice


def _rigidity(
    shaped: ShapedLayout,
    hinge_layout: HingeLayout,
    route: Route,
    progress: Progress,
    warnings: list[str],
) -> dict[str, Any]:
    """Stage rigidity: design.json's ``metrics.rigidity`` (:func:`design_rigidity`); a
    linkage the string does not lock adds a warning to ``warnings``."""
    linkage = shaped.tiling.linkage
    with progress.stage("rigidity"):
        rigidity = design_rigidity(
            linkage, shaped.assembled.tiles, hinge_layout.hinge_vertices, route
        )
    if not rigidity["isostatic"]:
        warnings.append(
            f"the assembled linkage with its string keeps {rigidity['internal_flexes']} internal "
            "flex(es) (metrics.rigidity); it may wobble when the string is tight"
        )
    return rigidity


def _simulation_block(
    simulation: SimulationResult,
    deployment: Deployment,
    progress: Progress,
    problems: list[str],
) -> dict[str, Any]:
    """design.json's ``metrics.simulation`` for the deployment of the chosen route; one that
    got stuck (the linkage does not deploy) adds a problem to ``problems``."""
    block = jsonable(simulation.to_json())
    # Wall-clock numbers go to timings_s, so everything else in design.json is reproducible.
    block.pop("time_s", None)
    progress.timings["simulate_per_step"] = float(block.pop("per_step_ms", 0.0)) / 1000.0
    runs = len(deployment.runs)
    block["runs"] = runs
    if not simulation.deployed:
        problems.append(
            "the deployment simulation got stuck ("
            f"{len(simulation.open_gaps)} route gaps open, tiles up to "
            f"{simulation.final_max_deviation_mm:.2f} mm from the assembled shape, worst "
            f"tiles {', '.join(str(w['tile']) for w in simulation.worst_tiles(3))}) with "
            f"every lift-point set the sweep tried ({runs}); see design.json "
            "metrics.simulation"
        )
    return block


def with_cad(result: Design, progress: Progress) -> Design:
    """Build the solids (flat and assembled pose) and measure them; the export stage writes
    them out in :func:`write_design`."""
    from drawstring.pipeline.cad_stage import build_cad, measure_cad

    with progress.stage("cad"):
        try:
            cad_flat, cad_assembled = build_cad(result)
        except InputError as refusal:
            if not result.problems:
                raise
            # Tiles too small (or too large) for the profile: a new size alone may not give a
            # design, so the refusal names what else is wrong (found before any solid).
            more = f" and {len(result.problems) - 1} more" if len(result.problems) > 1 else ""
            raise InputError(
                f"{refusal}; the design has problems besides, which --no-cad writes out to "
                f"look at: {result.problems[0]}{more}"
            ) from None
        measured = measure_cad(result, cad_flat)
    problems = [*result.problems, *cad_problems(measured)]
    warnings = [*result.warnings, *cad_warnings(measured, result.profile)]
    notes = [*result.notes, *(f"cad: {n}" for n in cad_flat.notes)]
    return replace(
        result,
        cad_flat=cad_flat,
        cad_assembled=cad_assembled,
        # the mass of the tiles as cut plus the hinge parts replaces the uncut tiles' estimate
        measured={**result.measured, "cad": measured, "mass_g": measured["mass_g"]},
        problems=tuple(problems),
        warnings=tuple(warnings),
        notes=tuple(notes),
        timings_s=progress.ordered_timings(),
    )


def with_options(options: DesignOptions, **changes: Any) -> DesignOptions:
    """A copy of ``options`` with some fields changed (for scripts and tests)."""
    return replace(options, **changes)
