"""The job list and a job's page as issue 14 asked for them, in a real headless Chromium over
real HTTP: no clipped column at 1280 px with a 120-character and a CJK job name, CJK glyphs
drawn (not boxes), the job's details above the submit form on a phone, the PD baseline as a
reference line on the learning curves, the total time and the attempts of a job that ran
twice, and a thumbnail of each finished job's satellite in the list.

No training runs here: one `modsat serve` without workers, and the jobs' histories written
through the job store (worker/store/, as a worker writes them), with files made through
their models in modsat_core/artefacts.py (design.json, evaluation.json, curve.json), as
modsat_core/evaluation/run_files.py's ``run_files`` makes them. The real pipeline's files are shown in
test_flow.py."""

from __future__ import annotations

import sqlite3

import pytest

from modsat_core.artefacts import (
    CurveFile,
    CurvePoint,
    DesignReport,
    EvaluationReport,
    ProgressRecord,
    RunSummary,
)
from worker.settings import default_db_url
from worker.store import JobStore

from .conftest import DESKTOP, PHONE, Serve, actuator_pixels, screenshot_dir

LONG_NAME = ("a-very-long-job-name-" * 6)[:120]
CJK_NAME = "模块化卫星の設計 共同设计 姿态控制 衛星モジュール 실험"
TOTAL = 3000

#: The full 3x3x3 cube with its one actuator at the centre (what `quick` grows), and a cross.
CUBE = [[[2 if (x, y, z) == (1, 1, 1) else 1 for z in range(3)] for y in range(3)] for x in range(3)]
CROSS = [[[0] * 3 for _ in range(3)] for _ in range(3)]
for _x, _y, _z in [(1, 1, 1), (0, 1, 1), (2, 1, 1), (1, 0, 1), (1, 2, 1), (1, 1, 0), (1, 1, 2)]:
    CROSS[_x][_y][_z] = 1
CROSS[0][1][1] = CROSS[2][1][1] = 2

#: Evaluation summaries (evaluate.MonteCarloResult.summary): `success_rate` is at the mission's
#: tolerance, 1 deg here (TOLERANCE), and the report tolerances 0.25 and 1 deg are scored too.
TOLERANCE = 1.0
PD_CUBE = {
    "episodes": 8,
    "success_rate": 1.0,
    "success_rate_at_0.25_deg": 0.875,
    "success_rate_at_1_deg": 1.0,
    "mean_return": -41.5,
    "std_return": 3.0,
    "safety_violations": 0,
    "median_final_error_deg": 0.05,
    "median_settling_time_s": 9.1,
    "median_slew_time_ratio": 1.4,
    "median_effort_Nms": 0.01,
    "max_peak_rate_rad_s": 0.05,
    "median_final_rate_rad_s": 0.0001,
}
POLICY_CUBE = {
    **PD_CUBE,
    "success_rate": 0.75,
    "success_rate_at_0.25_deg": 0.5,
    "success_rate_at_1_deg": 0.75,
    "mean_return": -60.25,
}


def _design(grid) -> DesignReport:
    """design.json as modsat_core.evaluation.run_files.design_report writes it (mass figures made up)."""
    flat = [v for plane in grid for row in plane for v in row]
    return DesignReport.of(grid, mass_kg=2.0 * sum(v != 0 for v in flat), principal_inertia_kgm2=[0.01, 0.01, 0.01])


def _curve(n: int = 5) -> list[CurvePoint]:
    """Learning-curve points as reports.curve_point makes them, less the report tolerances' success."""
    return [
        CurvePoint(
            env_steps=TOTAL * (i + 1) // n,
            updates=10 * i,
            valid=True,
            modules=27,
            actuators=1,
            mean_return=-120.0 + 15.0 * i,
            success_rate=0.1 * i,
            median_final_error_deg=2.0 / (i + 1),
            median_slew_time_ratio=2.0,
        )
        for i in range(n)
    ]


