"""``drawstring coupon``, and the printer presets in ``drawstring profiles``.

The library is imported inside the functions: ``drawstring --help`` loads no numpy.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path


def run_coupon(args: argparse.Namespace) -> int:
    """``drawstring coupon``: the test coupon of a profile and printer, in a folder."""
    from drawstring.output.coupon import write_coupon

    name = Path(args.profile).stem if args.profile.lower().endswith(".toml") else args.profile
    out = args.out if args.out is not None else Path.cwd() / f"coupon-{name}"
    folder, profile = write_coupon(args.profile, args.printer, out, slice_beds=args.slice)
    if not args.quiet:
        print(
            f"wrote {folder}: the {profile.name} test coupon of 3 x 3 tiles (coupon.md says "
            "what to check)"
        )
    return 0


def is_printer(name: str) -> bool:
    """Whether ``name`` is a shipped printer preset, or a .toml file holding one (a
    ``[toolheads]`` table)."""
    from drawstring.fabrication.printers import SHIPPED_PRINTERS

    if name in SHIPPED_PRINTERS:
        return True
    path = Path(name)
    if path.suffix.lower() != ".toml" or not path.is_file():
        return False
    try:
        return "toolheads" in tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return False


def show_printer(name: str) -> None:
    """A printer preset as TOML (``drawstring profiles --show``)."""
    from drawstring.fabrication.printers import load_printer

    print(load_printer(name).to_toml(), end="")


def print_printers() -> None:
    """Every shipped printer preset, with its toolheads, nozzle and source."""
    from drawstring.fabrication.printers import SHIPPED_PRINTERS, load_printer

    print("Printers (--printer NAME; the print jobs are planned on the printer's bed):")
    for name in SHIPPED_PRINTERS:
        printer = load_printer(name)
        plural = "s" if printer.toolheads > 1 else ""
        print(
            f"{name}: {printer.description}; {printer.toolheads} toolhead{plural}, "
            f"{printer.nozzle_mm:g} mm nozzle\n    source:    {printer.source}"
        )
