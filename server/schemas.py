"""The REST API's public models, and the conversion of store rows into them."""

from __future__ import annotations

import json
import re
from datetime import datetime, timezone
from typing import Annotated, Any, Literal

from fastapi import Path
from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, ValidationError

from modsat_core.artefacts import CurvePoint, ProgressRecord, RunSummary
from modsat_core.spec.jobspec import JobSpec
from modsat_core.spec.presets import PRESETS
from modsat_core.spec.sections import Mission
from modsat_core.spec.study import ALGORITHMS, DEFAULT_ALGORITHMS, MAX_SEEDS

JobStatus = Literal["queued", "running", "succeeded", "failed", "cancelled"]


def _digits(value: Any) -> Any:
    """An id in a path, or a count in a query, is written in digits: ``1.0``, ``1e0`` or ``+1``
    are refused (pydantic's lax mode would read them as 1)."""
    if isinstance(value, str) and not re.fullmatch(r"-?[0-9]+", value):
        raise ValueError("a whole number written in digits, e.g. 12")
    return value


#: For an integer in a path or a query: digits only (:func:`_digits`).
Digits = BeforeValidator(_digits)
JobId = Annotated[int, Digits, Path(description="The job's id.")]
StudyId = Annotated[int, Digits, Path(description="The study's id.")]


def clip(text: str, limit: int = 100) -> str:
    """``text`` quoted for an error message, cut to ``limit`` characters: an error does not
    echo a long request back."""
    return repr(text) if len(text) <= limit else f"{text[:limit]!r}... ({len(text)} characters)"


_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def safe_file_name(text: str, limit: int = 100) -> str:
    """``text`` as a file name any file system (and a ``Content-Disposition`` header) takes: each run of
    other characters than letters, digits, ``.``, ``_`` and ``-`` becomes ``-``, no ``-`` or ``.`` at
    either end, at most ``limit`` characters; empty if nothing is left."""
    return _UNSAFE.sub("-", text).strip("-.")[:limit].strip("-.")


def _time(t: float | None) -> datetime | None:
    return None if t is None else datetime.fromtimestamp(float(t), tz=timezone.utc)


def _json(text: str | None) -> Any:
    return None if text is None else json.loads(text)


class PresetSubmission(BaseModel):
    """Submit a named preset, optionally with some fields changed."""

    model_config = ConfigDict(
        extra="forbid",
        # Each example fits a job and a study's spec alike (a study flies it with TD3 and the GA by
        # default): `quick` as it stands is a first-order preset whose budget, flown so, is over the
        # work bound (422), which schemathesis found in a study assembled from these examples.
        json_schema_extra={
            "examples": [
                {"preset": "quick-td3"},
                {"preset": "quick", "overrides": {"seed": 3, "training": {"total_env_steps": 10000}}},
            ]
        },
    )

    preset: str = Field(description="Name of a preset (GET /api/presets).", json_schema_extra={"enum": list(PRESETS)})
    overrides: dict[str, Any] | None = Field(
        default_factory=dict,
        description="Fields of the spec to change, nested like the spec; merged into the preset (null: none).",
    )


class Progress(BaseModel):
    env_steps: int = Field(description="Environment steps done (as last reported by the training).")
    total_env_steps: int
    fraction: float = Field(description="env_steps / total_env_steps, between 0 and 1.")
    phase: str | None = Field(description="starting | training | evaluating | done, or null.")
    checkpoint_env_steps: int | None = Field(description="Where a resumed attempt starts from.")
    run_seconds: float = Field(description="Wall time of the finished attempts.")


class JobSummary(BaseModel):
    """A job as lists show it."""

    id: int
    name: str | None
    algorithm: str
    status: JobStatus
    created_at: datetime
    updated_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    attempt: int = Field(description="Attempts started so far (also the fencing token of the current one).")
    failures: int = Field(description="Failed attempts (error, crash, lost lease).")
    max_attempts: int = Field(description="Failed attempts allowed before the job is `failed`.")
    cancel_requested: bool
    worker_id: str | None
    lease_expires_at: datetime | None
    progress: Progress
    last_eval: CurvePoint | None = Field(description="The latest learning-curve point.")
    error: str | None
    url: str


class MetricsPoint(ProgressRecord):
    """One progress report: the training's record plus the row's bookkeeping."""

    seq: int = Field(description="Per-job sequence number, 1, 2, 3, ...")
    attempt: int
    time: datetime


