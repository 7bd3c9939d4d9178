"""Service hardening over real HTTP: other web pages cannot write or read through the user's
browser (Host, Origin, content type), no spec can exhaust the host, strict input types, the
queue cap, deleting jobs, conditional downloads, JSON 404s, the OpenAPI security scheme."""

from __future__ import annotations

import json
import threading

import httpx
import pytest

from modsat_core.spec.presets import PRESETS, get_preset
from server.settings import ServerSettings
from tests.worker.helpers import wait_for

TINY = {"preset": "quick-td3", "overrides": {"training": {"total_env_steps": 400}}}
EVIL = "http://evil.example"


def _raw(api, method: str, path: str, body: bytes = b"", **headers: str) -> httpx.Response:
    return api.client.request(method, path, content=body, headers=headers)


# ----------------------------------------------------------------------------- other web pages


def test_simple_cross_site_post_is_refused(api):
    """What a page on another site can send without a preflight: text/plain or a form, with its Origin."""
    body = json.dumps(TINY).encode()
    before = api.client.get("/api/jobs").json()["total"]
    r = _raw(api, "POST", "/api/jobs", body, **{"content-type": "text/plain", "origin": EVIL})
    assert r.status_code == 403 and "another origin" in r.json()["detail"]
    r = _raw(api, "POST", "/api/jobs", body, **{"content-type": "application/json", "origin": EVIL})
    assert r.status_code == 403, "a foreign Origin is refused whatever the content type"
    r = _raw(api, "POST", "/api/jobs", body, **{"content-type": "application/json", "sec-fetch-site": "cross-site"})
    assert r.status_code == 403, "a browser that says cross-site, even without Origin"
    r = _raw(api, "POST", "/api/jobs", body, **{"content-type": "text/plain"})
    assert r.status_code == 415 and "application/json" in r.json()["detail"]
    r = _raw(api, "POST", "/api/jobs", body, **{"content-type": "application/x-www-form-urlencoded"})
    assert r.status_code == 415
    r = _raw(api, "POST", "/api/jobs", body, **{"origin": "null", "content-type": "application/json"})
    assert r.status_code == 403, "sandboxed pages and file:// send Origin: null"
    assert api.client.get("/api/jobs").json()["total"] == before, "nothing was queued"


def test_same_origin_and_non_browser_writes_work(api):
    body = json.dumps(TINY).encode()
    r = _raw(
        api,
        "POST",
        "/api/jobs",
        body,
        **{"content-type": "application/json", "origin": api.base, "sec-fetch-site": "same-origin"},
    )
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    r = _raw(api, "POST", f"/api/jobs/{job_id}/cancel", origin=EVIL)
    assert r.status_code == 403 and api.client.get(f"/api/jobs/{job_id}").json()["status"] == "queued"
    r = _raw(api, "DELETE", f"/api/jobs/{job_id}", origin=EVIL)
    assert r.status_code == 403
    assert _raw(api, "POST", f"/api/jobs/{job_id}/cancel", origin=api.base).status_code == 200
    # curl and scripts send no Origin: unaffected
    assert api.client.post("/api/jobs", json=TINY).status_code == 201


def test_foreign_host_header_is_refused_for_reads_too(api):
    """DNS rebinding: a page on evil.example whose name resolves to 127.0.0.1 would read everything."""
    for path in ("/api/jobs", "/api/health", "/"):
        r = _raw(api, "GET", path, host=f"evil.example:{api.port}")
        assert r.status_code == 400 and "MODSAT_ALLOWED_HOSTS" in r.json()["detail"], path
    for host in (f"localhost:{api.port}", f"127.0.0.1:{api.port}", "localhost"):
        assert _raw(api, "GET", "/api/health", host=host).status_code == 200, host
    assert _raw(api, "GET", "/api/health", host=f"[::1]:{api.port}").status_code == 200
    assert _raw(api, "GET", "/api/health", host="a:b:c").status_code == 400


