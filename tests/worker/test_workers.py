"""Real worker processes on a real database (SQLite and PostgreSQL): exactly-once
execution, kill -9 recovery from the checkpoint, fencing of a paused worker, retries up
to the limit, a crashing training process, cancellation and graceful shutdown.

The jobs use the ``simulated`` runner (worker/runners.py): the real worker, child process,
pipe protocol and store, with a training that counts steps at a known rate instead of
learning. The real training runs end to end in tests/server/test_e2e.py."""

from __future__ import annotations

import json
import signal

import pytest

from modsat_core.spec.jobspec import parse_spec
from modsat_core.spec.presets import get_preset
from worker.store import JobStore

from .helpers import pid_alive, spec_json, submit, wait_for


def _status(store, job_id):
    return store.get_job(job_id)["status"]


def _outcomes(store, job_id):
    return [(a["attempt"], a["outcome"]) for a in store.list_attempts(job_id)]


def test_exactly_once_with_three_workers(store, db_url, spawn_worker):
    ids = [submit(store, 160, checkpoint_every=80) for _ in range(10)]
    for _ in range(3):
        spawn_worker(db_url, "simulated")
    wait_for(lambda: all(_status(store, i) == "succeeded" for i in ids), 120, "10 jobs to succeed")
    pids, workers = set(), set()
    for i in ids:
        job = store.get_job(i)
        assert job["attempt"] == 1 and job["failures"] == 0, f"job {i} ran more than once"
        assert _outcomes(store, i) == [(1, "succeeded")]
        run = json.loads(store.read_artifact(i, "run.json"))
        assert run["resumed_from"] is None and run["env_steps"] == 160
        pids.add(run["pid"])
        workers.add(store.list_attempts(i)[0]["worker_id"])
        seqs = [m["seq"] for m in store.metrics_after(i)]
        assert seqs == list(range(1, len(seqs) + 1)) and len(seqs) == 10
    assert len(pids) == 10, "each job ran in its own training process"
    assert len(workers) >= 2, "the three workers shared the queue"


def test_kill9_worker_mid_job_another_resumes_from_checkpoint(store, db_url, spawn_worker):
    job_id = submit(store, 4000, checkpoint_every=400)
    a = spawn_worker(db_url, "simulated")
    job = wait_for(lambda: (j := store.get_job(job_id))["checkpoint_env_steps"] and j, 30, "a first checkpoint")
    assert str(a.pid) in job["worker_id"]
    b = spawn_worker(db_url, "simulated")
    training = wait_for(a.children, 5, "the training child of worker A")

    a.signal(signal.SIGKILL)
    a.proc.wait(5)
    checkpoint = store.get_job(job_id)["checkpoint_env_steps"]
    published_by_a = len(store.metrics_after(job_id))
    assert 400 <= checkpoint < 4000
    wait_for(lambda: not any(pid_alive(p) for p in training), 5, "the orphaned training to exit")

    wait_for(lambda: _status(store, job_id) == "succeeded", 60, "the job to succeed on worker B")
    job = store.get_job(job_id)
    attempts = store.list_attempts(job_id)
    assert [(x["attempt"], x["outcome"]) for x in attempts] == [(1, "lease-expired"), (2, "succeeded")]
    assert str(b.pid) in attempts[1]["worker_id"]
    assert attempts[1]["resumed_from_env_steps"] == checkpoint
    assert json.loads(store.read_artifact(job_id, "run.json"))["resumed_from"] == checkpoint
    assert job["env_steps"] == 4000 and job["failures"] == 1

    rows = store.metrics_after(job_id)
    first = [r for r in rows if r["attempt"] == 1]
    second = [r for r in rows if r["attempt"] == 2]
    assert len(first) == published_by_a, "the dead worker's attempt published nothing after the kill"
    assert [r["seq"] for r in rows] == sorted(r["seq"] for r in rows)
    assert all(r["env_steps"] > checkpoint for r in second), "resumed from the checkpoint, not from 0"
    steps = [r["env_steps"] for r in second]
    assert steps == sorted(steps) and steps[-1] == 4000
    assert all(x["attempt"] == 2 for x in store.list_artifacts(job_id))


