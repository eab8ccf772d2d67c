"""The console tells the truth (issue 27): the models it lists are the models there are, the best lap it shows
is the best eval lap with its iteration, a report that exists is found, the live view shows only what the model
sees, and the browser's favicon request is answered."""

from __future__ import annotations

import json
import shutil

from tests.console.conftest import sse_events, wait_task


def _names(client) -> list[str]:
    return [m["name"] for m in client.get("/api/models").json()["models"]]


def test_a_racing_line_folder_is_not_a_model_and_the_quickstart_model_is(console):
    from racerlab.model import init_model

    root = console.app.state.workspace.root
    lines = root / "lines"  # what `racerlab line lab_oval --out lines/` leaves: a fitted action space, no model
    lines.mkdir()
    (lines / "model_metadata.json").write_text(json.dumps({"action_space": [{"steering_angle": 0, "speed": 1}],
                                                           "sensor": ["FRONT_FACING_CAMERA"]}))
    (lines / "lab_oval_mincurv.py").write_text("racing_line = []\n")
    init_model(root / "racerlab-out" / "quickstart-model", track="lab_oval")  # `racerlab quickstart` run here
    init_model(root / "mine", track="lab_oval")
    assert _names(console.client) == ["mine", "quickstart-model"]
    qs = console.client.get("/api/models/quickstart-model").json()
    assert qs["folder"] == "racerlab-out/quickstart-model" and qs["track"] == ["lab_oval"]
    assert "reward_function.py" in qs["files"] and qs["files"]["reward_function.py"]
    assert console.client.get("/api/models/lines").status_code == 404


def test_the_header_s_best_lap_is_the_best_eval_lap_with_its_iteration(console):
    from racerlab.logs import best_eval_lap
    from racerlab.model import init_model

    folder = init_model(console.app.state.workspace.root / "m", track="lab_oval")
    rows = [{"iteration": 1, "eval/best_lap": None, "best/lap_time": None, "best/lap_iteration": None,
             "best/checkpoint": "1_Step-100.pt"},
            {"iteration": 2, "eval/best_lap": 8.333, "best/lap_time": 8.333, "best/lap_iteration": 2,
             "best/checkpoint": "2_Step-200.pt"},
            {"iteration": 3, "eval/best_lap": 9.2, "best/lap_time": 8.333, "best/lap_iteration": 2,
             "best/checkpoint": "3_Step-300.pt"}]
    (folder.path / "metrics").mkdir()
    (folder.path / "metrics" / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    m = console.client.get("/api/models/m").json()
    assert (m["best_lap"], m["best_lap_iteration"]) == best_eval_lap(rows) == (8.333, 2)
    assert m["iteration"] == 3 and m["best_checkpoint"] == "3_Step-300.pt"
    assert m["best_rule"].startswith("the highest mean evaluation progress")
    # the live chart points carry what the header needs to follow the training
    events = sse_events(console.client, "/api/models/m/events", lambda ev: len(ev) >= 1, 30)
    last = events[0][1]["points"][-1]
    assert last["best/lap_iteration"] == 2 and last["best/checkpoint"] == "3_Step-300.pt"


def test_an_existing_report_is_found_with_head(trained):
    c = trained.client
    report = trained.app.state.workspace.root / "m1" / "report.html"
    report.unlink(missing_ok=True)
    assert c.head("/api/models/m1/report").status_code == 404
    wait_task(c, c.post("/api/models/m1/report").json()["key"])
    head = c.head("/api/models/m1/report")
    assert head.status_code == 200 and head.headers["content-type"].startswith("text/html")
    assert head.content == b""


def test_the_favicon_is_answered(console):
    r = console.client.get("/favicon.ico")
    assert r.status_code == 200 and r.headers["content-type"].startswith("image/svg+xml")
    assert r.content.startswith(b"<svg")


def test_the_live_view_shows_only_what_the_model_sees(trained):
    root = trained.app.state.workspace.root
    features = sse_events(trained.client, "/api/models/m1/live?car=1",
                          lambda ev: sum("car" in d for _, d in ev) >= 2, 120)
    views = [d for e, d in features if e == "view"]
    assert all(v["sees"] == [] for v in views)  # m1 sees a features vector
    assert not any("camera" in v or "lidar" in v for v in views)
    cam = root / "m1-camera"  # the same logs, as a camera + lidar model would have them
    shutil.copytree(root / "m1", cam, ignore=shutil.ignore_patterns("evaluation-*", "report.html"))
    meta = json.loads((cam / "model_metadata.json").read_text())
    (cam / "model_metadata.json").write_text(json.dumps({**meta, "sensor": ["FRONT_FACING_CAMERA", "LIDAR"]}))
    try:
        events = sse_events(trained.client, "/api/models/m1-camera/live?car=1",
                            lambda ev: any("camera" in d for _, d in ev), 120)
        view = next(d for _, d in events if "camera" in d)
        assert view["sees"] == ["camera", "lidar"] and view["camera"].startswith("data:image/png;base64,")
        assert len(view["lidar"]) == 64 == len(view["angles"])
    finally:
        shutil.rmtree(cam)
