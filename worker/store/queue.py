"""The queue protocol (docs/service.md): claims, leases, fencing, the reaper.

* ``claim`` takes the oldest claimable queued job atomically
  (``UPDATE ... WHERE id = (SELECT ... FOR UPDATE SKIP LOCKED) RETURNING ...``) and
  increments ``attempt``, the job's **fencing token**.
* Every write a worker makes for a job (heartbeat, progress, checkpoint, artefacts, final
  status) is conditional on ``id = :id AND attempt = :attempt AND status = 'running'``.
  A worker that lost its lease (its job was reaped and perhaps claimed again) matches no
  row and publishes nothing.
* ``reap`` requeues running jobs whose lease expired, or fails them after
  ``max_attempts`` failed attempts.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, overload

from sqlalchemy import Connection, and_, delete, func, insert, or_, select, update

from modsat_core.artefacts import ProgressRecord

from ..jsonsafe import to_json
from .artifacts import CHECKPOINT_NAME, drop_checkpoint, put_artifact
from .base import Claim, StoreBase
from .schema import TERMINAL_STATUSES, artifacts, attempts, db_now, jobs, metrics


class _Fenced(Exception):
    """Raised inside a write transaction when the fencing token no longer matches."""


@dataclass(frozen=True)
class Beat:
    """Answer to a heartbeat: ``alive`` False means the lease is lost (stop, publish nothing)."""

    alive: bool
    cancel_requested: bool = False


def _fence(c: Claim):
    return and_(jobs.c.id == c.job_id, jobs.c.attempt == c.attempt, jobs.c.status == "running")


class QueueProtocol(StoreBase):
    """What workers do: claim, heartbeat, publish, checkpoint, finish, fail; and the reaper."""

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
                put_artifact(conn, c, CHECKPOINT_NAME, data, "checkpoint")
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
                    put_artifact(conn, c, name, data, "output")
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
            drop_checkpoint(conn, c.job_id)
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
                drop_checkpoint(conn, c.job_id)
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
                drop_checkpoint(conn, c.job_id)
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
                    drop_checkpoint(conn, c.job_id)
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
