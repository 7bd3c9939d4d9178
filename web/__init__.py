"""The 3D viewer of modsat runs (viser): scene drawing, the `.viser` recording of a run's
evaluation slews, and the live viewer app used by ``modsat serve`` and ``modsat view``.

A leaf package: it needs numpy and viser, reads a run's stored JSON artefacts
(``design.json``, ``trajectories.json``, ``evaluation.json``, ``spec.json``) and never
imports torch, the job store or the web server, so that the worker (which stores the
recording) and the server (which runs the live viewer) can both use it. docs/viewer.md.
"""

from .run import Episode, RunData

__all__ = ["Episode", "RunData"]
