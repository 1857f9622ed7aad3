"""The ``drawstring`` command line's parser: its subcommands and their options."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any, NoReturn

from drawstring.app.status import EXIT_INPUT
from drawstring.app.studio.serve import add_studio_options
from drawstring.app.sweep.command import add_arguments as add_sweep_arguments
from drawstring.geometry.core.tile import HingeStrategy

#: Help of ``-v``, before the subcommand and after it.
VERBOSE_HELP = "log what each stage does, and every warning a library raises"


class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_INPUT, f"drawstring: error: {message} (see: {self.prog} --help)\n")


def _version() -> str:
    """The installed package's version (``unknown`` when run from an uninstalled tree)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("drawstring")
    except PackageNotFoundError:
        return "unknown"


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``drawstring`` and its subcommands."""
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
    design_p.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="build the CAD stage's tile solids as tasks on the Dask cluster "
        "whose scheduler is at this address (started with `dask scheduler`, workers with `dask "
        "worker ADDRESS`); the files are the same, byte for byte",
    )
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
    studio = sub.add_parser(
        "studio", parents=[verbose], help="design in the browser: serve the local web app"
    )
    add_studio_options(studio)
    sweep = sub.add_parser(
        "sweep", parents=[verbose], help="design every combination of a few options' values"
    )
    _add_design_options(sweep)
    add_sweep_arguments(sweep)
    _add_coupon_parser(sub, verbose)
    prof = sub.add_parser(
        "profiles", parents=[verbose], help="list the fabrication profiles and printer presets"
    )
    prof.add_argument(
        "--show",
        metavar="NAME",
        help="print a profile or a printer preset as TOML to copy and edit",
    )
    prof.add_argument("--size", type=float, help="estimate for a design this size (mm)")
    prof.add_argument("--tiles", type=int, help="estimate for this many tiles")
    return parser


def _add_design_options(p: argparse.ArgumentParser) -> None:
    """The options of ``drawstring design``, in the order ``--help`` lists them."""
    _add_input_options(p)
    _add_size_options(p)
    _add_shape_options(p)
    _add_run_options(p)


def _add_input_options(p: argparse.ArgumentParser) -> None:
    """What to design, for which profile, and where to write it."""
    p.add_argument("target", help="a mesh file (.obj .off .ply .stl) or a built-in target name")
    p.add_argument(
        "--profile",
        default="fdm-dual",
        help="fabrication profile: fdm-dual (default), laser-epdm, plywood-cnc or a .toml "
        "file; it gives the defaults of --tiles, --size, --thickness and --min-gap-angle",
    )
    p.add_argument("--out", type=Path, help="output folder (default ./TARGET-drawstring)")
    add_printer_options(p)


def add_printer_options(p: argparse.ArgumentParser) -> None:
    """``--printer`` and ``--slice`` (``drawstring design`` and ``drawstring coupon``)."""
    p.add_argument(
        "--printer",
        metavar="NAME|FILE.toml",
        help="printer preset the tiles print on: generic-dual, prusa-xl-2t, bambu-h2d, "
        "snapmaker-u1, generic-single or a .toml file (default: the profile's; drawstring "
        "profiles lists them); the print jobs are planned on its bed",
    )
    p.add_argument(
        "--slice",
        action="store_true",
        help="slice each print bed with PrusaSlicer (when installed) and report its printing "
        "time and filament in bom.csv (default: drawstring's estimate, fitted to PrusaSlicer's; "
        "PrusaSlicer's own numbers vary by seconds from run to run)",
    )


def _add_coupon_parser(sub: Any, verbose: argparse.ArgumentParser) -> None:
    """``drawstring coupon``."""
    coupon = sub.add_parser(
        "coupon",
        parents=[verbose],
        help="write a small test print (3 x 3 tiles) of a profile's hinges, channel and magnets",
    )
    coupon.add_argument(
        "--profile",
        default="fdm-dual",
        help="fabrication profile: fdm-dual (default), laser-epdm, plywood-cnc or a .toml file",
    )
    coupon.add_argument("--out", type=Path, help="output folder (default ./coupon-PROFILE)")
    add_printer_options(coupon)
    coupon.add_argument(
        "--quiet", action="store_true", help="print only errors (no line naming the folder)"
    )


def _add_size_options(p: argparse.ArgumentParser) -> None:
    """How many tiles, how large and how thick, and how far the gaps open."""
    from drawstring.fabrication.profiles import MAX_SIZE_MM, MAX_TILES, MIN_GRID_SIDE, MIN_TILES

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


def _add_shape_options(p: argparse.ArgumentParser) -> None:
    """Splits, corners, hinges, the assembled shape's weights and its up axis."""
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
        choices=tuple(HingeStrategy),
        default=None,
        help="hinges on top or bottom faces as the curvature asks (dual), or all on top with "
        "the tiles' overlaps trimmed (top); default: dual, or top where dual's layout misses "
        "the profile's tolerance and top's meets it",
    )
    p.add_argument(
        "--weights",
        type=float,
        nargs=3,
        metavar=("PLANAR", "SQUARE", "SURFACE"),
        default=None,
        help="assembled-shape weights, each 0 to 1e8, not all 0; override --fit (the paper's: "
        "10000 10 0.1)",
    )
    p.add_argument(
        "--fit",
        choices=("close", "paper"),
        default="close",
        help="the assembled shape: as close to the target as every flat-layout and hinge "
        "target allows (close, the default), or the paper's weights 10000 10 0.1 (paper)",
    )
    p.add_argument(
        "--up",
        type=float,
        nargs=3,
        metavar=("X", "Y", "Z"),
        default=(0.0, 0.0, 1.0),
        help="the assembled shape's resting up axis, for the lift points (default 0 0 1)",
    )


def _add_run_options(p: argparse.ArgumentParser) -> None:
    """Stages to skip, the seed, mesh repair, and what the run prints and exits with."""
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
        help="seed for any randomized step (default 0); no step is randomized, so it changes "
        "nothing: designs are deterministic",
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
        help="exit with status 4 when the design misses a quality target (the 1e-3 mm flat "
        "layout accuracy, the fit) or lists any warning",
    )
