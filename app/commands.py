"""The ``drawstring`` subcommands, one function each: ``design``, ``targets``, ``profiles``,
``simulate`` and ``view``, and the lines they print.

The library is imported inside the functions: ``drawstring --help`` loads no numpy.
"""

from __future__ import annotations

import argparse
import contextlib
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import TYPE_CHECKING

from drawstring.app.print_commands import is_printer, print_printers, show_printer
from drawstring.app.status import EXIT_DESIGN, EXIT_WARNINGS
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.core.tile import HingeStrategy

if TYPE_CHECKING:  # the pipeline loads numpy and scipy: not for --help
    from drawstring.pipeline.record import Design, DesignOptions


def run_design(args: argparse.Namespace) -> int:
    """``drawstring design``: design, write the folder, say what was written; the exit status
    says whether the design meets its targets."""
    from drawstring.geometry.core.native import STDOUT_FD, native_output_silenced
    from drawstring.output.folder import check_out_dir, default_out_dir
    from drawstring.output.folder import write_design as write
    from drawstring.pipeline.record import Progress
    from drawstring.pipeline.run import design

    options = design_options(args)
    options.validate()
    out = args.out if args.out is not None else default_out_dir(args.target)
    check_out_dir(out)  # refuse before hours of work, not after
    progress = Progress(quiet=args.quiet)
    # standard output is the "wrote" line's: what native libraries (HiGHS, OpenCASCADE) print
    # there meanwhile stays off it, unless -v (drawstring's own progress goes to stderr)
    with (
        _cad_tasks(getattr(args, "scheduler", None), options.cad, args.verbose) as where,
        native_output_silenced((STDOUT_FD,)),
    ):
        if where and not args.quiet:
            print(f"drawstring: the CAD stage's tiles run on {where}", file=sys.stderr)
        result = design(args.target, options, progress=progress)
        folder = write(result, out)
    if not args.quiet:
        _print_written(result, folder)
    return _design_status(result, folder, args.strict)


@contextlib.contextmanager
def _cad_tasks(scheduler: str | None, cad: bool, verbose: bool) -> Iterator[str]:
    """With a scheduler's address (and CAD asked for): the CAD stage's per-tile work goes to
    that Dask cluster meanwhile; yields where, in a phrase ("" for this machine)."""
    if scheduler is None or not cad:
        yield ""
        return
    from drawstring.app.executor import DaskExecutor
    from drawstring.geometry.core import parallel

    with DaskExecutor(scheduler, verbose=verbose) as executor, parallel.tasks_on(executor):
        yield executor.describe()


def design_options(args: argparse.Namespace) -> DesignOptions:
    """The options of ``drawstring design``'s arguments (not validated yet)."""
    from drawstring.pipeline.record import DesignOptions

    return DesignOptions(
        profile=args.profile,
        tiles=args.tiles,
        grid=tuple(args.grid) if args.grid else None,
        size_mm=args.size_mm,
        resolution=args.resolution,
        thickness_mm=args.thickness_mm,
        min_gap_angle_deg=args.min_gap_angle_deg,
        max_scale_factor=args.max_scale_factor,
        corners=tuple(args.corners) if args.corners else None,
        hinges=args.hinges,
        weights=tuple(args.weights) if args.weights is not None else None,
        fit=args.fit,
        up=tuple(args.up),
        simulate=not args.no_simulate,
        cad=not args.no_cad,
        co_optimize=not args.no_co_optimize,
        repair=args.repair,
        seed=args.seed,
        printer=args.printer,
        slice=args.slice,
    )


def _print_written(result: Design, folder: Path) -> None:
    """The "wrote" line on standard output; the target's repairs, notes and warnings on
    standard error."""
    print(f"wrote {folder}: {design_summary(result)}{print_jobs_note(folder)}")
    for repair in result.target.notes:  # a mesh file's repairs (design.json target.notes)
        print(f"note: target: {repair}", file=sys.stderr)
    # the "wrote" line is the command's output; notes and warnings are diagnostics
    for note in result.notes:
        print(f"note: {note}", file=sys.stderr)
    for warning in result.warnings:
        print(f"warning: {warning}", file=sys.stderr)


def _design_status(result: Design, folder: Path, strict: bool) -> int:
    """The exit status of a written design, with its one-line reason on standard error: 3 for
    problems (a measure over the profile's fabrication tolerance among them), 4 with
    ``--strict`` for a missed quality target or any warning, else 0."""
    misses = result.layout_misses()
    fix = "drop --no-co-optimize" if not result.options.co_optimize else closer_fit(result)
    if result.problems:
        listed = "; ".join(result.problems)
        tolerance = any("fabrication tolerance" in p for p in result.problems)
        print(
            f"drawstring: design problem: {listed} (the design was written to {folder}; "
            f"see design.json 'problems'{f'; {fix}' if tolerance and misses else ''})",
            file=sys.stderr,
        )
        return EXIT_DESIGN
    if strict and misses:
        print(
            f"drawstring: accuracy target missed (--strict): {'; '.join(misses)} (the design "
            f"was written to {folder}; see design.json 'quality'; {fix})",
            file=sys.stderr,
        )
        return EXIT_WARNINGS
    if strict and result.warnings:
        listed = "; ".join(result.warnings)
        print(
            f"drawstring: design warnings (--strict): {listed} (the design was written to "
            f"{folder}; see design.json 'warnings')",
            file=sys.stderr,
        )
        return EXIT_WARNINGS
    return 0


