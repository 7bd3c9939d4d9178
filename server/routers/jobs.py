"""``/api/jobs``: submit, list, get, metrics, events, cancel, artefacts. Routes stay short:
the SQL is in worker/store/."""

from __future__ import annotations

import asyncio
import json
import time
from typing import Annotated, Any

from fastapi import APIRouter, Header, HTTPException, Query, Request, Response
from fastapi.responses import JSONResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from worker.store import TERMINAL_STATUSES, QueueFull

from ..deps import SettingsDep, StoreDep, WriteAccess
from ..schemas import (
    ArtifactInfo,
    CancelResult,
    Digits,
    JobDetail,
    JobId,
    JobList,
    JobStatus,
    MetricsPage,
    artifact_info,
    clip,
    job_detail,
    job_summary,
    metrics_point,
    safe_file_name,
)
from ..submit import BadRequest, Invalid, invalid_response, job_from_body, json_content_type

router = APIRouter(prefix="/api/jobs", tags=["jobs"])

_SUBMIT_BODY = {
    "required": True,
    "content": {
        "application/json": {
            "schema": {
                "oneOf": [{"$ref": "#/components/schemas/JobSpec"}, {"$ref": "#/components/schemas/PresetSubmission"}]
            },
            "examples": {
                "preset": {"summary": "A preset", "value": {"preset": "quick"}},
                "preset-overrides": {
                    "summary": "A preset with changes",
                    "value": {"preset": "quick", "overrides": {"seed": 7}},
                },
            },
        }
    },
}
_ERRORS: dict[int | str, dict[str, Any]] = {404: {"description": "Unknown job"}}


def _unknown(job_id: int) -> HTTPException:
    return HTTPException(404, f"no job with id {job_id}")


def _detail(store, job_id: int) -> JobDetail | None:
    row = store.get_job(job_id)
    if row is None:
        return None
    return job_detail(row, store.latest_metrics(job_id), store.list_attempts(job_id))


@router.post(
    "",
    status_code=201,
    response_model=JobDetail,
    dependencies=[WriteAccess],
    openapi_extra={"requestBody": _SUBMIT_BODY},
    responses={
        400: {"description": "Body is not UTF-8 JSON"},
        401: {"description": "Missing or wrong bearer token"},
        413: {"description": "Body too large"},
        415: {"description": "Body not sent as `application/json` (UTF-8)"},
        422: {"description": "Invalid spec; `messages` name each field"},
        429: {"description": "The queue is full (`MODSAT_MAX_ACTIVE_JOBS`); `Retry-After` says when to try again"},
    },
)
async def submit_job(request: Request, store: StoreDep, settings: SettingsDep) -> JSONResponse:
    """Queue a training run. The body is a JobSpec, or `{"preset": NAME, "overrides": {...}}`,
    sent as `application/json`. A spec over this service's limits (memory, env steps,
    evaluation; docs/service.md) is 422 naming the field to lower; a full queue is 429."""
    json_content_type(request.headers.get("content-type"))
    raw = await request.body()
    try:
        spec = await run_in_threadpool(job_from_body, raw, settings.limits())
    except BadRequest as exc:
        raise HTTPException(400, str(exc)) from None
    except Invalid as exc:
        return invalid_response(exc)

    def create() -> JobDetail:
        job_id = store.submit(
            spec.model_dump_json(),
            name=spec.name,
            algorithm=spec.algorithm,
            total_env_steps=spec.training.total_env_steps,
            max_attempts=settings.max_attempts,
            max_active=settings.max_active_jobs,
        )
        job = _detail(store, job_id)
        assert job is not None  # the row was just inserted
        return job

    try:
        job = await run_in_threadpool(create)
    except QueueFull as exc:
        raise HTTPException(
            429,
            f"{exc.active} jobs are queued or running, the most this service takes "
            f"(MODSAT_MAX_ACTIVE_JOBS = {settings.max_active_jobs}); submit again when some "
            "have ended",
            headers={"Retry-After": "60"},
        ) from None
    return JSONResponse(job.model_dump(mode="json"), status_code=201, headers={"Location": job.url})


