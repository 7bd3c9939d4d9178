"""The service under hostile input (issue 47), over real HTTP: a slow invalid body does not stall the
API, error answers are bounded and name the field, duplicate keys are refused, the work a job may take
is bounded, and the published schema states what the server enforces."""

from __future__ import annotations

import json
import threading
import time

import pytest

from modsat_core.spec.limits import Limits, check
from modsat_core.spec.presets import PRESETS

#: The issue's worst case: 6,267 bytes, 1,000 problems (each used to rebuild the JSON schema, ~40 s).
SLOW_BODY = {"design": {"grid_size": 10, "fixed_design": [[[None] * 10 for _ in range(10)] for _ in range(10)]}}


def test_a_slow_invalid_body_does_not_delay_health(api):
    answers: list = []

    def send() -> None:
        t0 = time.monotonic()
        r = api.client.post("/api/jobs", json=SLOW_BODY)
        answers.append((r, time.monotonic() - t0))

    senders = [threading.Thread(target=send) for _ in range(3)]
    for s in senders:
        s.start()
    waits = []
    while any(s.is_alive() for s in senders) or len(waits) < 5:
        t0 = time.monotonic()
        assert api.client.get("/api/health").status_code == 200
        waits.append(time.monotonic() - t0)
        if len(waits) > 200:
            break
    for s in senders:
        s.join(60)
    assert max(waits) < 0.5, f"/api/health waited {max(waits):.2f} s while invalid bodies were validated"
    assert len(answers) == 3
    for r, took in answers:
        assert r.status_code == 422 and r.headers["content-type"] == "application/json", r.text[:200]
        body = r.json()
        assert body["messages"][0].startswith("design.fixed_design.0.0.0"), body["messages"][:2]
        assert body["detail"][0]["loc"] == ["body", "design", "fixed_design", 0, 0, 0]
        assert len(body["messages"]) == 21 and "980 more problems" in body["messages"][-1]
        assert len(r.content) < 10_000 and took < 5.0, (len(r.content), took)


@pytest.mark.parametrize(
    "body, field",
    [
        ({"preset": "x" * 1_000_000}, "preset"),
        ({"preset": "quick", "overrides": {"y" * 300_000: 1, "z" * 300_000: 2}}, "yyyy"),
        ({f"k{i}" * 2000: 1 for i in range(100)}, "k0k0"),
        ({"preset": "quick", "overrides": {"name": "n" * 500_000}}, "name"),
        ({"preset": "quick", "overrides": {"evaluation": {"conditions": [True]}}}, "evaluation.conditions.0"),
        ({"preset": "quick", "overrides": {"evaluation": {"conditions": [[None, None]]}}}, "evaluation.conditions.0"),
        ({"preset": "quick", "overrides": {"evaluation": {"conditions": [{"name": [1]}]}}}, "evaluation.conditions.0"),
        ({"preset": "quick", "overrides": {"modules": {"wheels": [{"name": [1]}]}}}, "modules.wheels.0.name"),
        ({"preset": "quick", "overrides": {"modules": {"wheels": [1.5]}}}, "modules.wheels.0"),
        ({"preset": "quick", "overrides": {"evaluation": {"conditions": ["c" * 100_000]}}}, "evaluation.conditions"),
    ],
)
def test_malformed_parts_are_bounded_json_422_naming_the_field(api, body, field):
    sent = len(json.dumps(body))
    r = api.client.post("/api/jobs", json=body)
    assert r.status_code == 422 and r.headers["content-type"] == "application/json", r.text[:300]
    messages = r.json()["messages"]
    assert messages[0].startswith(field), messages[:2]
    assert len(r.content) < 20_000 and (sent < 10_000 or len(r.content) < sent / 10), (len(r.content), sent)
    assert all(len(m) <= 420 for m in messages)
    assert "unhashable" not in r.text and "Traceback" not in r.text and "object has no attribute" not in r.text
    for path, wrapped in (("/api/studies", {"spec": body, "seeds": [0]}),):
        r = api.client.post(path, json=wrapped)
        assert r.status_code == 422 and len(r.content) < 20_000, r.text[:300]


