"""The console against clumsy and hostile input: a model trained from a terminal, requests that would block
it, endless reward functions, bad numbers, symlinks."""

from __future__ import annotations

import os
import subprocess
import sys

import racerlab

SRC = os.path.dirname(os.path.dirname(racerlab.__file__))  # the racerlab under test, in the child too


def _terminal_trainer(folder) -> subprocess.Popen:
    """A process holding the folder's training lock, as `racerlab train` started in a terminal does."""
    code = ("import time\nfrom racerlab.model import ModelFolder\n"
            f"ModelFolder({str(folder)!r}).lock().acquire()\nprint('held', flush=True)\ntime.sleep(60)\n")
    env = {**os.environ, "PYTHONPATH": os.path.abspath(SRC)}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_model_trained_from_a_terminal_shows_training_and_cannot_be_deleted(console):
    c = console.client
    assert c.post("/api/models", json={"name": "busy", "track": "lab_oval", "cars": 4}).status_code == 200
    folder = console.app.state.workspace.root / "busy"
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    proc = _terminal_trainer(folder)
    try:
        assert c.get("/api/models/busy").json()["state"] == "training"
        r = c.delete("/api/models/busy?confirm=busy")
        assert r.status_code == 409, r.text
        assert "stop its training first" in r.json()["error"]
        assert c.post("/api/models/busy/evaluate", json={}).status_code == 409
        assert c.post("/api/models/busy/train", json={"iterations": 1}).status_code == 409
        assert sorted(p.relative_to(folder) for p in folder.rglob("*") if p.name != "training.lock") == before
    finally:
        proc.kill()
        proc.wait()
    assert c.get("/api/models/busy").json()["state"] == "idle"  # the trainer died: the lock is free again
    assert c.delete("/api/models/busy?confirm=busy").status_code == 200
    assert not folder.exists()
    assert not [p for p in console.app.state.workspace.state_root.iterdir() if p.name.startswith("deleting-")]
