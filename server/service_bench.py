"""Benchmarks of the job service (not tests): ``modsat bench service [api] [queue] [--json]``
(its parser: server/cli/bench.py).

* ``api``: p50 / p99 latency of ``GET /api/jobs`` with 1,000 jobs stored, under 50
  concurrent clients on loopback (uvicorn in a subprocess, one process, as ``modsat serve``
  runs it; the clients run on the same machine and share its cores).
* ``queue``: jobs per second that 4 worker processes take from a queue of 1,000 no-op
  jobs: ``claim`` (the atomic claim alone) and ``cycle`` (claim + heartbeat + complete,
  the whole queue life of a job without its training); plus ``workers``: real
  ``python -m worker --runner noop`` processes, which also start a training child
  process per job.
* ``threads``: the run time of one short job through ``modsat serve`` with each
  ``MODSAT_TORCH_THREADS`` while other CPU-bound processes run.

SQLite is a file in a temporary directory; PostgreSQL is a database created for the run on
the server of ``--pg`` (default ``postgresql://postgres@127.0.0.1:5432/postgres``), skipped
with the reason if it cannot be reached.
"""

from __future__ import annotations

import asyncio
import json
import multiprocessing as mp
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import httpx

from worker.store import JobStore

DEFAULT_PG = "postgresql://postgres@127.0.0.1:5432/postgres"


def _spec_json() -> str:
    from modsat_core.spec.presets import get_preset

    return get_preset("quick").model_copy(update={"name": "bench"}).model_dump_json()


def _fill(store: JobStore, n: int, total_env_steps: int = 30_000) -> None:
    text = _spec_json()
    for _ in range(n):
        store.submit(text, name="bench", algorithm="td3-codesign", total_env_steps=total_env_steps, max_attempts=3)


class _PgDatabase:
    """A database created for the benchmark and dropped afterwards."""

    def __init__(self, admin_url: str):
        import psycopg

        self.admin_url, self.name = admin_url, f"modsat_bench_{os.getpid()}_{uuid.uuid4().hex[:6]}"
        with psycopg.connect(admin_url, autocommit=True, connect_timeout=3) as conn:
            conn.execute(f'CREATE DATABASE "{self.name}"')
        self.url = f"{admin_url.rsplit('/', 1)[0]}/{self.name}"

    def drop(self) -> None:
        import psycopg

        with psycopg.connect(self.admin_url, autocommit=True, connect_timeout=3) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


def _databases(which: list[str], pg_admin: str, tmp: Path):
    """Yield (kind, url, cleanup) for each requested backend, or (kind, None, reason)."""
    for kind in which:
        if kind == "sqlite":
            path = tmp / f"bench-{uuid.uuid4().hex[:6]}.db"
            yield kind, f"sqlite:///{path}", lambda: None
        else:
            try:
                db = _PgDatabase(pg_admin)
            except Exception as exc:  # report and skip
                yield kind, None, f"skipped: PostgreSQL not reachable at {pg_admin}: {exc}"
                continue
            yield kind, db.url, db.drop


# ----------------------------------------------------------------------------- API latency


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _hammer(base: str, clients: int, requests: int, path: str) -> list[float]:
    latencies: list[float] = []
    remaining = requests
    limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
    async with httpx.AsyncClient(base_url=base, limits=limits, timeout=60) as client:

        async def one_client() -> None:
            nonlocal remaining
            while remaining > 0:
                remaining -= 1
                t0 = time.perf_counter()
                r = await client.get(path)
                latencies.append(time.perf_counter() - t0)
                if r.status_code != 200:
                    raise RuntimeError(f"GET {path}: {r.status_code} {r.text[:200]}")

        await asyncio.gather(*(one_client() for _ in range(clients)))
    return latencies


