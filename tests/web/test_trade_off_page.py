"""The trade-off on the job page (docs/requirements.md): a finished `trade-off-3x3x3` job, cut to a few
updates, shows its requirements and its front as a chart; a click on a front point draws that design
and lists its figures, its flight conditions and its files."""

from __future__ import annotations

import pytest

from tests.web.conftest import DESKTOP, PHONE, screenshot_dir
from tests.worker.helpers import wait_for

pytestmark = pytest.mark.browser

TINY_TRADE_OFF = {
    "preset": "trade-off-3x3x3",
    "overrides": {
        "name": "trade-off-ci",
        "mission": {"episode_steps": 48},
        "training": {"total_env_steps": 4 * 16 * 8, "eval_every_steps": 4 * 16 * 8, "eval_episodes": 2},
        "diffsim": {
            "batch_size": 16,
            "window_steps": 8,
            "episode_steps": 24,
            "hidden_sizes": [16],
            "design_batch": 8,
            "design_slews": 2,
            "design_every": 2,
        },
        # eager: the page is under test, not the fused step (tests/core/test_conditions.py holds it)
        "evaluation": {"episodes": 4, "trajectories": 1, "conditions": ["delay-1"], "compiled": False},
    },
}


def test_a_click_on_a_front_point_draws_its_design_and_lists_its_files(service, new_page):
    r = service.client.post("/api/jobs", json=TINY_TRADE_OFF)
    assert r.status_code == 201, r.text
    job_id = r.json()["id"]
    job = wait_for(
        lambda: (
            (j := service.client.get(f"/api/jobs/{job_id}").json())["status"] in ("succeeded", "failed", "cancelled")
            and j
        ),
        300,
        "the trade-off job",
    )
    assert job["status"] == "succeeded", job["error_detail"]
    front = service.client.get(f"/api/jobs/{job_id}/artifacts/curve.json").json()["front"]
    shots = screenshot_dir()
    for name, viewport in (("desktop", DESKTOP), ("phone", PHONE)):
        page = new_page(viewport=viewport)
        page.goto(f"{service.base}/#job={job_id}")
        page.wait_for_selector("#trade-off:not([hidden]) svg.front-chart")
        assert "settled within 20 s" in page.text_content("#trade-off")
        assert page.locator("svg.front-chart .front-point").count() == len(front)
        page.locator("svg.front-chart .front-point").first.click()
        page.wait_for_selector("#front-point svg.thumb")
        detail = page.text_content("#front-point")
        assert f"Point 1 of {len(front)}" in detail and f"{front[0]['mass_kg']:.2f} kg" in detail
        assert "delay-1" in detail
        links = page.locator("#front-point .front-downloads a")
        assert links.count() >= 2
        assert links.first.get_attribute("download").endswith("front-1-design.json")
        page.screenshot(path=str(shots / f"trade-off-{name}.png"), full_page=True)
