"""The console refuses to delete a model that a running race uses (the race would re-create its folder: a ghost the
console neither lists nor lets you create or delete), and deletes it once the race is over."""

from __future__ import annotations

import threading

import pytest

from racerlab.console.security import ConsoleError
from tests.console.conftest import wait_task


def test_a_model_in_a_running_race_is_not_deleted(trained):
    c, w = trained.client, trained.app.state.workspace
    assert c.post("/api/models/m1/clone", json={"name": "m1-racer"}).status_code == 200
    r = c.post("/api/races", json={"models": ["m1-racer"], "trials": 3, "track": "lab_oval"})
    assert r.status_code == 200, r.text
    gone = c.delete("/api/models/m1-racer?confirm=m1-racer")
    assert gone.status_code == 409 and "a running race uses it" in gone.text
    assert c.get("/api/models/m1-racer").json()["state"] == "racing"
    wait_task(c, "race")
    assert (w.root / "m1-racer" / "model_metadata.json").is_file()  # whole, not a ghost re-created by the race
    assert c.delete("/api/models/m1-racer?confirm=m1-racer").status_code == 200
    assert not (w.root / "m1-racer").exists()
    assert "m1-racer" not in [m["name"] for m in c.get("/api/models").json()["models"]]


def test_a_task_for_a_deleted_model_does_not_start(trained):
    w = trained.app.state.workspace
    ran = threading.Event()
    r = trained.client.post("/api/models/m1/clone", json={"name": "m1-gone"})
    assert r.status_code == 200
    w.delete("m1-gone")
    with pytest.raises(ConsoleError, match="m1-gone: no such model") as err:
        w.run_task("race", "race-gone", ran.set, models=["m1-gone"])
    assert err.value.status == 404
    assert not ran.is_set() and not (w.root / "m1-gone").exists()
