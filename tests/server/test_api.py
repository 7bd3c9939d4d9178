"""The REST API over real HTTP (uvicorn subprocess, SQLite): submission forms, validation
messages, 400/401/404/409/413/422, listing, presets, schema, health, the page."""

from __future__ import annotations

import json

import httpx
import pytest

from modsat_core.spec.preset_times import run_time_text
from modsat_core.spec.presets import PRESETS, get_preset

TINY = {"preset": "quick-td3", "overrides": {"training": {"total_env_steps": 400}}}


def test_submit_preset_returns_201_with_location(api):
    r = api.client.post("/api/jobs", json=TINY)
    assert r.status_code == 201, r.text
    job = r.json()
    assert r.headers["location"] == f"/api/jobs/{job['id']}"
    assert job["status"] == "queued" and job["name"] == "quick-td3"
    assert job["spec"]["training"]["total_env_steps"] == 400
    assert job["spec"]["training"]["hidden_sizes"] == [256, 256], "the rest comes from the preset"
    assert job["control_dt_s"] == get_preset("quick-td3").mission.control_dt_s  # the page's one control step
    assert job["progress"] == {
        "env_steps": 0,
        "total_env_steps": 400,
        "fraction": 0.0,
        "phase": None,
        "checkpoint_env_steps": None,
        "run_seconds": 0.0,
    }
    again = api.client.get(r.headers["location"]).json()
    assert again["id"] == job["id"] and again["spec"] == job["spec"]


def test_submit_whole_spec(api):
    spec = get_preset("quick-td3").model_dump(mode="json")
    spec["name"] = "my run"
    spec["seed"] = 42
    r = api.client.post("/api/jobs", json=spec)
    assert r.status_code == 201, r.text
    assert r.json()["spec"]["seed"] == 42 and r.json()["name"] == "my run"


@pytest.mark.parametrize(
    "body, field, words",
    [
        ({"training": {"total_env_steps": 0}}, "training.total_env_steps", ">= 1"),
        ({"design": {"grid_size": 11}}, "design.grid_size", "<= 10"),
        ({"algorithm": "ppo"}, "algorithm", "td3-codesign"),
        ({"trainig": {}}, "trainig", "unknown field"),
        ({"preset": "quick-td3", "overrides": {"mission": {"slew_max_deg": 200}}}, "mission.slew_max_deg", "<= 180"),
        ({"preset": "nope"}, "preset", "known: "),
        ({"preset": "quick-td3", "overrides": [1]}, "overrides", "expected an object"),
        ({"preset": "quick-td3", "seed": 3}, "seed", "inside 'overrides'"),
        ([1, 2], "body", "expected a JSON object"),
        # neither a preset nor an algorithm: not the default 200,000-step td3-codesign job
        ({}, "algorithm", "names a preset"),
        ({"name": "x", "seed": 2}, "algorithm", "names a preset"),
    ],
)
def test_invalid_spec_is_422_naming_the_field(api, body, field, words):
    r = api.client.post("/api/jobs", json=body)
    assert r.status_code == 422, r.text
    messages = r.json()["messages"]
    assert any(m.startswith(field) or field in m for m in messages), messages
    assert any(words in m for m in messages), messages
    assert all(e["loc"][0] == "body" for e in r.json()["detail"])


def test_a_removed_training_key_is_422_at_the_key_unless_it_holds_its_no_op_value(api):
    old = {"preset": "quick-td3", "overrides": {"training": {"n_step": 3}}}
    r = api.client.post("/api/jobs", json=old)
    assert r.status_code == 422, r.text
    (msg,) = r.json()["messages"]
    assert msg.startswith("training.n_step: removed from modsat (it was 3 here)"), msg
    (err,) = r.json()["detail"]
    assert err["loc"] == ["body", "overrides", "training", "n_step"] and err["type"] == "removed_field"
    # an old run's spec.json, which lists the key at its no-op value, is accepted
    saved = {"preset": "quick-td3", "overrides": {"training": {"n_step": 1, "policy_noise_final": None}}}
    assert api.client.post("/api/jobs", json=saved).status_code == 201


@pytest.mark.parametrize("raw", [b"{", b"", b"\xff\xfe\x00", b"[" * 100_000 + b"]" * 100_000, b"1" * 5000])
def test_unreadable_body_is_400(api, raw):
    r = api.client.post("/api/jobs", content=raw, headers={"content-type": "application/json"})
    assert r.status_code == 400, r.text
    assert r.json()["detail"]


