"""``drawstring`` command line: a thin layer that parses options and calls the library.

Exit status: 0 success, 1 a bug in drawstring, 2 bad input (one line on stderr naming the
problem and the fix), 3 a design that misses a hard target (written, listed under
``problems``), 4 a design that misses an accuracy target of its flat layout (or, with
``--strict``, lists any warning), 130 Ctrl-C (:mod:`~drawstring.app.status`).

The options are :mod:`~drawstring.app.parser`'s, the subcommands
:mod:`~drawstring.app.commands`'; :func:`main` turns their errors into exit statuses.
"""

from __future__ import annotations

import os

# Dense algebra here is on small blocks (boundary loops, 3x3 fits); threaded BLAS stalls on
# them when the cores are busy. Set before numpy loads; a user's own setting wins.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import logging  # noqa: E402
import sys  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Sequence  # noqa: E402

from drawstring.app import commands, print_commands  # noqa: E402
from drawstring.app.parser import build_parser  # noqa: E402
from drawstring.app.status import (  # noqa: E402
    EXIT_INPUT,
    EXIT_INTERNAL,
    EXIT_INTERRUPTED,
)
from drawstring.app.terminal import closed_pipe_safe_stdout, library_warnings  # noqa: E402
from drawstring.geometry.core.errors import DesignError, InputError, InternalError  # noqa: E402


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line on ``argv`` (default: the process's arguments); the exit status."""
    with closed_pipe_safe_stdout():
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
    with library_warnings(args.verbose):
        try:
            return _run_command(parser, args)
        except KeyboardInterrupt:
            # design folders are replaced whole, and simulate's files with their report, with
            # Ctrl-C held back meanwhile: an interrupt leaves the old state or the new one
            print("drawstring: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED


def _run_command(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    """Run the subcommand; an error it raises becomes one line on stderr and its status."""
    try:
        if args.command == "design":
            return commands.run_design(args)
        if args.command == "targets":
            return commands.run_targets()
        if args.command == "profiles":
            return commands.run_profiles(args)
        if args.command == "view":
            return commands.run_view(args)
        if args.command == "simulate":
            return commands.run_simulate(args)
        if args.command == "studio":
            from drawstring.app.studio.serve import run_studio

            return run_studio(args, args.subparsers["design"])
        if args.command == "sweep":
            from drawstring.app.sweep.command import run as run_sweep

            return run_sweep(args)
        if args.command == "coupon":
            return print_commands.run_coupon(args)
    except InputError as exc:
        print(f"drawstring: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except DesignError as exc:
        # raised before anything was written (no closed string route, for one): exit 3
        # promises a written design, so this is a refusal
        print(f"drawstring: error: {exc}", file=sys.stderr)
        return EXIT_INPUT
    except Exception as exc:  # a bug: one line, the traceback with -v
        if args.verbose:
            traceback.print_exc(file=sys.stderr)
        what = str(exc) if isinstance(exc, InternalError) else f"{type(exc).__name__}: {exc}"
        print(
            f"drawstring: internal error: {what} (a bug in drawstring; "
            f"{'the traceback is above' if args.verbose else 'run with -v for the traceback'}"
            " and report it)",
            file=sys.stderr,
        )
        return EXIT_INTERNAL
    parser.error(f"unknown command {args.command}")


if __name__ == "__main__":
    sys.exit(main())