def test_duplicate_keys_are_refused_naming_the_key(api):
    for path, raw, loc in (
        ("/api/jobs", b'{"preset": "quick", "preset": "quick-td3"}', ["body", "preset"]),
        ("/api/jobs", b'{"preset": "quick", "overrides": {"seed": 1, "seed": 2}}', ["body", "overrides", "seed"]),
        ("/api/studies", b'{"spec": {"preset": "quick"}, "seeds": [0], "seeds": [1]}', ["body", "seeds"]),
    ):
        r = api.client.post(path, content=raw, headers={"Content-Type": "application/json"})
        assert r.status_code == 422, r.text
        err = r.json()["detail"][0]
        assert err["loc"] == loc and err["type"] == "duplicate_key" and "more than once" in err["msg"], err


# ----------------------------------------------------------------------------- the work a job may take


def test_every_preset_is_admitted_by_the_default_limits():
    for name, spec in PRESETS.items():
        assert check(spec, Limits()) == [], name


@pytest.mark.parametrize(
    "overrides, field, words",
    [
        (
            {"preset": "quick-td3", "overrides": {"training": {"total_env_steps": 20_000_000}}},
            "training.total_env_steps",
            "MODSAT_MAX_JOB_HOURS",
        ),
        (
            {"preset": "ga-3x3x3", "overrides": {"ga": {"population_size": 1000}}},
            "ga.population_size",
            "first generation",
        ),
        (
            {"preset": "quick", "overrides": {"diffsim": {"substeps": 1000, "window_steps": 500}}},
            "diffsim.batch_size",
            "GiB",
        ),
        (
            {"preset": "quick", "overrides": {"diffsim": {"substeps": 1000, "window_steps": 500, "batch_size": 1}}},
            "training.total_env_steps",
            "MODSAT_MAX_JOB_HOURS",
        ),
        (
            {"preset": "quick-td3", "overrides": {"training": {"checkpoint_every_steps": 1}}},
            "training.checkpoint_every_steps",
            "MODSAT_MAX_CHECKPOINTS",
        ),
    ],
)
def test_jobs_over_the_work_bound_are_422_naming_what_to_lower(api, overrides, field, words):
    r = api.client.post("/api/jobs", json=overrides)
    assert r.status_code == 422, r.text[:300]
    hits = [m for m in r.json()["messages"] if m.startswith(field)]
    assert hits and words in hits[0], r.json()["messages"]
    r = api.client.post(
        "/api/studies", json={"spec": overrides, "seeds": [0], "algorithms": [PRESETS[overrides["preset"]].algorithm]}
    )
    assert r.status_code == 422 and any(m.startswith(field) for m in r.json()["messages"]), r.text[:300]


def test_the_work_bound_is_a_setting(start_server, sqlite_url):
    s = start_server(sqlite_url, env={"MODSAT_MAX_JOB_HOURS": "0.001"})
    r = s.client.post("/api/jobs", json={"preset": "quick"})
    assert r.status_code == 422 and "MODSAT_MAX_JOB_HOURS" in r.text
    s = start_server(sqlite_url, env={"MODSAT_MAX_JOB_HOURS": "", "MODSAT_MAX_CHECKPOINTS": ""})
    body = {"preset": "quick-td3", "overrides": {"training": {"total_env_steps": 20_000_000}}}
    assert s.client.post("/api/jobs", json=body).status_code == 201


# ----------------------------------------------------------------------------- the published schema


def _walk(node):
    if isinstance(node, dict):
        yield node
        for v in node.values():
            yield from _walk(v)
    elif isinstance(node, list):
        for v in node:
            yield from _walk(v)


