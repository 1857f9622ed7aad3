"""The studio's HTTP API and page (FastAPI); ``docs/studio.md`` documents every route.

:func:`create_app` makes the application for a :class:`~.service.StudioConfig`; its lifespan
opens the :class:`~.service.Studio` (the data folder, the executor) and shuts it down.  Every
``/api`` route answers JSON (a refusal: ``{"detail": "one line"}`` with 422, 404 or 409) except
the report, the zips, the log and the event streams.
"""

from __future__ import annotations

import asyncio
import hmac
import json
from collections.abc import AsyncIterator, Awaitable, Callable
from contextlib import asynccontextmanager
from importlib import metadata, resources
from typing import Annotated, Any
from urllib.parse import urlsplit

from fastapi import FastAPI, File, Form, HTTPException, Request, Response, UploadFile
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, StreamingResponse
from starlette.background import BackgroundTask
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from drawstring.app.studio.files import (
    MAX_PROFILE_BYTES,
    builtin_preview,
    zip_folder,
)
from drawstring.app.studio.job import FINISHED
from drawstring.app.studio.service import Conflict, NotFound, Studio, StudioConfig
from drawstring.geometry.core.errors import InputError
from drawstring.geometry.target.builtins import BUILTIN_TARGETS

#: The page's own files (``static/``), by the name the page asks for.
STATIC_FILES = {
    "studio.js": "text/javascript",
    "studio.css": "text/css",
    "viewer.js": "text/javascript",
}
#: Files of the report's viewer (``output/web``) the page uses as they are.
REPORT_FILES = {"three.module.min.js": "text/javascript", "report.css": "text/css"}
#: Seconds between keep-alive comments on an idle event stream.
KEEP_ALIVE_S = 15.0
#: Headers of an event stream: no caching, no buffering by a proxy.
SSE_HEADERS = {"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}


class BodyLimit:
    """Refuse request bodies over ``limit`` bytes with 413, by their Content-Length or, sent
    in chunks, as soon as they pass it."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None and length.isdigit() and int(length) > self.limit:
            response = JSONResponse({"detail": self.message()}, status_code=413)
            await response(scope, receive, send)
            return
        seen = 0

        async def counted() -> Message:
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.limit:
                    raise HTTPException(413, self.message())
            return message

        await self.app(scope, counted, send)

    def message(self) -> str:
        return f"the upload is larger than the studio takes ({self.limit // 2**20} MiB)"


def _read_upload(upload: UploadFile, limit: int) -> bytes:
    data = upload.file.read(limit + 1)
    if len(data) > limit:
        raise HTTPException(413, f"{upload.filename or 'the file'} is over {limit // 1024} KiB")
    return data


def _version() -> str:
    try:
        return metadata.version("drawstring")
    except metadata.PackageNotFoundError:  # a checkout that was not installed
        return "unknown"


def _token_of(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip()
    return request.query_params.get("token")


def create_app(config: StudioConfig) -> FastAPI:
    """The studio's application (the page at ``/``, the API under ``/api``)."""

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        studio = Studio(config)
        app.state.studio = studio
        try:
            yield
        finally:
            studio.shutdown()

    app = FastAPI(
        title="drawstring studio",
        lifespan=lifespan,
        docs_url=None,  # the interactive docs load their scripts from a CDN
        redoc_url=None,
        openapi_url="/api/openapi.json",
    )
    app.add_middleware(BodyLimit, limit=config.upload_limit_bytes)

    @app.middleware("http")
    async def guard(
        request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        if config.allowed_hosts is not None:
            host = urlsplit(f"//{request.headers.get('host', '')}").hostname or ""
            if host not in config.allowed_hosts:
                return JSONResponse(
                    {"detail": f"this studio answers only as {', '.join(config.allowed_hosts)}"},
                    status_code=421,
                )
        if request.url.path.startswith("/api/"):
            if config.token is not None:
                given = _token_of(request) or ""
                if not hmac.compare_digest(given.encode(), config.token.encode()):
                    return JSONResponse(
                        {
                            "detail": "this studio needs its token: the URL it printed, or an "
                            "Authorization: Bearer header"
                        },  # fmt: skip
                        status_code=401,
                    )
            origin = request.headers.get("origin")
            if request.method not in ("GET", "HEAD") and origin is not None:
                if urlsplit(origin).netloc != request.headers.get("host"):
                    return JSONResponse(
                        {"detail": f"requests from another site ({origin}) are refused"},
                        status_code=403,
                    )
        return await call_next(request)

    @app.exception_handler(InputError)
    async def refused(request: Request, exc: InputError) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=422)

    @app.exception_handler(NotFound)
    async def not_found(request: Request, exc: NotFound) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=404)

    @app.exception_handler(Conflict)
    async def conflict(request: Request, exc: Conflict) -> JSONResponse:
        return JSONResponse({"detail": str(exc)}, status_code=409)

    def studio_of(request: Request) -> Studio:
        studio: Studio = request.app.state.studio
        return studio

    _page_routes(app)
    _catalogue_routes(app, studio_of)
    _design_routes(app, studio_of)
    _design_file_routes(app, studio_of)
    return app


