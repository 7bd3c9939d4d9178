"""The live viewer: a viser server where each browser tab picks finished runs, sees the
designed satellites and plays back their evaluation slews with time plots beside them.

Every connected browser gets its own session (``client.scene`` / ``client.gui``): what one
person picks or plays does not move anyone else's view. The runs come from a
:class:`RunSource`: the job store under ``modsat serve`` (server/viewer.py), or run
directories under ``modsat view``. A tab may pre-select through the query string of its
websocket URL (the web page embeds viser's client with
``?websocket=ws://HOST:PORT/?run=KEY&compare=KEY&controller=pd_baseline&episode=2&t=1.5``).
"""

from __future__ import annotations

import contextlib
import inspect
import logging
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import parse_qs, urlsplit

import numpy as np

from modsat_core.grid import describe

from .origin import host_allowed, host_names, origin_allowed
from .run import CONTROLLERS, Episode, RunData, sample_period
from .scene import draw_satellite, lay_out

log = logging.getLogger("modsat.viewer")

NONE = "(none)"
SPEEDS = {"0.25x": 0.25, "0.5x": 0.5, "1x": 1.0, "2x": 2.0, "4x": 4.0}
TICK_S = 0.05  # playback frame period (wall time)


class RunSource(Protocol):
    """Where the viewer finds runs. Keys are strings (a job id, a directory's index)."""

    def choices(self) -> list[tuple[str, str]]:
        """(key, label) of the runs that can be shown, newest first."""

    def load(self, key: str) -> RunData:
        """The run ``key``; raises KeyError if there is no such run."""

    def defaults(self, choices: list[tuple[str, str]]) -> tuple[str | None, str | None]:
        """The runs a new tab shows when it asks for none, given ``choices()``: (main, compare or None)."""


class DirRuns:
    """Runs from directories written by ``modsat train --out DIR`` (keys "1", "2", ...)."""

    def __init__(self, paths: list[str | Path]):
        self.paths = [Path(p) for p in paths]
        self._runs = [RunData.from_dir(p) for p in self.paths]  # fail early on a bad directory

    def choices(self) -> list[tuple[str, str]]:
        return [(str(i + 1), f"{p.name} ({r.short_algorithm})") for i, (p, r) in enumerate(zip(self.paths, self._runs))]

    def load(self, key: str) -> RunData:
        try:
            i = int(key) - 1
        except ValueError:
            raise KeyError(key) from None
        if not 0 <= i < len(self._runs):
            raise KeyError(key)
        return self._runs[i]

    def defaults(self, choices: list[tuple[str, str]]) -> tuple[str | None, str | None]:
        return (choices[0][0] if choices else None, choices[1][0] if len(choices) > 1 else None)


def _series(ep: Episode | None, times: np.ndarray, what: str) -> np.ndarray:
    """Values of ``what`` at ``times`` (hold-last beyond the end of the episode)."""
    if ep is None or not len(ep.t_s):
        return np.full(len(times), np.nan)
    v = {"error": ep.error_deg, "rate": ep.rate_rad_s, "momentum": ep.wheel_momentum_Nms}[what]
    return v[ep.indices_at(times + ep.t_s[0])].astype(np.float64)


PLOTS = (
    ("error", "error angle (deg)"),
    ("rate", "body rate |omega| (rad/s)"),
    ("momentum", "wheel momentum |h| (N m s)"),
)


