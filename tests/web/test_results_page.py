"""Issue 46, "show the user what they got", in a real headless Chromium: an ETA while a job trains, the
final evaluation as its own state, the job's wall time, the jobs list's result (success at the
tolerance, the kept design's objective), the archive link, a co-design job's objective with the kept
design against the other candidates and random designs, and chart ticks that read differently.

No training runs: one `modsat serve` without workers; the jobs' histories are written through the job
store as a worker writes them (test_job_list.Jobs)."""

from __future__ import annotations

import hashlib
import json
import time

import pytest
from sqlalchemy import insert, update

from modsat_core.artefacts import CurveFile, ProgressRecord
from worker.store.schema import artifacts, metrics
from worker.store.schema import jobs as job_rows

from .conftest import DESKTOP, PHONE, Serve, screenshot_dir
from .test_job_list import CROSS, CUBE, TOTAL, Jobs, _curve

pytestmark = pytest.mark.browser

# the paper's initial design: 27 modules, its centre the one wheel unit
FULL_CUBE = [[[1, 1, 1], [1, 1, 1], [1, 1, 1]], [[1, 1, 1], [1, 2, 1], [1, 1, 1]], [[1, 1, 1], [1, 1, 1], [1, 1, 1]]]
OBJECTIVE = {"module_price_s": 0.05, "wheel_price_s": 0.5, "payload_cells": [[0, 0, 0], [0, 1, 0]]}


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    d = tmp_path_factory.mktemp("results")
    s = Serve(d / "data", d / "serve.log", workers=0, viewer=False)
    j = Jobs(s)
    ids = {}
    # a co-design job: curve.json with design updates and the kept design's candidates
    ids["codesign"] = jid = j.submit(
        "codesign",
        algorithm="diffsim-codesign",
        objective=OBJECTIVE,
        # 120 control steps of 10 x 1/240 s: a 5 s episode, from the server's control step (JobDetail.control_dt_s)
        mission={"tolerance_deg": 1.0, "frame_skip": 10, "episode_steps": 120},
    )
    c = j.claim(jid)
    j.complete(c, CROSS)
    curve = CurveFile(
        algorithm="diffsim-codesign",
        points=_curve(),
        designs=[
            {
                "env_steps": 600 * (i + 1),
                "mean_objective_s": 14.0 - i,
                "best_objective_s": 11.0 - 0.5 * i,
                "valid_draws": 32,
            }
            for i in range(5)
        ],
        selection=[
            {"grid": CUBE, "objective_s": 10.75, "mode": True},
            {"grid": CROSS, "objective_s": 9.6, "mode": False},
        ],
        initial_design={"grid": FULL_CUBE, "objective_s": 23.45},
    )
    with j.store._write() as conn:  # the run's curve.json, as diffsim-codesign writes it
        data = curve.to_json()
        conn.execute(
            update(artifacts)
            .where(artifacts.c.job_id == jid, artifacts.c.name == "curve.json")
            .values(data=data, size=len(data), sha256=hashlib.sha256(data).hexdigest())
        )
    # a job training: records 100 s apart, 1,000 steps each (10 steps/s), 1,000 of 3,000 done
    ids["running"] = jid = j.submit("training")
    c = j.claim(jid)
    for k in (1, 2):
        j.store.publish_progress(
            c, ProgressRecord(env_steps=500 * k, total_env_steps=TOTAL, phase="training", elapsed_s=50.0 * k).to_dict()
        )
    ids["running_claim"] = c
    yield s, j, ids
    j.store.dispose()
    s.stop()


def test_an_eta_while_training_then_the_evaluation_as_its_own_state(jobs, new_page):
    serve, j, ids = jobs
    page = new_page(DESKTOP)
    page.goto(f"{serve.base}/#job={ids['running']}")
    page.wait_for_function("document.getElementById('d-eta').textContent.includes('left')")
    eta = page.text_content("#d-eta")
    assert "about 3 min left" in eta, eta  # 2,000 steps at 10 steps/s: 200 s
    assert not page.locator(".progress.big.evaluating").count()
    j.store.publish_progress(
        ids["running_claim"],
        ProgressRecord(env_steps=TOTAL, total_env_steps=TOTAL, phase="evaluating", elapsed_s=300.0).to_dict(),
    )
    page.wait_for_selector(".progress.big.evaluating")
    text = page.text_content("#d-progress")
    assert "Final evaluation" in text and "training took 5 min" in text, text
    assert page.text_content("#d-eta") == ""
    j.store.publish_progress(  # the evaluation's stage, as train() reports it
        ids["running_claim"],
        ProgressRecord(
            env_steps=TOTAL,
            total_env_steps=TOTAL,
            phase="evaluating",
            stage="3/4: the policy on 100 slews",
            elapsed_s=300.0,
        ).to_dict(),
    )
    page.wait_for_function("document.getElementById('d-progress').textContent.includes('3/4: the policy on 100 slews')")
    page.screenshot(path=str(screenshot_dir() / "evaluating-desktop.png"), full_page=True)


