"""Shared test helpers for the service: databases, worker processes, waiting.

The PostgreSQL tests use a database created for this test session on the local server
(``MODSAT_TEST_PG_URL``, default ``postgresql://postgres@127.0.0.1:5432/postgres`` as the
admin connection) and skip with the reason when none is reachable.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

REPO = Path(__file__).resolve().parents[2]
PG_ADMIN_URL = os.environ.get("MODSAT_TEST_PG_URL", "postgresql://postgres@127.0.0.1:5432/postgres")

#: Fast leases so that crash tests take seconds.
FAST_ENV = {
    "MODSAT_LEASE_S": "2.5",
    "MODSAT_HEARTBEAT_S": "0.4",
    "MODSAT_POLL_S": "0.2",
    "MODSAT_RETRY_DELAY_S": "0",
    "MODSAT_CANCEL_GRACE_S": "5",
    "MODSAT_SIM_STEPS_PER_S": "1000",
}


def wait_for(pred: Callable[[], Any], timeout: float, what: str, interval: float = 0.1) -> Any:
    """Poll ``pred`` until it returns something truthy; fail with ``what`` after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while True:
        value = pred()
        if value:
            return value
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout:.0f} s waiting for {what}")
        time.sleep(interval)


def spec_json(
    total_env_steps: int = 400,
    *,
    checkpoint_every: int = 100,
    num_envs: int = 16,
    seed: int = 0,
    name: str | None = None,
) -> str:
    """A tiny valid JobSpec (the quick preset with a small budget)."""
    from modsat_core.spec.jobspec import parse_spec
    from modsat_core.spec.presets import get_preset

    d = get_preset("quick-td3").model_dump(mode="json")
    d["seed"] = seed
    d["name"] = name or "test"
    d["training"].update(
        total_env_steps=total_env_steps,
        checkpoint_every_steps=checkpoint_every,
        eval_every_steps=max(1, total_env_steps // 2),
        num_envs=num_envs,
    )
    return parse_spec(d).model_dump_json()


def submit(store, total_env_steps: int = 400, *, max_attempts: int = 3, **kw) -> int:
    text = spec_json(total_env_steps, **kw)
    return store.submit(
        text, name="test", algorithm="td3-codesign", total_env_steps=total_env_steps, max_attempts=max_attempts
    )


class WorkerProc:
    """A real ``python -m worker`` process with its own session (so we can signal it alone)."""

    def __init__(self, db_url: str, runner: str, log_path: Path, env: dict[str, str] | None = None):
        self.log_path = log_path
        self._log = open(log_path, "wb")  # closed in stop()
        full_env = {**os.environ, **FAST_ENV, **(env or {})}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "worker", "--db", db_url, "--runner", runner],
            cwd=REPO,
            env=full_env,
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        self.pid = self.proc.pid

    def children(self) -> list[int]:
        """Pids of this worker's child processes (the training), from /proc."""
        out = []
        for task in Path(f"/proc/{self.pid}/task").glob("*"):
            try:
                out += [int(x) for x in (task / "children").read_text().split()]
            except OSError:
                pass
        return out

    def signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            os.kill(self.pid, sig)

    def pause_outside_a_write(self, db_url: str, job_id: int, tries: int = 100) -> None:
        """SIGSTOP the worker at a moment when it holds no write lock on ``job_id``.

        A process frozen inside a write transaction holds the database's one write lock
        (SQLite) or the job's row (PostgreSQL) until it resumes: every other writer waits, or
        skips the row. That is the database's behaviour, not the lease fencing a pause test is
        about, so a pause that lands inside a transaction is undone and tried again."""
        from sqlalchemy import select
        from sqlalchemy.exc import OperationalError

        from worker.store import JobStore
        from worker.store.schema import jobs

        probe = JobStore(db_url, busy_timeout_s=0.2)
        try:
            for _ in range(tries):
                self.signal(signal.SIGSTOP)
                try:  # SQLite: BEGIN IMMEDIATE; PostgreSQL: the job's row, without waiting
                    with probe._write_engine.begin() as conn:  # the store's write path
                        conn.execute(select(jobs.c.id).where(jobs.c.id == job_id).with_for_update(nowait=True))
                    return
                except OperationalError:
                    self.signal(signal.SIGCONT)
                    time.sleep(0.05)
        finally:
            probe.dispose()
        raise AssertionError(f"worker {self.pid} held a write lock at each of {tries} pauses")

    def stop(self, timeout: float = 15.0) -> int | None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self._log.close()
        return self.proc.returncode

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")


def pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:  # a zombie is dead for our purposes
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except OSError:
        return False


class PgServer:
    """Creates one throw-away database per test session on the local PostgreSQL server."""

    def __init__(self, admin_url: str = PG_ADMIN_URL):
        self.admin_url = admin_url
        self.reason: str | None = None
        self.url: str | None = None
        self.dbname = f"modsat_test_{os.getpid()}_{uuid.uuid4().hex[:6]}"

    def _admin(self):
        import psycopg

        return psycopg.connect(
            self.admin_url.replace("postgresql+psycopg", "postgresql"), autocommit=True, connect_timeout=3
        )

    def start(self) -> None:
        try:
            with self._admin() as conn:
                conn.execute(f'CREATE DATABASE "{self.dbname}"')
        except Exception as exc:  # any failure means: no PostgreSQL here
            self.reason = f"PostgreSQL not reachable at {self.admin_url} (set MODSAT_TEST_PG_URL): {exc}"
            return
        base = self.admin_url.rsplit("/", 1)[0]
        self.url = f"{base}/{self.dbname}"

    def stop(self) -> None:
        if self.url is None:
            return
        try:
            with self._admin() as conn:
                conn.execute(f'DROP DATABASE IF EXISTS "{self.dbname}" WITH (FORCE)')
        except Exception:  # best effort
            pass


def fresh_db_url(kind: str, tmp_path: Path, pg: PgServer) -> str:
    """An empty job store of ``kind`` (sqlite | postgresql) with the tables created."""
    from worker.store import JobStore

    if kind == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.db'}"
    else:
        if pg.url is None:
            pytest.skip(pg.reason or "PostgreSQL not available")
        url = pg.url
    store = JobStore(url)
    store.drop_schema()
    store.create_schema()
    store.dispose()
    return url


# ----------------------------------------------------------------------------- fixtures
# Imported by tests/worker/conftest.py and tests/server/conftest.py.


@pytest.fixture(scope="session")
def pg():
    server = PgServer()
    server.start()
    yield server
    server.stop()


@pytest.fixture(params=["sqlite", "postgresql"])
def db_url(request, tmp_path, pg) -> str:
    """An empty job store, once on SQLite and once on PostgreSQL."""
    return fresh_db_url(request.param, tmp_path, pg)


@pytest.fixture
def sqlite_url(tmp_path) -> str:
    return f"sqlite:///{tmp_path / 'jobs.db'}"


def process_factory(request, make: Callable[..., Any], describe: Callable[[Any], str]):
    """Body of a factory fixture (``yield from``): ``make(i, ...)`` starts the i-th process; at
    teardown every one is stopped and, if the test failed, ``describe(p)`` (its log) is printed."""
    procs: list[Any] = []

    def start(*args, **kwargs):
        p = make(len(procs), *args, **kwargs)
        procs.append(p)
        return p

    yield start
    for p in procs:
        p.stop()
    failed = getattr(request.node, "rep_call", None)  # set by the hook in tests/conftest.py
    if failed is not None and failed.failed:
        for p in procs:
            print(describe(p))


@pytest.fixture
def spawn_worker(tmp_path, request):
    """Start real worker processes: ``spawn(db_url, runner="simulated", env=None)``."""

    def make(i: int, db_url: str, runner: str = "simulated", env: dict[str, str] | None = None) -> WorkerProc:
        return WorkerProc(db_url, runner, tmp_path / f"worker{i}.log", env)

    yield from process_factory(request, make, lambda w: f"----- log of worker {w.pid}\n{w.log()}")
