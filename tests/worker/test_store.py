"""The job store (worker/store/) on a real database (SQLite and PostgreSQL):
atomic claims, leases, the reaper, retries, cancellation, fencing, metrics and artefacts."""

from __future__ import annotations

import threading
import time
from contextlib import contextmanager

import pytest
from sqlalchemy import event

from worker.store import CHECKPOINT_NAME, JobStore

from .helpers import submit


def test_concurrent_claims_take_each_job_exactly_once(store, db_url):
    ids = {submit(store) for _ in range(30)}
    claimed: list[tuple[str, int]] = []
    lock = threading.Lock()

    def claimer(name: str) -> None:
        own = JobStore(db_url)  # one engine per thread, like one per process
        try:
            while (c := own.claim(name, lease_s=60)) is not None:
                with lock:
                    claimed.append((name, c.job_id))
        finally:
            own.dispose()

    threads = [threading.Thread(target=claimer, args=(f"w{i}",)) for i in range(6)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    got = [j for _, j in claimed]
    assert sorted(got) == sorted(ids), "every job claimed exactly once"
    assert all(store.get_job(j)["attempt"] == 1 for j in ids)


def test_claim_order_and_lease(store):
    first, second = submit(store), submit(store)
    c = store.claim("w1", lease_s=30)
    assert c.job_id == first and c.attempt == 1 and c.checkpoint_env_steps is None
    job = store.get_job(first)
    assert job["status"] == "running" and job["worker_id"] == "w1"
    assert 29 < job["lease_expires_at"] - job["heartbeat_at"] <= 30.01
    assert store.claim("w2", lease_s=30).job_id == second
    assert store.claim("w3", lease_s=30) is None


def test_lost_lease_is_fenced_off(store):
    """A worker whose lease expired and whose job was claimed again publishes nothing."""
    job_id = submit(store)
    old = store.claim("w-old", lease_s=0.3)
    assert store.publish_progress(old, {"env_steps": 100, "phase": "training"}) == 1
    assert store.save_checkpoint(old, 100, b"ckpt-100")
    time.sleep(0.5)
    assert store.reap(retry_delay_s=0) == [(job_id, "queued")]
    new = store.claim("w-new", lease_s=30)
    assert new.attempt == 2 and new.checkpoint_env_steps == 100

    # Everything the old attempt tries now is refused, and changes nothing.
    assert store.heartbeat(old, lease_s=30).alive is False
    assert store.publish_progress(old, {"env_steps": 999}) is None
    assert store.save_checkpoint(old, 999, b"stale") is False
    assert store.complete(old, files={"policy.pt": b"stale"}, summary=None, env_steps=999, attempt_seconds=1) is False
    assert store.fail_attempt(old, error="x", detail=None, outcome="failed", retry_delay_s=0, attempt_seconds=0) is None
    assert store.finish_cancelled(old, attempt_seconds=0) is False
    assert store.release(old, attempt_seconds=0) is False

    job = store.get_job(job_id)
    assert job["status"] == "running" and job["attempt"] == 2 and job["worker_id"] == "w-new"
    assert job["env_steps"] == 100 and job["last_seq"] == 1
    assert store.load_checkpoint(job_id) == b"ckpt-100"
    assert [m["attempt"] for m in store.metrics_after(job_id)] == [1]
    assert store.list_artifacts(job_id)[0]["name"] == CHECKPOINT_NAME

    # The new holder works normally.
    assert store.heartbeat(new, lease_s=30).alive
    assert store.publish_progress(new, {"env_steps": 120}) == 2
    assert store.complete(new, files={"policy.pt": b"good"}, summary={"ok": 1}, env_steps=400, attempt_seconds=1)
    assert store.read_artifact(job_id, "policy.pt") == b"good"
    assert store.read_artifact(job_id, CHECKPOINT_NAME) is None  # no longer needed once succeeded
    outcomes = [(a["attempt"], a["outcome"]) for a in store.list_attempts(job_id)]
    assert outcomes == [(1, "lease-expired"), (2, "succeeded")]


def test_reaper_fails_job_after_retry_limit(store):
    job_id = submit(store, max_attempts=2)
    for expected in ("queued", "failed"):
        c = store.claim("w", lease_s=0.2)
        assert c is not None
        time.sleep(0.35)
        assert store.reap(retry_delay_s=0) == [(job_id, expected)]
    job = store.get_job(job_id)
    assert job["status"] == "failed" and job["failures"] == 2 and job["finished_at"] is not None
    assert "lease expired" in job["error"] and "no retries left" in job["error"]
    assert store.claim("w", lease_s=1) is None


def test_failed_attempt_retries_with_backoff(store):
    job_id = submit(store, max_attempts=3)
    c = store.claim("w", lease_s=30)
    status = store.fail_attempt(
        c,
        error="training raised ValueError: boom",
        detail="Traceback...",
        outcome="failed",
        retry_delay_s=0.6,
        attempt_seconds=0.1,
    )
    assert status == "queued"
    job = store.get_job(job_id)
    assert "ValueError: boom" in job["error"] and "retrying" in job["error"]
    assert store.claim("w", lease_s=30) is None, "not before the back-off"
    time.sleep(0.7)
    c2 = store.claim("w", lease_s=30)
    assert c2 is not None and c2.attempt == 2 and c2.failures == 1


def test_heartbeat_extends_lease_and_reports_cancel(store):
    job_id = submit(store)
    c = store.claim("w", lease_s=0.5)
    for _ in range(4):
        time.sleep(0.25)
        assert store.heartbeat(c, lease_s=0.5).alive
        assert store.reap(retry_delay_s=0) == []
    assert store.request_cancel(job_id) == "requested"
    beat = store.heartbeat(c, lease_s=0.5)
    assert beat.alive and beat.cancel_requested
    assert store.finish_cancelled(c, attempt_seconds=1.0)
    assert store.get_job(job_id)["status"] == "cancelled"
    assert store.request_cancel(job_id) == "cancelled"  # already cancelled: says so, changes nothing


def test_cancel_queued_and_finished(store):
    queued = submit(store)
    assert store.request_cancel(queued) == "stopped"
    assert store.get_job(queued)["status"] == "cancelled"
    assert store.claim("w", lease_s=5) is None
    done = submit(store)
    c = store.claim("w", lease_s=5)
    store.complete(c, files={}, summary=None, env_steps=400, attempt_seconds=0)
    assert store.request_cancel(done) == "succeeded"
    assert store.request_cancel(10**12) is None
    assert store.request_cancel(2**70) is None  # out of BIGINT range: unknown, not an error


def test_expired_lease_of_cancelled_job_ends_cancelled(store):
    job_id = submit(store)
    store.claim("w", lease_s=0.2)
    store.request_cancel(job_id)
    time.sleep(0.3)
    assert store.reap(retry_delay_s=0) == [(job_id, "cancelled")]


def test_release_requeues_without_counting_a_failure(store):
    job_id = submit(store, max_attempts=1)
    c = store.claim("w", lease_s=30)
    store.save_checkpoint(c, 200, b"ck")
    assert store.release(c, attempt_seconds=2.0)
    job = store.get_job(job_id)
    assert job["status"] == "queued" and job["failures"] == 0 and job["run_seconds"] == pytest.approx(2.0)
    c2 = store.claim("w", lease_s=30)
    assert c2.attempt == 2 and c2.checkpoint_env_steps == 200
    assert store.get_job(job_id)["env_steps"] == 200  # restarts at the checkpoint


def test_metrics_sequence_and_json_safety(store):
    job_id = submit(store)
    c = store.claim("w", lease_s=30)
    for i in range(1, 6):
        assert store.publish_progress(c, {"env_steps": 16 * i, "loss": float("nan"), "eval": None}) == i
    rows = store.metrics_after(job_id, after=2)
    assert [r["seq"] for r in rows] == [3, 4, 5]
    assert '"loss":null' in rows[0]["data"]
    assert store.latest_metrics(job_id)["seq"] == 5
    assert store.metrics_after(job_id, after=5) == []


def test_large_artifact_round_trip_in_chunks(store):
    job_id = submit(store)
    c = store.claim("w", lease_s=30)
    blob = bytes(range(256)) * (3 * 4096 + 17)  # ~3 MiB, not a multiple of the chunk
    assert store.complete(
        c, files={"policy.pt": blob, "curve.json": b"[]"}, summary={"a": 1}, env_steps=400, attempt_seconds=1
    )
    info = store.artifact_info(job_id, "policy.pt")
    assert info["size"] == len(blob)
    assert b"".join(store.iter_artifact(job_id, "policy.pt", info["size"], info["sha256"])) == blob
    assert [a["name"] for a in store.list_artifacts(job_id)] == ["curve.json", "policy.pt"]
    assert store.artifact_info(job_id, "../policy.pt") is None


def test_artifacts_are_served_with_their_content_type(store):
    job_id = submit(store)
    c = store.claim("w", lease_s=30)
    names = ["curve.json", "policy.pt", "policy_export.pt", "policy_export.pt2", "policy_export.onnx", "curve.png"]
    assert store.complete(c, files=dict.fromkeys(names, b"x"), summary=None, env_steps=400, attempt_seconds=1)
    types = {a["name"]: a["content_type"] for a in store.list_artifacts(job_id)}
    assert types == {
        "curve.json": "application/json",
        "curve.png": "image/png",
        **dict.fromkeys(
            ["policy.pt", "policy_export.pt", "policy_export.pt2", "policy_export.onnx"], "application/octet-stream"
        ),
    }


def test_list_filter_and_pagination(store):
    ids = [submit(store) for _ in range(7)]
    store.request_cancel(ids[0])
    total, page = store.list_jobs(limit=3, offset=0)
    assert total == 7 and [j["id"] for j in page] == ids[::-1][:3]
    total, page = store.list_jobs(statuses=["queued"], limit=10, offset=2)
    assert total == 6 and len(page) == 4
    assert store.status_counts() == {"queued": 6, "cancelled": 1}


@contextmanager
def _after_first_statement(store, action):
    """Run ``action`` (in another thread, on another connection) right after the first
    statement of ``store``'s next transaction, while that transaction is still open. It gets
    1 s; if it has to wait for a lock the transaction holds, it finishes after the commit."""
    threads: list[threading.Thread] = []

    def hook(_conn, _cursor, statement, *_args) -> None:
        if threads or statement.lstrip().upper().startswith("BEGIN"):
            return
        t = threading.Thread(target=action)
        threads.append(t)
        t.start()
        t.join(1.0)

    event.listen(store.engine, "after_cursor_execute", hook)
    try:
        yield
    finally:
        event.remove(store.engine, "after_cursor_execute", hook)
        for t in threads:
            t.join(60)
    assert threads, "the hook did not run"


def test_cancel_during_release_is_not_lost(store, db_url):
    """A cancel acknowledged while a shutting-down worker gives its job back ends the job,
    rather than leaving it queued (to be run again) with the cancel flag set."""
    job_id = submit(store)
    c = store.claim("w", lease_s=30)
    other, answers = JobStore(db_url), []
    try:
        with _after_first_statement(store, lambda: answers.append(other.request_cancel(job_id))):
            assert store.release(c, attempt_seconds=0.0)
    finally:
        other.dispose()
    assert answers in (["stopped"], ["requested"])
    assert store.get_job(job_id)["status"] == "cancelled"


def test_cancel_while_the_job_is_released_says_what_happened(store, db_url):
    """The status a cancel acts on cannot change under it: a running job that its worker
    gives back at that moment is reported as running (202), not as 'already cancelled'."""
    job_id = submit(store)
    c = store.claim("w", lease_s=30)
    other, released = JobStore(db_url), []
    try:
        with _after_first_statement(store, lambda: released.append(other.release(c, attempt_seconds=0.0))):
            answer = store.request_cancel(job_id)
    finally:
        other.dispose()
    assert answer == "requested"
    assert released == [True]
    assert store.get_job(job_id)["status"] == "cancelled"


def test_failure_text_with_nul_characters_is_stored(store):
    """A training's error message may contain NUL, which PostgreSQL text refuses."""
    job_id = submit(store, max_attempts=1)
    c = store.claim("w", lease_s=30)
    status = store.fail_attempt(
        c,
        error="training raised ValueError: a\x00b",
        detail="Traceback\x00...",
        outcome="failed",
        retry_delay_s=0,
        attempt_seconds=0.1,
    )
    assert status == "failed"
    job = store.get_job(job_id)
    assert "ValueError: a\\x00b" in job["error"] and job["error_detail"] == "Traceback\\x00..."
    assert store.list_attempts(job_id)[0]["outcome"] == "failed"


def test_artifact_name_with_nul_is_unknown(store):
    job_id = submit(store)
    assert store.artifact_info(job_id, "a\x00b") is None


def test_job_ids_are_never_reused_after_a_delete(store):
    """A deleted job's id stays dead: a client holding it must not find another job there."""
    first = submit(store)
    top = submit(store)
    assert store.delete_job(top) == "deleted"
    again = submit(store)
    assert again > top, f"job {top} was deleted and its id was given to a new job"
    assert store.delete_job(first) == "deleted" and store.delete_job(again) == "deleted"
    assert submit(store) > again, "an empty table does not start the ids again"


def _old_sqlite_store(path) -> str:
    """A SQLite job store as versions before AUTOINCREMENT created it (ids could be reused)."""
    import sqlite3

    from sqlalchemy.dialects import sqlite
    from sqlalchemy.schema import CreateIndex, CreateTable

    from worker.store.schema import metadata

    con = sqlite3.connect(path)
    for table in metadata.sorted_tables:
        con.execute(str(CreateTable(table).compile(dialect=sqlite.dialect())).replace("AUTOINCREMENT", ""))
        for index in table.indexes:
            con.execute(str(CreateIndex(index).compile(dialect=sqlite.dialect())))
    con.commit()
    con.close()
    return f"sqlite:///{path}"


def test_an_older_sqlite_store_is_migrated_and_keeps_its_jobs(tmp_path):
    url = _old_sqlite_store(tmp_path / "old.db")
    old = JobStore(url)
    ids = [submit(old) for _ in range(3)]
    c = old.claim("w", lease_s=30)
    assert c is not None and old.publish_progress(c, {"env_steps": 5, "phase": "training"}) == 1
    old.dispose()

    store = JobStore(url)
    try:
        store.create_schema()
        store.create_schema()  # once is enough; a second start finds nothing to do
        assert [j["id"] for j in store.list_jobs()[1]] == ids[::-1], "every job kept its id"
        assert store.get_job(ids[0])["status"] == "running" and store.metrics_after(ids[0])[0]["seq"] == 1
        assert store.list_attempts(ids[0])[0]["worker_id"] == "w", "rows of other tables still point at their job"
        with store._read() as conn:
            assert conn.exec_driver_sql("PRAGMA foreign_key_check").all() == []
            assert conn.exec_driver_sql("PRAGMA foreign_keys").scalar() == 1
            assert "ix_modsat_jobs_claim" in {r[1] for r in conn.exec_driver_sql("PRAGMA index_list(modsat_jobs)")}
        assert store.delete_job(ids[2]) == "deleted"
        assert submit(store) == ids[2] + 1, "after the migration a deleted id is not given again"
    finally:
        store.dispose()


def test_queue_cap_holds_under_parallel_submissions(store):
    """Counting the active jobs and queueing one are one step: parallel submissions never
    take the queue past its cap."""
    from worker.store import QueueFull

    for _ in range(7):
        submit(store)
    outcomes: list[str] = []
    barrier = threading.Barrier(12)

    def one() -> None:
        barrier.wait()
        try:
            store.submit("{}", name=None, algorithm="ga", total_env_steps=1, max_attempts=1, max_active=10)
            outcomes.append("queued")
        except QueueFull as exc:
            assert exc.active == 10
            outcomes.append("full")

    threads = [threading.Thread(target=one) for _ in range(12)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(outcomes) == ["full"] * 9 + ["queued"] * 3
    assert store.active_count() == 10
