"""The console's three budgets, measured with the real pieces: `racerlab console` as its own process,
Debian's chromium driven by Playwright, training as `racerlab train` started from the page's API.
One JSON line per measurement.

Budgets (issue 18): first page load <= 1 s; a live chart update <= 1 s after the iteration is logged;
an idle console <= 2 % of one core.

- page_load: a fresh browser context (cold cache) opens the console with --models model folders in the
  workspace; the time from navigation start until the models table is drawn (page, script, /api/models).
- live_update: a training of tiny settings runs while the training page is open; for each iteration, the
  time from the trainer's timestamp in metrics.jsonl to the moment the page drew the point.
- idle_cpu: CPU time of the console process over --idle-seconds with no browser, then with the models
  page open (it refreshes the states every 3 s), as a percentage of one core.

    python benchmarks/console_perf.py [--models 20] [--iterations 4] [--idle-seconds 30]
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

CHROMIUM = os.environ.get("RACERLAB_CHROMIUM") or shutil.which("chromium") or "/usr/bin/chromium"
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
         "--disable-component-update", "--disable-sync", "--no-first-run"]


def emit(**fields) -> None:
    print(json.dumps(fields), flush=True)


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def start_console(root: Path, port: int) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-m", "racerlab", "console", "--dir", str(root), "--port", str(port),
                             "--no-browser"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(200):
        try:
            urllib.request.urlopen(f"http://127.0.0.1:{port}/api/models", timeout=1)
            return proc
        except OSError:
            time.sleep(0.1)
    raise RuntimeError("the console did not start")


def idle_cpu(pid: int, seconds: float) -> float:
    t0, c0 = time.monotonic(), cpu_seconds(pid)
    time.sleep(seconds)
    return 100.0 * (cpu_seconds(pid) - c0) / (time.monotonic() - t0)


def page_load(browser, url: str, runs: int = 5) -> list[float]:
    times = []
    for _ in range(runs):
        ctx = browser.new_context()
        page = ctx.new_page()
        page.goto(url + "/", wait_until="commit")
        page.wait_for_selector("tr[data-model]")
        times.append(page.evaluate("performance.now()") / 1000)
        ctx.close()
    return times


def live_updates(browser, url: str, csrf: str, name: str, iterations: int) -> list[float]:
    page = browser.new_page()
    page.goto(f"{url}/#/model/{name}")
    page.wait_for_selector("#chart-reward")
    page.evaluate("([csrf, url, n]) => fetch(url, {method: 'POST', body: JSON.stringify({iterations: n}), "
                  "headers: {'X-CSRF-Token': csrf, 'Content-Type': 'application/json'}})",
                  [csrf, f"/api/models/{name}/train", iterations])
    page.wait_for_function(f"(window.__chartPoints || []).length >= {iterations}", timeout=900_000)
    points = page.evaluate("window.__chartPoints")
    page.wait_for_selector("#model-state:text('idle')", timeout=120_000)  # the trainer has exited
    page.close()
    return [p["shown"] - p["time"] for p in points]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", type=int, default=20)
    ap.add_argument("--iterations", type=int, default=4)
    ap.add_argument("--idle-seconds", type=float, default=30.0)
    ap.add_argument("--port", type=int, default=8791)
    args = ap.parse_args()
    from playwright.sync_api import sync_playwright

    from racerlab.console.modelapi import init_model

    root = Path(tempfile.mkdtemp(prefix="racerlab-console-bench-"))
    for i in range(args.models):
        init_model(root / f"model-{i:02d}", track="lab_oval", num_cars=4)
    hp = json.loads((root / "model-00" / "hyperparameters.json").read_text())
    (root / "model-00" / "hyperparameters.json").write_text(json.dumps({**hp, "num_episodes_between_training": 4}))
    proc = start_console(root, args.port)
    url = f"http://127.0.0.1:{args.port}"
    try:
        emit(measure="idle_cpu", clients="none", percent_of_core=round(idle_cpu(proc.pid, args.idle_seconds), 3),
             seconds=args.idle_seconds, budget=2.0)
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=FLAGS, headless=True)
            loads = page_load(browser, url)
            emit(measure="page_load", models=args.models, median_s=round(statistics.median(loads), 3),
                 max_s=round(max(loads), 3), runs=len(loads), budget_s=1.0)
            page = browser.new_page()
            page.goto(url + "/")
            page.wait_for_selector("tr[data-model]")
            emit(measure="idle_cpu", clients="models page open",
                 percent_of_core=round(idle_cpu(proc.pid, args.idle_seconds), 3), seconds=args.idle_seconds,
                 budget=2.0)
            csrf = re.search(r'name="csrf-token" content="([^"]+)"', page.content()).group(1)
            page.close()
            lags = live_updates(browser, url, csrf, "model-00", args.iterations)
            emit(measure="live_update", iterations=len(lags), median_s=round(statistics.median(lags), 3),
                 max_s=round(max(lags), 3), budget_s=1.0)
            browser.close()
    finally:
        proc.terminate()
        proc.wait(10)
        shutil.rmtree(root, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
