"""Fixtures for the API tests: a real uvicorn server in a subprocess, on a free port."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import pytest

from tests.worker.helpers import (  # noqa: F401
    FAST_ENV,
    REPO,
    fresh_db_url,
    pg,
    process_factory,
    spawn_worker,
    sqlite_url,
    wait_for,
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class HttpProc:
    """A server subprocess (``self.proc``, its output in ``self.log_path``) that answers
    ``GET /api/health``; ``stop()`` sends SIGINT (to its process group if ``group``), then
    SIGKILL after ``stop_timeout_s``."""

    group = False
    stop_timeout_s = 15.0

    def _up(self) -> bool:
        if self.proc.poll() is not None:
            raise AssertionError(f"{self.proc.args[:2]} exited:\n{self.log_path.read_text(errors='replace')}")
        try:
            return httpx.get(f"{self.base}/api/health", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    def _signal(self, sig: int) -> None:
        if self.group:
            os.killpg(self.proc.pid, sig)
        else:
            self.proc.send_signal(sig)

    def stop(self) -> None:
        self.client.close()
        if self.proc.poll() is None:
            self._signal(signal.SIGINT)
            try:
                self.proc.wait(self.stop_timeout_s)
            except subprocess.TimeoutExpired:
                self._signal(signal.SIGKILL)
                self.proc.wait()
        self._log.close()


class ServerProc(HttpProc):
    """``uvicorn server.app:create_app --factory`` with the given settings."""

    def __init__(self, db_url: str, log_path: Path, env: dict[str, str] | None = None):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log_path = log_path
        self._log = open(log_path, "wb")  # closed in stop()
        self.proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "uvicorn",
                "server.app:create_app",
                "--factory",
                "--host",
                "127.0.0.1",
                "--port",
                str(self.port),
                "--timeout-graceful-shutdown",
                "2",
            ],
            # The live viewer is tested in tests/web; here it would only take a port.
            cwd=REPO,
            env={**os.environ, **FAST_ENV, "MODSAT_VIEWER": "false", "MODSAT_DB_URL": db_url, **(env or {})},
            stdout=self._log,
            stderr=subprocess.STDOUT,
        )
        wait_for(self._up, 30, f"the API server on port {self.port}")
        self.client = httpx.Client(base_url=self.base, timeout=30)


@pytest.fixture
def start_server(tmp_path, request):
    """Factory: start API servers, ``start(db_url, env=None)``; stopped (logs shown on failure) at teardown."""

    def make(i: int, db_url: str, env: dict[str, str] | None = None) -> ServerProc:
        return ServerProc(db_url, tmp_path / f"server{i}.log", env)

    yield from process_factory(
        request,
        make,
        lambda s: f"----- log of the API server on port {s.port}\n{s.log_path.read_text(errors='replace')}",
    )


@pytest.fixture(params=["sqlite", "postgresql"])
def any_db_url(request, tmp_path, pg):  # noqa: F811 - pg is the fixture imported above
    """An empty job store, once on SQLite and once on PostgreSQL (skipped if unreachable)."""
    return fresh_db_url(request.param, tmp_path, pg)


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    """One server without workers and without a token, shared by a module's read/validation tests."""
    d = tmp_path_factory.mktemp("api")
    s = ServerProc(f"sqlite:///{d / 'jobs.db'}", d / "server.log")
    yield s
    s.stop()
