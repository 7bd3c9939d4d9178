"""The job store: every SQL statement of the service lives in this module.

One code path for SQLite and PostgreSQL. The queue protocol (docs/service.md):

* ``claim`` takes the oldest claimable queued job atomically
  (``UPDATE ... WHERE id = (SELECT ... FOR UPDATE SKIP LOCKED) RETURNING ...``) and
  increments ``attempt``, the job's **fencing token**.
* Every write a worker makes for a job (heartbeat, progress, checkpoint, artefacts, final
  status) is conditional on ``id = :id AND attempt = :attempt AND status = 'running'``.
  A worker that lost its lease (its job was reaped and perhaps claimed again) matches no
  row and publishes nothing.
* ``reap`` requeues running jobs whose lease expired, or fails them after
  ``max_attempts`` failed attempts.

Times are epoch seconds from the database's clock (``db_now``).
"""

from __future__ import annotations

import hashlib
import mimetypes
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, overload

from sqlalchemy import (
    Connection,
    LargeBinary,
    and_,
    delete,
    func,
    insert,
    literal,
    or_,
    select,
    update,
)
from sqlalchemy.engine import make_url
from sqlalchemy.exc import IntegrityError, ProgrammingError

from modsat_core.artefacts import ProgressRecord

from .db import (
    TERMINAL_STATUSES,
    artifacts,
    attempts,
    db_now,
    hold_queue,
    insert_job,
    jobs,
    make_engine,
    metadata,
    metrics,
    migrate_sqlite,
    study_jobs,
    workers,
)
from .jsonsafe import to_json
from .study_store import StudyQueries

#: A job id outside this range cannot exist (and would overflow a BIGINT bind parameter).
MAX_ID = 2**63 - 1
CHECKPOINT_NAME = "checkpoint.pt"
_READ_CHUNK = 1 << 20

#: Columns of a job shown in lists (the spec and the tracebacks are left to ``get_job``).
_LIST_COLUMNS = [c for c in jobs.c if c.name not in ("spec", "summary", "error_detail")]


class _Fenced(Exception):
    """Raised inside a write transaction when the fencing token no longer matches."""


@dataclass(frozen=True)
class Claim:
    """A job held by one worker. ``attempt`` is the fencing token of every write."""

    job_id: int
    attempt: int
    spec_json: str
    checkpoint_env_steps: int | None
    run_seconds: float
    failures: int
    max_attempts: int


@dataclass(frozen=True)
class Beat:
    """Answer to a heartbeat: ``alive`` False means the lease is lost (stop, publish nothing)."""

    alive: bool
    cancel_requested: bool = False


def content_type_for(name: str) -> str:
    if name.endswith(".json"):
        return "application/json"
    if name.endswith(".pt"):
        return "application/octet-stream"
    return mimetypes.guess_type(name)[0] or "application/octet-stream"


def _valid_id(job_id: int) -> bool:
    return 1 <= job_id <= MAX_ID


def _fence(c: Claim):
    return and_(jobs.c.id == c.job_id, jobs.c.attempt == c.attempt, jobs.c.status == "running")


