"""The live viewer's server: viser on one port, a :class:`Session` per browser tab, the runs
they load (a small cache shared by the tabs) and the playback clock. Runs in viser's threads."""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from urllib.parse import parse_qs, urlsplit

from ..origin import host_names
from ..run import RunData
from .guard import checked_handshakes, handshake_check
from .playback import PlaybackClock
from .session import Session
from .sources import RunSource

log = logging.getLogger("modsat.viewer")


class ViewerApp:
    """A viser server with one :class:`Session` per browser tab. Runs in viser's threads."""

    def __init__(
        self,
        source: RunSource,
        *,
        host: str = "127.0.0.1",
        port: int = 8080,
        label: str = "modsat viewer",
        cache_size: int = 8,
        allowed_hosts: set[str] | str | None = "",
    ):
        """``allowed_hosts``: the host names the websocket answers to, and whose pages may open
        it (origin.py); a string = extra names next to the loopback ones and ``host``."""
        import viser

        self.source = source
        self.host_names = host_names(host, allowed_hosts) if isinstance(allowed_hosts, str) else allowed_hosts
        with checked_handshakes(handshake_check(self.host_names)):
            self.server = viser.ViserServer(host=host, port=port, label=label)
        self.server.scene.set_up_direction("+z")
        self.sessions: dict[int, Session] = {}
        self._cache: OrderedDict[str, RunData] = OrderedDict()
        self._cache_size = cache_size
        self._cache_lock = threading.Lock()
        self.server.on_client_connect(self._connect)
        # viser's stub wants a callback returning None; it drops a sync callback's return value (the session).
        self.server.on_client_disconnect(lambda client: self.sessions.pop(client.client_id, None))  # type: ignore[type-var]
        self._clock = PlaybackClock(lambda: self.sessions.values())

    @property
    def port(self) -> int:
        """The port viser really listens on (it moves up when the asked one is busy)."""
        return self.server.get_port()

    def load(self, key: str) -> RunData:
        with self._cache_lock:
            if key in self._cache:
                self._cache.move_to_end(key)
                return self._cache[key]
        run = self.source.load(key)
        with self._cache_lock:
            self._cache[key] = run
            while len(self._cache) > self._cache_size:
                self._cache.popitem(last=False)
        return run

    def _connection(self, client):
        """viser's websocket connection of a tab (viser keeps the handshake request), or None."""
        try:
            return self.server._websock_server._live_connections.get(client.client_id)  # viser 1.1.1
        except AttributeError:
            return None

    def _query(self, client) -> dict[str, str]:
        """The query string of the tab's websocket URL."""
        conn = self._connection(client)
        path = conn.request.path if conn is not None and conn.request is not None else ""
        return {k: v[-1] for k, v in parse_qs(urlsplit(path).query).items()}

    def _connect(self, client) -> None:
        try:
            self.sessions[client.client_id] = Session(self, client, self._query(client))
        except Exception:  # a broken run must not take the viewer down
            log.exception("could not open a viewer session")
            client.gui.add_markdown("**modsat viewer**: could not open this view; see the server log.")

    def stop(self) -> None:
        self._clock.stop()
        self.server.stop()
