"""The live viewer: a viser server where each browser tab picks finished runs, sees the
designed satellites and plays back their evaluation slews with time plots beside them.

Every connected browser gets its own session (``client.scene`` / ``client.gui``): what one
person picks or plays does not move anyone else's view. The runs come from a
:class:`RunSource`: the job store under ``modsat serve`` (server/hosting.py), or run
directories under ``modsat view``. A tab may pre-select through the query string of its
websocket URL (the web page embeds viser's client with
``?websocket=ws://HOST:PORT/?run=KEY&compare=KEY&controller=pd_baseline&episode=2&t=1.5``).

One concept per module:

- ``app.py``: :class:`ViewerApp`, the viser server: one session per tab, the loaded runs.
- ``guard.py``: the Host / Origin check on every request, before viser answers it.
- ``sources.py``: where the runs come from (:class:`RunSource`, :class:`DirRuns`).
- ``session.py``: :class:`Session`, one tab: its controls, the runs it shows, the slew it plays.
- ``readouts.py``: what a tab writes about its runs (title, notes, readout, plot lines).
- ``playback.py``: the speeds and the clock that moves every playing tab on in wall time.
"""

from .app import ViewerApp
from .session import Session
from .sources import DirRuns, RunSource

__all__ = ["DirRuns", "RunSource", "Session", "ViewerApp"]