class JobStore(StudyQueries):
    """Jobs, attempts, metrics, artefacts, workers and studies in one SQL database."""

    def __init__(self, url: str, *, busy_timeout_s: float = 30.0):
        self.engine = make_engine(url, busy_timeout_s=busy_timeout_s)
        # Write transactions on SQLite start with BEGIN IMMEDIATE (see db.py).
        self._write_engine = self.engine.execution_options(modsat_write=True)
        self.backend = make_url(self.engine.url).get_backend_name()

    @property
    def url_for_humans(self) -> str:
        return self.engine.url.render_as_string(hide_password=True)

    def create_schema(self) -> None:
        """Create the tables that do not exist yet and bring older SQLite stores up to date
        (idempotent, safe from several processes).

        Two processes creating the tables at the same moment on PostgreSQL can collide;
        the loser tries again and then finds them."""
        for attempt in range(3):
            try:
                with self._write_engine.begin() as conn:
                    metadata.create_all(conn, checkfirst=True)
                break
            except (ProgrammingError, IntegrityError):
                if attempt == 2:
                    raise
                time.sleep(0.2 * (attempt + 1))
        if self.backend == "sqlite":
            migrate_sqlite(self.engine)

    def drop_schema(self) -> None:
        """Drop every table (tests and benchmarks)."""
        with self._write_engine.begin() as conn:
            metadata.drop_all(conn, checkfirst=True)

    def dispose(self) -> None:
        self.engine.dispose()

    @contextmanager
    def _write(self) -> Iterator[Connection]:
        with self._write_engine.begin() as conn:
            yield conn

    @contextmanager
    def _read(self) -> Iterator[Connection]:
        with self.engine.connect() as conn:
            yield conn

    def ping(self) -> None:
        with self._read() as conn:
            conn.execute(select(literal(1))).scalar_one()

    # ------------------------------------------------------------------ submit and read

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
        if not _valid_id(job_id):
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
        if not _valid_id(job_id):
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
        if not _valid_id(job_id):
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
                _drop_checkpoint(conn, job_id)
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
        if not _valid_id(job_id):
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

    # ------------------------------------------------------------------ artefacts (database store)

    def list_artifacts(self, job_id: int) -> list[dict[str, Any]]:
        cols = [c for c in artifacts.c if c.name != "data"]
        with self._read() as conn:
            rows = (
                conn.execute(
                    select(*cols)
                    .where(artifacts.c.job_id == job_id)
                    .order_by(artifacts.c.kind.desc(), artifacts.c.name)
                )
                .mappings()
                .all()
            )
        return [dict(r) for r in rows]

    def artifact_info(self, job_id: int, name: str) -> dict[str, Any] | None:
        if not _valid_id(job_id) or "\x00" in name:  # no stored name has a NUL (PostgreSQL rejects it)
            return None
        cols = [c for c in artifacts.c if c.name != "data"]
        with self._read() as conn:
            row = (
                conn.execute(select(*cols).where(artifacts.c.job_id == job_id, artifacts.c.name == name))
                .mappings()
                .first()
            )
        return dict(row) if row else None

    def read_artifact(self, job_id: int, name: str) -> bytes | None:
        with self._read() as conn:
            return conn.execute(
                select(artifacts.c.data).where(artifacts.c.job_id == job_id, artifacts.c.name == name)
            ).scalar_one_or_none()

    def iter_artifact(
        self, job_id: int, name: str, size: int, sha256: str, chunk: int = _READ_CHUNK
    ) -> Iterator[bytes]:
        """The artefact's bytes in chunks, so a large file never sits whole in the server's memory.

        If the file is replaced meanwhile (a newer checkpoint), the stream stops short rather
        than mix two versions; the client sees fewer bytes than Content-Length."""
        for start in range(0, size, chunk):
            part = func.substr(artifacts.c.data, start + 1, chunk, type_=LargeBinary)
            with self._read() as conn:
                data = conn.execute(
                    select(part).where(
                        artifacts.c.job_id == job_id, artifacts.c.name == name, artifacts.c.sha256 == sha256
                    )
                ).scalar_one_or_none()
            if not data:
                return
            yield bytes(data)

    def load_checkpoint(self, job_id: int) -> bytes | None:
        return self.read_artifact(job_id, CHECKPOINT_NAME)

    @staticmethod
    def _put_artifact(conn: Connection, c: Claim, name: str, data: bytes, kind: str) -> None:
        conn.execute(delete(artifacts).where(artifacts.c.job_id == c.job_id, artifacts.c.name == name))
        conn.execute(
            insert(artifacts).values(
                job_id=c.job_id,
                name=name,
                kind=kind,
                attempt=c.attempt,
                size=len(data),
                sha256=hashlib.sha256(data).hexdigest(),
                content_type=content_type_for(name),
                created_at=db_now(),
                data=data,
            )
        )

    # ------------------------------------------------------------------ workers

    def register_worker(self, worker_id: str, *, hostname: str, pid: int, runner: str, ttl_s: float) -> None:
        now = db_now()
        with self._write() as conn:
            conn.execute(
                insert(workers).values(
                    id=worker_id,
                    hostname=hostname,
                    pid=pid,
                    runner=runner,
                    started_at=now,
                    last_seen=now,
                    expires_at=now + ttl_s,
                )
            )

    def touch_worker(self, worker_id: str, *, job_id: int | None, ttl_s: float) -> None:
        now = db_now()
        with self._write() as conn:
            conn.execute(
                update(workers)
                .where(workers.c.id == worker_id)
                .values(last_seen=now, expires_at=now + ttl_s, job_id=job_id)
            )

    def worker_stopped(self, worker_id: str) -> None:
        with self._write() as conn:
            conn.execute(update(workers).where(workers.c.id == worker_id).values(stopped_at=db_now(), job_id=None))

    def live_workers(self) -> list[dict[str, Any]]:
        with self._read() as conn:
            rows = (
                conn.execute(
                    select(
                        workers.c.id,
                        workers.c.hostname,
                        workers.c.pid,
                        workers.c.runner,
                        workers.c.started_at,
                        workers.c.last_seen,
                        workers.c.job_id,
                    )
                    .where(workers.c.stopped_at.is_(None), workers.c.expires_at > db_now())
                    .order_by(workers.c.started_at)
                )
                .mappings()
                .all()
            )
        return [dict(r) for r in rows]

    # ------------------------------------------------------------------ the queue protocol

    def claim(self, worker_id: str, *, lease_s: float) -> Claim | None:
        """Atomically take the oldest claimable queued job, or return None."""
        now = db_now()
        pick = (
            select(jobs.c.id)
            .where(jobs.c.status == "queued", or_(jobs.c.run_after.is_(None), jobs.c.run_after <= now))
            .order_by(jobs.c.id)
            .limit(1)
            .with_for_update(skip_locked=True)  # rendered on PostgreSQL, omitted on SQLite
            .scalar_subquery()
        )
        stmt = (
            update(jobs)
            .where(jobs.c.id == pick, jobs.c.status == "queued")
            .values(
                status="running",
                attempt=jobs.c.attempt + 1,
                worker_id=worker_id,
                heartbeat_at=now,
                lease_expires_at=now + lease_s,
                started_at=func.coalesce(jobs.c.started_at, now),
                updated_at=now,
                run_after=None,
                phase="starting",
                env_steps=func.coalesce(jobs.c.checkpoint_env_steps, 0),
            )
            .returning(
                jobs.c.id,
                jobs.c.attempt,
                jobs.c.spec,
                jobs.c.checkpoint_env_steps,
                jobs.c.run_seconds,
                jobs.c.failures,
                jobs.c.max_attempts,
            )
        )
        with self._write() as conn:
            row = conn.execute(stmt).first()
            if row is None:
                return None
            claim = Claim(
                job_id=int(row.id),
                attempt=int(row.attempt),
                spec_json=row.spec,
                checkpoint_env_steps=row.checkpoint_env_steps,
                run_seconds=float(row.run_seconds),
                failures=int(row.failures),
                max_attempts=int(row.max_attempts),
            )
            conn.execute(
                insert(attempts).values(
                    job_id=claim.job_id,
                    attempt=claim.attempt,
                    worker_id=worker_id,
                    started_at=now,
                    outcome="running",
                    resumed_from_env_steps=claim.checkpoint_env_steps,
                )
            )
        return claim

    def heartbeat(self, c: Claim, *, lease_s: float) -> Beat:
        """Extend the lease; tells whether it is still ours and whether a cancel was asked for."""
        now = db_now()
        with self._write() as conn:
            row = conn.execute(
                update(jobs)
                .where(_fence(c))
                .values(lease_expires_at=now + lease_s, heartbeat_at=now)
                .returning(jobs.c.cancel_requested)
            ).first()
        return Beat(alive=False) if row is None else Beat(alive=True, cancel_requested=bool(row[0]))

    def publish_progress(self, c: Claim, data: Mapping[str, Any]) -> int | None:
        """Append one metrics row (fenced); returns its sequence number, or None if fenced off.

        ``data`` is a progress record (modsat_core.artefacts.ProgressRecord); one that does not
        fit raises :class:`~modsat_core.artefacts.ArtefactError`."""
        rec = ProgressRecord.parse(to_json(data))  # numpy numbers, NaN and inf made JSON first
        env_steps = rec.env_steps
        values: dict[str, Any] = {"last_seq": jobs.c.last_seq + 1, "env_steps": env_steps, "updated_at": db_now()}
        if rec.total_env_steps:
            values["total_env_steps"] = rec.total_env_steps
        if rec.phase:
            values["phase"] = rec.phase[:32]
        if rec.eval:
            values["last_eval"] = to_json(rec.eval.to_dict())
        with self._write() as conn:
            seq = conn.execute(update(jobs).where(_fence(c)).values(**values).returning(jobs.c.last_seq)).scalar()
            if seq is None:
                return None
            conn.execute(
                insert(metrics).values(
                    job_id=c.job_id,
                    seq=seq,
                    attempt=c.attempt,
                    created_at=db_now(),
                    env_steps=env_steps,
                    data=to_json(rec.to_dict()),
                )
            )
        return int(seq)

    def save_checkpoint(self, c: Claim, env_steps: int, data: bytes) -> bool:
        """Replace the job's checkpoint (fenced). A resumed attempt starts from it."""
        try:
            with self._write() as conn:
                r = conn.execute(
                    update(jobs).where(_fence(c)).values(checkpoint_env_steps=env_steps, updated_at=db_now())
                )
                if r.rowcount != 1:
                    raise _Fenced
                self._put_artifact(conn, c, CHECKPOINT_NAME, data, "checkpoint")
        except _Fenced:
            return False
        return True

    def complete(
        self,
        c: Claim,
        *,
        files: Mapping[str, bytes],
        summary: Any,
        env_steps: int,
        attempt_seconds: float,
        keep_checkpoint: bool = False,
    ) -> bool:
        """Store the outputs and mark the job succeeded, all in one fenced transaction."""
        now = db_now()
        try:
            with self._write() as conn:
                r = conn.execute(
                    update(jobs)
                    .where(_fence(c))
                    .values(
                        status="succeeded",
                        finished_at=now,
                        updated_at=now,
                        worker_id=None,
                        lease_expires_at=None,
                        phase="done",
                        env_steps=env_steps,
                        summary=None if summary is None else to_json(summary),
                        error=None,
                        error_detail=None,
                        run_seconds=jobs.c.run_seconds + attempt_seconds,
                    )
                )
                if r.rowcount != 1:
                    raise _Fenced
                for name, data in files.items():
                    self._put_artifact(conn, c, name, data, "output")
                if not keep_checkpoint:
                    conn.execute(
                        delete(artifacts).where(artifacts.c.job_id == c.job_id, artifacts.c.kind == "checkpoint")
                    )
                self._end_attempt(conn, c, "succeeded", now)
        except _Fenced:
            return False
        return True

    def finish_cancelled(self, c: Claim, *, attempt_seconds: float) -> bool:
        now = db_now()
        with self._write() as conn:
            r = conn.execute(
                update(jobs)
                .where(_fence(c))
                .values(
                    status="cancelled",
                    finished_at=now,
                    updated_at=now,
                    worker_id=None,
                    lease_expires_at=None,
                    phase=None,
                    run_seconds=jobs.c.run_seconds + attempt_seconds,
                )
            )
            if r.rowcount != 1:
                return False
            _drop_checkpoint(conn, c.job_id)
            self._end_attempt(conn, c, "cancelled", now)
        return True

    def release(self, c: Claim, *, attempt_seconds: float) -> bool:
        """Give a job back to the queue without counting a failure (worker shutting down).

        A job whose cancel was requested meanwhile ends ``cancelled`` instead."""
        now = db_now()
        with self._write() as conn:
            row = conn.execute(  # locked: a cancel that comes meanwhile waits, then sees the new status
                select(jobs.c.cancel_requested).where(_fence(c)).with_for_update()
            ).first()
            if row is None:
                return False
            cancelled = bool(row[0])
            conn.execute(
                update(jobs)
                .where(_fence(c))
                .values(
                    status="cancelled" if cancelled else "queued",
                    finished_at=now if cancelled else None,
                    updated_at=now,
                    worker_id=None,
                    lease_expires_at=None,
                    phase=None,
                    run_seconds=jobs.c.run_seconds + attempt_seconds,
                )
            )
            if cancelled:
                _drop_checkpoint(conn, c.job_id)
            self._end_attempt(conn, c, "cancelled" if cancelled else "released", now)
        return True

    def fail_attempt(
        self, c: Claim, *, error: str, detail: str | None, outcome: str, retry_delay_s: float, attempt_seconds: float
    ) -> str | None:
        """Record a failed attempt: requeue (after a back-off) or, at the retry limit, ``failed``.

        Returns the job's new status, or None if fenced off."""
        return self._fail(
            c,
            error=error,
            detail=detail,
            outcome=outcome,
            retry_delay_s=retry_delay_s,
            attempt_seconds=attempt_seconds,
            retry=True,
        )

    def fail_permanently(
        self, c: Claim, *, error: str, detail: str | None = None, attempt_seconds: float = 0.0
    ) -> str | None:
        """Fail the job at once, no retry (e.g. a stored spec this worker cannot read or run)."""
        return self._fail(
            c,
            error=error,
            detail=detail,
            outcome="failed",
            retry_delay_s=0.0,
            attempt_seconds=attempt_seconds,
            retry=False,
        )

    def _fail(
        self,
        c: Claim,
        *,
        error: str,
        detail: str | None,
        outcome: str,
        retry_delay_s: float,
        attempt_seconds: float,
        retry: bool,
    ) -> str | None:
        now = db_now()
        error, detail = _no_nul(error), _no_nul(detail)
        with self._write() as conn:
            row = conn.execute(  # locked, as in release()
                select(jobs.c.failures, jobs.c.max_attempts, jobs.c.cancel_requested).where(_fence(c)).with_for_update()
            ).first()
            if row is None:
                return None
            failures = int(row.failures) + 1
            status = _after_failure(failures, int(row.max_attempts), bool(row.cancel_requested), retry)
            conn.execute(
                update(jobs)
                .where(_fence(c))
                .values(
                    **_failure_values(status, failures, int(row.max_attempts), error, retry_delay_s, now),
                    error_detail=detail,
                    run_seconds=jobs.c.run_seconds + attempt_seconds,
                )
            )
            if status in TERMINAL_STATUSES:
                _drop_checkpoint(conn, c.job_id)
            self._end_attempt(conn, c, outcome, now, error)
        return status

    def reap(self, *, retry_delay_s: float) -> list[tuple[int, str]]:
        """Requeue (or fail) running jobs whose lease expired; returns [(job id, new status)]."""
        now = db_now()
        out = []
        with self._write() as conn:
            rows = conn.execute(
                select(
                    jobs.c.id,
                    jobs.c.attempt,
                    jobs.c.worker_id,
                    jobs.c.failures,
                    jobs.c.max_attempts,
                    jobs.c.cancel_requested,
                )
                .where(jobs.c.status == "running", jobs.c.lease_expires_at < now)
                .order_by(jobs.c.id)
                .with_for_update(skip_locked=True)
            ).all()
            for r in rows:
                c = Claim(
                    job_id=int(r.id),
                    attempt=int(r.attempt),
                    spec_json="",
                    checkpoint_env_steps=None,
                    run_seconds=0.0,
                    failures=int(r.failures),
                    max_attempts=int(r.max_attempts),
                )
                failures = c.failures + 1
                status = _after_failure(failures, c.max_attempts, bool(r.cancel_requested), True)
                error = f"lease expired: worker {r.worker_id} stopped sending heartbeats (attempt {c.attempt})"
                conn.execute(
                    update(jobs)
                    .where(_fence(c))
                    .values(
                        **_failure_values(status, failures, c.max_attempts, error, retry_delay_s, now),
                        error_detail=None,
                    )
                )
                if status in TERMINAL_STATUSES:
                    _drop_checkpoint(conn, c.job_id)
                self._end_attempt(conn, c, "lease-expired", now, error)
                out.append((c.job_id, status))
        return out

    @staticmethod
    def _end_attempt(conn: Connection, c: Claim, outcome: str, now: Any, error: str | None = None) -> None:
        conn.execute(
            update(attempts)
            .where(attempts.c.job_id == c.job_id, attempts.c.attempt == c.attempt)
            .values(ended_at=now, outcome=outcome, error=error)
        )


