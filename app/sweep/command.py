"""``drawstring sweep``: every combination of a few design options, designed on Dask.

:func:`add_arguments` turns the ``drawstring design`` options of a parser into the sweep's:
the list options (:data:`LIST_OPTIONS`) take comma lists, ``--out`` names the
sweep's folder, and ``--workers`` / ``--scheduler`` choose the cluster.  :func:`run` designs
every variant as a task on a :class:`~drawstring.app.executor.DaskExecutor`, writes each
variant's folder under the sweep's folder as it comes back, and the table after each.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from drawstring.app.status import EXIT_DESIGN
from drawstring.geometry.core.errors import InputError

if TYPE_CHECKING:  # the pipeline loads numpy and scipy, Dask its own: not for --help
    from drawstring.app.executor import TaskEvent
    from drawstring.app.sweep.table import Row
    from drawstring.app.sweep.task import VariantSpec
    from drawstring.app.sweep.variants import ListOption, Variant
    from drawstring.pipeline.record import DesignOptions

#: The options that take comma lists, in the order the variants vary them (the first slowest)
#: and name them.
LIST_OPTIONS = ("--profile", "--printer", "--size", "--tiles", "--hinges", "--fit", "--thickness")

#: The sweep's exit status when some variant did not exit 0 (refused, failed, or missed a
#: target): ``sweep.csv`` says which and why.
EXIT_VARIANTS = EXIT_DESIGN

#: The file that marks a folder as a sweep's (an earlier sweep's folder may be written again).
TABLE = "sweep.csv"
#: The sortable page of the same table.
PAGE = "sweep.html"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Make a parser holding ``drawstring design``'s options the sweep's: each list option
    takes a comma list (its choices checked per value later), ``--out`` is the sweep's folder,
    and ``--workers`` and ``--scheduler`` are added."""
    by_flag = {flag: action for action in parser._actions for flag in action.option_strings}
    lists: dict[str, _ListArgument] = {}
    for flag in LIST_OPTIONS:
        action = by_flag.get(flag)
        if action is None:  # an option this drawstring's designs may not have
            action = parser.add_argument(flag, metavar="VALUES")
        choices = tuple(action.choices) if action.choices is not None else None
        lists[flag] = _ListArgument(action.dest, choices, action.default)
        action.type, action.choices, action.default = None, None, None
        action.metavar = "A,B,..."
        action.help = f"{action.help or ''} (a comma list: one variant per value)".lstrip()
    by_flag["--out"].help = "the sweep's folder (default ./TARGET-sweep)"
    group = parser.add_mutually_exclusive_group()
    group.add_argument(
        "--workers",
        type=int,
        help="worker processes of the local cluster (default: one per core)",
    )
    group.add_argument(
        "--scheduler",
        metavar="tcp://HOST:PORT",
        help="run on the Dask cluster whose scheduler is at this address (started with `dask "
        "scheduler`, workers with `dask worker ADDRESS`) instead of a local cluster",
    )
    parser.set_defaults(sweep_lists=lists)


@dataclass(frozen=True)
class _ListArgument:
    """A list option's destination, the choices it allows, and its default as a design
    option."""

    dest: str
    choices: tuple[str, ...] | None
    default: object


def list_options(args: argparse.Namespace) -> list[ListOption]:
    """The list options given, in :data:`LIST_OPTIONS` order."""
    from drawstring.app.sweep.variants import ListOption, split_values

    out = []
    for flag, argument in args.sweep_lists.items():
        text = getattr(args, argument.dest, None)
        if text is not None:
            out.append(ListOption(flag, argument.dest, split_values(flag, text), argument.choices))
    return out


def base_options(args: argparse.Namespace) -> DesignOptions:
    """The options every variant shares: ``drawstring design``'s, from the same arguments, the
    list options at their defaults (each variant sets its own)."""
    from drawstring.app.commands import design_options

    shared = argparse.Namespace(**vars(args))
    for argument in args.sweep_lists.values():
        setattr(shared, argument.dest, argument.default)
    return design_options(shared)


def run(args: argparse.Namespace) -> int:
    """Run the sweep the parsed ``args`` describe; the exit status."""
    from drawstring.app.executor import DaskExecutor, Task
    from drawstring.app.sweep.table import Row, write_tables
    from drawstring.app.sweep.task import run_variant
    from drawstring.app.sweep.variants import variants

    lists = list_options(args)
    base = base_options(args)
    designs = variants(base, lists, args.target)
    out = check_sweep_dir(args.out if args.out is not None else default_sweep_dir(args.target))
    for variant in designs:
        check_variant_dir(out / variant.name)
    files = shipped_files(args.target, designs)
    rows = [Row(v.name, v.values) for v in designs]
    by_name = {row.variant: row for row in rows}
    tasks = []
    for variant, row in zip(designs, rows, strict=True):
        try:
            variant.options.validate()
        except InputError as exc:  # refused without a task; the others go on
            row.status, row.message = 2, str(exc)
            continue
        tasks.append(Task(variant.name, run_variant, (_spec(variant, args, files),)))
    quiet = args.quiet and not args.verbose
    with DaskExecutor(args.scheduler, args.workers, verbose=args.verbose) as executor:
        out.mkdir(parents=True, exist_ok=True)
        write_tables(out, rows)
        if not quiet:
            print(
                f"sweep: {len(designs)} variant{'s' if len(designs) != 1 else ''} of "
                f"{args.target} on {executor.describe()}",
                file=sys.stderr,
            )
        progress = _Progress(0, len(designs), quiet)
        for row in rows:
            if row.status is not None:
                progress.refused(row)
        for event in executor.run(tasks):
            if event.kind == "report":  # a variant sends none
                continue
            row = by_name[event.task.key]
            _record(out, row, event)
            if event.kind != "started":
                write_tables(out, rows)
            progress.show(event, row)
    return _report(out, rows, quiet)