class Jobs:
    """Submits over the API, then plays the worker's part on the store."""

    def __init__(self, serve: Serve):
        self.serve = serve
        self.store = JobStore(default_db_url(serve.data_dir))

    def submit(self, name: str, **overrides) -> int:
        r = self.serve.client.post(
            "/api/jobs",
            json={
                "preset": "quick-td3",
                "overrides": {
                    "name": name,
                    "training": {"total_env_steps": TOTAL},
                    "mission": {"tolerance_deg": TOLERANCE},
                    **overrides,
                },
            },
        )
        assert r.status_code == 201, r.text
        return r.json()["id"]

    def claim(self, job_id: int):
        c = self.store.claim("test-worker", lease_s=3600)
        assert c is not None and c.job_id == job_id, "the job just submitted is the oldest queued one"
        return c

    def finish(self, name: str, grid, *, pd=PD_CUBE, policy=POLICY_CUBE, elapsed_s: float = 62.0) -> int:
        job_id = self.submit(name)
        c = self.claim(job_id)
        self.complete(c, grid, pd=pd, policy=policy, elapsed_s=elapsed_s)
        return job_id

    def complete(self, c, grid, *, pd=PD_CUBE, policy=POLICY_CUBE, elapsed_s: float = 62.0) -> None:
        curve = _curve()
        for p in curve:
            assert self.store.publish_progress(
                c,
                ProgressRecord(
                    env_steps=p.env_steps,
                    total_env_steps=TOTAL,
                    phase="training",
                    eval=p,
                    elapsed_s=elapsed_s / 2,
                ).to_dict(),
            )
        self.store.publish_progress(c, ProgressRecord(env_steps=TOTAL, phase="done", elapsed_s=elapsed_s).to_dict())
        design = _design(grid)
        evaluation = EvaluationReport.model_validate(
            {
                "episodes": 8,
                "seed": 0,
                "design_valid": True,
                "policy": {"summary": policy, "episodes": []},
                "pd_baseline": {"summary": pd, "episodes": []},
            }
        )
        files = {
            "design.json": design.to_json(),
            "evaluation.json": evaluation.to_json(),
            "curve.json": CurveFile(algorithm="td3-codesign", points=curve).to_json(),
        }
        summary = RunSummary.model_validate({"policy": policy, "pd_baseline": pd, "design": design.figures()})
        assert self.store.complete(
            c, files=files, summary=summary.to_dict(), env_steps=TOTAL, attempt_seconds=elapsed_s
        )


@pytest.fixture(scope="module")
def jobs(tmp_path_factory):
    d = tmp_path_factory.mktemp("joblist")
    s = Serve(d / "data", d / "serve.log", workers=0, viewer=False)
    j = Jobs(s)
    ids = {
        "cube": j.finish("full-cube", CUBE),
        "cross": j.finish("cross", CROSS),
        "long": j.finish(LONG_NAME, CUBE),
        "cjk": j.finish(CJK_NAME, CROSS),
    }

    # A job that lost its first attempt's lease after 3 min 28 s, and succeeded on the second in
    # 62 s (the worker's elapsed_s counts only the second): 4 min 30 s in all.
    jid = j.submit("two-attempts")
    c = j.claim(jid)
    j.store.publish_progress(c, {"env_steps": 1000, "total_env_steps": TOTAL, "phase": "training", "elapsed_s": 200})
    assert (
        j.store.fail_attempt(
            c, error="lease expired", detail=None, outcome="lease-expired", retry_delay_s=0, attempt_seconds=0.0
        )
        == "queued"
    )
    c = j.claim(jid)
    j.complete(c, CUBE, elapsed_s=62.0)
    con = sqlite3.connect(s.data_dir / "modsat.db")
    with con:
        t0 = con.execute("select started_at from modsat_attempts where job_id = ? and attempt = 1", (jid,)).fetchone()[
            0
        ]
        con.execute(
            "update modsat_attempts set started_at = ?, ended_at = ? where job_id = ? and attempt = 1",
            (t0, t0 + 208.0, jid),
        )
        con.execute(
            "update modsat_attempts set started_at = ?, ended_at = ? where job_id = ? and attempt = 2",
            (t0 + 215.0, t0 + 277.0, jid),
        )
    con.close()
    ids["retried"] = jid
    ids["running"] = j.submit("still-running")
    c = j.claim(ids["running"])
    j.store.publish_progress(c, {"env_steps": 1200, "total_env_steps": TOTAL, "phase": "training", "elapsed_s": 30})
    ids["queued"] = j.submit("waiting")
    yield s, ids
    j.store.dispose()
    s.stop()


