"""One browser tab of the live viewer: its controls (viser's per-client GUI), the runs it
shows side by side in its own scene, and the slew it plays. A tab never moves another's view."""

from __future__ import annotations

import contextlib
import logging
import threading
from typing import Protocol

import numpy as np

from ..run import CONTROLLERS, Episode, RunData, sample_period
from ..scene import draw_satellite, lay_out
from .playback import SPEEDS
from .readouts import (
    PLOTS,
    design_and_evaluation,
    heading,
    plot_legend,
    readout_line,
    run_label,
    series,
    slew_options,
)
from .sources import RunSource

log = logging.getLogger("modsat.viewer")

NONE = "(none)"


class Viewer(Protocol):
    """What a session uses of the viewer app (app.py): the run list, and runs through its cache."""

    source: RunSource

    def load(self, key: str) -> RunData: ...


class Session:
    """One browser tab: its GUI, its scene and its playback state."""

    def __init__(self, app: Viewer, client, query: dict[str, str]):
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
        opts = slew_options(self.runs, self._controller())
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
                self.sats.append(
                    draw_satellite(scene, f"/{name}", run.grid, label=run_label(run), payload=run.payload_cells)
                )
            if len(self.runs) < 2:
                scene.remove_by_name("/B")
            if not self.runs:
                scene.remove_by_name("/A")
            self.client.camera.position = lay_out(scene, ["/A", "/B"][: len(self.sats)], self.sats, min_radius=1.5)
            self.client.camera.look_at = (0.0, 0.0, 0.0)
        self.title.content = heading(self.runs)
        self.info.content = design_and_evaluation(self.runs)

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
        for key, plot in self.plots.items():
            ys = tuple(series(e, times, key) for e in eps)
            plot.series = plot_legend(self.runs)
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
                parts.append(readout_line(r, e, i, self.t, alone=len(self.runs) == 1))
        self.readout.content = f"t = {self.t:.2f} s  \n" + "  \n".join(parts)

    # ------------------------------------------------------------------ playback
    def _toggle_play(self) -> None:
        if not self.playing and self.t >= self.duration - 1e-9:
            self.time_sl.value = 0.0
        self.playing = not self.playing
        self.play_btn.label = "Pause" if self.playing else "Play"

    def tick(self, dt_wall: float) -> None:
        """Move the slew on by ``dt_wall`` seconds of wall time at the tab's speed (the playback
        clock calls it); stop at the end."""
        if not self.playing:
            return
        with self.lock:
            t = min(self.duration, self.t + dt_wall * self.speed)
            if t >= self.duration:
                self.playing = False
                self.play_btn.label = "Play"
            self.time_sl.value = float(round(t, 4))
