"""Jobs that workers run, seen through the API: cancel a running job, a training that
raises ends `failed` with its message visible, and a finished job cannot be cancelled."""

from __future__ import annotations

from .conftest import wait_for


def _job(s, job_id):
    return s.client.get(f"/api/jobs/{job_id}").json()


def _submit(s, steps, **training):
    r = s.client.post(
        "/api/jobs", json={"preset": "quick-td3", "overrides": {"training": {"total_env_steps": steps, **training}}}
    )
    assert r.status_code == 201, r.text
    return r.json()["id"]


def test_cancel_running_job_over_http(start_server, sqlite_url, spawn_worker):
    s = start_server(sqlite_url)
    spawn_worker(sqlite_url, "simulated")
    job_id = _submit(s, 100_000, checkpoint_every_steps=100_000)
    wait_for(lambda: _job(s, job_id)["progress"]["env_steps"] > 0, 30, "the job to run")
    r = s.client.post(f"/api/jobs/{job_id}/cancel")
    assert r.status_code == 202 and "asked to stop" in r.json()["message"]
    assert r.json()["job"]["cancel_requested"] is True
    job = wait_for(lambda: (j := _job(s, job_id))["status"] == "cancelled" and j, 15, "the job to be cancelled")
    assert job["progress"]["env_steps"] < 100_000
    assert job["progress"]["checkpoint_env_steps"] is None, "a cancelled job does not keep its checkpoint"
    assert "checkpoint.pt" not in [a["name"] for a in s.client.get(f"/api/jobs/{job_id}/artifacts").json()]
    assert [a["outcome"] for a in job["attempts"]] == ["cancelled"]
    assert s.client.post(f"/api/jobs/{job_id}/cancel").status_code == 200

    done = _submit(s, 160)
    wait_for(lambda: _job(s, done)["status"] == "succeeded", 30, "the next job to succeed")
    r = s.client.post(f"/api/jobs/{done}/cancel")
    assert r.status_code == 409 and "already succeeded" in r.json()["detail"]


def test_training_that_raises_is_failed_with_its_message(start_server, sqlite_url, spawn_worker):
    s = start_server(sqlite_url, env={"MODSAT_MAX_ATTEMPTS": "2"})
    spawn_worker(sqlite_url, "raise")
    job_id = _submit(s, 400)
    job = wait_for(lambda: (j := _job(s, job_id))["status"] == "failed" and j, 40, "the job to fail")
    assert job["max_attempts"] == 2 and job["failures"] == 2
    assert "RuntimeError: simulated training failure" in job["error"]
    assert "no retries left" in job["error"]
    assert "Traceback" in job["error_detail"]
    assert [a["outcome"] for a in job["attempts"]] == ["failed", "failed"]
    listed = s.client.get("/api/jobs", params={"status": "failed"}).json()["items"]
    assert listed[0]["id"] == job_id and "simulated training failure" in listed[0]["error"]