class AttemptInfo(BaseModel):
    attempt: int
    worker_id: str
    started_at: datetime
    ended_at: datetime | None
    outcome: str = Field(description="running | succeeded | failed | crashed | lease-expired | cancelled | released")
    resumed_from_env_steps: int | None
    error: str | None


class JobDetail(JobSummary):
    """Everything about one job."""

    spec: dict[str, Any]
    control_dt_s: float | None = Field(
        None,
        description="The spec's control step, s (`Mission.control_dt_s`: the physics step times the frame skip); "
        "null for a spec this version cannot read.",
    )
    latest_metrics: MetricsPoint | None
    evaluation: RunSummary | None = Field(description="Summary of the final Monte-Carlo evaluation.")
    error_detail: str | None = Field(description="Traceback of the last failed attempt.")
    attempts: list[AttemptInfo]
    links: dict[str, str]


class JobList(BaseModel):
    total: int = Field(description="Jobs matching the filter.")
    limit: int
    offset: int
    next_offset: int | None = Field(description="Offset of the next page, null on the last one.")
    next_before_id: int | None = Field(
        None,
        description="Cursor of the next page (pass as `before_id`), null on the last one. Unlike offsets, "
        "cursor pages do not shift when jobs are submitted meanwhile.",
    )
    items: list[JobSummary]


class MetricsPage(BaseModel):
    job_id: int
    status: JobStatus
    after: int
    last_seq: int = Field(description="Pass this as `after` to get what comes next.")
    more: bool = Field(description="True if the limit cut the page short.")
    items: list[MetricsPoint]


class ArtifactInfo(BaseModel):
    name: str
    kind: Literal["output", "checkpoint"]
    size: int
    sha256: str
    content_type: str
    attempt: int
    created_at: datetime
    url: str


class CancelResult(BaseModel):
    message: str
    job: JobDetail


class RunTimeInfo(BaseModel):
    """One measured time per run of a preset (modsat_core.spec.preset_times)."""

    time: str = Field(description='A figure or a range with its unit, e.g. "68-75 s" or "207-242 s training".')
    cpu: str = Field(description='The CPU it was measured on, e.g. "AMD EPYC".')


class PresetInfo(BaseModel):
    name: str
    algorithm: str
    grid_size: int
    total_env_steps: int
    url: str
    time_per_run: list[RunTimeInfo] = Field(
        default_factory=list,
        description="How long a run took, as measured, one entry per CPU kind (the README's table); empty: "
        "not measured here.",
    )
    time_text: str = Field(description='`time_per_run` as one line, e.g. "68-75 s (AMD EPYC)", or "not measured here".')
    time_measured: str = Field(description="How the times were measured (threads, runs at a time, cores).")


class Health(BaseModel):
    status: Literal["ok"]
    version: str
    database: str
    jobs: dict[str, int]
    workers: list[dict[str, Any]]


def progress_of(row: dict[str, Any]) -> Progress:
    total = int(row["total_env_steps"] or 0)
    steps = int(row["env_steps"] or 0)
    # A finished run may stop up to num_envs - 1 steps short of its budget (whole batches).
    fraction = 1.0 if row.get("status") == "succeeded" else (min(1.0, steps / total) if total else 0.0)
    return Progress(
        env_steps=steps,
        total_env_steps=total,
        fraction=fraction,
        phase=row["phase"],
        checkpoint_env_steps=row["checkpoint_env_steps"],
        run_seconds=round(float(row["run_seconds"] or 0.0), 3),
    )


def job_summary(row: dict[str, Any]) -> JobSummary:
    return JobSummary(
        id=row["id"],
        name=row["name"],
        algorithm=row["algorithm"],
        status=row["status"],
        created_at=_time(row["created_at"]),
        updated_at=_time(row["updated_at"]),
        started_at=_time(row["started_at"]),
        finished_at=_time(row["finished_at"]),
        attempt=row["attempt"],
        failures=row["failures"],
        max_attempts=row["max_attempts"],
        cancel_requested=bool(row["cancel_requested"]),
        worker_id=row["worker_id"],
        lease_expires_at=_time(row["lease_expires_at"]),
        progress=progress_of(row),
        last_eval=_json(row["last_eval"]),
        error=row["error"],
        url=f"/api/jobs/{row['id']}",
    )