def bench_api(url: str, *, jobs: int = 1000, clients: int = 50, requests: int = 3000) -> dict:
    store = JobStore(url)
    store.create_schema()
    _fill(store, jobs)
    store.dispose()
    port = _free_port()
    base = f"http://127.0.0.1:{port}"
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "uvicorn",
            "server.app:create_app",
            "--factory",
            "--port",
            str(port),
            "--log-level",
            "warning",
            "--timeout-keep-alive",
            "30",
        ],
        env={**os.environ, "MODSAT_DB_URL": url},
    )
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                if httpx.get(f"{base}/api/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if time.monotonic() > deadline or proc.poll() is not None:
                raise RuntimeError("the API server did not start")
            time.sleep(0.2)
        asyncio.run(_hammer(base, clients, 200, "/api/jobs"))  # warm up
        cpu0 = _cpu_seconds(proc.pid)
        t0 = time.perf_counter()
        lat = asyncio.run(_hammer(base, clients, requests, "/api/jobs"))
        wall = time.perf_counter() - t0
        server_cpu = _cpu_seconds(proc.pid) - cpu0
    finally:
        proc.terminate()
        proc.wait(15)
    lat_ms = sorted(x * 1000 for x in lat)
    q = statistics.quantiles(lat_ms, n=100)
    return {
        "endpoint": "GET /api/jobs (limit 50, total count)",
        "jobs_stored": jobs,
        "clients": clients,
        "requests": len(lat_ms),
        "p50_ms": round(q[49], 1),
        "p90_ms": round(q[89], 1),
        "p99_ms": round(q[98], 1),
        "max_ms": round(lat_ms[-1], 1),
        "requests_per_s": round(len(lat_ms) / wall, 1),
        "server_cpu_ms_per_request": round(1000 * server_cpu / len(lat_ms), 2) if server_cpu else None,
        "load_average_1min": round(os.getloadavg()[0], 2),
    }


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process (Linux /proc; 0 elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return 0.0


# ----------------------------------------------------------------------------- queue throughput


def _claimer(url: str, mode: str, start, out) -> None:
    store = JobStore(url)
    name = f"bench-{os.getpid()}"
    n = 0
    start.wait()
    while (c := store.claim(name, lease_s=60)) is not None:
        if mode == "cycle":
            store.heartbeat(c, lease_s=60)
            store.complete(c, files={}, summary=None, env_steps=0, attempt_seconds=0.0)
        n += 1
    out.put(n)
    store.dispose()


def bench_claims(url: str, *, jobs: int = 1000, workers: int = 4, mode: str = "claim") -> dict:
    store = JobStore(url)
    store.create_schema()
    _fill(store, jobs)
    ctx = mp.get_context("spawn")
    start, out = ctx.Event(), ctx.Queue()
    procs = [ctx.Process(target=_claimer, args=(url, mode, start, out)) for _ in range(workers)]
    for p in procs:
        p.start()
    time.sleep(2.0)  # let every process import and connect before the clock starts
    t0 = time.perf_counter()
    start.set()
    counts = [out.get(timeout=600) for _ in procs]
    wall = time.perf_counter() - t0
    for p in procs:
        p.join(30)
    counts_db = store.status_counts()
    store.dispose()
    if sum(counts) != jobs:
        raise RuntimeError(f"claimed {sum(counts)} of {jobs} jobs")
    return {
        "mode": mode,
        "jobs": jobs,
        "workers": workers,
        "seconds": round(wall, 3),
        "jobs_per_s": round(jobs / wall, 1),
        "per_worker": counts,
        "final_status": counts_db,
    }


def bench_worker_processes(url: str, *, jobs: int = 100, workers: int = 4) -> dict:
    """Real workers with the no-op runner: each job also spawns its training child process."""
    store = JobStore(url)
    store.create_schema()
    _fill(store, jobs, total_env_steps=1)
    env = {**os.environ, "MODSAT_POLL_S": "0.05", "MODSAT_RUNNER": "noop"}
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "worker", "--db", url, "--idle-exit", "1.0"],
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
        for _ in range(workers)
    ]
    t0 = time.perf_counter()
    while store.status_counts().get("succeeded", 0) < jobs:
        if all(p.poll() is not None for p in procs):
            raise RuntimeError(f"workers exited early: {store.status_counts()}")
        time.sleep(0.05)
    wall = time.perf_counter() - t0
    for p in procs:
        p.wait(30)
    store.dispose()
    return {
        "mode": "worker processes, noop runner (child process per job)",
        "jobs": jobs,
        "workers": workers,
        "seconds": round(wall, 2),
        "jobs_per_s": round(jobs / wall, 1),
    }


# ----------------------------------------------------------------------------- torch threads

