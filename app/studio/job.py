"""One design job, as a child process runs it: design, write the folder, judge the result.

:func:`run_job` is what every executor runs (:mod:`.executor`): it takes a :class:`JobSpec`
(plain JSON values, so that it can cross to another process or machine) and a ``report``
callback for its stages, and returns a :class:`Outcome` whose exit status is the one
``drawstring design`` would exit with: 0 written, within the fabrication tolerance and
deploying, 2 refused or no design at all, 3 written with problems, 4 (strict only) a quality
target missed (written), 1 an internal error.
"""

from __future__ import annotations

import os

# As the command line: one BLAS thread (set before numpy loads; a user's own setting wins).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import logging  # noqa: E402
import traceback  # noqa: E402
from collections.abc import Callable, Iterator  # noqa: E402
from contextlib import contextmanager  # noqa: E402
from dataclasses import dataclass, field  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Literal  # noqa: E402

from drawstring.app.shipping import Shipped  # noqa: E402
from drawstring.geometry.core.errors import DesignError, InputError  # noqa: E402
from drawstring.output.folder import write_design  # noqa: E402
from drawstring.pipeline.policy import DEFAULT_POLICY, LayoutPolicy  # noqa: E402
from drawstring.pipeline.record import Design, DesignOptions, Progress  # noqa: E402
from drawstring.pipeline.run import design  # noqa: E402

log = logging.getLogger(__name__)

#: Where a job's design folder goes inside its job folder.
DESIGN_DIR = "design"

#: Job statuses.  ``done``: a design folder was written (exit status 0, 3 or 4); ``refused``:
#: the input was refused (2) or no design came of it, nothing written; ``failed``: no design
#: for another reason (a bug, exit 1, or the job's process ended).
Status = Literal["queued", "running", "done", "failed", "refused", "cancelled", "interrupted"]
FINISHED: tuple[Status, ...] = ("done", "failed", "refused", "cancelled", "interrupted")

#: Relative weight of each stage in the progress fraction, in pipeline order (roughly the
#: share of a design's time each takes at a hundred tiles or so; writing the pictures and the
#: report is a fixed few seconds).  A stage not listed moves the
#: stage's name but not the fraction; stages run again (a tighter tiling) never move it back.
STAGE_WEIGHTS: tuple[tuple[str, float], ...] = (
    ("target", 1.0),
    ("flatten", 2.0),
    ("tiling", 1.0),
    ("assembled", 4.0),
    ("flat", 3.0),
    ("co-optimize", 6.0),
    ("hinges", 2.0),
    ("lift", 1.0),
    ("route", 2.0),
    ("simulate", 12.0),
    ("rigidity", 1.0),
    ("cad", 30.0),
    ("write", 12.0),
)


@dataclass(frozen=True)
class JobSpec:
    """What a job designs.

    Attributes
    ----------
    id : str
        The design's id (letters and digits).
    folder : str
        The job folder; the design is written to its ``design/`` folder.
    target : str
        A built-in name, or the path of the mesh file in the job folder.
    options : dict
        Keyword arguments of :class:`DesignOptions`, JSON values (lists for tuples).
    strict : bool
        Exit status 4 for any warning, as ``--strict``.
    shown : dict
        Paths as they may appear in a message, and the name to show instead (an upload's
        name, not the server's folders).
    """

    id: str
    folder: str
    target: str
    options: dict[str, Any]
    strict: bool = False
    shown: dict[str, str] = field(default_factory=dict)

    def design_options(self) -> DesignOptions:
        values = {
            key: tuple(value) if isinstance(value, list) else value
            for key, value in self.options.items()
        }
        return DesignOptions(**values)

    def to_json(self) -> dict[str, Any]:
        return {
            "id": self.id,
            "folder": self.folder,
            "target": self.target,
            "options": self.options,
            "strict": self.strict,
            "shown": self.shown,
        }

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> JobSpec:
        return cls(
            id=str(data["id"]),
            folder=str(data["folder"]),
            target=str(data["target"]),
            options=dict(data["options"]),
            strict=bool(data.get("strict", False)),
            shown={str(k): str(v) for k, v in dict(data.get("shown", {})).items()},
        )

    def shown_text(self, text: str) -> str:
        """``text`` with the server's paths replaced by the names a person gave."""
        for path, name in self.shown.items():
            text = text.replace(path, name)
        return text


