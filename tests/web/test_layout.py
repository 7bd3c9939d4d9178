"""The page with many jobs, at desktop and phone widths, and with a bad spec typed in.

One `modsat serve` without workers (the jobs stay queued) and without the live viewer."""

from __future__ import annotations

import time

import pytest

from modsat_core.spec.presets import get_preset

from .conftest import DESKTOP, PHONE, Serve, open_submit_form, screenshot_dir

N_JOBS = 200


@pytest.fixture(scope="module")
def crowded(tmp_path_factory):
    d = tmp_path_factory.mktemp("crowded")
    # 200 queued jobs: above the default queue cap (MODSAT_MAX_ACTIVE_JOBS, 100), raised here.
    s = Serve(d / "data", d / "serve.log", workers=0, viewer=False, env={"MODSAT_MAX_ACTIVE_JOBS": "1000"})
    for i in range(N_JOBS):
        r = s.client.post("/api/jobs", json={"preset": "quick-td3", "overrides": {"name": f"job-{i + 1:03d}"}})
        assert r.status_code == 201, r.text
    yield s
    s.stop()


def _no_sideways_scroll(page, width: int) -> None:
    assert page.evaluate("document.scrollingElement.scrollWidth") <= width, "the page scrolls sideways"


def test_200_jobs_paginated_and_responsive(crowded, new_page):
    page = new_page(DESKTOP)
    t0 = time.monotonic()
    page.goto(crowded.base + "/")
    page.wait_for_selector(f"#job-{N_JOBS}")
    first_paint = time.monotonic() - t0
    assert page.locator("#job-rows tr").count() == 20, "one page of rows, not all 200"
    assert page.text_content("#page-info") == f"1\u201320 of {N_JOBS}"
    assert page.is_disabled("#prev-page") and not page.is_disabled("#next-page")
    assert first_paint < 8.0, f"the list took {first_paint:.1f} s to show"
    _no_sideways_scroll(page, DESKTOP["width"])

    # Paging stays quick; the last page ends at job 1.
    times = []
    for n in range(1, 4):
        t = time.monotonic()
        page.click("#next-page")
        page.wait_for_selector(f"#job-{N_JOBS - 20 * n}")
        times.append(time.monotonic() - t)
        assert page.text_content("#page-info") == f"{20 * n + 1}\u2013{20 * n + 20} of {N_JOBS}"
    assert max(times) < 3.0, f"page changes took {times} s"
    for _ in range(6):
        page.click("#next-page")
    page.wait_for_selector("#job-1")
    assert page.text_content("#page-info") == f"181\u2013200 of {N_JOBS}" and page.is_disabled("#next-page")
    page.click("#job-1")
    page.wait_for_function("document.querySelector('#detail-h').textContent.startsWith('Job #1')")
    assert page.text_content("#d-status") == "queued" and page.is_visible("#cancel-btn")

    # The status filter asks the server, not the page.
    page.select_option("#status-filter", "succeeded")
    page.wait_for_function("document.querySelector('#page-info').textContent === 'no jobs yet'")
    page.select_option("#status-filter", "queued")
    page.wait_for_selector(f"#job-{N_JOBS}")
    page.screenshot(path=str(screenshot_dir() / "job-list-200.png"))


def test_phone_width(crowded, new_page):
    page = new_page(PHONE, is_mobile=True, has_touch=True, device_scale_factor=2)
    page.goto(crowded.base + "/")
    page.wait_for_selector(f"#job-{N_JOBS}")
    _no_sideways_scroll(page, PHONE["width"])
    for sel in ("#job-table", "#next-page", "#preset", "#f-training-total_env_steps", "#submit-btn"):
        box = page.locator(sel).bounding_box()
        assert box is not None and box["x"] >= 0 and box["x"] + box["width"] <= PHONE["width"] + 1, sel
    assert not page.locator("th.opt").first.is_visible(), "secondary columns fold away on a phone"
    page.screenshot(path=str(screenshot_dir() / "phone-job-list.png"))
    page.tap(f"#job-{N_JOBS}")
    page.wait_for_function(f"document.querySelector('#detail-h').textContent.startsWith('Job #{N_JOBS}')")
    assert page.locator("#detail").bounding_box()["width"] <= PHONE["width"]
    page.screenshot(path=str(screenshot_dir() / "phone-job.png"))


def test_bad_spec_shows_the_field_error_next_to_the_form(crowded, new_page):
    page = new_page(DESKTOP)
    page.goto(crowded.base + "/")
    open_submit_form(page)
    before = crowded.client.get("/api/jobs").json()["total"]

    # A value out of range, typed into the JSON editor, and an unknown field.
    budget = get_preset("quick").training.total_env_steps  # the form's default preset
    text = page.input_value("#overrides").replace(f'"total_env_steps": {budget}', '"total_env_steps": 0')
    text = text.replace('"seed": 0,', '"seed": 0, "colour": "red",')
    page.fill("#overrides", text)
    assert page.input_value("#f-training-total_env_steps") == "0", "the editor updates the form fields"
    page.click("#submit-btn")
    errors = page.locator("#submit-errors")
    errors.wait_for(state="visible")
    shown = errors.text_content()
    assert "training.total_env_steps" in shown and "out of range" in shown, shown
    assert "colour: unknown field" in shown, shown
    field = page.locator("#f-training-total_env_steps")
    assert field.get_attribute("aria-invalid") == "true"
    assert "out of range" in page.text_content("#err-training-total_env_steps")
    assert page.is_visible("#submit-form") and page.is_visible("#job-table"), "the page is still there"
    # next to the form: right under the submit button, in view
    btn, box = page.locator("#submit-btn").bounding_box(), errors.bounding_box()
    assert 0 < box["y"] - (btn["y"] + btn["height"]) < 40
    errors.scroll_into_view_if_needed()
    page.screenshot(path=str(screenshot_dir() / "bad-spec.png"))

    # Not JSON at all: said before anything is sent.
    page.fill("#overrides", "{ not json")
    page.click("#submit-btn")
    page.wait_for_function("document.querySelector('#submit-errors').textContent.includes('not valid JSON')")
    assert crowded.client.get("/api/jobs").json()["total"] == before, "nothing was submitted"