def run_targets() -> int:
    """``drawstring targets``: the built-in targets, one a line."""
    from drawstring.geometry.target.builtins import BUILTIN_TARGETS

    width = max(len(name) for name in BUILTIN_TARGETS)
    for name, builtin in BUILTIN_TARGETS.items():
        print(f"{name:<{width}}  {builtin.description}")
    return 0


def run_profiles(args: argparse.Namespace) -> int:
    """``drawstring profiles``: every shipped profile with a rough estimate of a design, or
    one profile as TOML (``--show``)."""
    from drawstring.fabrication.profiles import (
        MAX_SIZE_MM,
        MAX_TILES,
        MIN_TILES,
        SHIPPED_PROFILES,
        load_profile,
    )

    if args.show:
        if args.size is not None or args.tiles is not None:
            raise InputError(
                "--size and --tiles estimate every profile and do not apply to --show; run "
                "drawstring profiles --size MM --tiles N for the estimate"
            )
        if is_printer(args.show):
            show_printer(args.show)
        else:
            print(load_profile(args.show).to_toml(), end="")
        return 0
    if args.size is not None and not (0 < args.size <= MAX_SIZE_MM):
        raise InputError(
            f"--size must be a positive number of millimetres up to {MAX_SIZE_MM:g} (got "
            f"{args.size})"
        )
    if args.tiles is not None and not MIN_TILES <= args.tiles <= MAX_TILES:
        raise InputError(
            f"--tiles must be between {MIN_TILES} and {MAX_TILES} (got {args.tiles}), as for "
            "drawstring design"
        )
    for name in SHIPPED_PROFILES:
        _print_profile(name, args.size, args.tiles)
    print_printers()
    print(
        "Estimate another design with `drawstring profiles --size MM --tiles N`; copy a "
        "profile or a printer with `drawstring profiles --show NAME > my.toml` and use "
        "--profile my.toml or --printer my.toml."
    )
    return 0


def _print_profile(name: str, size_mm: float | None, tiles_wanted: int | None) -> None:
    """A shipped profile: what it needs, uses and makes, the sizes it suits, and a rough
    estimate for a design of ``size_mm`` and ``tiles_wanted`` (the profile's defaults when
    None)."""
    from drawstring.fabrication.profiles import PROCESS_GUIDE, load_profile, rough_estimate

    profile = load_profile(name)
    machine, outputs = PROCESS_GUIDE[profile.process]
    size = size_mm if size_mm is not None else profile.default_size_mm
    tiles = tiles_wanted if tiles_wanted is not None else profile.default_tiles
    fits = profile.size_min_mm <= size <= profile.size_max_mm
    print(f"{name}: {profile.description}")
    print(f"    needs:     {machine}")
    print(
        f"    materials: {profile.tile_material} tiles {profile.thickness_mm:g} mm thick, "
        f"{profile.hinge_material} hinges, {profile.string_material}"
    )
    print(f"    makes:     {outputs}")
    print(
        f"    suits:     {profile.size_min_mm:g} to {profile.size_max_mm:g} mm "
        f"(default {profile.default_size_mm:g} mm, {profile.default_tiles} tiles)"
    )
    if not fits:
        # the estimate's model (tile thickness, panels, hinge parts) only holds in range
        print(f"    roughly:   not estimated: {size:g} mm is outside this profile's range")
        return
    guess = rough_estimate(profile, size, tiles)
    print(
        f"    roughly:   {guess.mass_g / 1000:.2f} kg, {guess.cost:.0f} "
        f"{profile.currency} of material, {guess.hours:.1f} h of {guess.basis} for a "
        f"{size:g} mm design of {tiles} tiles"
    )


def run_simulate(args: argparse.Namespace) -> int:
    """``drawstring simulate``: the deployment simulation added to a written design folder,
    and its verdict in one line; exit status 3 (a problem in design.json) when it does not
    deploy."""
    import json

    from drawstring.output.folder_simulation import simulate_folder

    folder = simulate_folder(args.folder, quiet=args.quiet)
    block = json.loads((folder / "design.json").read_text())["metrics"]["simulation"]
    verdict = "deployed"
    if not block["deployed"]:
        worst = ", ".join(str(w["tile"]) for w in block.get("worst_tiles", [])[:3])
        verdict = f"stuck ({len(block['open_gaps'])} gaps open; farthest tiles {worst})"
    if not args.quiet:
        print(
            f"{verdict} after {block['steps']} steps; tiles within "
            f"{mm_text(block['final_max_deviation_mm'])} of the assembled shape; wrote "
            f"{folder / 'deploy.gif'}"
        )
    if not block["deployed"]:
        print(
            "drawstring: design problem: the linkage does not deploy in the simulation "
            f"({verdict}; see {folder / 'design.json'} 'problems')",
            file=sys.stderr,
        )
        return EXIT_DESIGN
    return 0


