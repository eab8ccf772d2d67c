"""The console against clumsy and hostile input: a model trained from a terminal, requests that would block
it, endless reward functions, bad numbers, symlinks."""

from __future__ import annotations

import io
import shutil
import tarfile
import time
from concurrent.futures import ThreadPoolExecutor

import pytest

from tests.conftest import lock_holder


def test_a_model_trained_from_a_terminal_shows_training_and_cannot_be_deleted(console):
    c = console.client
    assert c.post("/api/models", json={"name": "busy", "track": "lab_oval", "cars": 4}).status_code == 200
    folder = console.app.state.workspace.root / "busy"
    before = sorted(p.relative_to(folder) for p in folder.rglob("*"))
    proc = lock_holder(folder)
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


# ---- 4: blocking work runs off the event loop ----------------------------------------------------------------
def _tar_gz(files: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for name, data in files.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


@pytest.mark.parametrize("route, module", [("/api/imports", "racerlab.console.exchange"),
                                           ("/api/uploads", "racerlab.console.runs")])
def test_checking_an_upload_does_not_stall_other_requests(console, monkeypatch, route, module):
    import importlib

    mod = importlib.import_module(module)
    real = mod.check_archive

    def slow(path, *a, **kw):  # a gzip bomb takes this long to read through
        time.sleep(4)
        return real(path, *a, **kw)

    monkeypatch.setattr(mod, "check_archive", slow)
    data = _tar_gz({"logs/metrics.json": b"{}"})
    c = console.client
    with ThreadPoolExecutor(1) as pool:
        upload = pool.submit(c.post, route, files={"file": ("big.tar.gz", data)}, data={"name": "up"})
        time.sleep(0.5)
        t0 = time.monotonic()
        assert c.get("/api/models").status_code == 200
        waited = time.monotonic() - t0
        upload.result()
    assert waited < 1.5, f"GET /api/models waited {waited:.1f} s behind the upload's check"


# ---- 5: an endless reward is cut ------------------------------------------------------------------------------
def test_an_endless_reward_call_is_cut_by_the_watchdog(console):
    reward = "def reward_function(params):\n    while True:\n        pass\n"
    r = console.client.post("/api/reward/check", json={"reward": reward}, timeout=300)
    assert r.status_code == 400, r.text
    assert "reward time budget" in r.json()["error"] and "\n" not in r.json()["error"]  # cut by the watchdog
    ok = "def reward_function(params):\n    return float(params['progress'])\n"
    r = console.client.post("/api/reward/check", json={"reward": ok, "samples": 2}, timeout=300)
    assert r.status_code == 200 and r.json()["map"].startswith("data:image/png"), r.text  # the console still works


def test_an_endless_loop_at_import_is_stopped_at_the_deadline(console, monkeypatch):
    from racerlab.console import runs

    monkeypatch.setattr(runs, "REWARD_CHECK_S", 4.0)
    reward = "while True:\n    pass\n\ndef reward_function(params):\n    return 1.0\n"
    r = console.client.post("/api/reward/check", json={"reward": reward}, timeout=300)
    assert r.status_code == 400 and "no answer within 4 s" in r.json()["error"], r.text


# ---- 12, 13: bad values are one line, never a 500 or a silent default -------------------------------------------
@pytest.mark.parametrize("method, url, body, field", [
    ("post", "/api/lines", {"track": "lab_oval", "margin": "wide"}, "margin"),
    ("post", "/api/lines", {"track": "lab_oval", "margin": "1e400"}, "margin"),
    ("post", "/api/reward/check", {"reward": "def reward_function(p):\n    return 1.0\n", "samples": "x"}, "samples"),
    ("post", "/api/models", {"name": "a", "max_speed": "fast"}, "max_speed"),
    ("post", "/api/models", {"name": "a", "cars": "many"}, "cars"),
    ("post", "/api/models", {"name": "a", "cars": -3}, "cars"),
    ("post", "/api/models", {"name": "a", "cars": "1e400"}, "cars"),
    ("post", "/api/models", {"name": None}, "model name None"),
    ("post", "/api/models", {"name": "a\n"}, "model name 'a\\n'"),
    ("post", "/api/models/m/train", {"minutes": "inf"}, "minutes"),
    ("post", "/api/models/m/train", {"episodes": "1e400"}, "episodes"),
    ("post", "/api/models/m/evaluate", {"trials": "1e400"}, "trials"),
    ("post", "/api/models/m/evaluate", {"continuous": "maybe"}, "continuous"),
    ("post", "/api/races", {"models": ["m"] * 1000}, "at most"),
])
def test_bad_values_are_one_line_naming_the_field(console, method, url, body, field):
    c = console.client
    if "/m/" in url:
        assert c.post("/api/models", json={"name": "m", "track": "lab_oval", "cars": 4}).status_code == 200
    r = getattr(c, method)(url, json=body)
    assert r.status_code == 400, r.text
    assert field in r.json()["error"] and "\n" not in r.json()["error"]
    assert not (console.app.state.workspace.root / "a").exists()
    assert not (console.app.state.workspace.root / "None").exists()


@pytest.mark.parametrize("body, error", [
    ({"iterations": 2.5}, "iterations must be a finite whole number > 0, got 2.5"),
    ({"episodes": "3.7"}, "episodes must be a finite whole number > 0, got '3.7'"),
    ({"minutes": 0}, "minutes must be a finite number > 0, got 0"),
    ({"iterations": True}, "iterations must be a finite whole number > 0, got True"),
])
def test_training_limits_are_refused_not_rounded(console, body, error):
    """One home for the console's numbers (`security.number`): a training's limits were truncated (2.5 iterations
    trained 2) while every other field refused a fraction."""
    c = console.client
    assert c.post("/api/models", json={"name": "m", "track": "lab_oval", "cars": 4}).status_code == 200
    r = c.post("/api/models/m/train", json=body)
    assert r.status_code == 400 and r.json()["error"] == error
    assert c.get("/api/models/m").json()["state"] == "idle"


def test_numbers_keep_their_kind_and_range():
    from racerlab.console.security import ConsoleError, number

    assert number({"n": "3"}, "n", integer=True, above=0) == 3 and type(number({"n": 3.0}, "n", integer=True)) is int
    assert number({"m": "0.25"}, "m", above=0) == 0.25 and number({}, "m", 7, above=0) == 7
    assert number({"x": 1}, "x", low=1, high=1) == 1
    for body, limits in [({"n": 0}, {"above": 0}), ({"n": -1e-9}, {"low": 0}), ({"n": "nan"}, {}),
                         ({"n": 2}, {"high": 1})]:
        with pytest.raises(ConsoleError):
            number(body, "n", **limits)


def test_race_rules_read_yes_and_no_as_written():
    from racerlab.console.runs import _rules

    assert _rules({"continuous": "false", "reverse": "true"}).continuous is False
    assert _rules({"continuous": "false", "reverse": "true"}).reverse is True
    assert _rules({}).continuous is True


# ---- 13: a running race can be cancelled -------------------------------------------------------------------------
def test_a_running_race_of_32_copies_is_cancelled_at_the_next_lap_end(console):
    from racerlab.logs import evaluation_dirs
    from racerlab.model import ModelFolder
    from tests.evaluate.models import write_checkpoint

    c = console.client
    w = console.app.state.workspace
    assert c.post("/api/models", json={"name": "m", "track": "lab_oval", "cars": 4}).status_code == 200
    write_checkpoint(ModelFolder(w.root / "m"))
    r = c.post("/api/races", json={"models": ["m"] * 32, "trials": 100, "track": "lab_oval"})
    assert r.status_code == 200 and r.json()["cancellable"], r.text  # 32 x 100 trials: ~1.5 minutes of racing here
    time.sleep(2.0)
    t0 = time.monotonic()
    r = c.post("/api/tasks/race/cancel")
    assert r.status_code == 200 and r.json()["cancelling"], r.text
    while c.get("/api/tasks/race").json()["status"] == "running":
        assert time.monotonic() - t0 < 10, "the race still runs after its cancel"
        time.sleep(0.1)
    task = c.get("/api/tasks/race").json()
    assert task["status"] == "cancelled" and not task["cancellable"]
    done = int(task["message"].split(" after ")[1].split(" of ")[0])
    assert task["message"].startswith(f"race cancelled after {done} of 32 models") and done < 32
    assert task["message"].endswith("no leaderboard was written" if done else "nothing was written")
    assert len(evaluation_dirs(w.root / "m")) == done  # whole evaluations only: the one on the track wrote nothing
    assert c.get("/api/races").json()["races"] == []
    r = c.post("/api/tasks/race/cancel")
    assert r.status_code == 409 and "not running (cancelled)" in r.json()["error"]
    assert c.post("/api/tasks/nothing/cancel").status_code == 404


def test_a_head_to_model_race_is_cancelled_at_the_next_lap_end(console):
    from racerlab.logs import evaluation_dirs
    from racerlab.model import ModelFolder
    from tests.evaluate.models import write_checkpoint

    c = console.client
    w = console.app.state.workspace
    for name in ("a", "b"):
        assert c.post("/api/models", json={"name": name, "track": "lab_oval", "cars": 4}).status_code == 200
        write_checkpoint(ModelFolder(w.root / name))
    r = c.post("/api/races", json={"models": ["a", "b", "a"], "head_to_model": True, "track": "lab_oval"})
    assert r.status_code == 400 and r.json()["error"] == "models: 3 entries; a head-to-model race takes two"
    r = c.post("/api/races", json={"models": ["a", "b"], "head_to_model": True, "trials": 100, "track": "lab_oval"})
    assert r.status_code == 200 and r.json()["cancellable"], r.text
    time.sleep(0.2)  # racing (100 trials of two untrained cars take ~2.5 s here, 50 took 1.2 s)
    t0 = time.monotonic()
    cancelled = c.post("/api/tasks/race/cancel")
    assert cancelled.status_code == 200 and cancelled.json()["cancelling"], (cancelled.text,
                                                                             c.get("/api/tasks/race").json())
    while c.get("/api/tasks/race").json()["status"] == "running":
        assert time.monotonic() - t0 < 10, "the head-to-model race still runs after its cancel"
        time.sleep(0.1)
    task = c.get("/api/tasks/race").json()
    assert task["status"] == "cancelled"
    assert task["message"] == "race cancelled after 0 of 2 models: nothing was written"
    assert evaluation_dirs(w.root / "a") == evaluation_dirs(w.root / "b") == []
    assert c.get("/api/races").json()["races"] == []


def test_a_task_that_cannot_stop_says_so(console):
    import threading

    gate = threading.Event()
    w = console.app.state.workspace
    w.run_task("report", "report:x", lambda: gate.wait(30) and {})
    try:
        r = console.client.post("/api/tasks/report:x/cancel")
        assert r.status_code == 409
        assert r.json()["error"] == "report:x: a report cannot be cancelled; wait for it to end"
    finally:
        gate.set()


# ---- 10: symbolic links -----------------------------------------------------------------------------------------
def test_a_linked_model_folder_or_file_is_neither_listed_nor_served(console, tmp_path):
    c = console.client
    root = console.app.state.workspace.root
    assert c.post("/api/models", json={"name": "real", "track": "lab_oval", "cars": 4}).status_code == 200
    outside = tmp_path / "elsewhere"
    shutil.copytree(root / "real", outside)
    (root / "linked").symlink_to(outside)
    secret = tmp_path / "secret.html"
    secret.write_text("<p>secret</p>")
    (root / "real" / "report.html").symlink_to(secret)
    r = c.get("/api/models")
    assert r.status_code == 200 and [m["name"] for m in r.json()["models"]] == ["real"]
    r = c.get("/api/models/real/report")
    assert r.status_code == 404 and "secret" not in r.text


def test_an_absurdly_nested_request_body_is_one_line(console):
    body = "[" * 100_000 + "]" * 100_000
    r = console.client.post("/api/models", content=body, headers={"Content-Type": "application/json"})
    assert r.status_code in (400, 422), r.text[:200]
    assert "Internal Server Error" not in r.text