@dataclass(frozen=True)
class Outcome:
    """How a job ended: its status, the design's exit status and a one-line message."""

    status: Status
    exit_status: int | None
    message: str


#: ``report(stage, progress)``: a stage began; progress is the fraction done, 0 to 1.
Report = Callable[[str, float], None]


class StageProgress(Progress):
    """A :class:`Progress` that also reports each stage's start with the fraction done."""

    def __init__(self, report: Report, *, simulate: bool, cad: bool) -> None:
        super().__init__(quiet=True)
        skipped = {"simulate"} if not simulate else set()
        skipped |= {"cad"} if not cad else set()
        weights = [(name, w) for name, w in STAGE_WEIGHTS if name not in skipped]
        total = sum(w for _, w in weights)
        self._start: dict[str, float] = {}
        done = 0.0
        for name, weight in weights:
            self._start[name] = done / total
            done += weight
        self._report = report
        self.fraction = 0.0

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        self.fraction = max(self.fraction, self._start.get(name, 0.0))
        self._report(name, self.fraction)
        with super().stage(name):
            yield


def run_job(
    spec: JobSpec,
    report: Report,
    *,
    inputs: Shipped | None = None,
    out: Path | None = None,
    policy: LayoutPolicy = DEFAULT_POLICY,
) -> Outcome:
    """Design ``spec``'s target, write its folder and judge it as ``drawstring design`` does.

    The folder goes to ``out`` (default: the job folder's ``design/``).  On a Dask worker,
    ``inputs`` are the job's files as the worker has them
    (:func:`~drawstring.app.shipping.shipped_inputs`) and ``policy`` the worker's.  Never raises
    for a design's failure: refusals, design problems and internal errors come back as an
    :class:`Outcome` (an internal error's traceback goes to the log).
    """

    def shown(text: str) -> str:
        return spec.shown_text(inputs.shown(text) if inputs is not None else text)

    try:
        options = inputs.options if inputs is not None else spec.design_options()
        options.validate()
        progress = StageProgress(report, simulate=options.simulate, cad=options.cad)
        target = inputs.target if inputs is not None else spec.target
        result = design(target, options, progress=progress, policy=policy)
        with progress.stage("write"):
            written = inputs.relabelled(result) if inputs is not None else result
            write_design(written, out if out is not None else Path(spec.folder) / DESIGN_DIR)
        report("write", 1.0)
        return judge(result, strict=spec.strict)
    except InputError as exc:
        return Outcome("refused", 2, shown(str(exc)))
    except DesignError as exc:
        # nothing was written: a refusal, as on the command line (3 promises a written design)
        return Outcome("refused", 2, shown(str(exc)))
    except Exception as exc:  # a bug in drawstring: one line here, the traceback in the log
        traceback.print_exc()
        text = shown(f"{type(exc).__name__}: {exc}")
        return Outcome("failed", 1, f"internal error: {text} (a bug in drawstring; see the log)")


def judge(result: Design, *, strict: bool) -> Outcome:
    """The written design's exit status and its one line, as the command line gives them."""
    if result.problems:
        listed = "; ".join(result.problems)
        return Outcome("done", 3, f"design problem: {listed} (see the report's checks)")
    misses = result.layout_misses()
    if strict and misses:
        listed = "; ".join(misses)
        return Outcome("done", 4, f"accuracy target missed: {listed} (see the report's checks)")
    if strict and result.warnings:
        listed = "; ".join(result.warnings)
        return Outcome("done", 4, f"design warnings (strict): {listed}")
    linkage = result.tiling.linkage
    parts = linkage.n_components
    bottom = int(result.hinge_layout.bottom.sum())
    text = (
        f"{linkage.n_tiles} tiles in {parts} part{'s' if parts > 1 else ''}, "
        f"{linkage.n_hinges} hinges ({bottom} on the bottom faces)"
    )
    if result.warnings:
        text += f"; {len(result.warnings)} warning{'s' if len(result.warnings) > 1 else ''}"
    return Outcome("done", 0, text)
