"""The FastAPI application: ``create_app()`` (uvicorn: ``server.app:create_app --factory``).

Everything lives under ``/api``; ``/`` is the web UI (web/, static files), ``/viser-client/``
viser's static client, and the live 3D viewer runs in the lifespan (server/hosting.py).
Nothing a client sends may produce a 5xx: bodies are size-limited before they are read,
parsed by hand (400 / 422 with messages that name the field), ids out of range are 404.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from contextlib import asynccontextmanager
from typing import Any

from fastapi import APIRouter, FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import HTMLResponse, JSONResponse
from fastapi.routing import APIRoute
from sqlalchemy.exc import OperationalError, SQLAlchemyError
from sqlalchemy.exc import TimeoutError as SQLAlchemyTimeoutError
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

import modsat_core
from modsat_core.spec.jobspec import JobSpec
from worker.store import JobStore

from . import api_docs
from .hosting import mount_static, start_viewer
from .routers.archive import router as archive_router
from .routers.jobs import router as jobs_router
from .routers.service import service_router
from .routers.studies import router as studies_router
from .routers.viewer import viewer_router
from .schemas import PresetSubmission, StudySubmission
from .security import CrossSiteGuard
from .settings import ServerSettings

log = logging.getLogger("modsat.server")


class BodySizeLimit:
    """413 for a request body over ``max_bytes``, checked before anything parses it.

    A declared Content-Length is checked first; a chunked body is read (at most
    ``max_bytes`` + one chunk) and then replayed to the application."""

    def __init__(self, app: ASGIApp, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def _reject(self, send: Send, status: int, detail: str) -> None:
        await JSONResponse({"detail": detail}, status_code=status)({"type": "http"}, _no_receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        too_big = f"request body larger than {self.max_bytes} bytes (MODSAT_MAX_BODY_BYTES)"
        length = dict(scope["headers"]).get(b"content-length")
        if length is not None:
            if not length.strip().isdigit():
                await self._reject(send, 400, "Content-Length is not a number")
                return
            if int(length) > self.max_bytes:
                await self._reject(send, 413, too_big)
                return
        chunks, size, more = [], 0, True
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                return
            chunk = message.get("body", b"")
            size += len(chunk)
            if size > self.max_bytes:
                await self._reject(send, 413, too_big)
                return
            chunks.append(chunk)
            more = message.get("more_body", False)
        body, replayed = b"".join(chunks), False

        async def replay() -> Message:
            nonlocal replayed
            if not replayed:
                replayed = True
                return {"type": "http.request", "body": body, "more_body": False}
            return await receive()  # after the body: wait for the disconnect, as usual

        await self.app(scope, replay, send)


async def _no_receive() -> Message:
    return {"type": "http.disconnect"}


def _readable(err: dict[str, Any]) -> str:
    path = ".".join(str(p) for p in err.get("loc", ())) or "(request)"
    shown = err.get("input")
    got = "" if shown is None or isinstance(shown, (dict, list)) else f"; got {str(shown)[:80]!r}"
    return f"{path}: {err.get('msg', 'invalid')}{got}"


def _install_error_handlers(app: FastAPI) -> None:
    @app.exception_handler(RequestValidationError)
    async def _validation(_request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [
            {"loc": list(e.get("loc", ())), "msg": _readable(e), "type": str(e.get("type", ""))} for e in exc.errors()
        ]
        return JSONResponse({"detail": errors, "messages": [e["msg"] for e in errors]}, status_code=422)

    @app.exception_handler(OperationalError)
    async def _db_down(_request: Request, exc: OperationalError) -> JSONResponse:
        log.error("database unavailable: %s", exc)
        return JSONResponse(
            {"detail": "the job database is unavailable; try again shortly"},
            status_code=503,
            headers={"Retry-After": "5"},
        )

    @app.exception_handler(SQLAlchemyTimeoutError)
    async def _pool_full(_request: Request, exc: SQLAlchemyTimeoutError) -> JSONResponse:
        log.error("no database connection free: %s", exc)
        return JSONResponse(
            {"detail": "the service is busy (no database connection free); try again shortly"},
            status_code=503,
            headers={"Retry-After": "5"},
        )

    @app.exception_handler(SQLAlchemyError)
    async def _db_error(_request: Request, exc: SQLAlchemyError) -> JSONResponse:
        log.exception("database error", exc_info=exc)
        return JSONResponse({"detail": "database error; see the server log"}, status_code=500)


def _api_not_found(routers: list[APIRouter]) -> APIRouter:
    """Requests under /api that no route of ``routers`` takes get JSON (not the web UI's static
    404): 405 with ``Allow`` for a path that exists with other methods, 404 for an unknown path.

    Starlette would answer the 405 itself if the web UI, mounted at ``/``, did not take every path."""
    r = APIRouter(prefix="/api", include_in_schema=False)

    @r.api_route("/{path:path}", methods=["GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS"])
    def unknown(path: str, request: Request) -> JSONResponse:
        allowed = sorted(
            {
                method
                for router in routers
                for route in router.routes
                if isinstance(route, APIRoute) and route.matches(request.scope)[0] != Match.NONE
                for method in route.methods or ()
            }
        )
        if allowed:
            return JSONResponse(
                {"detail": f"/api/{path[:200]} does not take {request.method}; it takes {', '.join(allowed)}"},
                status_code=405,
                headers={"Allow": ", ".join(allowed)},
            )
        return JSONResponse({"detail": f"no API endpoint /api/{path[:200]}; see /api/docs"}, status_code=404)

    return r


#: Answers that come from the middleware and the error handlers rather than from a route; the
#: OpenAPI schema lists them on the operations they can reach.
_EVERY_OPERATION: dict[str, dict[str, str]] = {
    "400": {"description": "A `Host` this server does not answer to (or an unreadable `Content-Length`)"},
    "413": {"description": "Request body over `MODSAT_MAX_BODY_BYTES`"},
    "503": {"description": "The job database is unavailable or busy; try again (`Retry-After`)"},
}
_WRITES: dict[str, dict[str, str]] = {
    "403": {"description": "A write from a page of another origin"},
}


#: pydantic's keywords that FastAPI leaves in a query parameter's schema when the type carries a
#: validator of its own (``Digits``), and the JSON Schema keywords they mean.
_BOUND_KEYWORDS = {"ge": "minimum", "le": "maximum", "gt": "exclusiveMinimum", "lt": "exclusiveMaximum"}


def _standard_bounds(node: dict[str, Any]) -> None:
    """Rename pydantic's ``ge``/``le``/``gt``/``lt`` in a parameter's schema to JSON Schema's keywords,
    onto the integer branch of an optional one (a client reads only the standard ones)."""
    bounds = {_BOUND_KEYWORDS[k]: node.pop(k) for k in list(node) if k in _BOUND_KEYWORDS}
    if not bounds:
        return
    targets = [b for b in node.get("anyOf", []) if b.get("type") in ("integer", "number")] or [node]
    for target in targets:
        target.update(bounds)


def _openapi(app: FastAPI, token: bool):
    """The generated schema, plus JobSpec (the submit body is read by hand, so FastAPI does not see it)."""

    def build() -> dict[str, Any]:
        if app.openapi_schema:
            return app.openapi_schema
        schema = get_openapi(title=app.title, version=app.version, description=app.description, routes=app.routes)
        comps = schema.setdefault("components", {}).setdefault("schemas", {})
        spec_schema = JobSpec.model_json_schema(ref_template="#/components/schemas/{model}")
        comps.update(spec_schema.pop("$defs", {}))
        comps["JobSpec"] = spec_schema
        comps["PresetSubmission"] = PresetSubmission.model_json_schema(ref_template="#/components/schemas/{model}")
        comps["StudySubmission"] = StudySubmission.model_json_schema(ref_template="#/components/schemas/{model}")
        comps["StudySubmission"]["properties"]["spec"] = {  # read by hand like the body of POST /api/jobs
            "oneOf": [{"$ref": "#/components/schemas/JobSpec"}, {"$ref": "#/components/schemas/PresetSubmission"}],
            "description": comps["StudySubmission"]["properties"]["spec"]["description"],
        }
        for ops in schema.get("paths", {}).values():
            for method, op in ops.items():
                for param in op.get("parameters", []):
                    _standard_bounds(param.get("schema", {}))
                responses = op.setdefault("responses", {})
                for code, response in (_EVERY_OPERATION | (_WRITES if method in ("post", "delete") else {})).items():
                    responses.setdefault(code, response)
                if not token:  # an open server: no operation needs the bearer token, so none declares it
                    op.pop("security", None)
                    responses.pop("401", None)
                elif "security" in op:
                    responses.setdefault("401", {"description": "Missing or wrong bearer token"})
        if not token:
            schema["components"].pop("securitySchemes", None)
        app.openapi_schema = schema
        return schema

    return build


def create_app(
    settings: ServerSettings | None = None, store: JobStore | None = None, announce: Callable[[str], None] | None = None
) -> FastAPI:
    """The API. ``store`` defaults to one opened from ``settings`` (created tables included);
    ``announce`` is told the live viewer's address once it runs (``modsat serve`` prints it)."""
    settings = settings or ServerSettings()

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        own = store is None
        app.state.store = store or JobStore(settings.resolved_db_url, busy_timeout_s=settings.sqlite_busy_timeout_s)
        app.state.store.create_schema()
        app.state.viewer = start_viewer(settings, app.state.store)
        if announce is not None:
            announce(
                f"port {app.state.viewer.port} (embedded in the page; also http://HOST:{app.state.viewer.port}/)"
                if app.state.viewer is not None
                else "off"
            )
        try:
            yield
        finally:
            if app.state.viewer is not None:
                app.state.viewer.stop()
            if own:
                app.state.store.dispose()

    app = FastAPI(
        title="modsat job service",
        version=modsat_core.__version__,
        lifespan=lifespan,
        description="Submit co-design training runs of modular satellites, follow them, download the results. "
        "See docs/service.md.",
        openapi_url="/api/openapi.json",
        docs_url=None,  # Swagger UI comes from a CDN: /api/docs is a page of our own (server/api_docs.py)
        redoc_url=None,
    )
    app.state.settings = settings
    if store is not None:
        app.state.store = store
    _install_error_handlers(app)
    routers = [jobs_router, archive_router, studies_router, service_router(), viewer_router()]
    for router in routers:
        app.include_router(router)

    @app.get("/api/docs", include_in_schema=False)
    def api_docs_page() -> HTMLResponse:
        return HTMLResponse(api_docs.render(app.openapi()), headers={"Content-Security-Policy": api_docs.CSP})

    app.include_router(_api_not_found(routers))
    mount_static(app, settings)

    # FastAPI's documented way to customise the schema is to replace the method.
    app.openapi = _openapi(app, token=settings.api_token is not None)  # type: ignore[method-assign]
    app.add_middleware(BodySizeLimit, max_bytes=settings.max_body_bytes)
    # Outermost: a request from another site is refused before its body is read.
    app.add_middleware(CrossSiteGuard, host_names=settings.host_names(), origins=settings.origin_list())
    return app