def run_view(args: argparse.Namespace) -> int:
    """``drawstring view``: a design's report opened in the browser."""
    from drawstring.output.report import open_report

    folder = Path(args.folder)
    if not folder.exists():
        raise InputError(f"{folder} does not exist; give the folder drawstring design wrote")
    if not (folder / "design.json").is_file():
        raise InputError(f"{folder} is not a drawstring design folder (no design.json)")
    path, opened = open_report(folder)
    print(path if opened else f"{path} (no browser could be started here: open it by hand)")
    return 0


def design_summary(result: Design) -> str:
    """What was designed, in a phrase: tiles, parts (and why it was split), hinges."""
    linkage = result.tiling.linkage
    parts = linkage.n_components
    text = f"{linkage.n_tiles} tiles in {parts} part{'s' if parts > 1 else ''}"
    if parts > 1:
        from drawstring.pipeline.layout_stage import absorbable_ratio, split_bound

        options = result.options
        bound = float(result.metrics().get("split_bound", 0.0))
        default = split_bound(options)
        # design.json keeps the bound to 6 digits; a retiling shrinks it by 30 % at least
        if bound < default - 1e-5:
            why = f"tightened from {default:.3g} for the accuracy targets (see the notes)"
        elif options.max_scale_factor < absorbable_ratio(options.min_gap_angle_deg):
            why = "the --max-scale-factor"
        else:
            why = (
                f"what one part's gaps can absorb opening within "
                f"[{options.min_gap_angle_deg:g}, 90] deg"
            )
        text += (
            f" (split along grid lines: the tile area ratio "
            f"{result.tiling.scale_factor_max_unsplit:.3g} exceeds {bound:.3g}, {why}; magnets "
            "join the parts)"
        )
    bottom = int(result.hinge_layout.bottom.sum())
    return f"{text}, {linkage.n_hinges} hinges ({bottom} on the bottom faces)"


def print_jobs_note(folder: Path) -> str:
    """``; printed in 7 jobs on 6 beds (...)`` when the fabrication files split the layout."""
    from drawstring.output.design_folder import print_job_counts

    jobs, beds = print_job_counts(folder)
    if jobs <= 1:
        return ""
    if jobs == beds:  # one job per bed (loose tiles are nested so)
        return f"; printed on {beds} beds (fabrication/assembly.md)"
    return (
        f"; larger than the bed: printed in {jobs} jobs on {beds} "
        f"bed{'s' if beds > 1 else ''} (fabrication/assembly.md)"
    )


def closer_fit(result: Design) -> str:
    """What to try when the flat layout misses its accuracy targets: the profile's least gap
    angle when the design asked for less, more and smaller tiles, a split bound below the
    largest part's area-scale ratio (which cuts the target into parts), or with dual hinges top
    ones (which leave no bottom hinge points to bring together)."""
    misses = result.layout_misses()
    dual = result.options.hinges == HingeStrategy.DUAL and "hinge_choice" not in result.measured
    if dual and all("in depth" in m for m in misses):
        # seen from above the hinges meet: only the bottom hinges' thickness step is left
        return "try --hinges top, which puts every hinge on the top faces, where it closes"
    tiles = result.tiling.linkage.n_tiles
    ratio = result.tiling.scale_factor_max
    fixes = [f"more tiles (e.g. --tiles {2 * tiles})"]
    if ratio > 1.005:
        fixes.append(
            f"a --max-scale-factor below {ratio:.3g}, this design's largest area-scale ratio, "
            "to split it into parts"
        )
    if dual:
        fixes.append("--hinges top")
    tried = f"{', '.join(fixes[:-1])} or {fixes[-1]}" if len(fixes) > 1 else fixes[0]
    chosen, usual = result.options.min_gap_angle_deg, result.profile.min_gap_angle_deg
    if chosen < usual:
        # gaps that open little leave the linkage less room to close its hinges, which more
        # tiles, splits or top hinges do not give back: the profile's angle comes first
        return (
            f"try the profile's --min-gap-angle {usual:g} first (this design has {chosen:g}); "
            f"failing that, {tried}"
        )
    return f"try {tried}"


def mm_text(value: float) -> str:
    """A distance for a progress line: three decimals, or 'under 0.001 mm'."""
    return "under 0.001 mm" if value < 0.0005 else f"{value:.3f} mm"
