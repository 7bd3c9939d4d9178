"""Issue 46, timing a user can trust: picking a preset in the submit form shows how long a run of it
took, as measured, with the CPU named (modsat_core.spec.preset_times, the README's figures), and says
"not measured here" for a preset never timed. A real headless Chromium at 1280 px; one `modsat serve`
without workers."""

from __future__ import annotations

import pytest

from modsat_core.spec.preset_times import HOW_MEASURED, NOT_MEASURED, run_time_text

from .conftest import DESKTOP, Serve, open_submit_form, screenshot_dir

pytestmark = pytest.mark.browser


@pytest.fixture(scope="module")
def serve(tmp_path_factory):
    d = tmp_path_factory.mktemp("preset-times")
    s = Serve(d / "data", d / "serve.log", workers=0, viewer=False)
    yield s
    s.stop()


def test_the_form_shows_each_presets_measured_time(serve, new_page):
    page = new_page(DESKTOP)
    page.goto(serve.base + "/")
    open_submit_form(page)
    box = page.locator("#preset-time")
    page.wait_for_function("document.getElementById('preset-time').textContent !== ''")
    for name in ("quick", "cpu-3x3x3", "diffsim-3x3x3", "paper-3x3x3", "quick"):
        page.select_option("#preset", name)
        want = run_time_text(name)
        page.wait_for_function("w => document.getElementById('preset-time').textContent.includes(w)", arg=want)
        text = box.text_content()
        if want == NOT_MEASURED:
            assert text == f"Time per run: {NOT_MEASURED}.", text
        else:
            assert "as measured" in text and HOW_MEASURED in text, text
        assert box.is_visible()
        b = box.bounding_box()
        assert b is not None and b["x"] >= 0 and b["x"] + b["width"] <= DESKTOP["width"], "inside the page"
    page.locator("#submit-form").screenshot(path=str(screenshot_dir() / "preset-time-desktop.png"))
