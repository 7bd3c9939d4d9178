"""``/api/studies``: one spec run over several seeds and algorithms (RL co-design and its GA twin
at the same env-step budget), created in one request; its jobs' status, the aggregate (the table
and the curves of modsat_core.evaluation.study_report) and the figure as it fills in."""

from __future__ import annotations

import json
from typing import Annotated, Any

from fastapi import APIRouter, HTTPException, Query, Request, Response
from fastapi.responses import JSONResponse
from starlette.concurrency import run_in_threadpool

from modsat_core.artefacts import ArtefactError, CurveFile, CurvePoint
from modsat_core.evaluation.run_folder import RunFolder
from modsat_core.evaluation.study_report import FILES, SavedRun, curves_png, saved_run, study, table_markdown
from modsat_core.spec.jobspec import JobSpec, SpecError, quote
from modsat_core.spec.study import (
    DEFAULT_ALGORITHMS,
    algorithm_problem,
    ga_problem,
    seed_problem,
    study_specs,
)
from worker.store import QueueFull

from ..deps import SettingsDep, StoreDep, WriteAccess
from ..schemas import Digits, StudyDetail, StudyId, StudyJob, StudyList, StudySummary, _time
from ..submit import BadRequest, Invalid, decode_json, invalid_response, json_content_type, limit_errors, spec_from_body

router = APIRouter(prefix="/api/studies", tags=["studies"])

_ERRORS: dict[int | str, dict[str, Any]] = {404: {"description": "Unknown study"}}


def _unknown(study_id: int) -> HTTPException:
    return HTTPException(404, f"no study with id {study_id}")


def _job_specs(body: Any, settings) -> tuple[JobSpec, list[int], list[str], list[JobSpec]]:
    if not isinstance(body, dict):
        raise Invalid([{"loc": ["body"], "msg": "body: expected a JSON object", "type": "dict_type"}])
    extra = sorted(set(body) - {"spec", "seeds", "algorithms"})
    if extra:
        raise Invalid(
            [
                {
                    "loc": ["body", k],
                    "msg": f"{quote(k)}: unknown field of a study; it has spec, seeds and algorithms",
                    "type": "extra_forbidden",
                }
                for k in extra
            ]
        )
    if "spec" not in body:
        raise Invalid([{"loc": ["body", "spec"], "msg": "spec: required (a JobSpec or a preset)", "type": "missing"}])
    prefix = ["overrides"] if isinstance(body["spec"], dict) and "preset" in body["spec"] else []  # as /api/jobs
    try:
        base = spec_from_body(body["spec"])
    except Invalid as exc:
        raise Invalid([{**e, "loc": ["body", "spec", *e["loc"][1:]]} for e in exc.errors], exc.omitted) from None
    seeds, algs = body.get("seeds"), body.get("algorithms", list(DEFAULT_ALGORITHMS))
    for key, problem in (("seeds", seed_problem(seeds)), ("algorithms", algorithm_problem(algs))):
        if problem:
            raise Invalid([{"loc": ["body", key], "msg": problem, "type": "value_error"}])
    if "ga" in algs and (problem := ga_problem(base)):
        raise Invalid([{"loc": ["body", "spec", "ga", "steps_per_design"], "msg": problem, "type": "value_error"}])
    assert isinstance(seeds, list) and isinstance(algs, list)  # checked above
    try:
        specs = study_specs(base, seeds, algs)
    except SpecError as exc:  # the spec is valid for its own algorithm but not for another one of the study
        msg = "algorithms: " + "; ".join(exc.messages)
        raise Invalid([{"loc": ["body", "algorithms"], "msg": msg, "type": "value_error"}]) from None
    for spec in specs[:: len(seeds)]:  # one per algorithm: the seed does not change the limits
        problems = limit_errors(spec, settings.limits(), ["spec", *prefix])
        if problems:
            raise Invalid(problems)
    return base, seeds, algs, specs


@router.post(
    "",
    status_code=201,
    response_model=StudyDetail,
    dependencies=[WriteAccess],
    openapi_extra={
        "requestBody": {
            "required": True,
            "content": {
                "application/json": {
                    "schema": {"$ref": "#/components/schemas/StudySubmission"},
                    # quick-td3, as in docs/studies.md: `quick` is a first-order (diffsim) preset
                    # whose env-step budget, flown by TD3 or the GA, is over the work bound (422).
                    "example": {
                        "spec": {"preset": "quick-td3"},
                        "seeds": [0, 1, 2],
                        "algorithms": ["td3-codesign", "ga"],
                    },
                }
            },
        }
    },
    responses={
        400: {"description": "Body is not UTF-8 JSON"},
        401: {"description": "Missing or wrong bearer token"},
        415: {"description": "Body not sent as `application/json` (UTF-8)"},
        422: {"description": "Invalid; `messages` name each field"},
        429: {"description": "The queue has no room for all of the study's jobs (`MODSAT_MAX_ACTIVE_JOBS`)"},
    },
)
async def submit_study(request: Request, store: StoreDep, settings: SettingsDep) -> JSONResponse:
    """Queue one job per seed and algorithm, all or none. A study over the queue's room is 429."""
    json_content_type(request.headers.get("content-type"))
    raw = await request.body()
    try:
        # CPU-bound (decoding, validating, the limits): in a thread, so that no body delays other requests.
        base, seeds, algs, specs = await run_in_threadpool(lambda: _job_specs(decode_json(raw), settings))
    except BadRequest as exc:
        raise HTTPException(400, str(exc)) from None
    except Invalid as exc:
        return invalid_response(exc)

    def create() -> StudyDetail:
        sid, _ = store.submit_study(
            name=base.name,
            spec_json=base.model_dump_json(),
            seeds=seeds,
            algorithms=algs,
            job_specs=[(s.algorithm, s.seed, s.model_dump_json(), s.training.total_env_steps) for s in specs],
            max_attempts=settings.max_attempts,
            max_active=settings.max_active_jobs,
        )
        detail = _detail(store, sid)
        assert detail is not None  # just created
        return detail

    try:
        detail = await run_in_threadpool(create)
    except QueueFull as exc:
        raise HTTPException(
            429,
            f"this study queues {len(specs)} jobs and {exc.active} are queued or running; the service takes "
            f"{settings.max_active_jobs} at once (MODSAT_MAX_ACTIVE_JOBS)",
            headers={"Retry-After": "60"},
        ) from None
    return JSONResponse(detail.model_dump(mode="json"), status_code=201, headers={"Location": detail.url})