def _drop_checkpoint(conn: Connection, job_id: int) -> None:
    """A job that has ended without success will not resume: its checkpoint (often the largest
    file, replay buffer included) is deleted."""
    conn.execute(delete(artifacts).where(artifacts.c.job_id == job_id, artifacts.c.kind == "checkpoint"))
    conn.execute(update(jobs).where(jobs.c.id == job_id).values(checkpoint_env_steps=None))


@overload
def _no_nul(text: str) -> str: ...
@overload
def _no_nul(text: None) -> None: ...
def _no_nul(text: str | None) -> str | None:
    """Error text from a training may hold NUL characters, which PostgreSQL text cannot store."""
    return None if text is None else text.replace("\x00", "\\x00")


def _after_failure(failures: int, max_attempts: int, cancel_requested: bool, retry: bool) -> str:
    if cancel_requested:
        return "cancelled"
    if not retry or failures >= max_attempts:
        return "failed"
    return "queued"


def _failure_values(
    status: str, failures: int, max_attempts: int, error: str, retry_delay_s: float, now: Any
) -> dict[str, Any]:
    if status == "failed":
        shown = f"{error} (failed attempt {failures} of {max_attempts}; no retries left)"
    elif status == "queued":
        shown = f"{error} (failed attempt {failures} of {max_attempts}; retrying)"
    else:
        shown = error
    delay = min(retry_delay_s * 2 ** (failures - 1), 3600.0) if retry_delay_s > 0 else 0.0
    return {
        "status": status,
        "failures": failures,
        "error": shown,
        "updated_at": now,
        "worker_id": None,
        "lease_expires_at": None,
        "phase": None,
        "finished_at": now if status in TERMINAL_STATUSES else None,
        "run_after": now + delay if status == "queued" and delay > 0 else None,
    }
