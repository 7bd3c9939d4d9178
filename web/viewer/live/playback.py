"""Playback in wall time: the speeds a tab offers, and the clock thread that moves every
playing tab on (each tab keeps its own time; the clock only says how much wall time passed)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Iterable
from typing import Protocol

log = logging.getLogger("modsat.viewer")

SPEEDS = {"0.25x": 0.25, "0.5x": 0.5, "1x": 1.0, "2x": 2.0, "4x": 4.0}
TICK_S = 0.05  # playback frame period (wall time)


class Playing(Protocol):
    def tick(self, dt_wall: float) -> None:
        """Move on by ``dt_wall`` seconds of wall time, if playing."""


class PlaybackClock:
    """A daemon thread that calls ``tick(dt_wall)`` on each of ``targets()`` every ``TICK_S``
    of wall time, until :meth:`stop`."""

    def __init__(self, targets: Callable[[], Iterable[Playing]]):
        self._targets = targets
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="modsat-viewer-playback", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(TICK_S):
            now = time.monotonic()
            for s in list(self._targets()):
                try:
                    s.tick(now - last)
                except Exception:  # a closed tab: forget it
                    log.debug("playback tick failed", exc_info=True)
            last = now

    def stop(self) -> None:
        self._stop.set()
