"""``/api/presets``, ``/api/schema`` and ``/api/health``: the named specs, the spec's JSON schema and
the service's state (database, jobs per status, live workers)."""

from __future__ import annotations

from typing import Any

from fastapi import APIRouter, HTTPException

import modsat_core
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.preset_times import HOW_MEASURED, run_time_text, run_times
from modsat_core.spec.presets import PRESETS

from ..deps import StoreDep
from ..schemas import Health, PresetInfo, RunTimeInfo, clip


def service_router() -> APIRouter:
    """A new router of the presets, the spec's schema and the health check (one per app)."""
    r = APIRouter(prefix="/api")

    @r.get("/presets", response_model=list[PresetInfo], tags=["specs"])
    def list_presets() -> list[PresetInfo]:
        """The named specs, each with its measured time per run (CPU named). Submit one with
        `{"preset": NAME}`."""
        return [
            PresetInfo(
                name=n,
                algorithm=s.algorithm,
                grid_size=s.design.grid_size,
                total_env_steps=s.training.total_env_steps,
                url=f"/api/presets/{n}",
                time_per_run=[RunTimeInfo(time=t.time, cpu=t.cpu) for t in run_times(n)],
                time_text=run_time_text(n),
                time_measured=HOW_MEASURED,
            )
            for n, s in PRESETS.items()
        ]

    @r.get("/presets/{name}", response_model=JobSpec, tags=["specs"], responses={404: {"description": "Unknown"}})
    def get_preset(name: str) -> JobSpec:
        """One preset as a whole JobSpec (edit it and POST it to /api/jobs)."""
        if name not in PRESETS:
            raise HTTPException(404, f"no preset named {clip(name)}; known: {', '.join(PRESETS)}")
        return PRESETS[name]

    @r.get("/schema", tags=["specs"])
    def spec_schema() -> dict[str, Any]:
        """The JSON schema of JobSpec (every field, its bounds and its description)."""
        return JobSpec.model_json_schema()

    @r.get("/health", response_model=Health, tags=["service"], responses={503: {"description": "Database down"}})
    def health(store: StoreDep) -> Health:
        """Database reachable, jobs per status, live workers."""
        workers = store.live_workers()
        return Health(
            status="ok",
            version=modsat_core.__version__,
            database=store.backend,
            jobs=store.status_counts(),
            workers=[{k: w[k] for k in ("id", "hostname", "pid", "runner", "job_id")} for w in workers],
        )

    return r
