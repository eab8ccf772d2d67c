"""End to end in a real browser: Debian's chromium driven by Playwright.

open the console → create a model in the wizard → start training → a chart point appears → stop →
run an evaluation → the video plays. Also: text from a model folder is shown as text, not run as HTML.
With RACERLAB_SCREENSHOTS=DIR the pages are saved there (docs/img holds the ones in docs/console.md).
Skipped, with the reason, where chromium or Playwright is missing.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from tests.console.conftest import Console

CHROMIUM = os.environ.get("RACERLAB_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]


@pytest.fixture(scope="module")
def browser():
    sync_api = pytest.importorskip("playwright.sync_api", reason="Playwright is not installed (pip install playwright)")
    if not Path(CHROMIUM).is_file():
        pytest.skip(f"no chromium at {CHROMIUM}: install Debian's package (apt-get install -y chromium) "
                    "or set RACERLAB_CHROMIUM")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
        assert b.version.split(".")[0] in _version(CHROMIUM)
        yield b
        b.close()


def _version(path: str) -> str:
    import subprocess

    return subprocess.run([path, "--version"], capture_output=True, text=True, timeout=60).stdout


def shot(page, name: str) -> None:
    folder = os.environ.get("RACERLAB_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.screenshot(path=str(Path(folder) / f"console_{name}.png"), full_page=False)


def test_create_train_stop_evaluate_play(browser, tmp_path):
    console = Console(tmp_path / "ws")
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    page.on("dialog", lambda d: d.accept())
    try:
        page.goto(console.url + "/")
        page.get_by_text("No models in this workspace yet").wait_for()
        page.click("text=New model >> nth=0")
        page.fill("#new-name", "e2e")
        page.fill("#track-search", "oval")  # ~130 tracks: the search keeps the ones whose name has it
        shown = page.evaluate("[...document.querySelectorAll('.trackpick')].filter(p => p.offsetParent)"
                              ".map(p => p.dataset.track)")
        assert "lab_oval" in shown and all("oval" in t.lower() for t in shown)
        page.click('.trackpick[data-track="lab_oval"]')
        assert _overlapping_labels(page) == 0
        page.fill("#new-cars", "4")
        page.fill('input[data-hp="num_episodes_between_training"]', "4")
        page.evaluate("window.scrollTo(0, 0)")
        shot(page, "wizard")
        page.click("#reward-check")
        page.locator("#reward-report").wait_for(timeout=60_000)
        page.locator("#reward-report").scroll_into_view_if_needed()
        shot(page, "wizard_reward")
        page.click("#new-create")
        page.wait_for_url("**/#/model/e2e")
        page.fill("#train-iterations", "300")  # stopped below, long before it ends
        page.click("#train-start")
        page.locator("#model-state", has_text="training").wait_for()
        assert page.locator("#train-start").text_content() == "Training…"
        # a chart point appears when the first iteration is logged, and the header follows it
        page.wait_for_function("document.querySelector('#chart-reward')?.dataset.points >= 1", timeout=300_000)
        lag = page.evaluate("window.__chartPoints[0].shown - window.__chartPoints[0].time")
        assert lag < 1.0, f"chart point shown {lag:.2f} s after the iteration was logged"
        page.wait_for_function("/iteration [1-9]/.test(document.querySelector('#model-header').textContent)",
                               timeout=30_000)
        # a features model sees a vector: the live view says so and shows no camera or lidar
        page.locator("#live-sees", has_text="features vector").wait_for(timeout=120_000)
        assert not page.locator("#live-camera").is_visible()
        shot(page, "training")
        page.click("#train-stop")
        page.locator("#model-state", has_text="idle").wait_for(timeout=120_000)
        page.locator("#train-start", has_text="Resume training").wait_for(timeout=30_000)
        logged = console.client.get("/api/models/e2e").json()["iteration"]
        page.wait_for_function(f"document.querySelector('#model-header').textContent.includes('iteration {logged} ')",
                               timeout=30_000)
        page.goto(console.url + "/#/model/e2e/evaluation")
        page.fill("#eval-trials", "1")
        page.locator(".form input[type=number]").nth(3).fill("1")  # resets allowed
        page.click("#eval-start")
        video = page.locator("video")
        video.wait_for(timeout=300_000)
        page.wait_for_function("document.querySelector('video').readyState >= 2", timeout=60_000)
        page.evaluate("document.querySelector('video').muted = true; document.querySelector('video').play()")
        page.wait_for_function("document.querySelector('video').currentTime > 0.3", timeout=30_000)
        assert page.evaluate("document.querySelector('video').videoWidth") > 0
        page.locator(".evaluation h3").first.scroll_into_view_if_needed()
        page.evaluate("window.scrollBy(0, 380)")
        shot(page, "evaluation")
        page.goto(console.url + "/#/models")
        page.locator('tr[data-model="e2e"] .badge', has_text="idle").wait_for()
        shot(page, "models")
        # a model whose training.toml is broken shows its (long) error inside the card
        bad = console.app.state.workspace.root / "broken"
        shutil.copytree(console.app.state.workspace.root / "e2e", bad, ignore=shutil.ignore_patterns("evaluation-*"))
        (bad / "training.toml").write_text("[track]\nnames = [\"" + "a_track_that_is_not_there_" * 6 + "\"]\n")
        page.reload()
        page.locator('tr[data-model="broken"]').wait_for()
        widths = page.evaluate("[document.querySelector('#models-table').scrollWidth, "
                               "document.querySelector('#models-card').clientWidth]")
        assert widths[0] <= widths[1], widths
    finally:
        page.close()
        console.stop()


def _overlapping_labels(page) -> int:
    """Pairs of action-fan labels whose boxes overlap (the default 5 actions, two at each side's angle)."""
    return page.evaluate("""() => {
      const boxes = [...document.querySelectorAll('.actions-fan .fan-label')].map(t => t.getBBox());
      let n = 0;
      for (let i = 0; i < boxes.length; i++) for (let j = 0; j < i; j++) {
        const a = boxes[i], b = boxes[j];
        if (a.x < b.x + b.width && b.x < a.x + a.width && a.y < b.y + b.height && b.y < a.y + a.height) n++;
      }
      return boxes.length ? n : -1;
    }""")


def test_text_from_files_is_not_run_as_html(browser, tmp_path):
    console = Console(tmp_path / "ws")
    c = console.client
    c.post("/api/models", json={"name": "x"})
    toml = console.app.state.workspace.root / "x" / "training.toml"
    evil = '<img src=y onerror="window.__pwned=1">'
    import re

    toml.write_text(re.sub(r"(?m)^names = .*$", f"names = ['{evil}']", toml.read_text()))
    page = browser.new_page()
    try:
        page.goto(console.url + "/")
        cell = page.locator('tr[data-model="x"] td').nth(2)
        cell.wait_for()
        assert cell.text_content() == evil
        assert page.evaluate("window.__pwned") is None
        assert page.locator("tr[data-model='x'] img").count() == 0
    finally:
        page.close()
        console.stop()


def test_exchange_tab_exports_for_the_car_and_offers_the_download(browser, tmp_path):
    from tests.exchange.conftest import make_model

    console = Console(tmp_path / "ws")
    make_model(console.app.state.workspace.root / "cam", "camera")
    page = browser.new_page(viewport={"width": 1280, "height": 700})
    try:
        page.goto(console.url + "/#/model/cam/exchange")
        page.click("#export-car")
        link = page.locator("#export-files a", has_text="cam-car.tar.gz")
        link.wait_for(timeout=120_000)
        with page.expect_download() as dl:
            link.click()
        assert dl.value.suggested_filename == "cam-car.tar.gz"
        assert page.locator("#export-status").text_content() == "cam-car.tar.gz written."
        shot(page, "exchange")
        page.goto(console.url + "/#/exchange")
        page.locator("#import-file").wait_for()
    finally:
        page.close()
        console.stop()


def test_a_running_race_is_cancelled_from_its_button(browser, tmp_path):
    from racerlab.model import ModelFolder
    from tests.evaluate.models import write_checkpoint

    console = Console(tmp_path / "ws")
    for name in ("r1", "r2", "r3"):
        console.client.post("/api/models", json={"name": name, "track": "lab_oval", "cars": 4})
        write_checkpoint(ModelFolder(console.app.state.workspace.root / name))
    page = browser.new_page(viewport={"width": 1280, "height": 700})
    try:
        page.goto(console.url + "/#/races")
        page.locator("#race-start").wait_for()
        assert page.locator("#race-cancel").is_disabled()  # nothing to cancel yet
        for box in page.locator("input[data-race]").all():
            box.check()
        page.fill("#race-trials", "100")  # three models x 100 laps: far longer than this test waits
        page.click("#race-start")
        page.locator("#race-cancel:not([disabled])").wait_for(timeout=10_000)
        page.click("#race-cancel")
        page.locator("#toast div", has_text="race cancelled after").wait_for(timeout=20_000)
        shot(page, "race_cancelled")
        assert page.locator("#race-cancel").is_disabled() and not page.locator("#race-start").is_disabled()
        assert console.client.get("/api/tasks/race").json()["status"] == "cancelled"
    finally:
        page.close()
        console.stop()


def test_the_line_panel_offers_the_line_methods_the_solver_has(browser, tmp_path):
    """The racing-line panel's method choices come from the server (line.METHODS), not a list of the page's own."""
    from racerlab.line import METHODS

    console = Console(tmp_path / "ws")
    page = browser.new_page(viewport={"width": 1280, "height": 900})
    try:
        page.goto(console.url + "/#analysis")
        page.locator("#line-track").wait_for()
        options = page.evaluate("[...document.querySelector('#line-method').options].map(o => o.text)")
        assert options == list(METHODS)
    finally:
        page.close()
        console.stop()
