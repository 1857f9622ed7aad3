"""The studio's work, apart from HTTP: designs as records and jobs, uploads, estimates.

:class:`Studio` keeps every design in the :class:`~.store.Store` under the data folder, runs
its job on an :class:`~.executor.Executor` and moves the record along as the job's events
come in.  Each design has a job folder, ``DATA/jobs/ID/``: the mesh or profile it was given
(``input/``), the job's log and the design folder (``design/``).  On start, designs that were
running when the studio stopped are marked ``interrupted`` (they can be run again) and queued
ones are queued again.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import logging
import os
import secrets
import shutil
import threading
import time
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from drawstring.app.studio.executor import (
    LOG_NAME,
    Executor,
    JobEvent,
    Listener,
    ProcessExecutor,
)
from drawstring.app.studio.files import (
    MAX_UPLOAD_BYTES,
    PREVIEW_SIZE_MM,
    check_mesh,
    check_profile,
    content_id,
    key_numbers,
    mesh_suffix,
    preview,
    safe_name,
    stored_name,
    write_file,
)
from drawstring.app.studio.job import DESIGN_DIR, FINISHED, JobSpec
from drawstring.app.studio.options import (
    OptionSpec,
    design_options,
    estimate,
    option_specs,
    parse_options,
)
from drawstring.app.studio.store import Store, Upload
from drawstring.fabrication.profiles import SHIPPED_PROFILES, Profile, load_profile
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.target.builtins import BUILTIN_TARGETS

log = logging.getLogger(__name__)

#: The message of a design whose job was running when the studio stopped.
INTERRUPTED = "the studio stopped while this design ran; run it again"

ExecutorFactory = Callable[[Listener, int | None], Executor]


def default_data_dir() -> Path:
    """The per-user data folder: ``$XDG_DATA_HOME/drawstring/studio`` (``~/.local/share`` by
    default)."""
    base = os.environ.get("XDG_DATA_HOME") or str(Path.home() / ".local" / "share")
    return Path(base) / "drawstring" / "studio"


@dataclass(frozen=True)
class StudioConfig:
    """How a studio runs.

    ``jobs``: designs running at once (default one per two cores); ``design_parser``: the
    command line's ``drawstring design`` parser, for each option's flag and help;
    ``executor``: makes the executor from the event listener and ``jobs`` (default
    :class:`ProcessExecutor`); ``token``: the token every API request must carry;
    ``allowed_hosts``: the host names a request may be addressed to (a page of another site
    whose name resolves to this machine is refused), or None for any; ``upload_limit_bytes``:
    the largest request body.
    """

    data: Path = field(default_factory=default_data_dir)
    jobs: int | None = None
    token: str | None = None
    allowed_hosts: tuple[str, ...] | None = None
    upload_limit_bytes: int = MAX_UPLOAD_BYTES
    design_parser: argparse.ArgumentParser | None = None
    executor: ExecutorFactory | None = None


class NotFound(LookupError):
    """No such design or upload (HTTP 404)."""


class Conflict(RuntimeError):
    """The design is not in a state that allows this (HTTP 409)."""


class Changes:
    """Wakes the event streams (asyncio tasks) when a record changes (in any thread)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._events: set[tuple[asyncio.AbstractEventLoop, asyncio.Event]] = set()

    def notify(self) -> None:
        with self._lock:
            events = list(self._events)
        for loop, event in events:
            with contextlib.suppress(RuntimeError):  # its loop is closed
                loop.call_soon_threadsafe(event.set)

    @contextlib.asynccontextmanager
    async def listen(self) -> AsyncIterator[asyncio.Event]:
        """An event set at every change while the block runs (clear it before reading)."""
        item = (asyncio.get_running_loop(), asyncio.Event())
        with self._lock:
            self._events.add(item)
        try:
            yield item[1]
        finally:
            with self._lock:
                self._events.discard(item)


