"""``drawstring`` command line: a thin layer that parses options and calls the library.

Exit status: 0 success, 2 bad input (one line on stderr naming the problem and the fix),
3 a design that misses a hard target (written, listed under ``problems``), 4 a design that
misses an accuracy target of its flat layout (or, with ``--strict``, lists any warning).
"""

from __future__ import annotations

import os

# Dense algebra here is on small blocks (boundary loops, 3x3 fits); threaded BLAS stalls on
# them when the cores are busy. Set before numpy loads; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import contextlib  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Iterator, Sequence  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import TYPE_CHECKING, Any, NoReturn, TextIO  # noqa: E402

from drawstring.geometry.core.errors import DesignError, InputError, InternalError  # noqa: E402

if TYPE_CHECKING:  # the pipeline loads numpy and scipy: not for --help
    from drawstring.pipeline.record import Design

#: A bug in drawstring (:class:`InternalError`): one line, the traceback under ``-v``.
EXIT_INTERNAL = 1
EXIT_INPUT = 2
EXIT_DESIGN = 3
#: The design was written and has no problems, but its flat layout misses an accuracy target
#: (flat edge error or hinge gap, seen from above or in depth, over 1e-3 mm,
#: :meth:`Design.layout_misses`); with ``--strict`` also any other warning (the surface
#: distance, a stuck simulation, an unreachable lift point, a loose linkage, the string's
#: friction).
EXIT_WARNINGS = 4
#: Ctrl-C: 128 + SIGINT, as a shell reports a process that SIGINT ended.
EXIT_INTERRUPTED = 130


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"drawstring: error: {message} (see: {self.prog} --help)\n")


def _add_design_options(p: argparse.ArgumentParser) -> None:
    from drawstring.fabrication.profiles import MAX_SIZE_MM, MAX_TILES, MIN_GRID_SIDE, MIN_TILES

    p.add_argument("target", help="a mesh file (.obj .off .ply .stl) or a built-in target name")
    p.add_argument(
        "--profile",
        default="fdm-dual",
        help="fabrication profile: fdm-dual (default), laser-epdm, plywood-cnc or a .toml "
        "file; it gives the defaults of --tiles, --size, --thickness and --min-gap-angle",
    )
    p.add_argument("--out", type=Path, help="output folder (default ./TARGET-drawstring)")
    size = p.add_mutually_exclusive_group()
    size.add_argument(
        "--tiles",
        type=int,
        help=f"approximate number of tiles, {MIN_TILES} to {MAX_TILES} (default: the profile's)",
    )
    size.add_argument(
        "--grid",
        type=int,
        nargs=2,
        metavar=("I", "J"),
        help=f"grid columns and rows, each at least {MIN_GRID_SIDE}, at most {MAX_TILES} tiles "
        "in all (instead of --tiles)",
    )
    p.add_argument(
        "--size",
        type=float,
        dest="size_mm",
        help=f"longest side of the shape in mm, above 0 and up to {MAX_SIZE_MM:g} (default: the "
        "profile's)",
    )
    p.add_argument(
        "--resolution",
        type=int,
        default=10_000,
        help="triangles of a built-in target, 100 to 1000000 (default 10000; a mesh file is "
        "used as it is)",
    )
    p.add_argument(
        "--thickness",
        type=float,
        dest="thickness_mm",
        help="tile thickness in mm, above 0 (default: the profile's; with CAD on, a thickness "
        "below what the profile's string channel needs is refused at once with that minimum; "
        "one the shape's curvature cannot take is refused with the largest that fits)",
    )
    p.add_argument(
        "--min-gap-angle",
        type=float,
        dest="min_gap_angle_deg",
        help="least opening of every gap in the flat layout, degrees, 0 to 60 (default: the "
        "profile's)",
    )
    p.add_argument(
        "--max-scale-factor",
        type=float,
        default=2.0,
        help="split parts whose tile area scale ratio exceeds this, in (1, 2] (default 2)",
    )
    p.add_argument(
        "--corners",
        type=int,
        nargs=4,
        metavar="V",
        help="boundary vertex ids of the rectangle corners (default: chosen automatically)",
    )
    p.add_argument(
        "--hinges",
        choices=("dual", "top"),
        default="dual",
        help="hinges on top or bottom faces as the curvature asks (dual, the default), or all "
        "on top with the tiles' overlaps trimmed (top)",
    )
    p.add_argument(
        "--weights",
        type=float,
        nargs=3,
        metavar=("PLANAR", "SQUARE", "SURFACE"),
        default=(1e4, 10.0, 0.1),
        help="assembled-shape weights, each 0 to 1e8, not all 0 (default and paper: 10000 10 "
        "0.1; 10000 1 100 hugs the target)",
    )
    p.add_argument(
        "--up",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=(0.0, 0.0, 1.0),
        help="the assembled shape's resting up axis, for the lift points (default 0 0 1)",
    )
    p.add_argument("--no-simulate", action="store_true", help="skip the deployment simulation")
    p.add_argument("--no-cad", action="store_true", help="skip solids and fabrication files")
    p.add_argument(
        "--no-co-optimize",
        action="store_true",
        help="keep the assembled shape as eq. 1 gives it (do not move it with the flat layout)",
    )
    p.add_argument(
        "--seed",
        type=int,
        default=0,
        help="seed for any randomized step (default 0); no step is randomized at present, so "
        "it changes nothing: designs are deterministic",
    )
    p.add_argument(
        "--repair",
        action="store_true",
        help="drop a mesh file's zero-area (degenerate) faces instead of refusing the file",
    )
    p.add_argument(
        "--quiet",
        action="store_true",
        help="print only errors and the one-line reason for a non-zero exit status (no "
        "progress, notes, warnings or folder line; design.json keeps them all)",
    )
    p.add_argument(
        "--strict",
        action="store_true",
        help="exit with status 4 when the design lists any warning (without it, only a missed "
        "flat-layout accuracy target does)",
    )