@router.get("", response_model=JobList)
def list_jobs(
    store: StoreDep,
    status: Annotated[list[JobStatus] | None, Query(description="Only jobs in these states (repeatable).")] = None,
    limit: Annotated[int, Digits, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Digits, Query(ge=0, le=1_000_000_000)] = 0,
    before_id: Annotated[
        int | None,
        Digits,
        Query(
            ge=1,
            le=2**63 - 1,
            description=("Only jobs with a smaller id: the cursor `next_before_id` of the previous page."),
        ),
    ] = None,
) -> JobList:
    """Jobs, newest first, one page at a time (by `offset`, or by the `before_id` cursor)."""
    statuses: list[str] | None = list(status) if status else None
    total, rows = store.list_jobs(statuses=statuses, limit=limit + 1, offset=offset, before_id=before_id)
    more, rows = len(rows) > limit, rows[:limit]
    nxt = offset + len(rows) if before_id is None and offset + len(rows) < total else None
    return JobList(
        total=total,
        limit=limit,
        offset=offset,
        next_offset=nxt,
        next_before_id=rows[-1]["id"] if more and rows else None,
        items=[job_summary(r) for r in rows],
    )


@router.get("/{job_id}", response_model=JobDetail, responses=_ERRORS)
def get_job(job_id: JobId, store: StoreDep) -> JobDetail:
    """Status, progress, latest metrics, evaluation summary, error and attempts of one job."""
    job = _detail(store, job_id)
    if job is None:
        raise _unknown(job_id)
    return job


@router.get("/{job_id}/metrics", response_model=MetricsPage, responses=_ERRORS)
def get_metrics(
    job_id: JobId,
    store: StoreDep,
    after: Annotated[int, Digits, Query(ge=0, le=2**31 - 1, description="Only rows with seq > after.")] = 0,
    limit: Annotated[int, Digits, Query(ge=1, le=5000)] = 1000,
) -> MetricsPage:
    """Progress rows in order; poll with `after` = the `last_seq` of the previous answer."""
    state = store.job_state(job_id)
    if state is None:
        raise _unknown(job_id)
    rows = store.metrics_after(job_id, after, limit + 1)  # one more row tells whether more remain
    more, rows = len(rows) > limit, rows[:limit]
    return MetricsPage(
        job_id=job_id,
        status=state[0],
        after=after,
        last_seq=rows[-1]["seq"] if rows else after,
        more=more,
        items=[metrics_point(r) for r in rows],
    )


def _sse(event: str, data: str, event_id: int | None = None) -> str:
    head = f"id: {event_id}\n" if event_id is not None else ""
    return f"{head}event: {event}\ndata: {data}\n\n"