def test_the_openapi_schema_states_what_the_server_enforces(api):
    schema = api.client.get("/api/openapi.json").json()
    params = {
        (path, p["name"]): p["schema"]
        for path, ops in schema["paths"].items()
        for op in ops.values()
        for p in op.get("parameters", [])
    }
    for node in _walk(list(params.values())):
        assert not {"ge", "le", "gt", "lt"} & set(node), node  # pydantic's words, not JSON Schema's
    assert params[("/api/jobs", "limit")]["minimum"] == 1 and params[("/api/jobs", "limit")]["maximum"] == 500
    assert params[("/api/jobs", "offset")]["minimum"] == 0
    before = next(b for b in params[("/api/jobs", "before_id")]["anyOf"] if b.get("type") == "integer")
    assert before["minimum"] == 1 and before["maximum"] == 2**63 - 1
    assert params[("/api/jobs/{job_id}/metrics", "after")]["maximum"] == 2**31 - 1
    comps = schema["components"]["schemas"]
    for name in ("JobSpec", "PresetSubmission", "StudySubmission", "Evaluation", "Condition"):
        assert comps[name]["additionalProperties"] is False, name
    pattern = comps["Condition"]["properties"]["name"]["pattern"]
    assert pattern == "^[a-z0-9][a-z0-9-]{0,39}$"
    # A condition is an object or the name of a standard one, in the schema as on the server.
    items = comps["Evaluation"]["properties"]["conditions"]["items"]["anyOf"]
    names = next(b for b in items if b.get("type") == "string")["enum"]
    assert "delay-1" in names and "nominal" not in names
    ok = {"preset": "quick", "overrides": {"evaluation": {"conditions": ["delay-1", {"name": "mine"}]}}}
    r = api.client.post("/api/jobs", json=ok)
    assert r.status_code == 201, r.text
    api.client.post(f"/api/jobs/{r.json()['id']}/cancel")
    for bad, field in (
        (["no-such-condition"], "evaluation.conditions"),
        ([{"name": "x\n"}], "evaluation.conditions.0"),
    ):
        r = api.client.post("/api/jobs", json={"preset": "quick", "overrides": {"evaluation": {"conditions": bad}}})
        assert r.status_code == 422 and r.json()["messages"][0].startswith(field), r.text[:300]
    r = api.client.post("/api/studies", json={"spec": {"preset": "quick"}, "seeds": [0], "colour": 1})
    assert r.status_code == 422


def test_the_published_request_examples_are_admitted(api):
    """Each request-body example in the OpenAPI schema is accepted as it stands (schemathesis's
    examples phase found the study example, a study of the diffsim preset `quick` flown by TD3 and
    the GA, refused as over the work bound: a 422 for the schema's own example)."""
    schema = api.client.get("/api/openapi.json").json()
    sent = 0
    for path, ops in schema["paths"].items():
        for op in ops.values():
            media = op.get("requestBody", {}).get("content", {}).get("application/json", {})
            examples = [e["value"] for e in media.get("examples", {}).values()]
            examples += [media["example"]] if "example" in media else []
            for body in examples:
                r = api.client.post(path, json=body)
                assert r.status_code == 201, (path, body, r.text[:400])
                jobs = r.json().get("jobs") or [r.json()]  # a study answers with its jobs
                for job in jobs:
                    api.client.post(f"/api/jobs/{job['id']}/cancel")
                sent += 1
    assert sent >= 3, "examples of POST /api/jobs and POST /api/studies"
    # The preset form's examples, which schemathesis also assembles into a study's body.
    for spec in schema["components"]["schemas"]["PresetSubmission"]["examples"]:
        for path, body in (("/api/jobs", spec), ("/api/studies", {"spec": spec, "seeds": [0, 1, 2]})):
            r = api.client.post(path, json=body)
            assert r.status_code == 201, (path, body, r.text[:400])
            for job in r.json().get("jobs") or [r.json()]:
                api.client.post(f"/api/jobs/{job['id']}/cancel")


def test_the_api_docs_work_offline(api):
    r = api.client.get("/api/docs")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/html")
    page = r.text
    assert "POST</span> /api/jobs" in page and "/api/openapi.json" in page and "&lt;= 500" in page
    assert "<script" not in page.lower() and "src=" not in page and 'href="http' not in page  # nothing from elsewhere
    csp = r.headers.get_list("content-security-policy")
    assert any("default-src 'none'" in c for c in csp) and any("frame-ancestors 'none'" in c for c in csp)
    assert r.headers["x-frame-options"] == "DENY"
