"""Model exchange from the console: exports run in the background and are downloaded by name, a car
archive imports back into a new model, a features model's car export is refused in one line, and a
malicious upload is refused before anything is written."""

from __future__ import annotations

import io
import json
import tarfile
import time

import torch

from racerlab.exchange.local import open_for_export
from tests.console.conftest import wait_task
from tests.exchange.conftest import make_model


def _finished(client, key: str, timeout: float = 300) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        t = client.get(f"/api/tasks/{key}").json()
        if t["status"] != "running":
            return t
        time.sleep(0.3)
    raise AssertionError(f"task {key} still running after {timeout} s")


def test_car_export_downloads_and_imports_back_as_a_new_model(console, tmp_path):
    c = console.client
    root = console.app.state.workspace.root
    make_model(root / "cam", "camera")
    assert c.post("/api/models/cam/export/car").json()["status"] == "running"
    done = wait_task(c, "export:cam:car")
    assert done["result"]["archive"] == "cam-car.tar.gz"
    assert [e["name"] for e in c.get("/api/models/cam/exports").json()["exports"]] == ["cam-car.tar.gz"]
    got = c.get("/api/models/cam/exports/cam-car.tar.gz")
    assert got.status_code == 200 and got.headers["content-disposition"].endswith('"cam-car.tar.gz"')
    with tarfile.open(fileobj=io.BytesIO(got.content)) as tar:
        assert sorted(tar.getnames()) == ["agent/model.pb", "model_metadata.json"]
        meta = json.loads(tar.extractfile("model_metadata.json").read())
    assert meta == json.loads((root / "cam" / "model_metadata.json").read_text())

    r = c.post("/api/imports", data={"name": "back"}, files={"file": ("cam-car.tar.gz", got.content, "x")})
    assert r.status_code == 200, r.text
    assert wait_task(c, "import:back")["result"]["model"] == "back"
    assert [m["name"] for m in c.get("/api/models").json()["models"]] == ["back", "cam"]
    back = c.get("/api/models/back").json()
    assert back["sensor"] == ["FRONT_FACING_CAMERA"] and back["checkpoints"]
    assert json.loads((root / "back" / "model_metadata.json").read_text())["action_space"] == meta["action_space"]
    cam, back = (open_for_export(root / name)[1] for name in ("cam", "back"))
    mine, theirs = cam.networks["policy"], back.networks["policy"]
    obs = {k: torch.rand(5, *s) * 255 for k, s in cam.shapes.items()}
    with torch.no_grad():  # the policy survives the trip through the car's frozen graph
        torch.testing.assert_close(theirs(obs), mine(obs), rtol=1e-4, atol=1e-5)
    # the same name again is refused before the upload is stored
    again = c.post("/api/imports", data={"name": "back"}, files={"file": ("x.tar.gz", got.content, "application/gzip")})
    assert again.status_code == 409


def test_droa_and_drfc_exports_hold_the_coach_tree(console):
    c = console.client
    make_model(console.app.state.workspace.root / "f", "camera", "continuous")
    for kind in ("droa", "drfc"):
        c.post(f"/api/models/f/export/{kind}")
        wait_task(c, f"export:f:{kind}")
        body = c.get(f"/api/models/f/exports/f-{kind}.tar.gz").content
        with tarfile.open(fileobj=io.BytesIO(body)) as tar:
            names = {n.removeprefix("./") for n in tar.getnames()}
        assert {"model_metadata.json", "reward_function.py", "model/.coach_checkpoint",
                "ip/hyperparameters.json"} <= names, (kind, names)


def test_features_model_car_export_is_refused_in_one_line(trained):
    c = trained.client  # m1: a features model trained for 2 iterations
    c.post("/api/models/m1/export/car")
    t = _finished(c, "export:m1:car")
    assert t["status"] == "failed"
    assert "\n" not in t["message"] and "FEATURES" in t["message"] and "--sensor camera" in t["message"]
    assert c.get("/api/models/m1/exports").json()["exports"] == []
    assert c.get("/api/models/m1/exports/m1-car.tar.gz").status_code == 404
    assert c.get("/api/models/m1/exports/..%2F..%2Fm1%2Fmodel_metadata.json").status_code == 404


def test_malicious_import_is_refused_with_nothing_written(console):
    c = console.client
    root = console.app.state.workspace.root
    before = [p for p in root.rglob("*") if p.is_file()]
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        data = b"{}"
        info = tarfile.TarInfo("../../escaped.json")
        info.size = len(data)
        tar.addfile(info, io.BytesIO(data))
        link = tarfile.TarInfo("model_metadata.json")
        link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
        tar.addfile(link)
    r = c.post("/api/imports", data={"name": "evil"}, files={"file": ("evil.tar.gz", buf.getvalue(), "x")})
    assert r.status_code == 400 and "outside the archive" in r.json()["error"]
    for bad_name in ("../evil", ".hidden", "a/b"):
        r = c.post("/api/imports", data={"name": bad_name}, files={"file": ("m.tar.gz", b"x", "application/gzip")})
        assert r.status_code in (400, 404), (bad_name, r.text)
    no_csrf = c.post("/api/imports", data={"name": "x"}, files={"file": ("m.tar.gz", b"x", "application/gzip")},
                     headers={"X-CSRF-Token": ""})
    assert no_csrf.status_code == 403
    assert [p for p in root.rglob("*") if p.is_file()] == before == []  # not even the upload is kept
    assert not (root.parent / "escaped.json").exists() and c.get("/api/models").json()["models"] == []
