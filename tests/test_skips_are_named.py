"""A test run without Chromium (or another optional tool) names each test it skipped and says why."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def test_a_run_without_chromium_names_each_skipped_browser_test_and_the_reason(tmp_path):
    env = {**os.environ, "RACERLAB_CHROMIUM": str(tmp_path / "no-chromium-here"),
           "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    p = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        "tests/console/test_browser.py"], cwd=REPO, env=env, capture_output=True, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stdout[-2000:]
    out = p.stdout
    assert "skipped, and why" in out
    for name in ("test_create_train_stop_evaluate_play", "test_text_from_files_is_not_run_as_html",
                 "test_exchange_tab_exports_for_the_car_and_offers_the_download"):
        line = next(x for x in out.splitlines() if x.startswith(f"tests/console/test_browser.py::{name}: "))
        assert f"no chromium at {tmp_path / 'no-chromium-here'}" in line and "apt-get install -y chromium" in line
