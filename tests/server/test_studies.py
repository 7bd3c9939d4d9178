"""Studies over HTTP: one spec over seeds and algorithms, created in one request, run by real
workers to completion, aggregated, and its figure served (issue 15)."""

from __future__ import annotations

import time

import pytest

from .test_e2e import TINY_QUICK

PNG = b"\x89PNG\r\n\x1a\n"

# `quick` cut down to seconds, with a GA whose inner TD3 gets twice its learning_starts per design.
TINY_STUDY_SPEC = {
    "preset": "quick-td3",
    "overrides": {
        **TINY_QUICK["overrides"],
        "name": "tiny study",
        "ga": {"population_size": 2, "steps_per_design": 400},
    },
}


@pytest.mark.slow
def test_study_over_http_runs_to_completion(start_server, sqlite_url, spawn_worker):
    s = start_server(sqlite_url)
    for _ in range(2):
        spawn_worker(sqlite_url, "train")
    r = s.client.post("/api/studies", json={"spec": TINY_STUDY_SPEC, "seeds": [0, 1]})
    assert r.status_code == 201, r.text
    study = r.json()
    assert r.headers["location"] == study["url"] == f"/api/studies/{study['id']}"
    assert study["algorithms"] == ["td3-codesign", "ga"] and study["seeds"] == [0, 1]
    assert study["status"] == "queued" and study["counts"] == {"queued": 4}
    assert sorted((j["algorithm"], j["seed"]) for j in study["jobs"]) == [
        ("ga", 0),
        ("ga", 1),
        ("td3-codesign", 0),
        ("td3-codesign", 1),
    ]
    for j in study["jobs"]:  # each job is the study's spec with its own seed and algorithm
        spec = s.client.get(j["url"]).json()["spec"]
        assert (spec["algorithm"], spec["seed"], spec["name"]) == (j["algorithm"], j["seed"], "tiny study")
        assert spec["training"]["total_env_steps"] == 600

    deadline = time.monotonic() + 400
    while (study := s.client.get(study["url"]).json())["status"] != "ended":
        assert time.monotonic() < deadline, study["counts"]
        time.sleep(1.0)
    assert study["counts"] == {"succeeded": 4}, [j["error"] for j in study["jobs"]]
    agg = study["aggregate"]
    assert list(agg["algorithms"]) == ["RL co-design", "GA"]
    for label, algorithm in (("RL co-design", "td3-codesign"), ("GA", "ga")):
        a = agg["algorithms"][label]
        assert a["seeds"] == [0, 1] and a["finished"] == 2
        # The figures are the jobs' own final evaluations, averaged over the seeds.
        returns = []
        for j in study["jobs"]:
            if j["algorithm"] == algorithm:
                ev = s.client.get(f"{j['url']}/artifacts/evaluation.json").json()
                returns.append(ev["policy"]["summary"]["mean_return"])
        assert a["policy"]["return"]["mean"] == pytest.approx(sum(returns) / 2)
        assert a["policy"]["return"]["n"] == 2 and len(a["designs"]) == 2
        assert a["curves"]["mean_return"]["env_steps"], label
    assert "| RL co-design | 0, 1 |" in study["table_markdown"] and "| GA | 0, 1 |" in study["table_markdown"]
    fig = s.client.get(study["figure_url"])
    assert fig.status_code == 200 and fig.headers["content-type"] == "image/png" and fig.content.startswith(PNG)
    listed = s.client.get("/api/studies").json()
    assert listed["total"] == 1 and listed["items"][0]["counts"] == {"succeeded": 4}