class Studio:
    """Designs, their jobs and uploads in one data folder."""

    def __init__(self, config: StudioConfig) -> None:
        self.config = config
        self.data = Path(config.data)
        for sub in ("jobs", "uploads", "tmp"):
            (self.data / sub).mkdir(parents=True, exist_ok=True)
        self.store = Store(self.data / "studio.sqlite3")
        self.changes = Changes()
        make = config.executor or (lambda listener, jobs: ProcessExecutor(listener, jobs))
        self.executor = make(self._on_event, config.jobs)
        self._summaries: dict[str, tuple[float, list[dict[str, Any]] | None]] = {}
        self._recover()

    # -- life ------------------------------------------------------------------------------

    def _recover(self) -> None:
        for record in self.store.with_status("running"):
            self._clean_staging(record["id"])
            self.store.update(
                record["id"], status="interrupted", message=INTERRUPTED, finished=time.time()
            )
        for record in self.store.with_status("queued"):
            spec = self.store.spec(record["id"])
            if spec is not None:
                self.executor.submit(JobSpec.from_json(spec))

    def shutdown(self) -> None:
        """Stop every job; the designs that were running become ``interrupted``, queued ones
        stay queued for the next start."""
        self.executor.shutdown()
        for record in self.store.with_status("running"):
            self._clean_staging(record["id"])
            self.store.update_if(
                record["id"], ("running",), status="interrupted", message=INTERRUPTED,
                finished=time.time(),
            )  # fmt: skip
        self.changes.notify()
        self.store.close()

    def _job_folder(self, design_id: str) -> Path:
        return self.data / "jobs" / design_id

    def _clean_staging(self, design_id: str) -> None:
        """Remove what a job stopped mid-write left (the design folder's staging copies)."""
        folder = self._job_folder(design_id)
        for staging in folder.glob(f".{DESIGN_DIR}.*.tmp"):
            shutil.rmtree(staging, ignore_errors=True)

    # -- jobs' events ----------------------------------------------------------------------

    def _on_event(self, event: JobEvent) -> None:
        now = time.time()
        if event.kind == "started":
            self.store.update_if(
                event.id, ("queued",), status="running", started=now, stage="", progress=0.0
            )
        elif event.kind == "stage":
            self.store.update_if(
                event.id, ("running",), stage=event.stage, progress=round(event.progress, 4)
            )
        else:
            outcome = event.outcome
            assert outcome is not None
            values: dict[str, Any] = {
                "status": outcome.status,
                "exit_status": outcome.exit_status,
                "message": outcome.message,
                "finished": now,
            }
            if outcome.status == "done":
                values["progress"] = 1.0
            if outcome.status != "done":
                self._clean_staging(event.id)
            if not self.store.update_if(event.id, ("queued", "running"), **values):
                if self.store.get(event.id) is None:  # removed meanwhile: its folder goes too
                    shutil.rmtree(self._job_folder(event.id), ignore_errors=True)
        self.changes.notify()

    # -- options, profiles, targets --------------------------------------------------------

    def option_specs(self) -> list[OptionSpec]:
        uploaded = tuple(upload.id for upload in self.store.uploads("profile"))
        return option_specs(self.config.design_parser, uploaded)

    def profile(self, name: str) -> tuple[Profile, Upload | None]:
        """A shipped profile by name or an uploaded one by id."""
        if name in SHIPPED_PROFILES:
            return load_profile(name), None
        upload = self.store.upload(name)
        if upload is None or upload.kind != "profile":
            raise InputError(
                f"unknown profile {name!r}; use one of {', '.join(SHIPPED_PROFILES)} or "
                "upload a .toml file"
            )
        return check_profile(self.data / "uploads" / upload.file, f"{upload.name}.toml"), upload

    def profiles(self) -> list[dict[str, Any]]:
        """The shipped profiles and the uploaded ones, each with its defaults and estimate."""
        from drawstring.fabrication.profiles import PROCESS_GUIDE

        rows = []
        names = [*SHIPPED_PROFILES, *(u.id for u in self.store.uploads("profile"))]
        for name in names:
            try:
                profile, upload = self.profile(name)
            except InputError as exc:  # an upload a newer schema refuses: shown, not offered
                log.warning("profile %s: %s", name, exc)
                continue
            needs, makes = PROCESS_GUIDE.get(profile.process, ("", ""))
            rows.append(
                {
                    "name": name,
                    "title": profile.name,
                    "uploaded": upload is not None,
                    "file": f"{upload.name}.toml" if upload is not None else None,
                    "process": profile.process,
                    "description": profile.description,
                    "needs": needs,
                    "makes": makes,
                    "defaults": {
                        "size_mm": profile.default_size_mm,
                        "tiles": profile.default_tiles,
                        "thickness_mm": profile.thickness_mm,
                        "min_gap_angle_deg": profile.min_gap_angle_deg,
                    },
                    "size_range_mm": [profile.size_min_mm, profile.size_max_mm],
                    "bed_mm": [profile.bed_x_mm, profile.bed_y_mm],
                    "currency": profile.currency,
                    "estimate": estimate(design_options({}), profile),
                }
            )
        return rows

    def add_profile(self, filename: str | None, data: bytes) -> dict[str, Any]:
        """Store an uploaded profile file once checked by the loader; its id names it."""
        shown = f"{safe_name(filename, 'profile')}.toml"
        if Path(filename or "").suffix.lower() != ".toml":
            raise InputError(f"{shown}: a profile is a .toml file (drawstring profiles --show)")
        upload_id = content_id(data)
        path = self.data / "uploads" / stored_name(upload_id, ".toml")
        write_file(path, data)
        try:
            profile = check_profile(path, shown)
        except InputError:
            path.unlink(missing_ok=True)
            raise
        name = safe_name(filename, "profile")
        info = {"title": profile.name}
        self.store.add_upload(Upload(upload_id, "profile", name, path.name, info))
        return next(row for row in self.profiles() if row["name"] == upload_id)

    def estimate(self, options_json: Any) -> dict[str, Any]:
        values, _ = parse_options(options_json, self.option_specs())
        profile, _ = self.profile(values.get("profile", "fdm-dual"))
        return estimate(design_options(values), profile)

    @staticmethod
    def targets() -> list[dict[str, str]]:
        return [{"name": t.name, "description": t.description} for t in BUILTIN_TARGETS.values()]

    def add_mesh(self, filename: str | None, data: bytes, *, repair: bool) -> dict[str, Any]:
        """Store an uploaded mesh once the loader accepts it; its id and 3D preview."""
        suffix = mesh_suffix(filename)
        name = safe_name(filename, "mesh")
        upload_id = content_id(data)
        path = self.data / "uploads" / stored_name(upload_id, suffix)
        write_file(path, data)
        try:
            target = check_mesh(path, f"{name}{suffix}", size_mm=PREVIEW_SIZE_MM, repair=repair)
        except InputError:
            path.unlink(missing_ok=True)
            raise
        info = {"suffix": suffix, "triangles": int(len(target.faces))}
        self.store.add_upload(Upload(upload_id, "mesh", name, path.name, info))
        shown = preview(target)
        shown["name"] = name
        return {"id": upload_id, "name": name, "file": f"{name}{suffix}", "preview": shown}

    # -- designs ---------------------------------------------------------------------------

    def create(self, target: str | None, options_json: Any) -> dict[str, Any]:
        """A new design of a built-in ``target`` or an uploaded mesh's id, queued.

        Raises
        ------
        InputError
            A bad option or profile, an unknown target, a mesh the loader refuses.
        """
        values, strict = parse_options(options_json, self.option_specs())
        profile, profile_upload = self.profile(values.get("profile", "fdm-dual"))
        if not target:
            raise InputError("give a target: a built-in name or an uploaded mesh")
        design_id = secrets.token_hex(6)
        folder = self._job_folder(design_id)
        shown: dict[str, str] = {}
        job_options = dict(values)
        mesh = self.store.upload(target) if target.startswith("upload:") else None
        try:
            if mesh is not None and mesh.kind == "mesh":
                source = self.data / "uploads" / mesh.file
                path = folder / "input" / f"{mesh.name}{mesh.info['suffix']}"
                path.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(source, path)
                shown[str(path)] = path.name
                size = values.get("size_mm") or profile.default_size_mm
                check_mesh(path, path.name, size_mm=size, repair=bool(values.get("repair")))
                name, job_target = mesh.name, str(path)
            elif target.strip().lower() in BUILTIN_TARGETS:
                name = job_target = target.strip().lower()
            else:
                raise InputError(
                    f"unknown target {target!r}: not a built-in ({', '.join(BUILTIN_TARGETS)}) "
                    "and not an uploaded mesh; upload an .obj, .off, .ply or .stl file"
                )
            if profile_upload is not None:
                path = folder / "input" / f"{profile_upload.name}.toml"
                path.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(self.data / "uploads" / profile_upload.file, path)
                shown[str(path)] = path.name
                job_options["profile"] = str(path)
            folder.mkdir(parents=True, exist_ok=True)
        except BaseException:
            shutil.rmtree(folder, ignore_errors=True)
            raise
        spec = JobSpec(design_id, str(folder), job_target, job_options, strict, shown)
        shown_options = {**values, **({"strict": True} if strict else {})}
        self.store.add(design_id, name, target, shown_options, spec.to_json())
        self.changes.notify()
        self.executor.submit(spec)
        return self.get(design_id)

    def get(self, design_id: str) -> dict[str, Any]:
        record = self.store.get(design_id)
        if record is None:
            raise NotFound(f"no design {design_id!r}")
        return self._with_summary(record)

    def all(self) -> list[dict[str, Any]]:
        return [self._with_summary(record) for record in self.store.all()]

    def _with_summary(self, record: dict[str, Any]) -> dict[str, Any]:
        folder = self.design_folder(record["id"])
        record["has_design"] = (folder / "design.json").is_file()
        record["has_fabrication"] = (folder / "fabrication").is_dir()
        record["numbers"] = None
        if record["has_design"] and record["status"] == "done":
            stamp = (folder / "design.json").stat().st_mtime
            cached = self._summaries.get(record["id"])
            if cached is None or cached[0] != stamp:
                cached = (stamp, key_numbers(folder))
                self._summaries[record["id"]] = cached
            record["numbers"] = cached[1]
        return record

    def design_folder(self, design_id: str) -> Path:
        return self._job_folder(design_id) / DESIGN_DIR

    def log_file(self, design_id: str) -> Path:
        return self._job_folder(design_id) / LOG_NAME

    def cancel(self, design_id: str) -> dict[str, Any]:
        record = self.get(design_id)
        if record["status"] not in ("queued", "running"):
            raise Conflict(f"design {design_id} is {record['status']}, not queued or running")
        if not self.executor.cancel(design_id):  # finished meanwhile, or held by no executor
            self.store.update_if(
                design_id, ("queued", "running"), status="cancelled", message="cancelled",
                finished=time.time(),
            )  # fmt: skip
            self.changes.notify()
        return self.get(design_id)

    def rerun(self, design_id: str) -> dict[str, Any]:
        """Run a finished design's job again, with the same target and options."""
        record = self.get(design_id)
        spec = self.store.spec(design_id)
        if record["status"] not in FINISHED or spec is None:
            raise Conflict(f"design {design_id} is {record['status']}; it runs already")
        self._clean_staging(design_id)
        changed = self.store.update_if(
            design_id, FINISHED, status="queued", stage="", progress=0.0, exit_status=None,
            message="", started=None, finished=None,
        )  # fmt: skip
        if not changed:
            raise Conflict(f"design {design_id} runs already")
        self.changes.notify()
        self.executor.submit(JobSpec.from_json(spec))
        return self.get(design_id)

    def remove(self, design_id: str) -> None:
        """Cancel a design's job and delete its record and folder."""
        if not self.store.remove(design_id):
            raise NotFound(f"no design {design_id!r}")
        held = self.executor.status(design_id) is not None
        self.executor.cancel(design_id)
        self._summaries.pop(design_id, None)
        if not held:  # else its folder goes when its job has ended (:meth:`_on_event`)
            shutil.rmtree(self._job_folder(design_id), ignore_errors=True)
        self.changes.notify()