def _static(name: str) -> bytes:
    return (resources.files("drawstring.app.studio") / "static" / name).read_bytes()


def _page_routes(app: FastAPI) -> None:
    @app.get("/", include_in_schema=False)
    def page() -> Response:
        return Response(
            _static("index.html"),
            media_type="text/html; charset=utf-8",
            headers={"Cache-Control": "no-cache"},
        )

    @app.get("/static/{name}", include_in_schema=False)
    def static(name: str) -> Response:
        media = STATIC_FILES.get(name)
        if media is not None:
            body = _static(name)
        elif name in REPORT_FILES:  # the report's three.js and style (output/web)
            media = REPORT_FILES[name]
            body = (resources.files("drawstring.output") / "web" / name).read_bytes()
        else:
            raise HTTPException(404, f"no file {name!r}")
        return Response(body, media_type=media, headers={"Cache-Control": "no-cache"})


def _catalogue_routes(app: FastAPI, studio_of: Callable[[Request], Studio]) -> None:
    @app.get("/api/status")
    def status(request: Request) -> dict[str, Any]:
        studio = studio_of(request)
        return {
            "version": _version(),
            "max_running": studio.executor.max_running,
            "upload_limit_bytes": studio.config.upload_limit_bytes,
            "profile_limit_bytes": MAX_PROFILE_BYTES,
        }

    @app.get("/api/targets")
    def targets(request: Request) -> list[dict[str, str]]:
        return studio_of(request).targets()

    @app.get("/api/targets/{name}/preview")
    def target_preview(name: str, size_mm: float | None = None) -> dict[str, Any]:
        if name not in BUILTIN_TARGETS:
            raise NotFound(f"no built-in target {name!r}; see /api/targets")
        return builtin_preview(name, size_mm) if size_mm else builtin_preview(name)

    @app.post("/api/meshes", status_code=201)
    def add_mesh(
        request: Request,
        mesh: Annotated[UploadFile, File()],
        repair: Annotated[bool, Form()] = False,
    ) -> dict[str, Any]:
        studio = studio_of(request)
        data = _read_upload(mesh, studio.config.upload_limit_bytes)
        return studio.add_mesh(mesh.filename, data, repair=repair)

    @app.get("/api/profiles")
    def profiles(request: Request) -> list[dict[str, Any]]:
        return studio_of(request).profiles()

    @app.post("/api/profiles", status_code=201)
    def add_profile(request: Request, profile: Annotated[UploadFile, File()]) -> dict[str, Any]:
        data = _read_upload(profile, MAX_PROFILE_BYTES)
        return studio_of(request).add_profile(profile.filename, data)

    @app.get("/api/options")
    def options(request: Request) -> list[dict[str, Any]]:
        return [spec.to_json() for spec in studio_of(request).option_specs()]

    @app.post("/api/estimate")
    async def estimate(request: Request) -> dict[str, Any]:
        return studio_of(request).estimate(await _json_body(request))


async def _json_body(request: Request) -> Any:
    try:
        return await request.json()
    except ValueError:
        raise InputError("the request body must be JSON (the options as an object)") from None


def _design_routes(app: FastAPI, studio_of: Callable[[Request], Studio]) -> None:
    @app.post("/api/designs", status_code=201)
    def create(
        request: Request,
        target: Annotated[str | None, Form()] = None,
        options: Annotated[str, Form()] = "{}",
        mesh: Annotated[UploadFile | None, File()] = None,
    ) -> dict[str, Any]:
        studio = studio_of(request)
        try:
            values = json.loads(options)
        except ValueError:
            raise InputError('options must be JSON, e.g. {"tiles": 60, "cad": false}') from None
        if mesh is not None and mesh.filename:
            repair = isinstance(values, dict) and values.get("repair") is True
            data = _read_upload(mesh, studio.config.upload_limit_bytes)
            target = studio.add_mesh(mesh.filename, data, repair=repair)["id"]
        return studio.create(target, values)

    @app.get("/api/designs")
    def designs(request: Request) -> list[dict[str, Any]]:
        return studio_of(request).all()

    @app.get("/api/designs/{design_id}")
    def one(request: Request, design_id: str) -> dict[str, Any]:
        return studio_of(request).get(design_id)

    @app.post("/api/designs/{design_id}/cancel")
    def cancel(request: Request, design_id: str) -> dict[str, Any]:
        return studio_of(request).cancel(design_id)

    @app.post("/api/designs/{design_id}/run")
    def rerun(request: Request, design_id: str) -> dict[str, Any]:
        return studio_of(request).rerun(design_id)

    @app.delete("/api/designs/{design_id}", status_code=204)
    def remove(request: Request, design_id: str) -> Response:
        studio_of(request).remove(design_id)
        return Response(status_code=204)