def test_no_other_site_may_frame_the_page_and_repeated_host_or_origin_is_refused(api):
    """Clickjacking: the page, the API and the downloads answer DENY; viser's client, which the page
    frames itself, SAMEORIGIN. Two Origin (or Host) headers: which would a check read? Refused."""
    for path in ("/", "/api/health", "/api/jobs"):
        r = api.client.get(path)
        assert r.headers["x-frame-options"] == "DENY", path
        assert r.headers["content-security-policy"] == "frame-ancestors 'none'", path
    r = api.client.get("/viser-client/")
    assert r.headers["x-frame-options"] == "SAMEORIGIN"
    assert r.headers["content-security-policy"] == "frame-ancestors 'self'"
    two = [("origin", api.base), ("origin", EVIL), ("content-type", "application/json")]
    r = api.client.request("POST", "/api/jobs", content=json.dumps(TINY).encode(), headers=two)
    assert r.status_code == 400 and "more than one origin header" in r.json()["detail"]
    import socket  # httpx will not send two Host headers: a raw request does

    with socket.create_connection(("127.0.0.1", api.port), timeout=10) as sock:
        sock.sendall(
            f"GET /api/health HTTP/1.1\r\nHost: localhost:{api.port}\r\nHost: evil.example\r\n"
            "Connection: close\r\n\r\n".encode()
        )
        answer = b""
        while chunk := sock.recv(65536):
            answer += chunk
    assert answer.startswith(b"HTTP/1.1 400"), answer[:300]  # the HTTP parser refuses it before the guard


def test_allowed_hosts_and_origins_are_settings(start_server, sqlite_url):
    s = start_server(
        sqlite_url,
        env={"MODSAT_ALLOWED_HOSTS": "sat.lab.example, 10.0.0.5", "MODSAT_ALLOWED_ORIGINS": "https://ops.lab.example"},
    )
    assert _raw(s, "GET", "/api/health", host="sat.lab.example:8000").status_code == 200
    assert _raw(s, "GET", "/api/health", host="10.0.0.5").status_code == 200
    assert _raw(s, "GET", "/api/health", host="evil.example").status_code == 400
    body = json.dumps(TINY).encode()
    r = _raw(s, "POST", "/api/jobs", body, **{"content-type": "application/json", "origin": "https://ops.lab.example"})
    assert r.status_code == 201, r.text
    r = _raw(
        s, "POST", "/api/jobs", body, **{"content-type": "application/json", "origin": "https://ops.lab.example.evil"}
    )
    assert r.status_code == 403


def test_an_empty_token_is_an_error_not_the_token_empty(monkeypatch):
    monkeypatch.setenv("MODSAT_API_TOKEN", "")
    with pytest.raises(ValueError, match="MODSAT_API_TOKEN is set but empty"):
        ServerSettings()
    monkeypatch.setenv("MODSAT_API_TOKEN", "  ")
    with pytest.raises(ValueError, match="empty"):
        ServerSettings()


# ----------------------------------------------------------------------------- specs that exhaust the host


def _preset(**sections) -> dict:
    return {"preset": "quick-td3", "overrides": sections}


@pytest.mark.parametrize(
    "body, field, words",
    [
        # the examples: a 10^3 grid with a 500,000-transition buffer is 9.4 GiB before the first step
        (
            _preset(design={"grid_size": 10}, training={"buffer_size": 500_000, "total_env_steps": 1_000_000}),
            "training.buffer_size",
            "GiB of memory",
        ),
        (
            _preset(design={"grid_size": 10}, training={"buffer_size": 10_000_000, "total_env_steps": 20_000_000}),
            "training.buffer_size",
            "MODSAT_MAX_JOB_MEMORY_GIB",
        ),
        (_preset(training={"total_env_steps": 1_000_000_000}), "training.total_env_steps", "MODSAT_MAX_ENV_STEPS"),
        (_preset(design={"grid_size": 10}, training={"num_envs": 8192}), "training.num_envs", "GiB of memory"),
        (
            _preset(mission={"episode_steps": 100_000}, evaluation={"episodes": 10_000}),
            "evaluation.episodes",
            "MODSAT_MAX_EVALUATION_STEPS",
        ),
        (_preset(training={"eval_every_steps": 1}), "training.eval_every_steps", "control steps"),
        (
            _preset(mission={"episode_steps": 100_000}, evaluation={"trajectories": 50, "episodes": 50}),
            "evaluation.trajectories",
            "recorded steps",
        ),
        # batch larger than the buffer: could never run
        (_preset(training={"batch_size": 65536, "buffer_size": 100}), "training.buffer_size", "at least batch_size"),
        # strict types
        (_preset(seed="3"), "seed", "valid integer"),
        (_preset(training={"total_env_steps": True}), "training.total_env_steps", "valid integer"),
        (_preset(training={"total_env_steps": 400.0}), "training.total_env_steps", "valid integer"),
    ],
)
def test_specs_a_host_cannot_take_are_422_naming_the_field(api, body, field, words):
    before = api.client.get("/api/jobs").json()["total"]
    r = api.client.post("/api/jobs", json=body)
    assert r.status_code == 422, r.text
    messages = r.json()["messages"]
    assert any(m.startswith(field) for m in messages), messages
    assert any(words in m for m in messages), messages
    locs = [".".join(map(str, e["loc"])) for e in r.json()["detail"]]
    assert any(loc == f"body.overrides.{field}" for loc in locs), locs
    assert api.client.get("/api/jobs").json()["total"] == before