def test_paused_worker_that_lost_its_lease_publishes_nothing(store, db_url, spawn_worker):
    """SIGSTOP a worker (its training child keeps running), let the lease expire and another
    worker take over, then SIGCONT it: every write it tries is fenced off."""
    job_id = submit(store, 4000, checkpoint_every=400)
    a = spawn_worker(db_url, "simulated")
    wait_for(lambda: store.get_job(job_id)["checkpoint_env_steps"], 30, "a first checkpoint")
    a.pause_outside_a_write(db_url, job_id)
    try:
        spawn_worker(db_url, "simulated")
        wait_for(lambda: store.get_job(job_id)["attempt"] == 2, 30, "worker B to take the job over")
    finally:
        a.signal(signal.SIGCONT)
    wait_for(lambda: _status(store, job_id) == "succeeded", 60, "the job to succeed")
    wait_for(lambda: "lease lost" in a.log() or "fenced off" in a.log(), 10, "worker A to notice")
    assert a.proc.poll() is None, "worker A carries on as a worker"

    attempts = store.list_attempts(job_id)
    assert [(x["attempt"], x["outcome"]) for x in attempts] == [(1, "lease-expired"), (2, "succeeded")]
    reaped_at = attempts[0]["ended_at"]
    late = [r for r in store.metrics_after(job_id) if r["attempt"] == 1 and r["created_at"] > reaped_at]
    assert late == [], "nothing from the fenced-off attempt after it lost the lease"
    assert all(x["attempt"] == 2 for x in store.list_artifacts(job_id))
    assert json.loads(store.read_artifact(job_id, "run.json"))["resumed_from"] == attempts[1]["resumed_from_env_steps"]


def test_training_that_raises_fails_after_retry_limit(store, db_url, spawn_worker):
    job_id = submit(store, max_attempts=3)
    spawn_worker(db_url, "raise")
    wait_for(lambda: _status(store, job_id) == "failed", 60, "the job to fail")
    job = store.get_job(job_id)
    assert job["attempt"] == 3 and job["failures"] == 3
    assert "training raised RuntimeError: simulated training failure" in job["error"]
    assert "failed attempt 3 of 3; no retries left" in job["error"]
    assert "Traceback" in job["error_detail"]
    assert _outcomes(store, job_id) == [(1, "failed"), (2, "failed"), (3, "failed")]


def test_crashing_training_process_is_retried_from_checkpoint(store, db_url, spawn_worker):
    job_id = submit(store, 800, checkpoint_every=160)
    spawn_worker(db_url, "tests.worker.runners_for_tests:crash_once")
    wait_for(lambda: _status(store, job_id) == "succeeded", 60, "the job to succeed")
    attempts = store.list_attempts(job_id)
    assert [(x["attempt"], x["outcome"]) for x in attempts] == [(1, "crashed"), (2, "succeeded")]
    assert "killed by SIGKILL" in attempts[0]["error"]
    assert attempts[1]["resumed_from_env_steps"] >= 160


def test_cancel_running_job(store, db_url, spawn_worker):
    job_id = submit(store, 60_000, checkpoint_every=100_000)
    spawn_worker(db_url, "simulated")
    wait_for(lambda: store.get_job(job_id)["env_steps"] > 0, 30, "the job to make progress")
    assert store.request_cancel(job_id) == "requested"
    wait_for(lambda: _status(store, job_id) == "cancelled", 10, "the job to be cancelled")
    job = store.get_job(job_id)
    assert job["env_steps"] < 60_000, "stopped early"
    # A cancelled job will not resume: its checkpoint is not kept (disk).
    assert job["checkpoint_env_steps"] is None and store.artifact_info(job_id, "checkpoint.pt") is None
    assert _outcomes(store, job_id) == [(1, "cancelled")]
    after = submit(store, 160)  # the worker carries on with the next job
    wait_for(lambda: _status(store, after) == "succeeded", 30, "the next job to succeed")


def test_sigterm_requeues_job_without_a_failure(store, db_url, spawn_worker):
    job_id = submit(store, 60_000, checkpoint_every=100_000, max_attempts=1)
    a = spawn_worker(db_url, "simulated")
    wait_for(lambda: store.get_job(job_id)["env_steps"] > 0, 30, "the job to make progress")
    a.signal(signal.SIGTERM)
    assert a.proc.wait(15) == 0
    job = store.get_job(job_id)
    assert job["status"] == "queued" and job["failures"] == 0 and job["worker_id"] is None
    assert job["checkpoint_env_steps"] is not None
    assert _outcomes(store, job_id) == [(1, "released")]