class Session:
    """One browser tab: its GUI, its scene and its playback state."""

    def __init__(self, app: ViewerApp, client, query: dict[str, str]):
        self.app, self.client = app, client
        self.lock = threading.RLock()
        self.runs: list[RunData] = []  # main, then the compared run
        self.sats: list = []
        self.t = 0.0
        self.duration = 0.0
        self.playing = False
        self.speed = 1.0
        self._build_gui()
        self._start(query)

    # ------------------------------------------------------------------ gui
    def _build_gui(self) -> None:
        gui = self.client.gui
        gui.configure_theme(control_width="medium", show_share_button=False)
        gui.main_panel.dock_right()  # the panel beside the scene, not over it
        self.title = gui.add_markdown("**modsat viewer**")
        with gui.add_folder("Runs"):
            self.run_dd = gui.add_dropdown("Run", [NONE], hint="A finished run: its satellite and slews.")
            self.cmp_dd = gui.add_dropdown(
                "Compare with", [NONE], hint="A second run side by side (e.g. RL vs GA), same slews."
            )
            self.refresh_btn = gui.add_button("Refresh list", hint="Look for newly finished runs.")
        with gui.add_folder("Playback"):
            self.ctrl_dd = gui.add_dropdown(
                "Controller",
                list(CONTROLLERS.values()),
                hint="The trained policy, or the PD baseline on the same design.",
            )
            self.ep_dd = gui.add_dropdown("Slew", ["-"], hint="A recorded evaluation slew (same seeds in every run).")
            self.time_sl = gui.add_slider("Time (s)", min=0.0, max=1.0, step=0.01, initial_value=0.0)
            self.play_btn = gui.add_button("Play", hint="Play / pause the slew.")
            self.speed_dd = gui.add_dropdown("Speed", list(SPEEDS), initial_value="1x")
            self.readout = gui.add_markdown("")
        with gui.add_folder("Time plots"):
            empty = (np.zeros(2), np.zeros(2))
            self.plots = {
                key: gui.add_uplot(
                    data=empty,
                    series=({"label": "t (s)"}, {"label": "-"}),
                    title=title,
                    scales={"x": {"time": False}},
                    aspect=2.2,
                )
                for key, title in PLOTS
            }
        with gui.add_folder("Design and evaluation"):
            self.info = gui.add_markdown("")

        self.run_dd.on_update(lambda _: self._guarded(self._runs_changed))
        self.cmp_dd.on_update(lambda _: self._guarded(self._runs_changed))
        self.refresh_btn.on_click(lambda _: self._guarded(self._refresh_choices))
        self.ctrl_dd.on_update(lambda _: self._guarded(self._controller_changed))
        self.ep_dd.on_update(lambda _: self._guarded(self._episode_changed))
        self.time_sl.on_update(lambda _: self._guarded(lambda: self._show_time(self.time_sl.value)))
        self.play_btn.on_click(lambda _: self._guarded(self._toggle_play))
        self.speed_dd.on_update(lambda _: setattr(self, "speed", SPEEDS.get(self.speed_dd.value, 1.0)))

    def _guarded(self, fn) -> None:
        try:
            with self.lock:
                fn()
        except Exception as exc:  # show it in the tab, keep the viewer alive
            log.exception("viewer session error")
            with contextlib.suppress(Exception):
                self.readout.content = f"**error:** {type(exc).__name__}: {exc}"

    # ------------------------------------------------------------------ selection
    def _start(self, query: dict[str, str]) -> None:
        choices = self.app.source.choices()  # read once: under `modsat serve` it queries the job store
        main, cmp_ = self.app.source.defaults(choices)
        main = query.get("run", main)
        cmp_ = query.get("compare", cmp_ if "run" not in query else None)
        with self.lock:
            self._set_choices(main, cmp_, choices)
            ctrl = query.get("controller")
            if ctrl in CONTROLLERS:
                self.ctrl_dd.value = CONTROLLERS[ctrl]
            self._runs_changed()
            ep = query.get("episode", "")
            if ep.isdigit() and 1 <= int(ep) <= len(self.ep_dd.options) and self.ep_dd.options[0] != "-":
                self.ep_dd.value = self.ep_dd.options[int(ep) - 1]
            try:
                t = float(query.get("t", "nan"))
            except ValueError:
                t = float("nan")
            if np.isfinite(t):
                self.time_sl.value = float(min(max(t, 0.0), self.duration))
            self.playing = query.get("play") == "1"
            self.play_btn.label = "Pause" if self.playing else "Play"

    def _set_choices(self, main: str | None, cmp_: str | None, choices: list[tuple[str, str]]) -> None:
        self.keys = dict(choices)  # key -> label, newest first
        for k in (main, cmp_):  # asked for by key but not in the list (e.g. an old job): add it
            if k is not None and k not in self.keys:
                try:
                    run = self.app.load(k)
                except KeyError:
                    continue
                self.keys[k] = f"{run.title} ({run.short_algorithm})"
        self.key_of = {label: key for key, label in self.keys.items()}
        labels = list(self.keys.values()) or [NONE]
        self.run_dd.options = labels
        self.cmp_dd.options = [NONE, *self.keys.values()]
        if main in self.keys:
            self.run_dd.value = self.keys[main]
        self.cmp_dd.value = self.keys[cmp_] if cmp_ in self.keys and cmp_ != main else NONE

    def _refresh_choices(self) -> None:
        main, cmp_ = self.key_of.get(self.run_dd.value), self.key_of.get(self.cmp_dd.value)
        self._set_choices(main, cmp_, self.app.source.choices())

    def _runs_changed(self) -> None:
        keys = [self.key_of.get(self.run_dd.value)]
        c = self.key_of.get(self.cmp_dd.value)
        if c is not None and c != keys[0]:
            keys.append(c)
        runs = []
        for k in keys:
            if k is None:
                continue
            try:
                runs.append(self.app.load(k))
            except KeyError:
                continue
        self.runs = runs
        self._draw()
        self._controller_changed()

    def _controller_changed(self) -> None:
        """The slews of the chosen controller (described from the main run's), then show one."""
        c = self._controller()
        n = max([len(r.episodes.get(c, [])) for r in self.runs] + [0])
        first = self.runs[0].episodes.get(c, []) if self.runs else []
        opts = [f"{i + 1}: {first[i].describe()}" if i < len(first) else f"{i + 1}" for i in range(n)] or ["-"]
        number = self.ep_dd.value.split(":")[0]
        keep = next((o for o in opts if o.split(":")[0] == number), opts[0])  # same slew number if it exists
        self.ep_dd.options = opts
        self.ep_dd.value = keep
        self._episode_changed()

    def _controller(self) -> str:
        return next((k for k, v in CONTROLLERS.items() if v == self.ctrl_dd.value), "policy")

    def _episodes(self) -> list[Episode | None]:
        try:
            i = int(self.ep_dd.value.split(":")[0]) - 1
        except ValueError:
            return [None for _ in self.runs]
        c = self._controller()
        return [r.episodes.get(c, [])[i] if i < len(r.episodes.get(c, [])) else None for r in self.runs]

    # ------------------------------------------------------------------ drawing
    def _draw(self) -> None:
        scene = self.client.scene
        with self.client.atomic():
            self.sats = []
            for name, run in zip("AB", self.runs):
                label = f"{run.short_algorithm}: {run.title}"
                self.sats.append(draw_satellite(scene, f"/{name}", run.grid, label=label))
            if len(self.runs) < 2:
                scene.remove_by_name("/B")
            if not self.runs:
                scene.remove_by_name("/A")
            self.client.camera.position = lay_out(scene, ["/A", "/B"][: len(self.sats)], self.sats, min_radius=1.5)
            self.client.camera.look_at = (0.0, 0.0, 0.0)
        self.title.content = self._title()
        self.info.content = self._info()

    def _title(self) -> str:
        if not self.runs:
            return "**modsat viewer**: no finished run yet. Refresh the list once a job has succeeded."
        names = " vs ".join(f"{r.short_algorithm} ({r.title})" for r in self.runs)
        return f"**modsat viewer**: {names}"

    def _info(self) -> str:
        lines = [
            "Grey cubes: structure modules; orange cubes: reaction-wheel actuators. "
            "Thick axes: body frame (x red, y green, z blue); faint copy: target attitude.",
            "",
        ]
        for r in self.runs:
            mass = r.design.mass_kg
            lines.append(
                f"**{r.short_algorithm}: {r.title}**: {describe(r.modules, r.actuators)}"
                + (f", {mass:.1f} kg" if mass is not None else "")
            )
            ev = r.evaluation
            for c, name in ((ev and ev.policy, "policy"), (ev and ev.pd_baseline, "PD baseline")):
                if c:
                    s = c.summary
                    lines.append(
                        f"- {name}: success {100 * s.success_rate:.0f} % of "
                        f"{s.episodes} slews, mean return {s.mean_return or 0:.1f}"
                    )
            lines.append("")
        return "\n".join(lines)

    def _episode_changed(self) -> None:
        eps = self._episodes()
        live = [e for e in eps if e is not None and len(e.t_s)]
        self.duration = max([e.duration_s for e in live] + [0.0])
        dt = sample_period(live)
        with self.client.atomic():
            for sat, e in zip(self.sats, eps):
                if e is not None and len(e.t_s):
                    sat.set_attitude(e.q_BN[0], e.q_TN)
            self.time_sl.max = max(self.duration, dt)
            self.time_sl.step = float(round(dt, 4)) or 0.01
        times = np.arange(0.0, self.duration + 1e-9, dt) if live else np.zeros(1)
        names = [f"{r.short_algorithm}: {r.title}" for r in self.runs]
        colors = ["#ff7f0e", "#1f77b4"]
        for key, plot in self.plots.items():
            ys = tuple(_series(e, times, key) for e in eps)
            plot.series = ({"label": "t (s)"}, *({"label": n, "stroke": c, "width": 2} for n, c in zip(names, colors)))
            plot.data = (times, *ys) if ys else (times, np.zeros(len(times)))
        self.t = -1.0
        if self.time_sl.value != 0.0:
            self.time_sl.value = 0.0
        else:
            self._show_time(0.0)

    def _show_time(self, t: float) -> None:
        self.t = float(t)
        eps = self._episodes()
        parts = []
        with self.client.atomic():
            for sat, e, r in zip(self.sats, eps, self.runs):
                if e is None or not len(e.t_s):
                    continue
                i = e.index_at(self.t + float(e.t_s[0]))
                sat.body.wxyz = e.q_BN[i]
                # Side by side, each line names its run (both could be RL, or both GA).
                who = r.short_algorithm if len(self.runs) == 1 else f"{r.short_algorithm} {r.title}"
                parts.append(
                    f"**{who}** error {e.error_deg[i]:.1f} deg, rate "
                    f"{e.rate_rad_s[i]:.3f} rad/s, wheels {e.wheel_momentum_Nms[i]:.4f} N m s"
                    + (" (episode over)" if self.t > e.duration_s + 1e-9 else "")
                )
        self.readout.content = f"t = {self.t:.2f} s  \n" + "  \n".join(parts)

    # ------------------------------------------------------------------ playback
    def _toggle_play(self) -> None:
        if not self.playing and self.t >= self.duration - 1e-9:
            self.time_sl.value = 0.0
        self.playing = not self.playing
        self.play_btn.label = "Pause" if self.playing else "Play"

    def tick(self, dt_wall: float) -> None:
        if not self.playing:
            return
        with self.lock:
            t = min(self.duration, self.t + dt_wall * self.speed)
            if t >= self.duration:
                self.playing = False
                self.play_btn.label = "Play"
            self.time_sl.value = float(round(t, 4))


