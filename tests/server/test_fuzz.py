"""Property-based fuzzing of the OpenAPI schema (schemathesis): whatever a client sends,
valid or not, the server answers without a 5xx. Small example counts keep it to seconds."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, Phase, given, settings
from schemathesis import GenerationMode

from .conftest import ServerProc

pytestmark = pytest.mark.slow  # 300 generated requests against a live server


@pytest.fixture(scope="module")
def fuzz_server(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz")
    # Event streams of jobs that never end (there are no workers here) stop after a second.
    s = ServerProc(f"sqlite:///{d / 'jobs.db'}", d / "server.log", env={"MODSAT_SSE_MAX_S": "1"})
    s.client.post("/api/jobs", json={"preset": "quick-td3"})  # something to find at small ids
    yield s
    s.stop()


@pytest.fixture(scope="module")
def api_schema(fuzz_server):
    return schemathesis.openapi.from_url(f"{fuzz_server.base}/api/openapi.json")


@pytest.mark.parametrize("mode", [GenerationMode.POSITIVE, GenerationMode.NEGATIVE], ids=["valid", "invalid"])
def test_no_server_errors(api_schema, mode):
    @given(case=api_schema.as_strategy(mode))
    @settings(
        max_examples=150, deadline=None, phases=[Phase.generate], suppress_health_check=list(HealthCheck), database=None
    )
    def check(case) -> None:
        response = case.call(timeout=30)
        assert response.status_code < 500, (
            f"{case.method} {case.formatted_path} {case.query} -> {response.status_code}: {response.text[:500]}"
        )

    check()