@router.get(
    "/{job_id}/events",
    responses={**_ERRORS, 200: {"content": {"text/event-stream": {}}, "description": "Server-sent events"}},
)
async def job_events(
    job_id: JobId,
    request: Request,
    store: StoreDep,
    settings: SettingsDep,
    after: Annotated[int, Digits, Query(ge=0, le=2**31 - 1, description="Start after this metrics seq.")] = 0,
    last_event_id: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> StreamingResponse:
    """A server-sent-events stream: `metrics` events (id = seq), `status` events when the
    status changes, and a final `end` event when the job has ended. Reconnecting clients
    send `Last-Event-ID` (or `after`) and get only what they missed."""
    state = await run_in_threadpool(store.job_state, job_id)
    if state is None:
        raise _unknown(job_id)
    seen = (last_event_id or "").strip()
    if seen.isascii() and seen.isdigit():  # ASCII only: int() refuses '²'; and no 5,000-digit int()
        after = max(after, 2**31 - 1 if len(seen) > 10 else min(int(seen), 2**31 - 1))

    async def stream():
        last, shown = after, None
        t_end = time.monotonic() + settings.sse_max_s
        next_keepalive = time.monotonic() + settings.sse_keepalive_s
        yield "retry: 2000\n\n"
        while True:
            rows = await run_in_threadpool(store.metrics_after, job_id, last, 500)
            for r in rows:
                last = r["seq"]
                yield _sse("metrics", metrics_point(r).model_dump_json(), last)
            if len(rows) == 500:
                continue
            row = await run_in_threadpool(store.get_job, job_id)
            if row is None:
                yield _sse("end", json.dumps({"id": job_id, "status": "deleted"}))
                return
            if (row["status"], bool(row["cancel_requested"])) != shown:
                shown = (row["status"], bool(row["cancel_requested"]))
                yield _sse("status", job_summary(row).model_dump_json())
            if row["status"] in TERMINAL_STATUSES and row["last_seq"] <= last:
                yield _sse("end", json.dumps({"id": job_id, "status": row["status"], "last_seq": last}))
                return
            now = time.monotonic()
            if now >= t_end:
                yield _sse("timeout", json.dumps({"id": job_id, "last_seq": last}))
                return
            if now >= next_keepalive:
                next_keepalive = now + settings.sse_keepalive_s
                yield ": keep-alive\n\n"
            if await request.is_disconnected():
                return
            await asyncio.sleep(settings.sse_poll_s)

    return StreamingResponse(
        stream(), media_type="text/event-stream", headers={"Cache-Control": "no-cache", "X-Accel-Buffering": "no"}
    )


@router.post(
    "/{job_id}/cancel",
    response_model=CancelResult,
    dependencies=[WriteAccess],
    responses={
        **_ERRORS,
        202: {"description": "Running job: the worker stops it"},
        401: {"description": "Missing or wrong bearer token"},
        409: {"description": "The job has already ended"},
    },
)
def cancel_job(job_id: JobId, store: StoreDep, response: Response) -> CancelResult:
    """Cancel a queued job (at once) or a running one (its worker stops it within a heartbeat)."""
    outcome = store.request_cancel(job_id)
    if outcome is None:
        raise _unknown(job_id)
    if outcome in ("succeeded", "failed"):
        raise HTTPException(409, f"job {job_id} has already {outcome}; there is nothing to cancel")
    messages = {
        "stopped": f"job {job_id} was queued and is now cancelled",
        "requested": f"job {job_id} is running; its worker has been asked to stop it",
    }
    if outcome == "requested":
        response.status_code = 202
    return CancelResult(message=messages.get(outcome, f"job {job_id} is already cancelled"), job=_detail(store, job_id))


@router.delete(
    "/{job_id}",
    status_code=204,
    dependencies=[WriteAccess],
    responses={
        **_ERRORS,
        204: {"description": "Deleted"},
        401: {"description": "Missing or wrong bearer token"},
        409: {"description": "The job is running; cancel it first"},
    },
)
def delete_job(job_id: JobId, store: StoreDep) -> Response:
    """Delete a job that is not running (queued or ended) with its metrics and files. A
    running job is 409: cancel it, and delete it once its worker has stopped it."""
    outcome = store.delete_job(job_id)
    if outcome is None:
        raise _unknown(job_id)
    if outcome != "deleted":
        raise HTTPException(
            409,
            f"job {job_id} is running; cancel it first (POST /api/jobs/{job_id}/cancel), "
            "then delete it once it has stopped",
        )
    return Response(status_code=204)


@router.get("/{job_id}/artifacts", response_model=list[ArtifactInfo], responses=_ERRORS)
def list_artifacts(job_id: JobId, store: StoreDep) -> list[ArtifactInfo]:
    """Files of the job: outputs of a finished run (policy, the standalone controller as
    TorchScript `policy_export.pt`, torch.export `policy_export.pt2` and ONNX `policy_export.onnx`
    (docs/export.md), design, evaluation, trajectories, curve, the `.viser` 3D recording) and,
    while it runs, its latest checkpoint."""
    if store.job_state(job_id) is None:
        raise _unknown(job_id)
    return [artifact_info(job_id, r) for r in store.list_artifacts(job_id)]


@router.get(
    "/{job_id}/artifacts/{name}",
    responses={
        **_ERRORS,
        200: {"content": {"application/octet-stream": {}}, "description": "The file"},
        304: {"description": "`If-None-Match` names the file's ETag: not sent again"},
    },
)
def download_artifact(
    job_id: JobId,
    name: str,
    store: StoreDep,
    if_none_match: Annotated[str | None, Header(include_in_schema=False)] = None,
) -> Response:
    """Download one file. Only names in the job's list exist; anything else is 404. The ETag
    is the file's SHA-256: `If-None-Match` with it answers 304."""
    info = store.artifact_info(job_id, name)
    if info is None:
        if store.job_state(job_id) is None:
            raise _unknown(job_id)
        raise HTTPException(404, f"job {job_id} has no artefact named {clip(name)}; see /api/jobs/{job_id}/artifacts")
    etag = f'"{info["sha256"]}"'
    if if_none_match is not None and (
        if_none_match.strip() == "*" or etag in {t.strip().removeprefix("W/") for t in if_none_match.split(",")}
    ):
        return Response(status_code=304, headers={"ETag": etag})
    filename = safe_file_name(f"modsat-job-{job_id}-{info['name']}")
    return StreamingResponse(
        store.iter_artifact(job_id, info["name"], int(info["size"]), info["sha256"]),
        media_type=info["content_type"],
        headers={
            "Content-Length": str(info["size"]),
            "ETag": etag,
            "Content-Disposition": f'attachment; filename="{filename}"',
        },
    )
