"""A study in the web UI, in a real headless Chromium: a study of two seeds, RL co-design and its
GA twin, submitted over the API and run by real workers; the page lists it, shows its figure
as it fills in, its table over seeds and its jobs, and a job's link opens that job."""

from __future__ import annotations

import time

import pytest

from tests.worker.helpers import wait_for

from .conftest import DESKTOP, PHONE, Serve, screenshot_dir

pytestmark = pytest.mark.browser

# About 15 s per job on 2 cores; the GA's inner TD3 gets twice its learning_starts per design.
TINY_STUDY = {
    "spec": {
        "preset": "quick-td3",
        "overrides": {
            "name": "study-ci",
            "ga": {"population_size": 2, "steps_per_design": 48},
            "training": {
                "total_env_steps": 96,
                "learning_starts": 24,
                "eval_every_steps": 48,
                "eval_episodes": 2,
                "batch_size": 32,
                "hidden_sizes": [32, 32],
            },
            "evaluation": {"episodes": 4, "trajectories": 1},
        },
    },
    "seeds": [0, 1],
}


@pytest.fixture(scope="module")
def service(tmp_path_factory, request):
    d = tmp_path_factory.mktemp("serve-study")
    s = Serve(d / "data", d / "serve.log", workers=2, viewer=False)
    yield s
    s.stop()
    if request.session.testsfailed:
        print(f"----- log of modsat serve on port {s.port}\n{s.log()}")


def test_a_study_fills_in_on_its_page(service, new_page):
    r = service.client.post("/api/studies", json=TINY_STUDY)
    assert r.status_code == 201, r.text
    study = r.json()
    page = new_page(DESKTOP)
    page.goto(service.base + "/")
    row = page.locator(f"#study-{study['id']}")
    row.wait_for()
    assert "study-ci" in row.text_content() and "td3-codesign vs ga" in row.text_content()
    row.click()
    page.wait_for_selector("#study-body:not([hidden])")
    assert page.locator("#study-jobs tbody tr").count() == 4

    # The page reloads the study while its jobs run, until every one has ended.
    deadline = time.monotonic() + 300
    while "4 succeeded" not in (page.text_content("#study-head") or ""):
        head = page.text_content("#study-head") or ""
        assert "failed" not in head, service.client.get(study["url"]).json()["jobs"]
        assert time.monotonic() < deadline, head
        time.sleep(1.0)
    for method in ("RL co-design", "GA"):
        cells = page.locator(f"#study-table tr[data-method='{method}'] td")
        assert cells.first.text_content() == "2 of 2", method
    # The figure is the served PNG of the finished study, drawn.
    wait_for(lambda: page.evaluate("document.querySelector('#study-fig').naturalWidth") > 0, 30, "the figure")
    assert page.get_attribute("#study-fig", "src").startswith(study["figure_url"])
    page.screenshot(path=str(screenshot_dir() / "study.png"), full_page=True)

    # A job's link opens it in the job pane.
    job = study["jobs"][2]
    page.click(f"#study-jobs a[href='#job={job['id']}']")
    page.wait_for_function(f"location.hash.includes('job={job['id']}')")
    page.wait_for_selector("#detail-body:not([hidden])")
    page.wait_for_function("document.querySelector('#d-status').textContent === 'succeeded'")
    assert page.locator(f"#job-rows tr.selected[data-id='{job['id']}']").count() == 1


def test_the_study_fits_a_phone(service, new_page):
    page = new_page(PHONE)
    page.goto(service.base + "/")
    page.locator("#study-rows tr").first.click()
    page.wait_for_selector("#study-body:not([hidden])")
    wait_for(lambda: page.evaluate("document.querySelector('#study-fig').naturalWidth") > 0, 30, "the figure")
    fig = page.locator("#study-fig").bounding_box()
    assert fig is not None and fig["width"] <= PHONE["width"], "the figure is scaled to the screen"
    assert page.evaluate("document.documentElement.scrollWidth") <= PHONE["width"], "no sideways scrolling"
