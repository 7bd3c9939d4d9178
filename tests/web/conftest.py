"""Browser tests: `modsat serve` in a subprocess (free ports, a temporary data directory) and
Debian's headless Chromium driven by Playwright (never a downloaded browser).

They skip, saying why, where /usr/bin/chromium (or ``MODSAT_CHROMIUM``) or the playwright
package is missing; CI installs both (.ci/run). Screenshots go to ``$MODSAT_SCREENSHOTS``,
default ``build/screenshots`` (git-ignored)."""

from __future__ import annotations

import io
import os
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests.server.conftest import HttpProc, free_port
from tests.worker.helpers import REPO, wait_for

CHROMIUM = os.environ.get("MODSAT_CHROMIUM", "/usr/bin/chromium")
MODSAT = str(Path(sys.executable).with_name("modsat"))
# Flags that work on a closed network with software WebGL (shared/VIEWER-NOTES.md).
CHROMIUM_FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--enable-unsafe-swiftshader",
]
DESKTOP = {"width": 1280, "height": 800}
PHONE = {"width": 390, "height": 844}

#: The `quick` preset's actuator colour (web.viewer.scene.ACTUATOR_SRGB), as an HSV test below.
ACTUATOR_HUE_DEG = (15.0, 45.0)


def screenshot_dir() -> Path:
    d = Path(os.environ.get("MODSAT_SCREENSHOTS") or REPO / "build" / "screenshots")
    d.mkdir(parents=True, exist_ok=True)
    return d


def open_submit_form(page) -> None:
    """Wait until the page has loaded the default preset into the JSON editor and built the
    form fields from it. The preset's <option> appears one request earlier (the presets list,
    then the preset itself), so waiting for the option alone races the editor."""
    page.wait_for_selector("#preset option[value=quick]", state="attached")
    page.wait_for_selector("#f-training-total_env_steps", state="attached")


def actuator_pixels(png: bytes, box: tuple[float, float, float, float] | None = None) -> int:
    """Pixels of the actuator orange (saturated, hue 15-45 deg) in a PNG, optionally only
    inside ``box`` = (x0, y0, x1, y1) as fractions of the image. The faint target ghost
    (opacity 0.2, so pale) and the red / green / blue axes do not count."""
    import numpy as np
    from PIL import Image

    img = np.asarray(Image.open(io.BytesIO(png)).convert("RGB")).astype(np.float64) / 255.0
    if box is not None:
        h, w = img.shape[:2]
        img = img[int(box[1] * h) : int(box[3] * h), int(box[0] * w) : int(box[2] * w)]
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    mx, mn = img.max(axis=-1), img.min(axis=-1)
    sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-9), 0.0)
    hue = np.degrees(np.arctan2(np.sqrt(3) * (g - b), 2 * r - g - b)) % 360.0
    mask = (sat > 0.45) & (mx > 0.35) & (hue >= ACTUATOR_HUE_DEG[0]) & (hue <= ACTUATOR_HUE_DEG[1])
    return int(mask.sum())


class Serve(HttpProc):
    """``modsat serve`` on free ports with its own data directory (and its worker processes,
    hence the process group)."""

    group = True
    stop_timeout_s = 30.0

    def __init__(
        self,
        data_dir: Path,
        log_path: Path,
        *,
        workers: int = 1,
        viewer: bool = True,
        env: dict[str, str] | None = None,
    ):
        self.port = free_port()
        self.base = f"http://127.0.0.1:{self.port}"
        self.data_dir = data_dir
        self.log_path = log_path
        self._log = open(log_path, "wb")  # closed in stop()
        cmd = [MODSAT, "serve", "--workers", str(workers), "--data-dir", str(data_dir), "--port", str(self.port)]
        cmd += ["--viewer-port", "0"] if viewer else ["--no-viewer"]
        env = {
            **os.environ,
            "MODSAT_POLL_S": "0.2",
            "MODSAT_SSE_POLL_S": "0.2",
            "MODSAT_HEARTBEAT_S": "2",
            **(env or {}),
        }
        self.proc = subprocess.Popen(
            cmd, cwd=REPO, env=env, stdout=self._log, stderr=subprocess.STDOUT, start_new_session=True
        )
        wait_for(self._up, 60, f"modsat serve on port {self.port}")
        self.client = httpx.Client(base_url=self.base, timeout=30)

    def log(self) -> str:
        return self.log_path.read_text(errors="replace")


def _missing(reason: str):
    """Skip on a machine without the browser; fail where it is required (CI sets MODSAT_REQUIRE_BROWSER)."""
    if os.environ.get("MODSAT_REQUIRE_BROWSER"):
        pytest.fail(f"{reason}, and MODSAT_REQUIRE_BROWSER is set")
    pytest.skip(reason)


@pytest.fixture(scope="session")
def browser():
    if not Path(CHROMIUM).exists():
        _missing(f"no Chromium at {CHROMIUM} (apt-get install chromium, or set MODSAT_CHROMIUM)")
    try:
        from playwright import sync_api
    except ImportError:
        _missing("the playwright package is not installed (pip install -e '.[test]')")
    pw = sync_api.sync_playwright().start()
    b = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_FLAGS)  # a fresh temp profile
    yield b
    b.close()
    pw.stop()


@pytest.fixture
def new_page(browser, request):
    """Factory: a page in a fresh context (viewport as given); JS errors fail the test."""
    contexts, errors = [], []

    def make(viewport=DESKTOP, **kw):
        ctx = browser.new_context(viewport=viewport, **kw)
        contexts.append(ctx)
        page = ctx.new_page()
        page.set_default_timeout(30_000)
        page.on("pageerror", lambda e: errors.append(str(e)))
        return page

    yield make
    for ctx in contexts:
        ctx.close()
    assert not errors, f"JavaScript errors in the page: {errors}"


@pytest.fixture(scope="module")
def service(tmp_path_factory, request):
    """One `modsat serve` with a worker and the live viewer, for a module's tests."""
    d = tmp_path_factory.mktemp("serve")
    s = Serve(d / "data", d / "serve.log")
    yield s
    s.stop()
    if request.session.testsfailed:
        print(f"----- log of modsat serve on port {s.port}\n{s.log()}")


def close_webgl_notice(frame) -> None:
    """viser warns about software WebGL in a notification; close it (it covers the scene)."""
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        buttons = frame.locator(".mantine-Notification-root button")
        if buttons.count():
            for i in range(buttons.count()):
                try:
                    buttons.nth(i).click(timeout=2000)
                except Exception:  # it may close by itself meanwhile
                    pass
            return
        time.sleep(0.2)