def test_oversized_body_is_413_declared_and_chunked(api):
    big = json.dumps({"name": "x" * 2_000_000}).encode()
    r = api.client.post("/api/jobs", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413 and "larger than" in r.json()["detail"]

    def chunks():  # no Content-Length: Transfer-Encoding chunked
        for _ in range(40):
            yield b" " * 65536

    r = api.client.post("/api/jobs", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413


def test_unknown_job_is_404_everywhere(api):
    for path in (
        "/api/jobs/999999",
        "/api/jobs/999999/metrics",
        "/api/jobs/999999/events",
        "/api/jobs/999999/artifacts",
        "/api/jobs/999999/artifacts/policy.pt",
        "/api/jobs/0",
        "/api/jobs/-3",
        f"/api/jobs/{2**80}",
    ):
        r = api.client.get(path)
        assert r.status_code == 404, (path, r.text)
        assert "no job" in r.json()["detail"]
    assert api.client.post("/api/jobs/999999/cancel").status_code == 404
    assert api.client.get("/api/jobs/abc").status_code == 422


def test_artifact_names_outside_the_stored_set_are_404(api):
    job_id = api.client.post("/api/jobs", json=TINY).json()["id"]
    assert api.client.get(f"/api/jobs/{job_id}/artifacts").json() == []
    for name in ("..%2Fx", "..%2F..%2Fetc%2Fpasswd", "policy.pt", "%2e%2e", "%2e%2e%2f%2e%2e%2fmodsat.db", "modsat.db"):
        r = api.client.get(f"/api/jobs/{job_id}/artifacts/{name}")
        assert r.status_code == 404, (name, r.status_code)
    # An un-encoded ../ is normalised by the client (and would be by any browser).
    raw = httpx.get(f"{api.base}/api/jobs/{job_id}/artifacts/../x")
    assert raw.status_code == 404


def test_list_filter_and_pagination(api):
    ids = [api.client.post("/api/jobs", json=TINY).json()["id"] for _ in range(5)]
    api.client.post(f"/api/jobs/{ids[0]}/cancel")
    page = api.client.get("/api/jobs", params={"limit": 2}).json()
    assert page["limit"] == 2 and page["offset"] == 0 and len(page["items"]) == 2
    assert page["items"][0]["id"] == ids[-1], "newest first"
    assert page["next_offset"] == 2 and page["total"] >= 5
    everything, offset = [], 0
    while offset is not None:
        p = api.client.get("/api/jobs", params={"limit": 3, "offset": offset}).json()
        everything += [j["id"] for j in p["items"]]
        offset = p["next_offset"]
    assert len(everything) == page["total"] == len(set(everything))
    cancelled = api.client.get("/api/jobs", params={"status": "cancelled"}).json()
    assert ids[0] in [j["id"] for j in cancelled["items"]]
    assert all(j["status"] == "cancelled" for j in cancelled["items"])
    both = api.client.get("/api/jobs", params=[("status", "cancelled"), ("status", "queued")]).json()
    assert both["total"] == page["total"]
    r = api.client.get("/api/jobs", params={"status": "done", "limit": 0})
    assert r.status_code == 422
    assert any(m.startswith("query.status") for m in r.json()["messages"])
    assert any(m.startswith("query.limit") for m in r.json()["messages"])


def test_cancel_queued_job(api):
    job_id = api.client.post("/api/jobs", json=TINY).json()["id"]
    r = api.client.post(f"/api/jobs/{job_id}/cancel")
    assert r.status_code == 200
    assert r.json()["job"]["status"] == "cancelled" and "now cancelled" in r.json()["message"]
    again = api.client.post(f"/api/jobs/{job_id}/cancel")
    assert again.status_code == 200 and "already cancelled" in again.json()["message"]
    assert api.client.get(f"/api/jobs/{job_id}").json()["status"] == "cancelled"


def test_metrics_and_events_of_a_job_without_progress(api):
    job_id = api.client.post("/api/jobs", json=TINY).json()["id"]
    m = api.client.get(f"/api/jobs/{job_id}/metrics", params={"after": 0}).json()
    assert m == {"job_id": job_id, "status": "queued", "after": 0, "last_seq": 0, "more": False, "items": []}
    api.client.post(f"/api/jobs/{job_id}/cancel")
    with api.client.stream("GET", f"/api/jobs/{job_id}/events") as r:
        assert r.headers["content-type"].startswith("text/event-stream")
        text = r.read().decode()
    assert "event: status" in text and text.rstrip().endswith('"last_seq": 0}')
    assert "event: end" in text and '"status": "cancelled"' in text


def test_presets_schema_health_and_page(api):
    presets = api.client.get("/api/presets").json()
    assert [p["name"] for p in presets] == list(PRESETS)
    times = {p["name"]: p for p in presets}  # the form's estimates: the README's, CPU named
    assert times["quick"]["time_text"] == run_time_text("quick") and times["quick"]["time_per_run"][0]["cpu"]
    assert times["paper-3x3x3"]["time_per_run"] == [] and times["paper-3x3x3"]["time_text"] == "not measured here"
    quick = api.client.get("/api/presets/quick").json()
    assert quick == get_preset("quick").model_dump(mode="json")
    r = api.client.get("/api/presets/nope")
    assert r.status_code == 404 and "quick" in r.json()["detail"]
    schema = api.client.get("/api/schema").json()
    assert "training" in schema["properties"] and "$defs" in schema
    health = api.client.get("/api/health").json()
    assert health["status"] == "ok" and health["database"] == "sqlite"
    assert sum(health["jobs"].values()) >= 1
    openapi = api.client.get("/api/openapi.json").json()
    assert "JobSpec" in openapi["components"]["schemas"]
    page = api.client.get("/")
    assert page.status_code == 200 and "text/html" in page.headers["content-type"] and "app.js" in page.text
    assert "/api/jobs" in api.client.get("/app.js").text, "the web UI reads the API"
    assert api.client.get("/viser-client/").status_code == 200, "viser's static client is served"
    assert api.client.get("/no-such-file.js").status_code == 404
    assert api.client.get("/api/viewer").json() == {
        "enabled": False,
        "port": None,
        "client": "/viser-client/",
        "recording": "evaluation.viser",
    }


def test_writes_need_the_bearer_token_when_set(start_server, sqlite_url):
    s = start_server(sqlite_url, env={"MODSAT_API_TOKEN": "s3cret"})
    r = s.client.post("/api/jobs", json=TINY)
    assert r.status_code == 401 and r.headers["www-authenticate"] == "Bearer"
    assert "Authorization: Bearer" in r.json()["detail"]
    r = s.client.post("/api/jobs", json=TINY, headers={"Authorization": "Bearer wrong"})
    assert r.status_code == 401
    r = s.client.post("/api/jobs", json={"bad": 1}, headers={"Authorization": "Basic s3cret"})
    assert r.status_code == 401, "the token is checked before the body"
    ok = s.client.post("/api/jobs", json=TINY, headers={"Authorization": "Bearer s3cret"})
    assert ok.status_code == 201
    job_id = ok.json()["id"]
    assert s.client.post(f"/api/jobs/{job_id}/cancel").status_code == 401
    assert s.client.post(f"/api/jobs/{job_id}/cancel", headers={"Authorization": "Bearer s3cret"}).status_code == 200
    assert s.client.get(f"/api/jobs/{job_id}").status_code == 200, "reads stay open"
    assert s.client.get("/api/jobs").status_code == 200


@pytest.mark.parametrize("last_event_id", [b"9" * 5000, b"\xb2", b"12x"])
def test_unusable_last_event_id_is_not_a_500(api, last_event_id):
    """Last-Event-ID is a client's echo of an id; one that is not a small ASCII number
    (5,000 digits are more than int() converts; '\\xb2' is '²', a digit to isdigit()) is ignored
    or clamped, never a 500."""
    job_id = api.client.post("/api/jobs", json=TINY).json()["id"]
    api.client.post(f"/api/jobs/{job_id}/cancel")
    with api.client.stream("GET", f"/api/jobs/{job_id}/events", headers=[(b"last-event-id", last_event_id)]) as r:
        assert r.status_code == 200
        text = r.read().decode()
    assert "event: end" in text and '"status": "cancelled"' in text


def test_nul_characters_are_4xx_on_both_databases(start_server, any_db_url):
    """PostgreSQL text cannot hold NUL: a job name or an artefact name with one was a 500 there."""
    s = start_server(any_db_url)
    r = s.client.post("/api/jobs", json={"preset": "quick-td3", "overrides": {"name": "a\u0000b"}})
    assert r.status_code == 422, r.text
    assert any(m.startswith("name:") and "NUL" in m for m in r.json()["messages"])
    assert r.json()["detail"][0]["loc"] == ["body", "overrides", "name"]
    job_id = s.client.post("/api/jobs", json=TINY).json()["id"]
    r = s.client.get(f"/api/jobs/{job_id}/artifacts/a%00b")
    assert r.status_code == 404 and "no artefact" in r.json()["detail"]


def test_metrics_pages_say_more_only_when_rows_remain(start_server, sqlite_url):
    """`more` was `len(page) == limit`: true when exactly `limit` rows remained, so a client
    asked for an empty page. Three progress rows, read two at a time."""
    from worker.store import JobStore

    s = start_server(sqlite_url)
    job_id = s.client.post("/api/jobs", json=TINY).json()["id"]
    store = JobStore(sqlite_url)
    try:
        claim = store.claim("test-worker", lease_s=30)
        assert claim.job_id == job_id
        for step in (16, 32, 48):
            store.publish_progress(claim, {"env_steps": step})
    finally:
        store.dispose()
    first = s.client.get(f"/api/jobs/{job_id}/metrics", params={"limit": 2}).json()
    assert [m["env_steps"] for m in first["items"]] == [16, 32] and first["more"] is True
    second = s.client.get(f"/api/jobs/{job_id}/metrics", params={"after": first["last_seq"], "limit": 2}).json()
    assert [m["env_steps"] for m in second["items"]] == [48] and second["more"] is False
    exact = s.client.get(f"/api/jobs/{job_id}/metrics", params={"limit": 3}).json()
    assert len(exact["items"]) == 3 and exact["more"] is False
