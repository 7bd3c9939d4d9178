"""What the API process serves besides the API: the live 3D viewer, viser's client and the page.

* The live viewer (web.viewer.live) runs in the app's lifespan, in viser's own threads,
  on ``viewer_port`` (its real port: ``GET /api/viewer``). Its runs are the job store's
  succeeded jobs (:class:`StoreRuns`).
* ``/viser-client/`` serves viser's static client (one self-contained HTML file from the
  installed package). The web page embeds it with ``?websocket=ws://HOST:PORT/?run=ID``
  (the live viewer) or ``?playbackPath=/api/jobs/ID/artifacts/evaluation.viser`` (a
  recording, no Python viewer needed).
* ``/`` serves web/ (plain HTML, JS and CSS; nothing from a CDN).
"""

from __future__ import annotations

import logging
from pathlib import Path

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles

import web
from modsat_core.evaluation.run_folder import RunFolder
from web.viewer.run import RunData, learner_label

from .settings import ServerSettings

log = logging.getLogger("modsat.server")

#: The page, scripts and styles of the web UI (package data of ``web``).
WEB_STATIC_DIR = Path(web.__file__).resolve().parent / "static"
#: Artefacts a job needs to be shown in 3D.
NEEDED = ("design.json", "trajectories.json")


class StoreRuns:
    """The viewer's runs: succeeded jobs that have a design and trajectories (keys = job ids)."""

    def __init__(self, store, limit: int = 100):
        self.store, self.limit = store, limit

    def _rows(self) -> list[dict]:
        _, rows = self.store.list_jobs(statuses=["succeeded"], limit=self.limit, offset=0)
        return [r for r in rows if set(NEEDED) <= {a["name"] for a in self.store.list_artifacts(r["id"])}]

    def choices(self) -> list[tuple[str, str]]:
        out = []
        for r in self._rows():
            kind = learner_label(r["algorithm"] or "")
            out.append((str(r["id"]), f"#{r['id']} {r['name'] or r['algorithm']} ({kind})"))
        return out

    def load(self, key: str) -> RunData:
        try:
            job_id = int(key)
        except ValueError:
            raise KeyError(key) from None
        row = self.store.get_job(job_id)
        if row is None or row["status"] != "succeeded":
            raise KeyError(key)
        files = {n: self.store.read_artifact(job_id, n) for n in (*NEEDED, "evaluation.json", "spec.json")}
        if any(files[n] is None for n in NEEDED):
            raise KeyError(key)
        run = RunFolder(f"/api/jobs/{job_id}", files)
        return RunData.from_folder(run, title=f"job {job_id} {row['name'] or ''}".strip())

    def defaults(self, choices: list[tuple[str, str]]) -> tuple[str | None, str | None]:
        return (choices[0][0] if choices else None, None)


def start_viewer(settings: ServerSettings, store):
    """The live viewer on ``settings.viewer_port``, or None when it is disabled or cannot start."""
    if not settings.viewer:
        return None
    from web.viewer.live import ViewerApp

    try:
        app = ViewerApp(
            StoreRuns(store), host=settings.host, port=settings.viewer_port, allowed_hosts=settings.host_names()
        )
    except Exception:  # the API works without the viewer; say why it is missing
        log.exception("the 3D viewer could not start; the API runs without it")
        return None
    log.info("modsat: 3D viewer on port %d", app.port)
    return app


def mount_static(app: FastAPI, settings: ServerSettings) -> None:
    """viser's client at /viser-client/, web/ at / (mounted last: the API routes come first)."""
    import viser

    client_dir = Path(viser.__file__).resolve().parent / "client" / "build"
    app.mount("/viser-client", StaticFiles(directory=client_dir, html=True), name="viser-client")
    web = Path(settings.web_dir) if settings.web_dir else WEB_STATIC_DIR
    if web.is_dir():
        app.mount("/", StaticFiles(directory=web, html=True), name="web")
    else:
        log.warning("no web UI: %s is not a directory (set MODSAT_WEB_DIR)", web)