def metrics_point(row: dict[str, Any]) -> MetricsPoint:
    data = json.loads(row["data"])
    data.pop("seq", None)
    data.pop("attempt", None)
    data.pop("time", None)
    data["env_steps"] = row["env_steps"]
    return MetricsPoint(seq=row["seq"], attempt=row["attempt"], time=_time(row["created_at"]), **data)


def _control_dt_s(spec: Any) -> float | None:
    try:
        return Mission.model_validate(spec.get("mission", {})).control_dt_s
    except (AttributeError, ValidationError):
        return None


def job_detail(row: dict[str, Any], latest: dict[str, Any] | None, attempts: list[dict[str, Any]]) -> JobDetail:
    base = job_summary(row).model_dump()
    jid = row["id"]
    spec = json.loads(row["spec"])
    return JobDetail(
        **base,
        spec=spec,
        control_dt_s=_control_dt_s(spec),
        latest_metrics=metrics_point(latest) if latest else None,
        evaluation=_json(row["summary"]),
        error_detail=row["error_detail"],
        attempts=[
            AttemptInfo(**{**a, "started_at": _time(a["started_at"]), "ended_at": _time(a["ended_at"])})
            for a in attempts
        ],
        links={
            "self": f"/api/jobs/{jid}",
            "metrics": f"/api/jobs/{jid}/metrics",
            "events": f"/api/jobs/{jid}/events",
            "artifacts": f"/api/jobs/{jid}/artifacts",
            "cancel": f"/api/jobs/{jid}/cancel",
        },
    )


def artifact_info(job_id: int, row: dict[str, Any]) -> ArtifactInfo:
    return ArtifactInfo(
        name=row["name"],
        kind=row["kind"],
        size=row["size"],
        sha256=row["sha256"],
        content_type=row["content_type"],
        attempt=row["attempt"],
        created_at=_time(row["created_at"]),
        url=f"/api/jobs/{job_id}/artifacts/{row['name']}",
    )


# ----------------------------------------------------------------------------- studies (/api/studies)


class StudySubmission(BaseModel):
    """A study: ``spec`` (a JobSpec, or ``{"preset": NAME, "overrides": {...}}``) flown once per
    seed and algorithm; every job is the spec with its own ``seed`` and ``algorithm``."""

    model_config = ConfigDict(extra="forbid")  # as the server reads it: an unknown field is 422

    spec: dict[str, Any] = Field(description='A JobSpec, or {"preset": NAME, "overrides": {...}}.')
    seeds: list[Annotated[int, Field(ge=0, lt=2**31)]] = Field(
        min_length=1,
        max_length=MAX_SEEDS,
        description=f"1 to {MAX_SEEDS} distinct seeds.",
        examples=[[0, 1, 2]],
        json_schema_extra={"uniqueItems": True},
    )
    algorithms: list[Literal[ALGORITHMS]] = Field(  # type: ignore[valid-type]
        default=list(DEFAULT_ALGORITHMS),
        min_length=1,
        description="RL co-design and/or its GA twin (or the controllers of a fixed design); distinct.",
        json_schema_extra={"uniqueItems": True},
    )


class StudyJob(BaseModel):
    id: int
    url: str
    algorithm: str
    seed: int
    status: JobStatus
    env_steps: int
    total_env_steps: int
    run_seconds: float
    last_eval: CurvePoint | None
    error: str | None


class StudySummary(BaseModel):
    id: int
    name: str | None
    seeds: list[int]
    algorithms: list[str]
    created_at: datetime
    counts: dict[str, int] = Field(description="Its jobs per status.")
    url: str


class StudyList(BaseModel):
    total: int
    limit: int
    offset: int
    items: list[StudySummary]


class StudyDetail(StudySummary):
    spec: JobSpec
    status: Literal["queued", "running", "ended"] = Field(description="`ended` once every job has ended.")
    jobs: list[StudyJob]
    aggregate: dict[str, Any] = Field(
        description="Per method: final Monte-Carlo figures of its finished runs (mean, std, n over seeds), PD on "
        "their designs, the designs' symmetry numbers, and the learning curves (mean and std over seeds)."
    )
    table_markdown: str
    figure_url: str


# ----------------------------------------------------------------------------- the viewer (/api/viewer)


class ViewerInfo(BaseModel):
    enabled: bool = Field(description="Whether the live viewer runs in this server.")
    port: int | None = Field(description="The port it really listens on (same host as the API).")
    client: str = Field(description="Path of viser's static client on this server (live and recordings).")
    recording: str = Field(description="Artefact name of a finished job's .viser recording.")
