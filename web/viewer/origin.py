"""Which web pages may talk to a modsat server: shared by the API (server/security.py) and the
live viewer's websocket (live/guard.py). No dependencies beyond the standard library."""

from __future__ import annotations

from urllib.parse import urlsplit

LOOPBACK = frozenset({"localhost", "127.0.0.1", "::1"})


def host_names(bind_host: str, extra: str = "") -> set[str] | None:
    """The names a server bound to ``bind_host`` answers to: the loopback names, the bind
    address itself (unless it is every interface) and ``extra`` (comma-separated; ``*`` = any,
    returned as None)."""
    more = {h.strip().lower().strip("[]") for h in extra.split(",") if h.strip()}
    if "*" in more:
        return None
    names = set(LOOPBACK) | more
    if bind_host not in ("0.0.0.0", "::", ""):
        names.add(bind_host.lower().strip("[]"))
    return names


def host_name(host_header: str) -> str | None:
    """The name part of a ``Host`` header ('[::1]:8000' -> '::1'); None if it cannot be read."""
    try:
        parts = urlsplit("//" + host_header.strip())
        name = parts.hostname
        _ = parts.port  # a port that is not a number: ValueError
    except ValueError:
        return None
    return name.lower() if name else None


def host_allowed(host_header: str | None, names: set[str] | None) -> bool:
    if names is None:
        return True
    name = host_name(host_header or "")
    return name is not None and name in names


def origin_allowed(origin: str | None, names: set[str] | None) -> bool:
    """Whether a page at ``origin`` may open a websocket here: its host must be one we answer
    to (a page on localhost, any port: the API's page embeds the viewer from another port)."""
    if origin is None or names is None:
        return True  # not a browser, or any host allowed
    try:
        name = urlsplit(origin.strip()).hostname
    except ValueError:
        return False
    return name is not None and name.lower() in names
