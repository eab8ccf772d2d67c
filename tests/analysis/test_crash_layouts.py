"""The crash map of an evaluation with random box layouts: `racerlab evaluate` keeps each episode's layout in
layouts.json, and `racerlab report` draws every episode's crashes with the boxes that episode had."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import racerlab.cli as cli
import racerlab.evaluate.api as api
from racerlab.analysis.report import log_layouts, write_report
from racerlab.sim.objects import BOX_FOOTPRINT_M, CAR_FOOTPRINT_M
from racerlab.sim.pursuit import PurePursuit
from racerlab.spec import MODEL_POINT_AHEAD_M
from racerlab.track import load_file
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model

CONTINUOUS = {"steering_angle": {"low": -30, "high": 30}, "speed": {"low": 0.5, "high": 4.0}}


def _centre_line_driver(model, world, device="cpu"):
    """Drives the centre line at 1.5 m/s whatever the weights: it runs into the boxes standing across it."""
    pp = PurePursuit.on_centre_line(world.sim.track, speed=1.5)

    def policy(obs):
        steer, v = pp(world.sim)
        return np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1)

    return policy


@pytest.fixture
def random_boxes_run(tmp_path, monkeypatch):
    monkeypatch.setattr(api, "make_policy", _centre_line_driver)
    track = aws_track_path("reInvent2019_track")
    folder = write_model(tmp_path / "m", track, CONTINUOUS, "lidar")
    write_checkpoint(folder)
    assert cli.main(["evaluate", str(folder.path), "--trials", "3", "--no-continuous", "--max-resets", "6",
                     "--collision-penalty", "1", "--race-type", "object_avoidance", "--number-of-obstacles", "4",
                     "--randomize-obstacle-locations"]) == 0
    return sorted(folder.path.glob("evaluation-*"))[-1], load_file(track)


def test_each_episode_keeps_its_own_layout_and_its_crashes_are_at_its_boxes(random_boxes_run):
    import pandas as pd

    run, track = random_boxes_run
    rec = json.loads((run / "layouts.json").read_text())
    assert rec["kind"] == "box" and rec["size"] == [0.4, 0.3]
    assert [lay["episodes"] for lay in rec["layouts"]] == [[0], [1], [2]]  # three trials, a reset each
    layouts = log_layouts(run)
    assert not np.array_equal(layouts[0]["xy"], layouts[1]["xy"])  # random: re-drawn at every reset
    width = float(np.median(np.hypot(*(track.inner - track.outer).T)))
    for lay in layouts:  # every box stands on a lane line, a quarter of the road off the centre line
        off = track.project(lay["xy"]).lateral
        np.testing.assert_allclose(np.abs(off), width / 4, atol=0.03)
    trace = pd.read_csv(next((run / "evaluation-simtrace").glob("*.csv")))
    crashed = trace[trace["episode_status"] == "crashed"]
    assert len(crashed) >= 3
    # a crash needs a car corner inside a box: the model point is at most (car half diagonal + the model point's
    # 0.14 m + the footprint's half diagonal) from a box of the layout of its own episode
    reach = math.hypot(*np.multiply(CAR_FOOTPRINT_M, 0.5)) + MODEL_POINT_AHEAD_M + math.hypot(
        *np.multiply(BOX_FOOTPRINT_M, 0.5))
    for _, row in crashed.iterrows():
        own = layouts[int(row["episode"])]["xy"]
        assert np.hypot(own[:, 0] - row["X"], own[:, 1] - row["Y"]).min() <= reach


def test_report_draws_one_crash_map_per_episode_layout(random_boxes_run):
    run, _ = random_boxes_run
    html = write_report(run).read_text()
    objects = html[html.index('id="objects"'):]
    assert "of the episodes it happened in (layouts.json)" in objects
    assert "random layout, re-drawn every episode" not in objects
    assert objects.index("data:image/png;base64,") < objects.index("Episodes with the most crashes")


def test_a_fixed_layout_is_written_once_per_episode_and_drawn_as_one_map(tmp_path, monkeypatch):
    monkeypatch.setattr(api, "make_policy", _centre_line_driver)
    folder = write_model(tmp_path / "m", aws_track_path("reInvent2019_track"), CONTINUOUS, "lidar")
    write_checkpoint(folder)
    assert cli.main(["evaluate", str(folder.path), "--trials", "2", "--max-resets", "3", "--collision-penalty", "1",
                     "--race-type", "object_avoidance", "--object-positions", "0.5,1"]) == 0
    run = sorted(folder.path.glob("evaluation-*"))[-1]
    layouts = log_layouts(run)
    assert len(layouts) == 1 and layouts[0]["episodes"][0] == 0  # continuous laps: one sim episode
    html = write_report(run).read_text()
    assert "and the boxes; race: object_avoidance" in html
