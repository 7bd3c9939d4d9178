"""The 3D viewer of modsat runs (viser): scene drawing, the `.viser` recording of a run's
evaluation slews, and the live viewer app used by ``modsat serve`` and ``modsat view``.

A leaf package: it needs numpy and viser, reads a run's stored JSON artefacts
(``design.json``, ``trajectories.json``, ``evaluation.json``, ``spec.json``) and never
imports torch, the job store or the web server, so that the worker (which stores the
recording) and the server (which runs the live viewer) can both use it. docs/viewer.md.

- ``run.py``: a run's data as the viewer reads it (:class:`RunData`, :class:`Episode`).
- ``scene.py``: drawing a satellite and laying runs out side by side.
- ``recording.py``: the ``.viser`` recording of a run's evaluation slews (the one owner of its format).
- ``origin.py``: which pages may talk to a modsat server (Host / Origin); the live viewer's guard
  and the API's (server/security.py) both use it.
- ``live/``: the live viewer app, one session per browser tab.
"""

from .run import Episode, RunData

__all__ = ["Episode", "RunData"]
