"""The SQL of studies (``/api/studies``): a study and its jobs are created in one transaction."""

from __future__ import annotations

import json
from typing import Any

from sqlalchemy import func, insert, select

from .base import StoreBase, valid_id
from .schema import db_now, hold_queue, insert_job, jobs, studies, study_jobs

#: What a study shows of each of its jobs.
_JOB_COLUMNS = [
    jobs.c.id,
    jobs.c.name,
    jobs.c.status,
    jobs.c.env_steps,
    jobs.c.total_env_steps,
    jobs.c.last_eval,
    jobs.c.run_seconds,
    jobs.c.error,
]


class StudyQueries(StoreBase):
    """A study and its jobs are created in one transaction."""

    def submit_study(
        self,
        *,
        name: str | None,
        spec_json: str,
        seeds: list[int],
        algorithms: list[str],
        job_specs: list[tuple[str, int, str, int]],
        max_attempts: int,
        max_active: int | None = None,
    ) -> tuple[int, list[int]]:
        """Create a study and queue its jobs, all or nothing. ``job_specs``: (algorithm, seed,
        spec JSON, total env steps) per job. Returns (study id, job ids). With ``max_active``,
        raises :class:`~worker.store.QueueFull` when its jobs do not all fit in the queue."""
        with self._write() as conn:
            hold_queue(conn, len(job_specs), max_active)
            sid = int(
                conn.execute(
                    insert(studies)
                    .values(
                        name=name,
                        spec=spec_json,
                        seeds=json.dumps(seeds),
                        algorithms=json.dumps(algorithms),
                        created_at=db_now(),
                    )
                    .returning(studies.c.id)
                ).scalar_one()
            )
            ids = []
            for algorithm, seed, job_json, total in job_specs:
                jid = insert_job(conn, job_json, name, algorithm, total, max_attempts)
                conn.execute(insert(study_jobs).values(study_id=sid, job_id=jid, algorithm=algorithm, seed=seed))
                ids.append(jid)
        return sid, ids

    def get_study(self, study_id: int) -> dict[str, Any] | None:
        """The study's row with ``jobs``: each job's id, algorithm, seed, status and progress."""
        if not valid_id(study_id):
            return None
        with self._read() as conn:
            row = conn.execute(select(studies).where(studies.c.id == study_id)).mappings().first()
            if row is None:
                return None
            members = (
                conn.execute(
                    select(study_jobs.c.algorithm, study_jobs.c.seed, *_JOB_COLUMNS)
                    .join(jobs, jobs.c.id == study_jobs.c.job_id)
                    .where(study_jobs.c.study_id == study_id)
                    .order_by(study_jobs.c.job_id)
                )
                .mappings()
                .all()
            )
        return {**_decode(dict(row)), "jobs": [dict(m) for m in members]}

    def list_studies(self, *, limit: int = 50, offset: int = 0) -> tuple[int, list[dict[str, Any]]]:
        """(total, one page newest first), each with ``counts``: its jobs per status."""
        with self._read() as conn:
            total = conn.execute(select(func.count()).select_from(studies)).scalar_one()
            rows = [
                _decode(dict(r))
                for r in conn.execute(
                    select(studies.c.id, studies.c.name, studies.c.seeds, studies.c.algorithms, studies.c.created_at)
                    .order_by(studies.c.id.desc())
                    .limit(limit)
                    .offset(offset)
                )
                .mappings()
                .all()
            ]
            ids = [r["id"] for r in rows]
            counts = conn.execute(
                select(study_jobs.c.study_id, jobs.c.status, func.count())
                .join(jobs, jobs.c.id == study_jobs.c.job_id)
                .where(study_jobs.c.study_id.in_(ids))
                .group_by(study_jobs.c.study_id, jobs.c.status)
            ).all()
        for r in rows:
            r["counts"] = {str(st): int(n) for sid, st, n in counts if sid == r["id"]}
        return int(total), rows


def _decode(row: dict[str, Any]) -> dict[str, Any]:
    for key in ("seeds", "algorithms"):
        if key in row:
            row[key] = json.loads(row[key])
    return row
