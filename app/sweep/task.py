"""One variant of a sweep, as it runs on a Dask worker.

The client sends a :class:`VariantSpec`: the target and options as given on its command line,
and the bytes of every file they name (a mesh file, a profile's TOML).  :func:`run_variant`
designs the variant with :func:`~drawstring.pipeline.run.design` among those files
(:func:`~drawstring.app.shipping.shipped_inputs`), writes its folder with
:func:`~drawstring.output.folder.write_design` into a temporary folder of the worker, and
returns every file of that folder in a :class:`VariantOutcome`; the client writes them under
the sweep's folder.  Nothing is left on the worker.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from drawstring.app.shipping import WORKER_POLICY, Files, folder_files, shipped_inputs
from drawstring.geometry.core.errors import DesignError, InputError
from drawstring.pipeline.record import Design, DesignOptions

log = logging.getLogger(__name__)


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
    with shipped_inputs(spec.files, spec.target, spec.options) as shipped:

        def done(status: int, message: str, files: Files = ()) -> VariantOutcome:
            message = shipped.shown(message)  # a refusal names the file as the user gave it
            return VariantOutcome(spec.name, status, message, files, time.perf_counter() - start)

        try:
            result = design(
                shipped.target,
                shipped.options,
                progress=Progress(quiet=True),
                policy=WORKER_POLICY,
            )
            folder = write_design(shipped.relabelled(result), shipped.root / "out" / spec.name)
        except InputError as exc:
            return done(2, str(exc))
        except DesignError as exc:
            return done(3, f"design problem: {exc}")
        except Exception as exc:  # a bug: the other variants go on
            log.exception("variant %s failed", spec.name)
            return done(1, f"internal error: {type(exc).__name__}: {exc}")
        status, message = verdict(result, spec.strict)
        return done(status, message, folder_files(folder))


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