VERBOSE_HELP = "log what each stage does, and every warning a library raises"


def _mm(value: float) -> str:
    """A distance for a progress line: three decimals, or 'under 0.001 mm'."""
    return "under 0.001 mm" if value < 0.0005 else f"{value:.3f} mm"


def _version() -> str:
    """The installed package's version (``unknown`` when run from an uninstalled tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("drawstring")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="drawstring",
        description="Turn a curved surface into a flat auxetic linkage pulled shut by one string.",
    )
    parser.add_argument("-v", "--verbose", action="store_true", help=VERBOSE_HELP)
    parser.add_argument("--version", action="version", version=f"drawstring {_version()}")
    # -v also after the subcommand.  SUPPRESS: a subcommand that does not see -v must not
    # overwrite the main parser's value with a default of its own.
    verbose = _Parser(add_help=False)
    verbose.add_argument(
        "-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help=VERBOSE_HELP
    )
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    parser.set_defaults(subparsers=sub.choices)
    design_p = sub.add_parser(
        "design", parents=[verbose], help="design a linkage for a target and write its files"
    )
    _add_design_options(design_p)
    sub.add_parser("targets", parents=[verbose], help="list the built-in targets")
    sim = sub.add_parser(
        "simulate", parents=[verbose], help="simulate the deployment of an existing design"
    )
    sim.add_argument("folder", type=Path, help="a design folder written by `drawstring design`")
    sim.add_argument(
        "--quiet", action="store_true", help="print only errors (no progress or verdict line)"
    )
    view = sub.add_parser(
        "view", parents=[verbose], help="open a design's report.html in the browser"
    )
    view.add_argument("folder", type=Path, help="a design folder written by `drawstring design`")
    prof = sub.add_parser("profiles", parents=[verbose], help="list the fabrication profiles")
    prof.add_argument("--show", metavar="NAME", help="print a profile as TOML to copy and edit")
    prof.add_argument("--size", type=float, help="estimate for a design this size (mm)")
    prof.add_argument("--tiles", type=int, help="estimate for this many tiles")
    return parser


def _run_design(args: argparse.Namespace) -> int:
    from drawstring.output.folder import check_out_dir, default_out_dir
    from drawstring.output.folder import write_design as write
    from drawstring.pipeline.record import DesignOptions, Progress
    from drawstring.pipeline.run import design

    options = DesignOptions(
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
        weights=tuple(args.weights),
        up=tuple(args.up),
        simulate=not args.no_simulate,
        cad=not args.no_cad,
        co_optimize=not args.no_co_optimize,
        repair=args.repair,
        seed=args.seed,
    )
    options.validate()
    out = args.out if args.out is not None else default_out_dir(args.target)
    check_out_dir(out)  # refuse before hours of work, not after
    progress = Progress(quiet=args.quiet)
    result = design(args.target, options, progress=progress)
    folder = write(result, out)
    if not args.quiet:
        print(f"wrote {folder}: {_summary(result)}{_print_jobs(folder)}")
        for repair in result.target.notes:  # a mesh file's repairs (design.json target.notes)
            print(f"note: target: {repair}", file=sys.stderr)
        # the "wrote" line is the command's output; notes and warnings are diagnostics
        for note in result.notes:
            print(f"note: {note}", file=sys.stderr)
        for warning in result.warnings:
            print(f"warning: {warning}", file=sys.stderr)
    if result.problems:
        listed = "; ".join(result.problems)
        print(
            f"drawstring: design problem: {listed} (the design was written to {folder}; "
            "see design.json 'problems')",
            file=sys.stderr,
        )
        return EXIT_DESIGN
    misses = result.layout_misses()
    if misses:
        fix = "drop --no-co-optimize" if not result.options.co_optimize else _closer_fit(result)
        print(
            f"drawstring: accuracy target missed: {'; '.join(misses)} (the design was written "
            f"to {folder}; see design.json 'warnings'; {fix})",
            file=sys.stderr,
        )
        return EXIT_WARNINGS
    if args.strict and result.warnings:
        listed = "; ".join(result.warnings)
        print(
            f"drawstring: design warnings (--strict): {listed} (the design was written to "
            f"{folder}; see design.json 'warnings')",
            file=sys.stderr,
        )
        return EXIT_WARNINGS
    return 0


def _run_targets() -> int:
    from drawstring.geometry.target.builtins import BUILTIN_TARGETS

    width = max(len(name) for name in BUILTIN_TARGETS)
    for name, builtin in BUILTIN_TARGETS.items():
        print(f"{name:<{width}}  {builtin.description}")
    return 0


def _run_profiles(args: argparse.Namespace) -> int:
    from drawstring.fabrication.profiles import (
        MAX_SIZE_MM,
        MAX_TILES,
        MIN_TILES,
        PROCESS_GUIDE,
        SHIPPED_PROFILES,
        load_profile,
        rough_estimate,
    )

    if args.show:
        if args.size is not None or args.tiles is not None:
            raise InputError(
                "--size and --tiles estimate every profile and do not apply to --show; run "
                "drawstring profiles --size MM --tiles N for the estimate"
            )
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
        profile = load_profile(name)
        machine, outputs = PROCESS_GUIDE[profile.process]
        size = args.size if args.size is not None else profile.default_size_mm
        tiles = args.tiles if args.tiles is not None else profile.default_tiles
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
            continue
        guess = rough_estimate(profile, size, tiles)
        print(
            f"    roughly:   {guess.mass_g / 1000:.2f} kg, {guess.cost:.0f} "
            f"{profile.currency} of material, {guess.hours:.1f} h of {guess.basis} for a "
            f"{size:g} mm design of {tiles} tiles"
        )
    print(
        "Estimate another design with `drawstring profiles --size MM --tiles N`; copy a "
        "profile with `drawstring profiles --show NAME > my.toml` and use --profile my.toml."
    )
    return 0


def _run_simulate(args: argparse.Namespace) -> int:
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
            f"{_mm(block['final_max_deviation_mm'])} of the assembled shape; wrote "
            f"{folder / 'deploy.gif'}"
        )
    return 0


def _run_view(args: argparse.Namespace) -> int:
    from drawstring.output.report import open_report

    folder = Path(args.folder)
    if not folder.exists():
        raise InputError(f"{folder} does not exist; give the folder drawstring design wrote")
    if not (folder / "design.json").is_file():
        raise InputError(f"{folder} is not a drawstring design folder (no design.json)")
    path, opened = open_report(folder)
    print(path if opened else f"{path} (no browser could be started here: open it by hand)")
    return 0


def _summary(result: Design) -> str:
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


def _print_jobs(folder: Path) -> str:
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


def _closer_fit(result: Design) -> str:
    """What to try when the flat layout misses its accuracy targets: more, smaller tiles, a
    split bound below the largest part's area-scale ratio (which cuts the target into parts),
    or with dual hinges top ones (no bottom hinge points to bring together: of the misses in a
    sweep of 10 targets at 50, 120 and 300 tiles, every dual one met the targets with top
    hinges)."""
    misses = result.layout_misses()
    if result.options.hinges == "dual" and all("in depth" in m for m in misses):
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
    if result.options.hinges == "dual":
        fixes.append("--hinges top")
    tried = f"{', '.join(fixes[:-1])} or {fixes[-1]}" if len(fixes) > 1 else fixes[0]
    chosen, usual = result.options.min_gap_angle_deg, result.profile.min_gap_angle_deg
    if chosen < usual:
        # Gaps that open little leave the linkage less room: the 200-tile seashell at 0 deg
        # misses by 4.4e-3 mm and meets the targets at the profile's 12 deg, where none of the
        # other fixes mends it (400 tiles 0.023 mm, --max-scale-factor 1.3 6.0e-3, top hinges
        # 4.2e-3).
        return (
            f"try the profile's --min-gap-angle {usual:g} first (this design has {chosen:g}); "
            f"failing that, {tried}"
        )
    return f"try {tried}"


#: Logger that Python warnings raised inside the libraries (numpy, scipy, OCP) go to with -v.
LIBRARY_LOGGER = "drawstring.library"


@contextlib.contextmanager
def _library_warnings(verbose: bool) -> Iterator[None]:
    """Python warnings raised while a command runs: one log line each with ``-v``, none
    without.  What a user needs to know about a design is in its own ``warnings`` and
    ``problems``; a library's numerical warning (an overflow in a trial step the solver then
    refuses, a deprecation) is a detail for whoever debugs it.  The previous warning state
    comes back on return (``main`` may be called from a script or a test)."""
    log = logging.getLogger(LIBRARY_LOGGER)

    def show(
        message: Warning | str,
        category: type[Warning],
        filename: str,
        lineno: int,
        file: object = None,
        line: str | None = None,
    ) -> None:
        log.warning("%s: %s (%s:%d)", category.__name__, message, filename, lineno)

    with warnings.catch_warnings():
        if verbose:
            warnings.simplefilter("default")  # once per place, as Python shows them
            warnings.showwarning = show
        else:
            warnings.simplefilter("ignore")
        yield


class _ClosedPipeSafe:
    """Standard output that goes quiet once its reader has gone (``drawstring profiles |
    head -1``): the rest is discarded and the command still ends with its own exit status."""

    def __init__(self, stream: TextIO) -> None:
        self._stream = stream
        self._gone = False

    def _drop(self) -> None:
        self._gone = True
        with contextlib.suppress(OSError, ValueError):
            # later flushes (also the interpreter's at exit) then write to nowhere
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, self._stream.fileno())
            os.close(devnull)

    def write(self, text: str) -> int:
        if not self._gone:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._drop()
        return len(text)

    def flush(self) -> None:
        if not self._gone:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._drop()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


@contextlib.contextmanager
def _closed_pipe_safe_stdout() -> Iterator[None]:
    stream = sys.stdout
    sys.stdout = _ClosedPipeSafe(stream)
    try:
        yield
    finally:
        sys.stdout.flush()
        sys.stdout = stream


def main(argv: Sequence[str] | None = None) -> int:
    with _closed_pipe_safe_stdout():
        return _main(argv)


def _main(argv: Sequence[str] | None) -> int:
    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if unknown:
        # named by the subcommand's parser, whose --help lists what it takes
        args.subparsers[args.command].error(f"unrecognized arguments: {' '.join(unknown)}")
    args.verbose = getattr(args, "verbose", False)
    quiet = getattr(args, "quiet", False) and not args.verbose
    logging.basicConfig(
        level=logging.INFO if args.verbose else logging.ERROR if quiet else logging.WARNING,
        format="%(levelname)s %(name)s: %(message)s",
    )
    with _library_warnings(args.verbose):
        try:
            return _run_command(parser, args)
        except KeyboardInterrupt:
            # design folders are replaced whole, and simulate's files with their report, with
            # Ctrl-C held back meanwhile: an interrupt leaves the old state or the new one
            print("drawstring: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED


def _run_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    try:
        if args.command == "design":
            return _run_design(args)
        if args.command == "targets":
            return _run_targets()
        if args.command == "profiles":
            return _run_profiles(args)
        if args.command == "view":
            return _run_view(args)
        if args.command == "simulate":
            return _run_simulate(args)
    except InputError as exc:
        print(f"drawstring: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except DesignError as exc:
        print(f"drawstring: design problem: {exc}", file=sys.stderr)
        return EXIT_DESIGN
    except InternalError as exc:
        logging.getLogger(__name__).debug("internal error", exc_info=True)
        print(
            f"drawstring: internal error: {exc} (a bug in drawstring; run with -v for the "
            "traceback and report it)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    parser.error(f"unknown command {args.command}")


if __name__ == "__main__":
    sys.exit(main())
