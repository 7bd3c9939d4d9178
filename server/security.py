"""Protection against other web pages: the ``Host`` and ``Origin`` checks (docs/service.md).

A browser lets any web page send "simple" requests (a form POST, ``text/plain`` bodies) to
any address, the user's ``localhost`` included, and a page on a name that resolves to
127.0.0.1 (DNS rebinding) can even read the answers. With no token set (the default), the
service would take such a request for the user's own. So, for HTTP and websockets:

* ``Host`` must be a name this server answers to (:meth:`ServerSettings.host_names`):
  400 otherwise, which defeats DNS rebinding for reads too.
* A request that writes (any method but GET, HEAD, OPTIONS) from a browser must come from
  this server's own origin or one listed in ``MODSAT_ALLOWED_ORIGINS``: a foreign
  ``Origin``, or ``Sec-Fetch-Site: cross-site``, is 403. Clients that are not browsers
  (curl, scripts) send neither header and are not affected.
* Websockets (the API has none; the viewer's are checked in web/viewer/live/guard.py with the
  same rules, web/viewer/origin.py) must come from a page on an allowed host.

Submissions must also be ``application/json`` (415), see routers/jobs.py.

No other site may frame the page (clickjacking: the job page's Cancel is one click away): every HTTP
answer carries ``X-Frame-Options: DENY`` and ``Content-Security-Policy: frame-ancestors 'none'``,
except viser's client (``/viser-client/``), which the page itself frames: ``SAMEORIGIN`` and
``frame-ancestors 'self'``. A request with more than one ``Host`` or ``Origin`` header is refused
(400), as the viewer's guard does: which one a proxy or the check would read is not to be guessed.
"""

from __future__ import annotations

from fastapi.responses import JSONResponse
from starlette.types import ASGIApp, Receive, Scope, Send

from web.viewer.origin import host_allowed, origin_allowed

SAFE_METHODS = frozenset({"GET", "HEAD", "OPTIONS"})
#: Framing headers of every answer, and of viser's client (the page frames it; nobody else may).
NO_FRAMING = [(b"x-frame-options", b"DENY"), (b"content-security-policy", b"frame-ancestors 'none'")]
SELF_FRAMING = [(b"x-frame-options", b"SAMEORIGIN"), (b"content-security-policy", b"frame-ancestors 'self'")]


class CrossSiteGuard:
    """ASGI middleware: the ``Host`` check for every request, the ``Origin`` check for writes."""

    def __init__(self, app: ASGIApp, *, host_names: set[str] | None, origins: set[str]):
        self.app, self.host_names, self.origins = app, host_names, origins

    async def _reject(self, scope: Scope, send: Send, status: int, detail: str) -> None:
        if scope["type"] == "websocket":
            await send({"type": "websocket.close", "code": 1008, "reason": detail[:120]})
            return
        await JSONResponse({"detail": detail}, status_code=status)(scope, _no_receive, send)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] not in ("http", "websocket"):
            await self.app(scope, receive, send)
            return
        names = [k.decode("latin-1").lower() for k, _ in scope["headers"]]
        repeated = sorted({n for n in ("host", "origin") if names.count(n) > 1})
        if repeated:
            await self._reject(scope, send, 400, f"more than one {' and '.join(repeated)} header")
            return
        headers = {k.decode("latin-1").lower(): v.decode("latin-1") for k, v in scope["headers"]}
        host = headers.get("host", "")
        if not host_allowed(host, self.host_names):
            await self._reject(
                scope,
                send,
                400,
                (
                    f"this server does not answer to the host name {host[:100]!r}; "
                    "add it to MODSAT_ALLOWED_HOSTS if it is really this server"
                ),
            )
            return
        origin = headers.get("origin")
        if scope["type"] == "websocket":
            if not origin_allowed(origin, self.host_names):
                await self._reject(scope, send, 403, "websocket from a page of another site")
                return
        elif scope["method"] not in SAFE_METHODS:
            own = f"{scope.get('scheme', 'http')}://{host}".lower()
            cross_site = headers.get("sec-fetch-site", "").lower() == "cross-site"
            foreign = origin is not None and origin.strip().rstrip("/").lower() not in ({own} | self.origins)
            if foreign or (cross_site and origin is None):
                await self._reject(
                    scope,
                    send,
                    403,
                    (
                        f"a write from a page of another origin ({(origin or 'cross-site')[:100]}) is refused; "
                        "list that origin in MODSAT_ALLOWED_ORIGINS if it is yours"
                    ),
                )
                return
        if scope["type"] == "http":
            framing = SELF_FRAMING if scope.get("path", "").startswith("/viser-client") else NO_FRAMING

            async def framed(message):
                if message["type"] == "http.response.start":
                    message = {**message, "headers": [*message.get("headers", []), *framing]}
                await send(message)

            await self.app(scope, receive, framed)
            return
        await self.app(scope, receive, send)


async def _no_receive():
    return {"type": "http.disconnect"}