def test_kill9_during_real_training_resumes_from_its_checkpoint(sqlite_url, spawn_worker):
    """The same recovery with modsat_core.training.train: its checkpoint bytes cross the pipe, land in the
    database, and a new worker's training continues from them."""
    store = JobStore(sqlite_url)
    store.create_schema()
    d = get_preset("quick-td3").model_dump(mode="json")
    d["training"].update(
        total_env_steps=640,
        learning_starts=160,
        eval_every_steps=320,
        checkpoint_every_steps=160,
        train_frequency=16,
        batch_size=32,
        hidden_sizes=[16, 16],
    )
    d["evaluation"].update(episodes=2, trajectories=0)
    spec = parse_spec(d)
    job_id = store.submit(
        spec.model_dump_json(), name="real", algorithm=spec.algorithm, total_env_steps=640, max_attempts=3
    )
    a = spawn_worker(sqlite_url, "train")
    wait_for(lambda: (store.get_job(job_id)["checkpoint_env_steps"] or 0) >= 160, 120, "a real checkpoint")
    a.signal(signal.SIGKILL)
    a.proc.wait(5)
    checkpoint = store.get_job(job_id)["checkpoint_env_steps"]
    assert checkpoint < 640, "killed mid-run"
    spawn_worker(sqlite_url, "train")
    wait_for(lambda: _status(store, job_id) == "succeeded", 180, "the resumed training to succeed")
    attempts = store.list_attempts(job_id)
    assert [(x["outcome"], x["resumed_from_env_steps"]) for x in attempts] == [
        ("lease-expired", None),
        ("succeeded", checkpoint),
    ]
    second = [r["env_steps"] for r in store.metrics_after(job_id) if r["attempt"] == 2]
    assert second and min(second) > checkpoint
    curve = json.loads(store.read_artifact(job_id, "curve.json"))
    assert curve["points"][-1]["env_steps"] >= 640
    store.dispose()


def test_result_the_database_refuses_fails_the_attempt_instead_of_hanging(store, db_url, spawn_worker):
    """Only a database outage is retried when the end of an attempt is recorded; a statement
    the database will always refuse fails the attempt (before, the worker retried it for ever
    and the job stayed `running` with a live lease)."""
    job_id = submit(store, 160, max_attempts=2)
    spawn_worker(db_url, "tests.worker.runners_for_tests:long_file_name")
    wait_for(lambda: _status(store, job_id) in ("succeeded", "failed"), 60, "the job to end")
    if store.backend == "postgresql":  # SQLite does not enforce the VARCHAR(200) of the name
        job = store.get_job(job_id)
        assert job["status"] == "failed" and "worker error: DataError" in job["error"], job["error"]
        assert _outcomes(store, job_id) == [(1, "crashed"), (2, "crashed")]


def test_training_gets_one_torch_thread_by_default(store, db_url, spawn_worker):
    """Torch's default (a thread per core) measured about 20x slower on a busy 2-core machine."""
    first = submit(store, 160)
    w = spawn_worker(db_url, "tests.worker.runners_for_tests:torch_threads")
    wait_for(lambda: _status(store, first) == "succeeded", 60, "the job to succeed")
    assert json.loads(store.get_job(first)["summary"]) == {"threads": 1, "omp": "1"}
    w.stop()
    second = submit(store, 160)
    spawn_worker(db_url, "tests.worker.runners_for_tests:torch_threads", env={"MODSAT_TORCH_THREADS": "2"})
    wait_for(lambda: _status(store, second) == "succeeded", 60, "the job to succeed")
    assert json.loads(store.get_job(second)["summary"])["threads"] == 2


def test_spec_that_cannot_run_here_fails_once_without_retries(store, db_url, spawn_worker):
    """device 'cuda' on a machine without a GPU: the same error three times helps nobody."""
    import torch

    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU: device 'cuda' runs here")
    spec = json.loads(spec_json(160))
    spec["training"]["device"] = "cuda"
    job_id = store.submit(json.dumps(spec), name="cuda", algorithm="td3-codesign", total_env_steps=160, max_attempts=3)
    spawn_worker(db_url, "train")
    wait_for(lambda: _status(store, job_id) == "failed", 90, "the job to fail")
    job = store.get_job(job_id)
    assert job["attempt"] == 1 and job["failures"] == 1
    assert "torch sees no GPU" in job["error"] and "Traceback" in job["error_detail"]
    assert _outcomes(store, job_id) == [(1, "failed")]


def test_worker_refuses_a_job_over_its_own_limits(store, db_url, spawn_worker):
    """Workers may run on smaller machines than the API assumed: they check the limits again."""
    job_id = submit(store, 160)
    spawn_worker(db_url, "noop", env={"MODSAT_MAX_ENV_STEPS": "100"})
    wait_for(lambda: _status(store, job_id) == "failed", 60, "the job to fail")
    job = store.get_job(job_id)
    assert "limits refuse the job" in job["error"] and "MODSAT_MAX_ENV_STEPS" in job["error"]
    assert job["failures"] == 1
