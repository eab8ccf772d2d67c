"""Shared fixtures: the real AWS track files live in ../shared/tracks next to the repository.

``RACERLAB_TEST_AWS_TRACKS`` points the tests at another copy; tests that need a real track
are skipped, not failed, when none is there.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from racerlab.track import load_file

REPO = Path(__file__).resolve().parents[1]
AWS_TRACKS = Path(os.environ.get("RACERLAB_TEST_AWS_TRACKS") or REPO.parent / "shared" / "tracks")


def lock_holder(folder) -> subprocess.Popen:
    """Another process holding `folder`'s training lock, as `racerlab train` started in a terminal does; it imports
    the racerlab under test and lets go when killed (or after 60 s)."""
    import racerlab

    code = ("import time\nfrom racerlab.model import ModelFolder\n"
            f"ModelFolder({str(folder)!r}).lock().acquire()\nprint('held', flush=True)\ntime.sleep(60)\n")
    env = {**os.environ, "PYTHONPATH": os.path.dirname(os.path.dirname(os.path.abspath(racerlab.__file__)))}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "held"
    return proc


def aws_track_path(name: str) -> Path:
    p = AWS_TRACKS / f"{name}.npy"
    if not p.is_file():
        pytest.skip(f"real AWS track {name} not found in {AWS_TRACKS}")
    return p


@pytest.fixture
def aws_track():
    """Load a real AWS track by file stem, e.g. aws_track('reInvent2019_track')."""
    return lambda name: load_file(aws_track_path(name))


def pytest_terminal_summary(terminalreporter):
    """Each skipped test by name with its reason (pytest's own summary groups skips by the line that skipped, so
    three browser tests skipped for want of Chromium read as one line without their names)."""
    skipped = terminalreporter.stats.get("skipped", [])
    if not skipped:
        return
    terminalreporter.section(f"{len(skipped)} skipped, and why")
    for rep in skipped:
        reason = rep.longrepr[2] if isinstance(rep.longrepr, tuple) else str(rep.longrepr)
        terminalreporter.write_line(f"{rep.nodeid}: {reason.removeprefix('Skipped: ')}")
