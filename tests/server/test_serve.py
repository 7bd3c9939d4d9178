"""`modsat serve` as a person runs it: start, work, Ctrl-C, start again -- every job is intact,
and the job that was running when it stopped resumes from its checkpoint."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import httpx

from tests.worker.helpers import FAST_ENV, pid_alive

from .conftest import free_port, wait_for

MODSAT = str(Path(sys.executable).with_name("modsat"))


class Serve:
    def __init__(self, data_dir: Path, log: Path, workers: int = 1):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.log_path = log
        self._log = open(log, "wb")
        self.proc = subprocess.Popen(
            [
                MODSAT,
                "serve",
                "--workers",
                str(workers),
                "--data-dir",
                str(data_dir),
                "--port",
                str(self.port),
                "--runner",
                "simulated",
            ],
            env={**os.environ, **FAST_ENV},
            stdout=self._log,
            stderr=subprocess.STDOUT,
            start_new_session=True,  # its own process group, like a terminal's foreground job
        )
        wait_for(self._up, 30, "modsat serve to answer")
        self.client = httpx.Client(base_url=self.base, timeout=30)

    def _up(self) -> bool:
        assert self.proc.poll() is None, self.log_path.read_text()
        try:
            return httpx.get(f"{self.base}/api/health", timeout=2).status_code == 200
        except httpx.HTTPError:
            return False

    def ctrl_c(self) -> int:
        """SIGINT to the whole process group, as Ctrl-C in a terminal does."""
        self.client.close()
        os.killpg(self.proc.pid, signal.SIGINT)
        try:
            return self.proc.wait(30)
        finally:
            if self.proc.poll() is None:
                os.killpg(self.proc.pid, signal.SIGKILL)
            self._log.close()

    def job(self, job_id: int) -> dict:
        return self.client.get(f"/api/jobs/{job_id}").json()

    def snapshot(self) -> dict:
        out = {}
        for j in self.client.get("/api/jobs", params={"limit": 500}).json()["items"]:
            jid = j["id"]
            out[jid] = {
                "job": self.job(jid),
                "metrics": self.client.get(f"/api/jobs/{jid}/metrics").json()["items"],
                "artifacts": self.client.get(f"/api/jobs/{jid}/artifacts").json(),
            }
        return out


def _submit(s: Serve, steps: int, checkpoint_every: int = 100_000) -> int:
    r = s.client.post(
        "/api/jobs",
        json={
            "preset": "quick-td3",
            "overrides": {"training": {"total_env_steps": steps, "checkpoint_every_steps": checkpoint_every}},
        },
    )
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_ctrl_c_and_restart_keep_every_job(tmp_path):
    data = tmp_path / "data"
    s = Serve(data, tmp_path / "serve1.log")
    try:
        short = [_submit(s, 300) for _ in range(3)]
        long = _submit(s, 8000, checkpoint_every=1000)
        cancelled = _submit(s, 300)
        assert s.client.post(f"/api/jobs/{cancelled}/cancel").json()["job"]["status"] == "cancelled"
        wait_for(lambda: all(s.job(j)["status"] == "succeeded" for j in short), 60, "the short jobs")
        wait_for(lambda: s.job(long)["progress"]["checkpoint_env_steps"], 30, "a checkpoint of the long job")
        workers = [w["pid"] for w in s.client.get("/api/health").json()["workers"]]
        assert len(workers) == 1
        before = s.snapshot()
    finally:
        code = s.ctrl_c()
    log = (tmp_path / "serve1.log").read_text()
    assert code == 0, log
    assert "modsat: API" in log and "modsat: stopped" in log
    wait_for(lambda: not any(pid_alive(p) for p in workers), 5, "the workers to exit")

    s2 = Serve(data, tmp_path / "serve2.log", workers=0)
    try:
        after = s2.snapshot()
        assert set(after) == set(before), "no job lost"
        for jid in [*short, cancelled]:
            assert after[jid] == before[jid], f"job {jid} changed across the restart"
        stopped = after[long]["job"]
        assert stopped["status"] == "queued" and stopped["failures"] == 0, "requeued, not failed"
        assert [a["outcome"] for a in stopped["attempts"]] == ["released"]
        checkpoint = stopped["progress"]["checkpoint_env_steps"]
        assert checkpoint >= 1000
        assert after[long]["metrics"][: len(before[long]["metrics"])] == before[long]["metrics"]
    finally:
        assert s2.ctrl_c() == 0

    s3 = Serve(data, tmp_path / "serve3.log", workers=1)
    try:
        job = wait_for(lambda: (j := s3.job(long))["status"] == "succeeded" and j, 60, "the long job to finish")
        assert [(a["outcome"], a["resumed_from_env_steps"]) for a in job["attempts"]] == [
            ("released", None),
            ("succeeded", checkpoint),
        ]
    finally:
        assert s3.ctrl_c() == 0


def test_a_taken_port_is_reported_before_anything_starts(tmp_path):
    """A second `modsat serve` on the same port: one clear line, no viewer, no worker."""
    import socket

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        r = subprocess.run(
            [
                MODSAT,
                "serve",
                "--workers",
                "1",
                "--data-dir",
                str(tmp_path / "d"),
                "--port",
                str(port),
                "--viewer-port",
                "0",
            ],
            capture_output=True,
            text=True,
            timeout=60,
            env={**os.environ, **FAST_ENV},
        )
    assert r.returncode == 1
    assert f"cannot listen on 127.0.0.1:{port}" in r.stderr and "--port" in r.stderr, r.stderr
    assert "worker" not in r.stdout and "viewer" not in r.stdout.lower(), r.stdout
