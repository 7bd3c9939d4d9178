"""Issue 46: a job's outputs in one zip with plain names (``GET /api/jobs/{id}/archive.zip``), and the
figures the jobs list compares (``GET /api/jobs/{id}/outcome``). In process: a job store on a SQLite
file, a job claimed and completed by hand, the app under Starlette's test client."""

from __future__ import annotations

import hashlib
import io
import json
import zipfile

import pytest
from fastapi.testclient import TestClient

from modsat_core.spec.presets import get_preset
from server.app import create_app
from server.schemas import safe_file_name
from server.settings import ServerSettings
from worker.store import JobStore

GRID = [[[1, 2, 0], [0, 0, 0], [0, 0, 0]], [[0] * 3] * 3, [[0] * 3] * 3]
OTHER = [[[1, 1, 2], [0, 0, 0], [0, 0, 0]], [[0] * 3] * 3, [[0] * 3] * 3]


@pytest.fixture
def store(tmp_path):
    s = JobStore(f"sqlite:///{tmp_path / 'jobs.db'}")
    s.create_schema()
    yield s
    s.dispose()


@pytest.fixture
def client(store, monkeypatch):
    monkeypatch.delenv("MODSAT_MAX_ARCHIVE_BYTES", raising=False)
    app = create_app(ServerSettings(viewer=False), store=store)
    app.state.store = store
    app.state.settings = ServerSettings(viewer=False)
    return TestClient(app, base_url="http://127.0.0.1")


def finished_job(store, files: dict[str, bytes], *, preset="quick", name="my run/1", summary=None) -> int:
    spec = get_preset(preset).model_copy(update={"name": name})
    job_id = store.submit(
        spec.model_dump_json(), name=name, algorithm=spec.algorithm, total_env_steps=100, max_attempts=3
    )
    claim = store.claim("test-worker", lease_s=30)
    assert claim is not None and claim.job_id == job_id
    store.save_checkpoint(claim, 50, b"checkpoint bytes")
    assert store.complete(claim, files=files, summary=summary, env_steps=100, attempt_seconds=1.0)
    return job_id


def test_the_archive_holds_every_output_under_its_plain_name(client, store):
    big = bytes(range(256)) * 9000  # over one read chunk of the store: streamed in parts
    files = {
        "policy_export.onnx": big,
        "design.json": json.dumps({"grid": GRID}).encode(),
        "evaluation.json": b'{"episodes": 4}',
        "curve.json": b'{"points": []}',
        "spec.json": b"{}",
    }
    job_id = finished_job(store, files)
    r = client.get(f"/api/jobs/{job_id}/archive.zip")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "application/zip"
    folder = f"my-run-1-{job_id}"
    assert r.headers["content-disposition"] == f'attachment; filename="{folder}.zip"'
    zf = zipfile.ZipFile(io.BytesIO(r.content))
    assert zf.testzip() is None
    names = set(zf.namelist())
    assert names == {f"{folder}/{n}" for n in files} | {f"{folder}/SHA256SUMS"}  # no checkpoint
    for n, data in files.items():
        assert zf.read(f"{folder}/{n}") == data
    sums = dict(line.split("  ")[::-1] for line in zf.read(f"{folder}/SHA256SUMS").decode().splitlines())
    assert sums == {n: hashlib.sha256(d).hexdigest() for n, d in files.items()}


def test_one_sanitizer_names_the_archive_and_each_download(client, store):
    assert safe_file_name("my run/1") == "my-run-1"
    assert safe_file_name('../a"b\r\nc.zip') == "a-b-c.zip"  # no path, no quote, no header break
    assert safe_file_name("..//..") == "" and safe_file_name("x" * 300) == "x" * 100
    job_id = finished_job(store, {"design.json": b"{}"}, name="../..")
    r = client.get(f"/api/jobs/{job_id}/archive.zip")
    assert r.headers["content-disposition"] == f'attachment; filename="modsat-job-{job_id}.zip"'
    r = client.get(f"/api/jobs/{job_id}/artifacts/design.json")
    assert r.headers["content-disposition"] == f'attachment; filename="modsat-job-{job_id}-design.json"'


def test_no_archive_for_a_job_without_outputs_or_over_the_limit(client, store, monkeypatch):
    spec = get_preset("quick")
    queued = store.submit(
        spec.model_dump_json(), name=None, algorithm=spec.algorithm, total_env_steps=100, max_attempts=3
    )
    r = client.get(f"/api/jobs/{queued}/archive.zip")
    assert r.status_code == 404 and "no output files yet" in r.json()["detail"]
    assert client.get("/api/jobs/999999/archive.zip").status_code == 404
    assert store.request_cancel(queued) == "stopped"
    done = finished_job(store, {"policy.pt": b"x" * 5000}, name=None)
    assert (
        client.get(f"/api/jobs/{done}/archive.zip")
        .headers["content-disposition"]
        .endswith(f'filename="modsat-job-{done}.zip"')
    )
    monkeypatch.setenv("MODSAT_MAX_ARCHIVE_BYTES", "4096")  # read once, with the other settings
    client.app.state.settings = ServerSettings(viewer=False)
    assert client.app.state.settings.max_archive_bytes == 4096
    r = client.get(f"/api/jobs/{done}/archive.zip")
    assert r.status_code == 409 and "one by one" in r.json()["detail"]


def test_the_outcome_is_success_at_the_tolerance_and_the_kept_designs_objective(client, store):
    summary = {"policy": {"episodes": 100, "success_rate": 0.97, "mean_return": 6638.2}}
    curve = {
        "algorithm": "diffsim-codesign",
        "points": [],
        "selection": [{"grid": OTHER, "objective_s": 9.5}, {"grid": GRID, "objective_s": 10.25}],
    }
    files = {"curve.json": json.dumps(curve).encode(), "design.json": json.dumps({"grid": GRID}).encode()}
    job_id = finished_job(store, files, preset="diffsim-3x3x3", summary=summary)
    out = client.get(f"/api/jobs/{job_id}/outcome").json()
    tol = get_preset("diffsim-3x3x3").mission.tolerance_deg
    assert out["success_rate"] == 0.97 and out["episodes"] == 100 and out["tolerance_deg"] == tol
    assert out["objective_s"] == 10.25  # the kept design's (design.json), not the smallest candidate's
    assert out["mass_kg"] is None


def test_a_trade_offs_outcome_is_the_kept_designs_mass_and_settling(client, store):
    curve = {
        "algorithm": "diffsim-codesign",
        "points": [],
        "front": [
            {"grid": OTHER, "mass_kg": 3.0, "median_settling_s": 4.0},
            {"grid": GRID, "mass_kg": 2.0, "median_settling_s": 7.5},
        ],
        "kept": {"grid": GRID, "meets_requirements": True},
    }
    job_id = finished_job(store, {"curve.json": json.dumps(curve).encode()}, preset="trade-off-3x3x3")
    out = client.get(f"/api/jobs/{job_id}/outcome").json()
    assert (out["mass_kg"], out["median_settling_s"], out["meets_requirements"]) == (2.0, 7.5, True)
    assert out["success_rate"] is None  # no summary stored: null, not a guess