#: The `quick` preset cut to a benchmark: 1,008 env steps, learning from step 256, 8 final slews.
THREADS_JOB = {
    "preset": "quick",
    "overrides": {
        "training": {"total_env_steps": 1008, "learning_starts": 256, "eval_every_steps": 100_000},
        "evaluation": {"episodes": 8},
    },
}


def _busy() -> None:
    while True:
        pass


def bench_threads(threads: list[int], busy: int = 1) -> dict:
    """``THREADS_JOB`` through ``modsat serve`` (SQLite, one worker) with each
    ``MODSAT_TORCH_THREADS``, while ``busy`` other CPU-bound processes run: the job's
    ``run_seconds`` each time (issue 13: torch's default of a thread per core was about 20x
    slower on a busy 2-core machine)."""
    burners = [mp.get_context("spawn").Process(target=_busy, daemon=True) for _ in range(busy)]
    for b in burners:
        b.start()
    out: dict = {"job": THREADS_JOB, "busy_processes": busy, "run_seconds": {}}
    try:
        for n in threads:
            with tempfile.TemporaryDirectory(prefix="modsat-bench-threads-") as tmp:
                port = _free_port()
                env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "MKL_NUM_THREADS")}
                proc = subprocess.Popen(
                    [
                        sys.executable,
                        "-m",
                        "server.cli",
                        "serve",
                        "--workers",
                        "1",
                        "--port",
                        str(port),
                        "--no-viewer",
                        "--data-dir",
                        tmp,
                    ],
                    env={**env, "MODSAT_TORCH_THREADS": str(n)},
                    stdout=subprocess.DEVNULL,
                    stderr=subprocess.DEVNULL,
                    start_new_session=True,
                )
                try:
                    c = httpx.Client(base_url=f"http://127.0.0.1:{port}", timeout=30)
                    deadline = time.monotonic() + 60
                    while True:
                        try:
                            if c.get("/api/health").status_code == 200:
                                break
                        except httpx.HTTPError:
                            pass
                        if time.monotonic() > deadline:
                            raise RuntimeError("modsat serve did not start")
                        time.sleep(0.5)
                    job = c.post("/api/jobs", json=THREADS_JOB).json()
                    while (j := c.get(f"/api/jobs/{job['id']}").json())["status"] not in ("succeeded", "failed"):
                        time.sleep(2)
                    out["run_seconds"][str(n)] = j["progress"]["run_seconds"] if j["status"] == "succeeded" else None
                finally:
                    os.killpg(proc.pid, 2)
                    proc.wait(60)
    finally:
        for b in burners:
            b.kill()
    t = out["run_seconds"]
    if t.get("1"):
        out["ratio_to_1_thread"] = {k: (v / t["1"] if v else None) for k, v in t.items()}
    return out


# ----------------------------------------------------------------------------- the report


def bench_service(
    what: list[str],
    *,
    db: list[str],
    pg: str | None,
    jobs: int,
    clients: int,
    requests: int,
    workers: int,
    quiet: bool = False,
) -> dict:
    """``modsat bench service api queue``: the report of each database in ``db`` (a line per database
    on stderr as it finishes unless ``quiet``)."""
    pg = pg or os.environ.get("MODSAT_BENCH_PG_URL", DEFAULT_PG)
    report: dict = {
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "platform": platform.platform()},
        "results": {},
    }
    with tempfile.TemporaryDirectory(prefix="modsat-bench-") as tmp:
        for kind, url, cleanup in _databases(db, pg, Path(tmp)):
            res: dict = {}
            report["results"][kind] = res
            if url is None:
                res["error"] = cleanup
                continue
            try:
                if "api" in what:
                    res["api"] = bench_api(url, jobs=jobs, clients=clients, requests=requests)
                    JobStore(url).drop_schema()
                if "queue" in what:
                    for mode in ("claim", "cycle"):
                        res[f"queue_{mode}"] = bench_claims(url, jobs=jobs, workers=workers, mode=mode)
                        JobStore(url).drop_schema()
                    res["queue_worker_processes"] = bench_worker_processes(url, jobs=40, workers=workers)
                    JobStore(url).drop_schema()
            finally:
                cleanup()
            if not quiet:
                print(f"{kind}: {json.dumps(res)}", file=sys.stderr, flush=True)
    return report
