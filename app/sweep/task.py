"""One variant of a sweep, as it runs on a Dask worker.

The client sends a :class:`VariantSpec`: the target and options as given on its command line,
and the bytes of every file they name (a mesh file, a profile's TOML).  :func:`run_variant`
designs the variant with :func:`~drawstring.pipeline.run.design`, writes its folder with
:func:`~drawstring.output.folder.write_design` into a temporary folder of the worker, and
returns every file of that folder in a :class:`VariantOutcome`; the client writes them under
the sweep's folder.  Nothing is left on the worker.

A file the worker sees at the same path with the same bytes (a local cluster, a shared file
system) is read there.  Otherwise its bytes are written into the temporary folder: at the same
relative path under a working folder the variant runs in, for a path given relative to the
client's working folder; elsewhere for an absolute one, the design made from that copy and
relabelled with the path as given.  Either way the folder is the one ``drawstring design``
writes on the client, byte for byte (timings aside), except that ``report.html`` cannot name the
bed of a profile given by an absolute path the worker does not see.
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import os
import tempfile
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

from drawstring.geometry.core.errors import DesignError, InputError
from drawstring.pipeline.policy import DEFAULT_POLICY
from drawstring.pipeline.record import Design, DesignOptions

log = logging.getLogger(__name__)

#: The layout policy of a variant: the design's own, with no work run ahead in a forked child.
#: A Dask worker runs its task in a thread of a process with threads of its own (forking there
#: is unsafe), and a nanny's worker process is daemonic (it may not have children); the
#: cluster's cores are kept busy by the other variants instead.  Work run ahead never changes a
#: design (docs/architecture.md, determinism), so the folder is the one the command line writes.
VARIANT_POLICY = replace(DEFAULT_POLICY, retile_ahead=False, co_speculate=False)

#: Held while a variant that names files runs: one that runs in a working folder of its own
#: changes the process's, which a worker's other threads must not see (one thread per worker
#: process is the rule, docs/scaling.md; with more, such variants take turns).
_WORKING_FOLDER = threading.Lock()


#: A folder's files: (relative POSIX path, bytes).
Files = tuple[tuple[str, bytes], ...]


@dataclass(frozen=True)
class VariantSpec:
    """What a worker needs to design one variant."""

    name: str
    target: str
    options: DesignOptions
    #: (path as given, bytes) of the target's mesh file and of each option naming a file
    files: Files = ()
    #: exit status 4 on any warning, as ``drawstring design --strict``
    strict: bool = False


@dataclass(frozen=True)
class VariantOutcome:
    """A variant's exit status (as ``drawstring design`` would exit), its one-line message
    (empty for 0), and its design folder's files, relative POSIX path and bytes (none when
    nothing was written: status 2 or 1)."""

    name: str
    status: int
    message: str
    files: Files
    seconds: float


def run_variant(spec: VariantSpec) -> VariantOutcome:
    """Design one variant and return its folder's files; never raises for the design's own
    errors (a refusal is status 2, a design problem 3, a bug 1, each with its message)."""
    from drawstring.output.folder import write_design
    from drawstring.pipeline.record import Progress
    from drawstring.pipeline.run import design

    start = time.perf_counter()
    lock = _WORKING_FOLDER if spec.files else contextlib.nullcontext()
    with lock, tempfile.TemporaryDirectory(prefix="drawstring-variant-") as tmp:
        root = Path(tmp)
        copies = _copies(spec.files, root / "copies")
        given = {copy: path for path, copy in copies.items()}

        def done(status: int, message: str, files: Files = ()) -> VariantOutcome:
            for copy, path in given.items():  # a refusal names the file as the user gave it
                message = message.replace(copy, path)
            return VariantOutcome(spec.name, status, message, files, time.perf_counter() - start)

        options = replace(
            spec.options,
            **{
                f.name: copies[value]
                for f in dataclasses.fields(spec.options)
                if isinstance(value := getattr(spec.options, f.name), str) and value in copies
            },
        )
        try:
            with _working_folder(spec.files, root / "work"):
                result = design(
                    copies.get(spec.target, spec.target),
                    options,
                    progress=Progress(quiet=True),
                    policy=VARIANT_POLICY,
                )
                folder = write_design(_relabelled(result, given), root / "out" / spec.name)
        except InputError as exc:
            return done(2, str(exc))
        except DesignError as exc:
            return done(3, f"design problem: {exc}")
        except Exception as exc:  # a bug: the other variants go on
            log.exception("variant %s failed", spec.name)
            return done(1, f"internal error: {type(exc).__name__}: {exc}")
        status, message = verdict(result, spec.strict)
        files = tuple(
            (path.relative_to(folder).as_posix(), path.read_bytes())
            for path in sorted(folder.rglob("*"))
            if path.is_file()
        )
        return done(status, message, files)


def verdict(result: Design, strict: bool) -> tuple[int, str]:
    """The exit status ``drawstring design`` gives a written design, and its reason."""
    if result.problems:
        return 3, f"design problem: {'; '.join(result.problems)}"
    misses = result.layout_misses()
    if misses:
        return 4, f"accuracy target missed: {'; '.join(misses)}"
    if strict and result.warnings:
        return 4, f"design warnings (--strict): {'; '.join(result.warnings)}"
    return 0, ""


def _seen(path: str, data: bytes) -> bool:
    """Whether this process sees ``data`` at ``path``."""
    try:
        return Path(path).read_bytes() == data
    except OSError:
        return False


def _relative(path: str) -> bool:
    """A path inside the working folder it is given relative to."""
    return not Path(path).is_absolute() and ".." not in Path(path).parts


def _copies(files: Files, folder: Path) -> dict[str, str]:
    """Absolute path as given -> the path of its copy in ``folder``, for each such file this
    worker does not see there with those bytes."""
    copies: dict[str, str] = {}
    for i, (path, data) in enumerate(files):
        if _relative(path) or _seen(path, data):
            continue
        copy = folder / str(i) / Path(path).name  # the file's name, hence the target's, is kept
        copy.parent.mkdir(parents=True)
        copy.write_bytes(data)
        copies[path] = str(copy)
    return copies


@contextlib.contextmanager
def _working_folder(files: Files, folder: Path) -> Iterator[None]:
    """Where a relative path is not seen here with its bytes: every relative file written at
    its path under ``folder``, the process's working folder ``folder`` meanwhile."""
    relative = [(path, data) for path, data in files if _relative(path)]
    if all(_seen(path, data) for path, data in relative):
        yield
        return
    for path, data in relative:
        (folder / path).parent.mkdir(parents=True, exist_ok=True)
        (folder / path).write_bytes(data)
    here = os.getcwd()
    os.chdir(folder)
    try:
        yield
    finally:
        os.chdir(here)


def _relabelled(result: Design, given: dict[str, str]) -> Design:
    """``result`` with every path of a copy replaced by the path as given, as the command line
    records it (the target's source as given; an option naming a file as ``str(Path(...))``)."""
    if not given:
        return result
    target = result.target
    if target.source in given:
        target = replace(target, source=given[target.source])
    options = replace(
        result.options,
        **{
            f.name: str(Path(given[value]))
            for f in dataclasses.fields(result.options)
            if isinstance(value := getattr(result.options, f.name), str) and value in given
        },
    )
    return replace(result, target=target, options=options)