def _spec(variant: Variant, args: argparse.Namespace, files: dict[str, bytes]) -> VariantSpec:
    """The task's input: the variant, with the bytes of the files it names."""
    from drawstring.app.sweep.task import VariantSpec

    named = {args.target, *(v for v in vars(variant.options).values() if isinstance(v, str))}
    shipped = tuple((path, data) for path, data in files.items() if path in named)
    return VariantSpec(variant.name, args.target, variant.options, shipped, strict=args.strict)


def _record(out: Path, row: Row, event: TaskEvent) -> None:
    """Take a task's end into its row; a written variant's files go to its folder."""
    from drawstring.app.shipping import place_folder
    from drawstring.app.sweep.table import measured

    if event.kind == "started":
        row.measured["worker"] = event.worker
        return
    if event.kind == "failed":
        row.status, row.message = 1, f"not designed: {event.error}"
        return
    outcome = event.result
    row.status, row.message = outcome.status, outcome.message
    if outcome.files:
        files = dict(outcome.files)
        place_folder(out / row.variant, files)
        row.written = True
        row.measured = measured(files, outcome.seconds, event.worker)
    else:
        row.measured = {"design_s": round(outcome.seconds, 1), "worker": event.worker}


@dataclass
class _Progress:
    """The progress lines on stderr: variants done and running, and each start and end."""

    done: int
    total: int
    quiet: bool

    def __post_init__(self) -> None:
        self.running: set[str] = set()

    def refused(self, row: Row) -> None:
        """A variant refused before it was sent."""
        self.done += 1
        self._line(f"{row.variant}: exit {row.status} ({row.message})")

    def _line(self, what: str) -> None:
        if not self.quiet:
            print(
                f"[{self.done}/{self.total} done, {len(self.running)} running] {what}",
                file=sys.stderr,
                flush=True,
            )

    def show(self, event: TaskEvent, row: Row) -> None:
        name = event.task.key
        if event.kind == "started":
            self.running.add(name)
            what = f"{name} started on {event.worker}"
        else:
            self.running.discard(name)
            self.done += 1
            what = f"{name}: exit {row.status}"
            if row.measured.get("tiles") is not None:
                what += f", {row.measured['tiles']} tiles"
            if row.measured.get("design_s") is not None:
                what += f", {row.measured['design_s']} s"
            if event.worker:
                what += f" on {event.worker}"
            if row.message:
                what += f" ({row.message})"
        self._line(what)


def _report(out: Path, rows: list[Row], quiet: bool) -> int:
    """The closing line and the sweep's exit status."""
    statuses: dict[int, int] = {}
    for row in rows:
        status = row.status if row.status is not None else 1
        statuses[status] = statuses.get(status, 0) + 1
    written = sum(row.written for row in rows)
    counts = ", ".join(f"{n} exit {s}" for s, n in sorted(statuses.items()))
    if not quiet:
        print(f"wrote {out}: {written} of {len(rows)} variants ({counts}); see {out / PAGE}")
    if statuses.keys() - {0}:
        failing = [row.variant for row in rows if row.status != 0]
        print(
            f"drawstring: {len(failing)} of {len(rows)} variants did not exit 0 "
            f"({', '.join(failing[:3])}{', ...' if len(failing) > 3 else ''}); see "
            f"{out / TABLE}",
            file=sys.stderr,
        )
        return EXIT_VARIANTS
    return 0


def default_sweep_dir(target: str) -> Path:
    """``./NAME-sweep`` for a built-in name or a mesh file's stem."""
    path = Path(target)
    name = path.stem if path.suffix else target.strip().lower()
    return Path.cwd() / f"{name}-sweep"


def check_sweep_dir(out: Path) -> Path:
    """Refuse a sweep folder that is a file, or a non-empty folder that is not a sweep's."""
    out = out.absolute()
    if out.exists() and not out.is_dir():
        raise InputError(f"output path {out} exists and is a file; choose another --out")
    if out.is_dir() and any(out.iterdir()) and not (out / TABLE).is_file():
        raise InputError(
            f"output folder {out} exists and is not a drawstring sweep (no {TABLE}); choose "
            "another --out"
        )
    return out


def check_variant_dir(folder: Path) -> None:
    """Refuse a variant's folder that cannot be replaced (as ``drawstring design --out``)."""
    from drawstring.output.folder import check_out_dir

    check_out_dir(folder)


def shipped_files(target: str, designs: list[Variant]) -> dict[str, bytes]:
    """The files the variants name (the mesh file, profiles' TOML), path as given -> bytes:
    sent with each task, so that workers need not see the client's files."""
    from drawstring.geometry.target.builtins import BUILTIN_TARGETS

    paths = []
    if target.strip().lower() not in BUILTIN_TARGETS or Path(target).suffix:
        if not Path(target).is_file():
            names = ", ".join(BUILTIN_TARGETS)
            raise InputError(
                f"unknown target {target!r}: not a built-in ({names}) and not a mesh file; "
                "see `drawstring targets`"
            )
        paths.append(target)
    for variant in designs:
        for value in vars(variant.options).values():
            if isinstance(value, str) and Path(value).suffix and Path(value).is_file():
                paths.append(value)
    files = {}
    for path in dict.fromkeys(paths):
        try:
            files[path] = Path(path).read_bytes()
        except OSError as exc:
            raise InputError(f"cannot read {path} ({exc.strerror or exc})") from None
    return files