def _grey_pixels(png: bytes) -> int:
    """Pixels of the structure's grey: unsaturated, neither the white background nor black."""
    import io

    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64) / 255.0
    mx, mn = img.max(axis=-1), img.min(axis=-1)
    return int(((mx - mn < 0.12) & (mx > 0.3) & (mx < 0.9)).sum())


def _open(page, base: str, job: int | None = None) -> None:
    page.goto(base + "/" + (f"#job={job}" if job else ""))
    page.wait_for_selector("#job-rows tr[data-id]")
    if job:
        page.wait_for_function(f"document.querySelector('#detail-h').textContent.startsWith('Job #{job}')")


def test_no_clipped_column_at_1280_with_long_and_cjk_names(jobs, new_page):
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base)
    wrap = page.locator("#jobs .table-wrap")
    assert wrap.evaluate("w => w.scrollWidth <= w.clientWidth"), "the job table scrolls sideways: a column is cut off"
    box = wrap.bounding_box()
    heads = page.locator("#job-table thead th")
    assert heads.all_text_contents() == ["#", "name", "status", "progress", "result"]
    for i in range(heads.count()):
        h = heads.nth(i).bounding_box()
        assert h["x"] >= box["x"] - 0.5 and h["x"] + h["width"] <= box["x"] + box["width"] + 0.5, (
            f"header {heads.nth(i).text_content()!r} is outside the table's box"
        )
        assert h["x"] + h["width"] <= DESKTOP["width"]
    for key in ("long", "cjk"):
        row = page.locator(f"#job-{ids[key]}")
        name = row.locator(".job-name")
        assert name.get_attribute("title") == (LONG_NAME if key == "long" else CJK_NAME), "the full name on hover"
        # The name is cut inside its cell (ellipsis), the columns after it stay in the table.
        assert name.evaluate("e => e.scrollWidth > e.clientWidth && getComputedStyle(e).textOverflow === 'ellipsis'")
        cell = row.locator("td.name").bounding_box()
        nb = name.bounding_box()
        assert nb["x"] + nb["width"] <= cell["x"] + cell["width"] + 0.5
        for sel in ("td.status .badge", "td.prog .progress", "td.ret"):
            b = row.locator(sel).bounding_box()
            assert b is not None and b["width"] > 0 and b["x"] + b["width"] <= box["x"] + box["width"] + 0.5, sel
        assert row.locator("td.status").text_content() == "succeeded"
        # the final evaluation's success at the mission's tolerance, not a curve point's raw return (issue 46)
        page.wait_for_function(f"document.querySelector('#job-{ids[key]} td.ret').textContent !== ''")
        assert row.locator("td.ret").text_content() == "75 % @ 1\u00b0", "the result shows"
    page.screenshot(path=str(screenshot_dir() / "job-list-long-names.png"))


