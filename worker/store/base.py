"""The job store's engine and transactions, shared by the query mixins of :class:`worker.store.JobStore`."""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from sqlalchemy import Connection, literal, select
from sqlalchemy.engine import make_url
from sqlalchemy.exc import IntegrityError, ProgrammingError

from .schema import make_engine, metadata, migrate_sqlite

#: A job id outside this range cannot exist (and would overflow a BIGINT bind parameter).
MAX_ID = 2**63 - 1


def valid_id(job_id: int) -> bool:
    return 1 <= job_id <= MAX_ID


class StoreBase:
    """One SQL database (SQLite or PostgreSQL): its engine, write and read transactions, tables."""

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
