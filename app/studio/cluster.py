"""The studio's jobs on a Dask cluster (``drawstring studio --scheduler ADDRESS``).

:class:`DaskJobExecutor` is an :class:`~.executor.Executor` over the executor ``drawstring
sweep`` uses (:class:`~drawstring.app.executor.DaskExecutor`): each job is one task, sent with
the bytes of the files it names (an uploaded mesh, an uploaded profile).  On a worker,
:func:`run_cluster_job` runs :func:`~.job.run_job` in a temporary folder, sends each stage
back as it begins, and returns the design folder's files and its log; the studio writes them
into the job folder, as a job run on this machine leaves them.  The cluster decides how many
jobs run at once (one per worker thread); a job whose worker dies runs again on another.
"""

from __future__ import annotations

import contextlib
import io
import threading
import time
from pathlib import Path
from typing import Any, Literal

from drawstring.app.executor import DaskExecutor, Task, TaskEvent, report
from drawstring.app.shipping import WORKER_POLICY, Files, folder_files, place_folder
from drawstring.app.studio.executor import LOG_NAME, JobEvent, Listener
from drawstring.app.studio.job import DESIGN_DIR, JobSpec, Outcome

#: What a job sends back: status, exit status, message, the design folder's files, its log.
JobResult = tuple[str, int | None, str, Files, str]


class DaskJobExecutor:
    """Jobs as tasks on the Dask cluster whose scheduler is at ``scheduler``."""

    def __init__(self, listener: Listener, scheduler: str) -> None:
        self._listener = listener
        self._dask = DaskExecutor(scheduler)
        self._dask.__enter__()  # refuses (InputError) a scheduler it cannot reach
        self.max_running = self._dask.thread_count()
        self._lock = threading.Lock()
        self._futures: dict[str, Any] = {}
        self._specs: dict[str, JobSpec] = {}
        self._started: set[str] = set()
        self._closed = False

    def submit(self, spec: JobSpec) -> None:
        with self._lock:
            if self._closed:
                raise RuntimeError("the executor is shut down")
            self._specs[spec.id] = spec
        task = Task(spec.id, run_cluster_job, (spec.to_json(), _job_files(spec)))
        future = self._dask.submit(task, self._on_task)
        with self._lock:
            self._futures[spec.id] = future

    def cancel(self, job_id: str) -> bool:
        with self._lock:
            future = self._futures.pop(job_id, None)
            self._specs.pop(job_id, None)
            self._started.discard(job_id)
        if future is None:
            return False
        self._dask.cancel(future)
        self._listener(
            JobEvent(job_id, "finished", outcome=Outcome("cancelled", None, "cancelled"))
        )
        return True

    def status(self, job_id: str) -> Literal["queued", "running"] | None:
        with self._lock:
            if job_id not in self._futures:
                return None
            return "running" if job_id in self._started else "queued"

    def shutdown(self) -> None:
        with self._lock:
            self._closed = True
            futures = list(self._futures.values())
            self._futures.clear()
            self._specs.clear()
        for future in futures:
            self._dask.cancel(future)
        self._dask.close()

    def _on_task(self, event: TaskEvent) -> None:
        job_id = event.task.key
        with self._lock:
            spec = self._specs.get(job_id)
            first_start = event.kind == "started" and job_id not in self._started
            if event.kind == "started":
                self._started.add(job_id)
            if event.kind in ("finished", "failed"):
                self._futures.pop(job_id, None)
                self._specs.pop(job_id, None)
                self._started.discard(job_id)
        if spec is None:  # cancelled meanwhile
            return
        if event.kind == "started":
            if first_start:
                self._listener(JobEvent(job_id, "started"))
        elif event.kind == "report":
            stage, fraction = event.result
            self._listener(JobEvent(job_id, "stage", str(stage), float(fraction)))
        else:
            self._listener(JobEvent(job_id, "finished", outcome=_received(spec, event)))


def _job_files(spec: JobSpec) -> Files:
    """The bytes of the files a job names: its mesh, a profile's TOML."""
    named = [spec.target, *(v for v in spec.options.values() if isinstance(v, str))]
    return tuple(
        (path, Path(path).read_bytes()) for path in dict.fromkeys(named) if Path(path).is_file()
    )


def _received(spec: JobSpec, event: TaskEvent) -> Outcome:
    """A finished task's outcome, its folder and log written into the job folder."""
    folder = Path(spec.folder)
    if event.kind == "failed":
        message = f"internal error: the cluster did not run the design ({event.error})"
        _append_log(folder, f"{message}\n")
        return Outcome("failed", 1, message)
    status, exit_status, message, files, log = event.result
    if files:
        place_folder(folder / DESIGN_DIR, dict(files))
    _append_log(folder, f"designed on {event.worker}\n{log}")
    return Outcome(status, exit_status, message)


def _append_log(folder: Path, text: str) -> None:
    with contextlib.suppress(OSError), (folder / LOG_NAME).open("a", encoding="utf-8") as log:
        log.write(text)


def run_cluster_job(spec_data: dict[str, Any], files: Files) -> JobResult:
    """On a worker: one studio job among its shipped files; its stages go to the studio as they
    begin.  Returns the outcome, the design folder's files and the job's log."""
    from drawstring.app.shipping import shipped_inputs
    from drawstring.app.studio.job import run_job

    spec = JobSpec.from_json(spec_data)
    log = io.StringIO()
    with shipped_inputs(files, spec.target, spec.design_options()) as inputs:
        out = inputs.root / DESIGN_DIR

        def stage(name: str, fraction: float) -> None:
            log.write(f"{time.strftime('%H:%M:%S')} stage {name}\n")
            report((name, fraction))

        with contextlib.redirect_stderr(log), contextlib.redirect_stdout(log):
            outcome = run_job(spec, stage, inputs=inputs, out=out, policy=WORKER_POLICY)
        log.write(f"finished: {outcome.status} (exit status {outcome.exit_status})\n")
        written = folder_files(out) if out.is_dir() else ()
    return outcome.status, outcome.exit_status, outcome.message, written, log.getvalue()
