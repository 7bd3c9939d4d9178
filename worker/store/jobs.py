"""Jobs as clients see them: submit, read, cancel, delete (``/api/jobs``)."""

from __future__ import annotations

from typing import Any

from sqlalchemy import and_, delete, func, literal, select, update

from .artifacts import drop_checkpoint
from .base import StoreBase, valid_id
from .schema import artifacts, attempts, db_now, hold_queue, insert_job, jobs, metrics, study_jobs

#: Columns of a job shown in lists (the spec and the tracebacks are left to ``get_job``).
_LIST_COLUMNS = [c for c in jobs.c if c.name not in ("spec", "summary", "error_detail")]


class JobQueries(StoreBase):
    """Submitting and reading jobs, their metrics and attempts; cancelling and deleting them."""

    def submit(
        self,
        spec_json: str,
        *,
        name: str | None,
        algorithm: str,
        total_env_steps: int,
        max_attempts: int,
        max_active: int | None = None,
    ) -> int:
        """Queue a job; returns its id. With ``max_active``, raises :class:`QueueFull` instead
        when that many jobs are queued or running (counted and inserted in one step)."""
        with self._write() as conn:
            hold_queue(conn, 1, max_active)
            return insert_job(conn, spec_json, name, algorithm, total_env_steps, max_attempts)

    def get_job(self, job_id: int) -> dict[str, Any] | None:
        if not valid_id(job_id):
            return None
        with self._read() as conn:
            row = conn.execute(select(jobs).where(jobs.c.id == job_id)).mappings().first()
            return dict(row) if row else None

    def list_jobs(
        self, *, statuses: list[str] | None = None, limit: int = 50, offset: int = 0, before_id: int | None = None
    ) -> tuple[int, list[dict[str, Any]]]:
        """(total matching, one page newest first). ``before_id``: only jobs with a smaller id
        (a cursor: pages do not shift when jobs arrive meanwhile); ``total`` ignores it."""
        where = jobs.c.status.in_(statuses) if statuses else literal(True)
        page = where if before_id is None else and_(where, jobs.c.id < before_id)
        with self._read() as conn:
            total = conn.execute(select(func.count()).select_from(jobs).where(where)).scalar_one()
            rows = (
                conn.execute(select(*_LIST_COLUMNS).where(page).order_by(jobs.c.id.desc()).limit(limit).offset(offset))
                .mappings()
                .all()
            )
        return int(total), [dict(r) for r in rows]

    def status_counts(self) -> dict[str, int]:
        with self._read() as conn:
            rows = conn.execute(select(jobs.c.status, func.count()).group_by(jobs.c.status)).all()
        return {s: int(n) for s, n in rows}

    def job_state(self, job_id: int) -> tuple[str, bool, int] | None:
        """(status, cancel_requested, last_seq): the cheap poll of the event stream."""
        if not valid_id(job_id):
            return None
        with self._read() as conn:
            row = conn.execute(
                select(jobs.c.status, jobs.c.cancel_requested, jobs.c.last_seq).where(jobs.c.id == job_id)
            ).first()
        return (row[0], bool(row[1]), int(row[2])) if row else None

    def metrics_after(self, job_id: int, after: int = 0, limit: int = 1000) -> list[dict[str, Any]]:
        """Progress rows with ``seq > after``, oldest first."""
        with self._read() as conn:
            rows = (
                conn.execute(
                    select(metrics.c.seq, metrics.c.attempt, metrics.c.created_at, metrics.c.env_steps, metrics.c.data)
                    .where(metrics.c.job_id == job_id, metrics.c.seq > after)
                    .order_by(metrics.c.seq)
                    .limit(limit)
                )
                .mappings()
                .all()
            )
        return [dict(r) for r in rows]

    def latest_metrics(self, job_id: int) -> dict[str, Any] | None:
        with self._read() as conn:
            row = (
                conn.execute(
                    select(metrics.c.seq, metrics.c.attempt, metrics.c.created_at, metrics.c.env_steps, metrics.c.data)
                    .where(metrics.c.job_id == job_id)
                    .order_by(metrics.c.seq.desc())
                    .limit(1)
                )
                .mappings()
                .first()
            )
        return dict(row) if row else None

    def list_attempts(self, job_id: int) -> list[dict[str, Any]]:
        with self._read() as conn:
            rows = (
                conn.execute(select(attempts).where(attempts.c.job_id == job_id).order_by(attempts.c.attempt))
                .mappings()
                .all()
            )
        return [dict(r) for r in rows]

    def request_cancel(self, job_id: int) -> str | None:
        """Cancel a job. Returns ``stopped`` (it was queued and is now cancelled),
        ``requested`` (it is running; the worker stops it), the terminal status it already
        had (``succeeded``, ``failed``, ``cancelled``), or None for an unknown job."""
        if not valid_id(job_id):
            return None
        now = db_now()
        with self._write() as conn:
            # The row is locked (PostgreSQL; SQLite: BEGIN IMMEDIATE) so that its status cannot
            # change between reading it and acting on it (a release, a claim, a failure).
            status = conn.execute(
                select(jobs.c.status).where(jobs.c.id == job_id).with_for_update()
            ).scalar_one_or_none()
            if status == "queued":
                conn.execute(
                    update(jobs)
                    .where(jobs.c.id == job_id, jobs.c.status == "queued")
                    .values(status="cancelled", cancel_requested=True, finished_at=now, updated_at=now, phase=None)
                )
                drop_checkpoint(conn, job_id)
                return "stopped"
            if status == "running":
                conn.execute(
                    update(jobs)
                    .where(jobs.c.id == job_id, jobs.c.status == "running")
                    .values(cancel_requested=True, updated_at=now)
                )
                return "requested"
        return status

    def active_count(self) -> int:
        """Jobs queued or running (the service's cap on them: ``max_active_jobs``)."""
        with self._read() as conn:
            return int(
                conn.execute(
                    select(func.count()).select_from(jobs).where(jobs.c.status.in_(("queued", "running")))
                ).scalar_one()
            )

    def delete_job(self, job_id: int) -> str | None:
        """Delete a job that is not running (ended, or still queued: no worker holds it) with
        its metrics, attempts and artefacts. Returns ``deleted``, ``running`` (nothing is
        deleted: cancel it first), or None for an unknown job."""
        if not valid_id(job_id):
            return None
        with self._write() as conn:
            status = conn.execute(
                select(jobs.c.status).where(jobs.c.id == job_id).with_for_update()
            ).scalar_one_or_none()
            if status is None or status == "running":
                return status
            # Children first and explicitly: SQLite enforces ON DELETE CASCADE only with a pragma.
            for table in (artifacts, metrics, attempts, study_jobs):
                conn.execute(delete(table).where(table.c.job_id == job_id))
            conn.execute(delete(jobs).where(jobs.c.id == job_id))
        return "deleted"
