"""The viewer's port answers only the pages it should: every request (viser's page, or the
websocket's upgrade) is checked against the allowed host names (web/viewer/origin.py) before viser
sees it, so a refused websocket never gets a session or a message of the scene
(docs/service.md, "The viewer's port")."""

from __future__ import annotations

import contextlib
import inspect
import logging
import threading
from collections.abc import Callable, Iterator
from typing import Any

from ..origin import host_allowed, origin_allowed

log = logging.getLogger("modsat.viewer")


def refusal(headers, names: set[str] | None) -> tuple[int, str] | None:
    """Why a request may not be answered, as (HTTP status, reason): a repeated ``Host``,
    ``Origin`` or ``Upgrade`` header, a foreign Host (DNS rebinding: for the page and the
    websocket alike) or a websocket from a page of another site. ``headers``: websockets';
    ``names``: the host names the viewer answers to (None = any)."""
    for name in ("Host", "Origin", "Upgrade"):
        if len(headers.get_all(name)) > 1:
            return 400, f"more than one {name} header"
    host = headers.get("Host")
    if not host_allowed(host, names):
        return 400, f"host {(host or '')[:100]!r} is not one this viewer answers to"
    origin = headers.get("Origin")
    if (headers.get("Upgrade") or "").lower() == "websocket" and not origin_allowed(origin, names):
        return 403, f"a page of another site ({origin[:100]!r})"
    return None


def handshake_check(names: set[str] | None) -> Callable[[Any, Any], Any]:
    """websockets' ``process_request``, to run before viser's: a refused request gets its HTTP
    error instead of the page or the websocket's 101 (no session, no message of the scene)."""

    def check(connection, request):
        refused = refusal(request.headers, names)
        if refused is None:
            return None
        status, why = refused
        what = "a websocket" if (request.headers.get("Upgrade") or "").lower() == "websocket" else "a request"
        log.warning("viewer: refused %s: %s", what, why)
        return connection.respond(status, f"refused: {why}\n")

    return check


_PATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def checked_handshakes(check: Callable[[Any, Any], Any]) -> Iterator[None]:
    """Have the websocket server that viser starts meanwhile run ``check`` on every request
    before viser's own ``process_request`` (its page, or the websocket's upgrade).

    viser 1.1.1 builds its ``process_request`` inside its server thread and offers no hook
    before the handshake; its connect callback comes after the 101 and the first messages.
    So ``websockets.asyncio.server.serve`` is wrapped while viser starts (the ViserServer
    constructor returns once the server listens). If viser started no server through it,
    the viewer does not start: it would be unchecked."""
    import websockets.asyncio.server as ws_server

    serve = ws_server.serve
    used = False

    def checked_serve(*args, process_request=None, **kwargs):
        nonlocal used
        used = True

        async def process(connection, request):
            response = check(connection, request)
            if response is None and process_request is not None:
                response = process_request(connection, request)
                if inspect.isawaitable(response):
                    response = await response
            return response

        return serve(*args, process_request=process, **kwargs)

    with _PATCH_LOCK:
        ws_server.serve = checked_serve  # type: ignore[assignment,misc]
        try:
            yield
        finally:
            ws_server.serve = serve  # type: ignore[misc]
    if not used:
        raise RuntimeError(
            "viser did not start its server through websockets.asyncio.server.serve; "
            "the viewer's Host and Origin checks cannot be installed"
        )