@pytest.mark.parametrize("viewport", [DESKTOP, PHONE], ids=["desktop", "phone"])
def test_a_codesign_job_shows_its_objective_result_times_and_archive(jobs, new_page, viewport):
    serve, _j, ids = jobs
    jid = ids["codesign"]
    page = new_page(viewport)
    page.goto(f"{serve.base}/#job={jid}")
    page.wait_for_selector("#codesign:not([hidden]) table.codesign-table")
    objective = page.text_content("#objective-text")
    assert "0.05 s per module" in objective and "0.5 s more per wheel unit" in objective, objective
    assert "the whole episode, 5.0 s" in objective, objective
    assert "Payload: 2 cells" in page.text_content("#codesign")
    kept = page.locator("#codesign tr.kept")
    assert kept.count() == 1 and "9.60" in kept.text_content()  # the kept design is design.json's (CROSS)
    assert page.locator("#codesign tr.random").count() == 2 and "14.00" in page.text_content("#codesign")
    initial = page.locator("#codesign tr.initial")  # curve.json's initial_design: objective, its prices, its parts
    assert initial.count() == 1
    cells = [c.text_content() for c in initial.locator("td").all()]
    assert "full cube" in initial.text_content() and cells == ["23.45", "21.60", "1.85", "27 / 1"], cells
    assert page.locator("#codesign svg.chart").count() == 1
    assert page.get_attribute("#archive-link", "href") == f"/api/jobs/{jid}/archive.zip"
    times = page.text_content("#d-times")
    assert "wall time" in times and "waited" in times, times
    # the list: success at the tolerance from the final evaluation, the kept design's objective
    cell = page.locator(f"#job-{jid} td.ret")
    if viewport is DESKTOP:
        page.wait_for_function(f"document.querySelector('#job-{jid} td.ret').textContent.includes('J ')")
        assert cell.text_content() == "75 % @ 1\u00b0 \u00b7 J 9.60 s", cell.text_content()
    # every chart's tick labels differ along each axis
    for svg in page.locator("svg.chart").all():
        for axis in ("y-tick", "x-tick"):
            labels = [t.text_content() for t in svg.locator(f"text.{axis}").all()]
            assert len(labels) == len(set(labels)), labels
    name = "desktop" if viewport is DESKTOP else "phone"
    page.screenshot(path=str(screenshot_dir() / f"codesign-{name}.png"), full_page=True)


def test_a_long_runs_evaluation_is_found_past_the_first_page_of_records(jobs, new_page):
    """A finished job of 5,100 training records, then the final evaluation's: the page reads every page of
    records (it read the first 5,000 only), keeping running aggregates, and splits the wall time at the
    evaluation's start."""
    serve, j, _ids = jobs
    jid = j.submit("long")
    c = j.claim(jid)
    n = 5100
    with j.store._write() as conn:  # as publish_progress writes them, in one transaction
        conn.execute(
            insert(metrics),
            [
                {
                    "job_id": jid,
                    "seq": k,
                    "attempt": c.attempt,
                    "created_at": time.time(),
                    "env_steps": k,
                    "data": json.dumps(
                        ProgressRecord(env_steps=k, total_env_steps=n, phase="training", elapsed_s=0.1 * k).to_dict()
                    ),
                }
                for k in range(1, n + 1)
            ],
        )
        conn.execute(update(job_rows).where(job_rows.c.id == jid).values(last_seq=n, env_steps=n))
    j.store.publish_progress(
        c,
        ProgressRecord(
            env_steps=n, total_env_steps=n, phase="evaluating", stage="2/4: PD on the same 100 slews", elapsed_s=510.0
        ).to_dict(),
    )
    j.complete(c, CROSS)
    page = new_page(DESKTOP)
    page.goto(f"{serve.base}/#job={jid}")
    page.wait_for_function("document.getElementById('d-times').textContent.includes('wall time')")
    times = page.text_content("#d-times")
    assert "training 8 min 30 s" in times and "final evaluation" in times, times


def test_tick_labels_differ_where_the_range_is_narrow(jobs, new_page):
    serve, _j, _ids = jobs
    page = new_page(DESKTOP)
    page.goto(serve.base)
    page.wait_for_function("window.modsatCharts !== undefined")
    for lo, hi in ((6630, 6690), (1140, 1260), (6638, 6638.5), (0, 819200), (0.1, 0.14)):
        labels = page.evaluate(f"window.modsatCharts.tickLabels(window.modsatCharts.niceTicks({lo}, {hi}, 5))")
        assert len(labels) == len(set(labels)) > 1, labels
    assert page.evaluate("window.modsatCharts.tickLabels([1150, 1175, 1200])") == ["1.15k", "1.175k", "1.2k"]