def _run_of(store, study_spec: JobSpec, job: dict[str, Any]) -> SavedRun:
    """A finished job from its files; a running (or failed) one from its curve points so far."""
    ref = f"/api/jobs/{job['id']}"
    if job["status"] == "succeeded":
        files = {n: store.read_artifact(job["id"], n) for n in FILES}
        if all(files.values()):
            try:
                return saved_run(RunFolder(ref, files))
            except ArtefactError:
                pass  # shown by its curve below; the job page has its files
    points = []
    if job["algorithm"] != "ga":  # a GA's progress points are its inner TD3's, not the GA's fitness
        for row in store.metrics_after(job["id"], 0, 100_000):
            ev = json.loads(row["data"]).get("eval")
            if ev is not None:
                points.append(ev)
    spec = study_spec.model_copy(update={"seed": job["seed"], "algorithm": job["algorithm"]})
    try:
        curve = CurveFile.model_validate({"algorithm": job["algorithm"], "points": points})
    except ValueError:  # a point not in the format: the job page shows its metrics as they are
        curve = CurveFile.model_validate({"algorithm": job["algorithm"], "points": []})
    return SavedRun(path=ref, spec=spec, curve=curve)


def _detail(store, study_id: int) -> StudyDetail | None:
    row = store.get_study(study_id)
    if row is None:
        return None
    spec = JobSpec.model_validate_json(row["spec"])
    runs = [_run_of(store, spec, j) for j in row["jobs"]]
    result = study(runs) if runs else {"grid_size": spec.design.grid_size, "algorithms": {}}
    statuses = [j["status"] for j in row["jobs"]]
    counts = {s: statuses.count(s) for s in dict.fromkeys(statuses)}
    ended = all(s in ("succeeded", "failed", "cancelled") for s in statuses)
    status = "ended" if ended else "queued" if all(s == "queued" for s in statuses) else "running"
    url = f"/api/studies/{study_id}"
    return StudyDetail(
        id=study_id,
        name=row["name"],
        seeds=row["seeds"],
        algorithms=row["algorithms"],
        created_at=_time(row["created_at"]),
        counts=counts,
        url=url,
        spec=spec,
        status=status,
        jobs=[
            StudyJob(
                id=j["id"],
                url=f"/api/jobs/{j['id']}",
                algorithm=j["algorithm"],
                seed=j["seed"],
                status=j["status"],
                env_steps=j["env_steps"],
                total_env_steps=j["total_env_steps"],
                run_seconds=j["run_seconds"],
                last_eval=None if j["last_eval"] is None else CurvePoint.parse(j["last_eval"]),
                error=j["error"],
            )
            for j in row["jobs"]
        ],
        aggregate=result,
        table_markdown=table_markdown(result),
        figure_url=f"{url}/curves.png",
    )


@router.get("", response_model=StudyList)
def list_studies(
    store: StoreDep,
    limit: Annotated[int, Digits, Query(ge=1, le=500)] = 50,
    offset: Annotated[int, Digits, Query(ge=0, le=1_000_000_000)] = 0,
) -> StudyList:
    """Studies, newest first, with their jobs counted per status."""
    total, rows = store.list_studies(limit=limit, offset=offset)
    items = [
        StudySummary(**{**r, "created_at": _time(r["created_at"]), "url": f"/api/studies/{r['id']}"}) for r in rows
    ]
    return StudyList(total=total, limit=limit, offset=offset, items=items)


@router.get("/{study_id}", response_model=StudyDetail, responses=_ERRORS)
def get_study(study_id: StudyId, store: StoreDep) -> StudyDetail:
    """The study's jobs (status, progress) and the aggregate over the seeds of each method so far."""
    detail = _detail(store, study_id)
    if detail is None:
        raise _unknown(study_id)
    return detail


@router.get(
    "/{study_id}/curves.png",
    responses={**_ERRORS, 200: {"content": {"image/png": {}}, "description": "The learning curves"}},
    response_class=Response,
)
def study_figure(study_id: StudyId, store: StoreDep) -> Response:
    """Learning curves of each method against env steps, mean ± std over seeds, as they fill in."""
    detail = _detail(store, study_id)
    if detail is None:
        raise _unknown(study_id)
    n = detail.spec.design.grid_size
    title = f"study {study_id}: {n}x{n}x{n}, {detail.spec.mission.tolerance_deg:g} deg"
    png = curves_png(detail.aggregate, title)
    return Response(png, media_type="image/png", headers={"Cache-Control": "no-store"})