def test_cjk_names_are_drawn_not_boxes(jobs, new_page):
    """Each CJK character drawn in the page's font must differ from the others and from a code
    point no font has (the 'tofu' box a missing glyph becomes)."""
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base)
    font = page.locator(f"#job-{ids['cjk']} .job-name").evaluate("e => getComputedStyle(e).font")
    chars = ["模", "卫", "の", "設", "실"]
    shapes = page.evaluate(
        """([font, chars]) => {
        const c = document.createElement('canvas'); c.width = 40; c.height = 40;
        const g = c.getContext('2d', { willReadFrequently: true });
        return chars.map((ch) => {
            g.clearRect(0, 0, 40, 40); g.font = font.replace(/\\d+px/, '28px'); g.fillStyle = '#000';
            g.textBaseline = 'top'; g.fillText(ch, 4, 4);
            const d = g.getImageData(0, 0, 40, 40).data; let s = '';
            for (let i = 3; i < d.length; i += 4) s += d[i] > 127 ? '1' : '0';
            return s;
        });
    }""",
        [font, [*chars, "\U0010fffd"]],
    )
    tofu, drawn = shapes[-1], shapes[:-1]
    assert all("1" in s for s in drawn), "something is drawn"
    assert all(s != tofu for s in drawn), "a CJK character is drawn as the missing-glyph box (install fonts-noto-cjk)"
    assert len(set(drawn)) == len(drawn), "different CJK characters look the same: boxes"
    row = page.locator(f"#job-{ids['cjk']}")
    row.screenshot(path=str(screenshot_dir() / "job-row-cjk.png"))


def test_phone_shows_the_job_before_the_form(jobs, new_page):
    serve, ids = jobs
    page = new_page(PHONE, is_mobile=True, has_touch=True, device_scale_factor=2)
    _open(page, serve.base)
    page.tap(f"#job-{ids['cube']}")
    page.wait_for_function(f"document.querySelector('#detail-h').textContent.startsWith('Job #{ids['cube']}')")
    # the tap scrolls the job to the top once its details are in: wait for that, then measure
    # everything at once in page coordinates (measuring box by box raced the scroll)
    page.wait_for_function("Math.abs(document.querySelector('#detail').getBoundingClientRect().top) < 2")
    jobs_box, detail, form = page.evaluate(
        """(sels) => sels.map((s) => {
        const r = document.querySelector(s).getBoundingClientRect();
        return { x: r.x, y: r.y + window.scrollY, width: r.width, height: r.height };
    })""",
        ["#jobs", "#detail", "#submit"],
    )
    assert jobs_box["y"] + jobs_box["height"] <= detail["y"], "the list, then the job"
    assert detail["y"] + detail["height"] <= form["y"], "the job's details come before the submit form"
    assert detail["width"] <= PHONE["width"] and form["width"] <= PHONE["width"]
    assert page.evaluate("document.scrollingElement.scrollWidth") <= PHONE["width"], "no sideways scroll"
    page.screenshot(path=str(screenshot_dir() / "phone-job-selected.png"))  # where the tap scrolled to
    page.screenshot(path=str(screenshot_dir() / "phone-job-before-form.png"), full_page=True)


def test_desktop_keeps_the_job_beside_the_list(jobs, new_page):
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base, ids["cube"])
    lst, detail, form = (page.locator(s).bounding_box() for s in ("#jobs", "#detail", "#submit"))
    assert detail["x"] >= lst["x"] + lst["width"], "the job is on the right"
    assert abs(detail["y"] - lst["y"]) < 1, "at the top, beside the list"
    assert 0 <= form["y"] - (lst["y"] + lst["height"]) <= 24, "the form right under the list, whatever the job's height"


