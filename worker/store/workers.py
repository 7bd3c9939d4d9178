"""Worker processes: registered at start, seen at each heartbeat, listed by ``GET /api/health``."""

from __future__ import annotations

from typing import Any

from sqlalchemy import insert, select, update

from .base import StoreBase
from .schema import db_now, workers


class WorkerQueries(StoreBase):
    """The workers table."""

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