def test_every_preset_fits_the_default_limits(api):
    for name in PRESETS:  # presets added later are covered too
        spec = get_preset(name).model_dump(mode="json")
        r = api.client.post("/api/jobs", json=spec)
        assert r.status_code == 201, (name, r.text)
        assert api.client.post(f"/api/jobs/{r.json()['id']}/cancel").status_code == 200


def test_queue_cap_is_429(start_server, sqlite_url):
    s = start_server(sqlite_url, env={"MODSAT_MAX_ACTIVE_JOBS": "2"})
    ids = [s.client.post("/api/jobs", json=TINY).json()["id"] for _ in range(2)]
    r = s.client.post("/api/jobs", json=TINY)
    assert r.status_code == 429 and "MODSAT_MAX_ACTIVE_JOBS" in r.json()["detail"] and r.headers["retry-after"]
    s.client.post(f"/api/jobs/{ids[0]}/cancel")
    assert s.client.post("/api/jobs", json=TINY).status_code == 201, "an ended job frees its place"


# ----------------------------------------------------------------------------- deleting, downloads, 404s


def test_delete_queued_and_ended_jobs_not_running_ones(start_server, sqlite_url, spawn_worker):
    s = start_server(sqlite_url)
    queued = s.client.post("/api/jobs", json=TINY).json()["id"]
    assert s.client.delete(f"/api/jobs/{queued}").status_code == 204, "no worker holds a queued job"
    assert s.client.get(f"/api/jobs/{queued}").status_code == 404
    assert s.client.get(f"/api/jobs/{queued}/metrics").status_code == 404
    assert s.client.delete(f"/api/jobs/{queued}").status_code == 404
    assert s.client.delete("/api/jobs/99999999").status_code == 404
    long = {
        "preset": "quick-td3",
        "overrides": {"training": {"total_env_steps": 1_000_000, "checkpoint_every_steps": 1_000_000}},
    }
    running = s.client.post("/api/jobs", json=long).json()["id"]
    spawn_worker(sqlite_url, "simulated")
    wait_for(lambda: s.client.get(f"/api/jobs/{running}").json()["status"] == "running", 30, "the job to run")
    r = s.client.delete(f"/api/jobs/{running}")
    assert r.status_code == 409 and "cancel it first" in r.json()["detail"]
    s.client.post(f"/api/jobs/{running}/cancel")
    wait_for(lambda: s.client.get(f"/api/jobs/{running}").json()["status"] == "cancelled", 30, "the cancel")
    assert s.client.delete(f"/api/jobs/{running}").status_code == 204