def _design_file_routes(app: FastAPI, studio_of: Callable[[Request], Studio]) -> None:
    @app.get("/api/designs/{design_id}/report")
    def report(request: Request, design_id: str) -> FileResponse:
        studio = studio_of(request)
        studio.get(design_id)
        path = studio.design_folder(design_id) / "report.html"
        if not path.is_file():
            raise NotFound(f"design {design_id} has no report yet")
        return FileResponse(path, media_type="text/html; charset=utf-8")

    @app.get("/api/designs/{design_id}/log")
    def job_log(request: Request, design_id: str) -> PlainTextResponse:
        studio = studio_of(request)
        studio.get(design_id)
        path = studio.log_file(design_id)
        text = path.read_text(encoding="utf-8", errors="replace") if path.is_file() else ""
        return PlainTextResponse(text)

    def zipped(request: Request, design_id: str, part: str | None) -> FileResponse:
        studio = studio_of(request)
        record = studio.get(design_id)
        folder = studio.design_folder(design_id)
        if not (folder / "design.json").is_file():
            raise NotFound(f"design {design_id} has no design folder yet ({record['status']})")
        top = f"{record['name']}-drawstring"
        if part is not None:
            folder = folder / part
            top = part
            if not folder.is_dir():
                raise NotFound(f"design {design_id} has no {part}/ (it was made without CAD)")
        path = zip_folder(folder, top, studio.data / "tmp")
        name = f"{record['name']}-{design_id}{'-' + part if part else ''}.zip"
        return FileResponse(
            path,
            media_type="application/zip",
            filename=name,
            background=BackgroundTask(path.unlink, missing_ok=True),
        )

    @app.get("/api/designs/{design_id}/files.zip")
    def files_zip(request: Request, design_id: str) -> FileResponse:
        return zipped(request, design_id, None)

    @app.get("/api/designs/{design_id}/fabrication.zip")
    def fabrication_zip(request: Request, design_id: str) -> FileResponse:
        return zipped(request, design_id, "fabrication")

    @app.get("/api/designs/{design_id}/events")
    async def design_events(request: Request, design_id: str) -> StreamingResponse:
        studio = studio_of(request)
        studio.get(design_id)
        return StreamingResponse(
            _one_design_events(studio, design_id),
            media_type="text/event-stream",
            headers=SSE_HEADERS,
        )

    @app.get("/api/events")
    async def events(request: Request, since: int | None = None) -> StreamingResponse:
        studio = studio_of(request)
        last = request.headers.get("last-event-id")
        start = since if since is not None else int(last) if last and last.isdigit() else None
        return StreamingResponse(
            _all_events(studio, studio.store.revision if start is None else start),
            media_type="text/event-stream",
            headers=SSE_HEADERS,
        )


def _event(kind: str, data: Any, event_id: int | None = None) -> str:
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {kind}\ndata: {json.dumps(data)}\n\n"


async def _one_design_events(studio: Studio, design_id: str) -> AsyncIterator[str]:
    """The design's record each time it changes, until it is finished or removed."""
    async with studio.changes.listen() as changed:
        last = ""
        while True:
            changed.clear()
            try:
                record = studio.get(design_id)
            except NotFound:
                yield _event("removed", {"id": design_id})
                return
            text = json.dumps(record)
            if text != last:
                yield f"event: design\ndata: {text}\n\n"
                last = text
            if record["status"] in FINISHED:
                return
            try:
                await asyncio.wait_for(changed.wait(), KEEP_ALIVE_S)
            except TimeoutError:
                yield ": keep-alive\n\n"


async def _all_events(studio: Studio, revision: int) -> AsyncIterator[str]:
    """Every design changed or removed after ``revision``, as it changes, for ever."""
    async with studio.changes.listen() as changed:
        yield _event("hello", {"revision": revision}, revision)
        while True:
            changed.clear()
            rows, gone, now = studio.store.changed_since(revision)
            for row in rows:
                try:
                    record = studio.get(row["id"])
                except NotFound:
                    continue
                yield _event("design", record, now)
            for design_id in gone:
                yield _event("removed", {"id": design_id}, now)
            revision = now
            try:
                await asyncio.wait_for(changed.wait(), KEEP_ALIVE_S)
            except TimeoutError:
                yield ": keep-alive\n\n"