def test_study_submissions_are_checked(start_server, sqlite_url):
    s = start_server(sqlite_url, env={"MODSAT_MAX_ACTIVE_JOBS": "5"})
    post = s.client.post
    spec = {"preset": "quick-td3"}

    def invalid(body, loc: list, words: str) -> None:
        r = post("/api/studies", json=body)
        assert r.status_code == 422, r.text
        errors = r.json()["detail"]
        assert any(e["loc"] == ["body", *loc] and words in e["msg"] for e in errors), errors

    invalid({"spec": spec, "seeds": []}, ["seeds"], "1 to 16 distinct")
    invalid({"spec": spec, "seeds": [1, 1]}, ["seeds"], "distinct")
    invalid({"spec": spec, "seeds": [True]}, ["seeds"], "integers")
    invalid({"spec": spec, "seeds": list(range(17))}, ["seeds"], "1 to 16")
    invalid({"spec": spec, "seeds": [0], "algorithms": ["sac"]}, ["algorithms"], "td3-codesign, ga, td3-control")
    invalid({"spec": spec, "seeds": [0], "algorithms": [{}]}, ["algorithms"], "distinct names")  # was a 500
    invalid({"spec": spec, "seeds": [0], "algorithms": [[]]}, ["algorithms"], "distinct names")
    invalid({"spec": spec, "seeds": [0], "algorithms": ["diffsim-control"]}, ["algorithms"], "design.fixed_design")
    invalid({"spec": spec, "seeds": [0], "algorithms": []}, ["algorithms"], "non-empty")
    invalid({"spec": spec, "seeds": [0], "colour": 1}, ["colour"], "unknown field")
    invalid({"seeds": [0]}, ["spec"], "required")
    invalid({"spec": {"preset": "nope"}, "seeds": [0]}, ["spec", "preset"], "unknown preset")
    over = {"preset": "quick-td3", "overrides": {"training": {"batch_size": 0}}}
    invalid({"spec": over, "seeds": [0]}, ["spec", "overrides", "training", "batch_size"], "batch_size")
    unfair = {"preset": "quick-td3", "overrides": {"ga": {"steps_per_design": 3000}}}  # learning_starts 2000
    invalid({"spec": unfair, "seeds": [0]}, ["spec", "ga", "steps_per_design"], "inner TD3")
    r = post(
        "/api/studies",
        content=b'{"spec": {"preset": "quick-td3"}, "seeds": [0]}',
        headers={"content-type": "text/plain"},
    )
    assert r.status_code == 415
    r = post("/api/studies", content=b"{not json", headers={"content-type": "application/json"})
    assert r.status_code == 400
    r = post("/api/studies", json={"spec": spec, "seeds": [0]}, headers={"origin": "http://evil.example"})
    assert r.status_code == 403
    assert s.client.get("/api/jobs").json()["total"] == 0  # nothing above queued anything

    # The queue's room: 3 seeds x 2 methods is over 5 and nothing is queued; 2 x 2 fits.
    r = post("/api/studies", json={"spec": spec, "seeds": [0, 1, 2]})
    assert r.status_code == 429 and "queues 6 jobs" in r.json()["detail"]
    assert s.client.get("/api/jobs").json()["total"] == 0
    r = post("/api/studies", json={"spec": spec, "seeds": [4, 5]})
    assert r.status_code == 201, r.text
    study = r.json()
    assert study["status"] == "queued" and len(study["jobs"]) == 4
    assert study["aggregate"]["algorithms"]["RL co-design"]["finished"] == 0
    assert s.client.get(study["figure_url"]).content.startswith(PNG)  # an empty figure, not an error
    assert s.client.get("/api/studies/999").status_code == 404
    assert s.client.get("/api/studies/0").status_code == 404
    assert s.client.get("/api/studies/99999999999999999999").status_code in (404, 422)

    # A job deleted from the study leaves the others.
    job = study["jobs"][0]
    assert s.client.delete(job["url"]).status_code == 204
    again = s.client.get(study["url"]).json()
    assert [j["id"] for j in again["jobs"]] == [j["id"] for j in study["jobs"][1:]]


def test_study_store_on_both_databases(any_db_url):
    from worker.store import JobStore

    store = JobStore(any_db_url)
    try:
        sid, ids = store.submit_study(
            name="s",
            spec_json="{}",
            seeds=[3, 4],
            algorithms=["td3-codesign"],
            job_specs=[("td3-codesign", 3, '{"a": 1}', 100), ("td3-codesign", 4, '{"a": 2}', 100)],
            max_attempts=2,
        )
        row = store.get_study(sid)
        assert row is not None and row["seeds"] == [3, 4] and [j["id"] for j in row["jobs"]] == ids
        assert [(j["seed"], j["status"]) for j in row["jobs"]] == [(3, "queued"), (4, "queued")]
        total, rows = store.list_studies()
        assert total == 1 and rows[0]["counts"] == {"queued": 2}
        assert store.delete_job(ids[0]) == "deleted"
        assert [j["id"] for j in store.get_study(sid)["jobs"]] == ids[1:]
        assert store.get_study(sid + 1) is None and store.get_study(0) is None
    finally:
        store.dispose()


def test_running_jobs_fill_in_the_curves(start_server, sqlite_url):
    """While its jobs run, a study's curves are their evaluation points so far, averaged where every
    seed has one (the worker's part is played on the store)."""
    from modsat_core.artefacts import CurvePoint, ProgressRecord
    from worker.store import JobStore

    s = start_server(sqlite_url)
    study = s.client.post(
        "/api/studies", json={"spec": {"preset": "quick-td3"}, "seeds": [0, 1], "algorithms": ["td3-codesign"]}
    ).json()
    store = JobStore(sqlite_url)
    try:
        returns = {0: [10.0, 30.0], 1: [20.0]}  # seed 0 evaluated twice, seed 1 once so far
        for job in study["jobs"]:
            c = store.claim("test-worker", lease_s=3600)
            assert c is not None and c.job_id == job["id"]
            for i, ret in enumerate(returns[job["seed"]]):
                point = CurvePoint(env_steps=2500 * (i + 1), mean_return=ret, success_rate=0.5 * i)
                rec = ProgressRecord(env_steps=2500 * (i + 1), phase="training", eval=point).to_dict()
                assert store.publish_progress(c, rec)
    finally:
        store.dispose()
    agg = s.client.get(study["url"]).json()
    assert agg["status"] == "running" and agg["counts"] == {"running": 2}
    rl = agg["aggregate"]["algorithms"]["RL co-design"]
    assert rl["finished"] == 0 and rl["policy"]["return"]["n"] == 0
    curve = rl["curves"]["mean_return"]
    assert curve["env_steps"] == [2500] and curve["mean"] == [15.0]  # 5000: seed 1 has not got there
    assert curve["std"] == [pytest.approx(7.0710678)]
    fig = s.client.get(agg["figure_url"])
    assert fig.status_code == 200 and fig.content.startswith(PNG)