def test_finished_job_download_answers_if_none_match_and_can_be_deleted(start_server, sqlite_url, spawn_worker):
    s = start_server(sqlite_url)
    job_id = s.client.post("/api/jobs", json=TINY).json()["id"]
    spawn_worker(sqlite_url, "noop")
    wait_for(lambda: s.client.get(f"/api/jobs/{job_id}").json()["status"] == "succeeded", 60, "the job to succeed")
    r = s.client.get(f"/api/jobs/{job_id}/artifacts/result.json")
    assert r.status_code == 200 and r.content == b'{"runner": "noop"}'
    etag = r.headers["etag"]
    again = s.client.get(f"/api/jobs/{job_id}/artifacts/result.json", headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == etag
    other = s.client.get(f"/api/jobs/{job_id}/artifacts/result.json", headers={"If-None-Match": '"abc"'})
    assert other.status_code == 200
    assert s.client.delete(f"/api/jobs/{job_id}").status_code == 204
    assert s.client.get(f"/api/jobs/{job_id}/artifacts/result.json").status_code == 404


def test_unknown_api_paths_are_json_404(api):
    for method, path in (("GET", "/api/nope"), ("POST", "/api/jobs/1/nope"), ("GET", "/api/jobs/1/x/y")):
        r = api.client.request(method, path)
        assert r.status_code in (404, 405), (method, path, r.status_code)
        assert r.headers["content-type"].startswith("application/json"), (method, path)
    r = api.client.get("/api/nope")
    assert r.status_code == 404 and "/api/docs" in r.json()["detail"]


def test_openapi_declares_the_bearer_token_only_when_one_is_set(api, start_server, sqlite_url):
    open_schema = api.client.get("/api/openapi.json").json()
    post = open_schema["paths"]["/api/jobs"]["post"]
    assert "security" not in post and "401" not in post["responses"]
    assert "securitySchemes" not in open_schema["components"]
    assert open_schema["components"]["schemas"]["PresetSubmission"]["properties"]["preset"]["enum"] == [
        "paper-3x3x3",
        "paper-5x5x5",
        "ga-3x3x3",
        "ga-5x5x5",
        "quick",
        "quick-td3",
        "diffsim-3x3x3",
        "diffsim-5x5x5",
        "cpu-3x3x3",
        "trade-off-3x3x3",
        "trade-off-5x5x5",
        "trade-off-7x7x7",
        "trade-off-10x10x10",
    ]
    s = start_server(sqlite_url, env={"MODSAT_API_TOKEN": "s3cret"})
    closed = s.client.get("/api/openapi.json").json()
    assert closed["paths"]["/api/jobs"]["post"]["security"] and "securitySchemes" in closed["components"]


def test_cursor_pages_do_not_shift_when_jobs_arrive(start_server, sqlite_url):
    s = start_server(sqlite_url)
    ids = [s.client.post("/api/jobs", json=TINY).json()["id"] for _ in range(5)]
    first = s.client.get("/api/jobs", params={"limit": 2}).json()
    assert [j["id"] for j in first["items"]] == ids[:2:-1][:2] and first["next_before_id"] == ids[3]
    s.client.post("/api/jobs", json=TINY)  # arrives between two pages: offset pages would repeat a job
    second = s.client.get("/api/jobs", params={"limit": 2, "before_id": first["next_before_id"]}).json()
    assert [j["id"] for j in second["items"]] == [ids[2], ids[1]]
    last = s.client.get("/api/jobs", params={"limit": 2, "before_id": second["next_before_id"]}).json()
    assert [j["id"] for j in last["items"]] == [ids[0]] and last["next_before_id"] is None
    assert s.client.get("/api/jobs", params={"before_id": 0}).status_code == 422


@pytest.mark.parametrize("path", ["/api/jobs", "/api/studies"])
def test_queue_cap_holds_under_parallel_submissions(start_server, any_db_url, path):
    """25 clients submit at once into a queue with room for 3: exactly 3 are queued, the others
    get 429 (the count and the insert are one step, on SQLite and PostgreSQL)."""
    from concurrent.futures import ThreadPoolExecutor

    s = start_server(any_db_url, env={"MODSAT_MAX_ACTIVE_JOBS": "10"})
    for _ in range(7):
        assert s.client.post("/api/jobs", json=TINY).status_code == 201
    body = TINY if path == "/api/jobs" else {"spec": TINY, "seeds": [0], "algorithms": ["td3-codesign"]}
    barrier = threading.Barrier(25)

    def submit(_: int) -> int:
        with httpx.Client(base_url=s.base, timeout=60) as c:
            barrier.wait()
            return c.post(path, json=body).status_code

    with ThreadPoolExecutor(25) as pool:
        codes = sorted(pool.map(submit, range(25)))
    assert codes == [201] * 3 + [429] * 22
    assert s.client.get("/api/jobs", params={"status": ["queued", "running"]}).json()["total"] == 10


# ----------------------------------------------------------------------------- strict reading (issue 38)


def test_a_body_that_is_not_utf8_is_refused_naming_the_encoding(api):
    """JSON bodies are UTF-8 (docs/service.md); a UTF-16 body is not guessed at but refused."""
    for encoding in ("utf-16", "utf-16-le", "utf-32"):
        r = _raw(api, "POST", "/api/jobs", json.dumps(TINY).encode(encoding), **{"Content-Type": "application/json"})
        assert r.status_code == 400 and "UTF-8" in r.json()["detail"], (encoding, r.text)
    r = _raw(api, "POST", "/api/jobs", json.dumps(TINY).encode("utf-16"), **{"Content-Type": "application/json"})
    assert "UTF-16" in r.json()["detail"], "a byte order mark says which encoding was sent"
    r = _raw(api, "POST", "/api/studies", json.dumps({"spec": TINY, "seeds": [0]}).encode("utf-16"),
             **{"Content-Type": "application/json"})  # fmt: skip
    assert r.status_code == 400 and "UTF-8" in r.json()["detail"]
    r = _raw(
        api, "POST", "/api/jobs", json.dumps(TINY).encode(), **{"Content-Type": "application/json; charset=utf-16"}
    )
    assert r.status_code == 415 and "UTF-8" in r.json()["detail"]
    r = _raw(api, "POST", "/api/jobs", json.dumps(TINY).encode(), **{"Content-Type": "application/json; charset=UTF-8"})
    assert r.status_code == 201
    api.client.post(f"/api/jobs/{r.json()['id']}/cancel")


def test_error_messages_do_not_echo_a_long_request(api):
    job = api.client.post("/api/jobs", json=TINY).json()["id"]
    api.client.post(f"/api/jobs/{job}/cancel")
    name = "x" * 12_000
    for path in (f"/api/jobs/{job}/artifacts/{name}", f"/api/presets/{name}", f"/api/{name}"):
        r = api.client.get(path)
        assert r.status_code == 404 and len(r.content) < 600, (path[:40], len(r.content))
        assert "xxxx" in r.json()["detail"], "the start of the name is shown"


def test_a_method_a_path_does_not_take_is_405_with_allow(api):
    for method, path, allowed in (
        ("PUT", "/api/jobs", {"GET", "POST"}),
        ("PATCH", "/api/jobs/1", {"GET", "DELETE"}),
        ("DELETE", "/api/studies", {"GET", "POST"}),
        ("GET", "/api/jobs/1/cancel", {"POST"}),
    ):
        r = api.client.request(method, path)
        assert r.status_code == 405, (method, path, r.status_code)
        assert set(r.headers["allow"].replace(" ", "").split(",")) == allowed, (method, path)
        assert method in r.json()["detail"] and r.headers["content-type"].startswith("application/json")
    assert api.client.put("/api/nope").status_code == 404, "an unknown path stays 404"


@pytest.mark.parametrize("path", ["/api/jobs/{}", "/api/jobs/{}/metrics", "/api/studies/{}"])
def test_ids_are_integers_written_as_integers(api, path):
    job = api.client.post("/api/jobs", json=TINY).json()["id"]
    api.client.post(f"/api/jobs/{job}/cancel")
    field = "study_id" if "studies" in path else "job_id"
    for bad in (f"{job}.0", f"{job}e0", f"+{job}", f"0x{job}", f"{job}_0", f"%20{job}"):
        r = api.client.get(path.format(bad))
        assert r.status_code == 422 and field in r.json()["messages"][0], (bad, r.text)
    if "studies" not in path:
        assert api.client.get(path.format(job)).status_code == 200
        assert api.client.get(path.format(f"0{job}")).status_code == 200, "leading zeros are still digits"
    assert api.client.get(path.format(-1)).status_code == 404 and api.client.get(path.format(2**70)).status_code == 404


def test_counts_and_cursors_in_a_query_are_digits_too(api):
    """`?limit=1.0` or `?before_id=1e0` are not read as 1: a 422 naming the parameter."""
    for query, name in (("limit=1.0", "limit"), ("offset=1e0", "offset"), ("before_id=%2B5", "before_id")):
        r = api.client.get(f"/api/jobs?{query}")
        assert r.status_code == 422 and name in r.json()["messages"][0], (query, r.text)
    r = api.client.get("/api/studies?limit=2.0")
    assert r.status_code == 422 and "limit" in r.json()["messages"][0], r.text
    assert api.client.get("/api/jobs?limit=2&offset=0").status_code == 200


def test_openapi_lists_every_status_an_operation_answers(api):
    """A client generated from the schema knows each answer: the middleware's (400 Host, 403
    Origin, 413 body size, 503 database) and the routes' own (415, 429, ...)."""
    paths = api.client.get("/api/openapi.json").json()["paths"]

    def codes(path: str, method: str) -> set[str]:
        return set(paths[path][method]["responses"])

    every = {"400", "503"}
    assert {"201", "403", "413", "415", "422", "429"} | every <= codes("/api/jobs", "post")
    assert {"201", "403", "413", "415", "422", "429"} | every <= codes("/api/studies", "post")
    assert {"200", "202", "403", "404", "409", "422"} | every <= codes("/api/jobs/{job_id}/cancel", "post")
    assert {"204", "403", "404", "409", "422"} | every <= codes("/api/jobs/{job_id}", "delete")
    assert {"200", "304", "404", "422"} | every <= codes("/api/jobs/{job_id}/artifacts/{name}", "get")
    for path, ops in paths.items():
        for method, op in ops.items():
            assert every <= set(op["responses"]), (method, path)