def test_pd_baseline_on_the_learning_curves(jobs, new_page):
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base, ids["cube"])
    page.wait_for_function("document.querySelector('#curves').dataset.reference === 'pd'")
    ret, succ = page.locator("#curves svg.chart").nth(0), page.locator("#curves svg.chart").nth(1)
    line = ret.locator("line.ref")
    assert line.count() == 1
    assert float(line.get_attribute("data-value")) == PD_CUBE["mean_return"]
    # The line is drawn where -41.5 is on the chart's y axis (read from two of its tick labels),
    # and the axis reaches up to it.
    ticks = sorted(
        (float(t.text_content()), float(t.get_attribute("y")) - 4)
        for t in ret.locator("text.tick[text-anchor=end]").all()
    )
    (v0, y0), (v1, y1) = ticks[0], ticks[-1]
    y = float(line.get_attribute("y1"))
    expect = y0 + (y1 - y0) * (PD_CUBE["mean_return"] - v0) / (v1 - v0)
    assert abs(y - expect) < 1.0, (y, expect, ticks)
    assert float(line.get_attribute("y1")) == float(line.get_attribute("y2")), "horizontal"
    assert max(p[1] for p in ticks) >= y >= 26 - 0.5, "inside the plot"
    assert "PD baseline, same design: -41.5" in ret.text_content()
    # The success chart: the policy at the mission tolerance (all that the curve points hold), the
    # PD baseline at that tolerance and at the other one it was scored at.
    refs = {r.get_attribute("data-name"): float(r.get_attribute("data-value")) for r in succ.locator("line.ref").all()}
    assert refs == {"PD baseline, within 1 deg: 100 %": 100.0, "PD baseline, within 0.25 deg: 88 %": 87.5}, refs
    assert succ.locator("path.series").count() == 1
    assert succ.locator("path.series").get_attribute("data-name") == "policy, within 1 deg"
    page.locator("#curves").screenshot(path=str(screenshot_dir() / "curves-pd-baseline.png"))


def test_total_time_and_attempts_of_a_retried_job(jobs, new_page):
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base, ids["retried"])
    text = page.text_content("#d-progress")
    assert text.endswith("done \u00b7 4 min 30 s over 2 attempts"), text
    assert "62 s" not in text
    assert page.is_visible("#d-attempts")
    assert page.text_content("#d-attempts") == "attempt 1: 3 min 28 s, lease-expired \u00b7 attempt 2: 62 s, succeeded"
    page.locator("#detail .detail-head").screenshot(path=str(screenshot_dir() / "job-two-attempts-head.png"))
    page.screenshot(path=str(screenshot_dir() / "job-two-attempts.png"))

    # A job of one attempt says its time alone.
    _open(page, serve.base, ids["cross"])
    page.wait_for_function(f"document.querySelector('#detail-h').textContent.startsWith('Job #{ids['cross']}')")
    assert page.text_content("#d-progress").endswith("done \u00b7 62 s")
    assert page.is_hidden("#d-attempts")


def test_thumbnails_of_finished_jobs_in_the_list(jobs, new_page):
    serve, ids = jobs
    page = new_page(DESKTOP)
    _open(page, serve.base)
    for key in ("cube", "cross", "long", "cjk", "retried"):
        page.wait_for_selector(f"#job-{ids[key]} svg.thumb")
    for key in ("running", "queued"):
        assert page.locator(f"#job-{ids[key]} svg.thumb").count() == 0, "no design before a job has finished"
    cube = page.locator(f"#job-{ids['cube']} svg.thumb")
    assert cube.get_attribute("data-actuators") == "1" and cube.get_attribute("data-structure") == "26"
    assert cube.locator("polygon.a").count() == 3, "the centre actuator's three faces are drawn"
    assert page.locator(f"#job-{ids['cross']} svg.thumb polygon.a").count() == 6
    # Not WebGL: inline SVG, no canvas in the list.
    assert page.locator("#job-table canvas").count() == 0
    # Pixels: the actuator's orange shows through the structure, and the grey structure is there.
    png = cube.screenshot()
    assert actuator_pixels(png) > 20, "the centre actuator of the full cube is seen"
    assert _grey_pixels(png) > 100, "the structure is drawn in grey"
    for key in ("cube", "cross"):
        page.locator(f"#job-{ids[key]} td.name").screenshot(path=str(screenshot_dir() / f"thumb-{key}.png"))
    page.locator("#jobs").screenshot(path=str(screenshot_dir() / "job-list-thumbnails.png"))
    # The same picture, larger, beside the job's design figures.
    _open(page, serve.base, ids["cube"])
    pic = page.wait_for_selector("#evaluation .design-pic svg.thumb")
    assert pic.get_attribute("data-actuators") == "1"
    page.locator("#evaluation").screenshot(path=str(screenshot_dir() / "job-design-picture.png"))