_PATCH_LOCK = threading.Lock()


@contextlib.contextmanager
def _checked_handshakes(check: Callable[[Any, Any], Any]) -> Iterator[None]:
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
        with _checked_handshakes(self._handshake):
            self.server = viser.ViserServer(host=host, port=port, label=label)
        self.server.scene.set_up_direction("+z")
        self.sessions: dict[int, Session] = {}
        self._cache: OrderedDict[str, RunData] = OrderedDict()
        self._cache_size = cache_size
        self._cache_lock = threading.Lock()
        self._stop = threading.Event()
        self.server.on_client_connect(self._connect)
        # viser's stub wants a callback returning None; it drops a sync callback's return value (the session).
        self.server.on_client_disconnect(lambda client: self.sessions.pop(client.client_id, None))  # type: ignore[type-var]
        self._ticker = threading.Thread(target=self._tick_loop, name="modsat-viewer-playback", daemon=True)
        self._ticker.start()

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

    def _refused(self, headers) -> tuple[int, str] | None:
        """Why a request may not be answered, as (HTTP status, reason): a repeated ``Host``,
        ``Origin`` or ``Upgrade`` header, a foreign Host (DNS rebinding: for the page and the
        websocket alike) or a websocket from a page of another site. ``headers``: websockets'."""
        for name in ("Host", "Origin", "Upgrade"):
            if len(headers.get_all(name)) > 1:
                return 400, f"more than one {name} header"
        host = headers.get("Host")
        if not host_allowed(host, self.host_names):
            return 400, f"host {(host or '')[:100]!r} is not one this viewer answers to"
        origin = headers.get("Origin")
        if (headers.get("Upgrade") or "").lower() == "websocket" and not origin_allowed(origin, self.host_names):
            return 403, f"a page of another site ({origin[:100]!r})"
        return None

    def _handshake(self, connection, request):
        """websockets' ``process_request``, before viser's: a refused request gets its HTTP error
        instead of the page or the websocket's 101 (no session, no message of the scene)."""
        refused = self._refused(request.headers)
        if refused is None:
            return None
        status, why = refused
        what = "a websocket" if (request.headers.get("Upgrade") or "").lower() == "websocket" else "a request"
        log.warning("viewer: refused %s: %s", what, why)
        return connection.respond(status, f"refused: {why}\n")

    def _connect(self, client) -> None:
        try:
            self.sessions[client.client_id] = Session(self, client, self._query(client))
        except Exception:  # a broken run must not take the viewer down
            log.exception("could not open a viewer session")
            client.gui.add_markdown("**modsat viewer**: could not open this view; see the server log.")

    def _tick_loop(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(TICK_S):
            now = time.monotonic()
            for s in list(self.sessions.values()):
                try:
                    s.tick(now - last)
                except Exception:  # a closed tab: forget it
                    log.debug("playback tick failed", exc_info=True)
            last = now

    def stop(self) -> None:
        self._stop.set()
        self.server.stop()
