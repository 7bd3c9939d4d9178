"""End to end with the real training: submit the `quick` preset (with a tiny budget) over
HTTP, watch the metrics grow over polling and over the event stream, get a succeeded job,
download the policy and load it."""

from __future__ import annotations

import hashlib
import io
import json
import threading
import time
import warnings

import httpx
import pytest

pytestmark = pytest.mark.slow  # a quick run through the whole service

# The quick preset, cut down so that the run takes seconds on 2 cores.
TINY_QUICK = {
    "preset": "quick-td3",
    "overrides": {
        "name": "e2e",
        "training": {
            "total_env_steps": 600,
            "learning_starts": 200,
            "eval_every_steps": 300,
            "checkpoint_every_steps": 200,
            "train_frequency": 16,
            "batch_size": 32,
            "hidden_sizes": [32, 32],
        },
        "evaluation": {"episodes": 2, "trajectories": 1},
    },
}
OUTPUTS = {
    "spec.json",
    "curve.json",
    "curve.png",
    "design.json",
    "evaluation.json",
    "trajectories.json",
    "policy.pt",
    "policy_export.pt",
    "policy_export.pt2",
    "policy_export.onnx",
    "evaluation.viser",
}


def _read_events(base: str, job_id: int, out: list[tuple[str, str]]) -> None:
    """Collect (event, data) pairs of the job's SSE stream until it ends."""
    event = None
    with httpx.stream("GET", f"{base}/api/jobs/{job_id}/events", timeout=300) as r:
        for line in r.iter_lines():
            if line.startswith("event: "):
                event = line[7:]
            elif line.startswith("data: ") and event:
                out.append((event, line[6:]))
                if event == "end":
                    return


def test_quick_preset_over_http(start_server, sqlite_url, spawn_worker):
    import torch

    from modsat_core.agent.policy_file import load_policy

    s = start_server(sqlite_url)
    spawn_worker(sqlite_url, "train")
    r = s.client.post("/api/jobs", json=TINY_QUICK)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]

    events: list[tuple[str, str]] = []
    reader = threading.Thread(target=_read_events, args=(s.base, job_id, events), daemon=True)
    reader.start()

    # Poll the incremental metrics until the job ends; the rows must keep coming.
    seen, last, polls_with_news = [], 0, 0
    deadline = time.monotonic() + 240
    while True:
        page = s.client.get(f"/api/jobs/{job_id}/metrics", params={"after": last}).json()
        if page["items"]:
            polls_with_news += 1
            seen += page["items"]
            last = page["last_seq"]
        if page["status"] in ("succeeded", "failed", "cancelled") and not page["more"]:
            break
        assert time.monotonic() < deadline, "the quick run took too long"
        time.sleep(0.5)

    job = s.client.get(f"/api/jobs/{job_id}").json()
    assert job["status"] == "succeeded", job["error_detail"] or job["error"]
    assert polls_with_news >= 2, "metrics arrived over time, not all at once"
    assert [m["seq"] for m in seen] == list(range(1, len(seen) + 1))
    steps = [m["env_steps"] for m in seen]
    assert steps == sorted(steps) and 600 - 16 < steps[-1] <= 600  # whole batches of 16, never over
    assert all("elapsed_s" in m and m["attempt"] == 1 for m in seen)
    assert any(m.get("eval") for m in seen), "learning-curve points come with the metrics"
    assert job["progress"]["fraction"] == 1.0 and job["latest_metrics"]["seq"] == seen[-1]["seq"]
    assert job["last_eval"] is not None
    assert 0.0 <= job["evaluation"]["policy"]["success_rate"] <= 1.0
    assert job["evaluation"]["pd_baseline"]["episodes"] == 2
    assert [(a["attempt"], a["outcome"]) for a in job["attempts"]] == [(1, "succeeded")]

    reader.join(30)
    kinds = [e for e, _ in events]
    assert kinds.count("metrics") == len(seen), "the stream carried every metrics row"
    assert kinds[-1] == "end" and json.loads(events[-1][1])["status"] == "succeeded"
    statuses = [json.loads(d)["status"] for e, d in events if e == "status"]
    assert statuses[-1] == "succeeded" and "running" in statuses

    files = {a["name"]: a for a in s.client.get(f"/api/jobs/{job_id}/artifacts").json()}
    assert OUTPUTS <= set(files), set(files)
    assert "checkpoint.pt" not in files, "the checkpoint is dropped once the run succeeded"

    policy = s.client.get(f"/api/jobs/{job_id}/artifacts/policy.pt")
    assert policy.status_code == 200
    assert len(policy.content) == files["policy.pt"]["size"]
    assert hashlib.sha256(policy.content).hexdigest() == files["policy.pt"]["sha256"]
    assert 'filename="modsat-job-' in policy.headers["content-disposition"]
    raw = torch.load(io.BytesIO(policy.content), weights_only=True)
    assert raw["format"] == "modsat-policy"
    actor, grid, spec = load_policy(policy.content)
    assert spec.name == "e2e" and grid is not None and grid.shape == (3, 3, 3)
    assert sum(p.numel() for p in actor.parameters()) > 0

    exported = s.client.get(f"/api/jobs/{job_id}/artifacts/policy_export.pt").content
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # torch.jit is deprecated, still the export format
        assert torch.jit.load(io.BytesIO(exported)) is not None
    for name in ("policy_export.pt2", "policy_export.onnx"):  # docs/export.md
        r = s.client.get(f"/api/jobs/{job_id}/artifacts/{name}")
        assert r.status_code == 200 and r.headers["content-type"] == "application/octet-stream" and r.content
    assert s.client.get(f"/api/jobs/{job_id}/artifacts/curve.png").content.startswith(b"\x89PNG")
    design = s.client.get(f"/api/jobs/{job_id}/artifacts/design.json").json()
    assert design["grid_size"] == 3
