"""Races with objects from the command line and the API: the [race] flags of `evaluate` and `race`, crash
counts in the results, and head-to-model races."""

from __future__ import annotations

import json
import math

import pandas as pd
import pytest

import racerlab.cli as cli
from racerlab.track import load_file
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model


@pytest.fixture
def straight():
    return aws_track_path("Straight_track")


def model(tmp_path, track, name="m", actions=((0.0, 1.0),), sensor="lidar"):
    folder = write_model(tmp_path / name, track, actions, sensor)
    write_checkpoint(folder)
    return folder


def test_race_flags_of_evaluate_put_boxes_on_the_track(tmp_path, straight, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    folder = model(tmp_path, straight)  # one action: straight down the centre line at 1 m/s
    # a box in the inner lane half way: its footprint (0.4 m across, centred a quarter of the width off the
    # centre line) reaches the car's side, so the car crashes into it, restarts behind it in the other lane
    assert cli.main(["evaluate", str(folder.path), "--trials", "1", "--collision-penalty", "1",
                     "--race-type", "object_avoidance", "--object-positions", "0.5,1"]) == 0
    out = capsys.readouterr().out
    assert "1 crashes" in out
    run = sorted(folder.path.glob("evaluation-*"))[-1]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["result"]["crashes"] == 1 and summary["laps"][0]["crashed"] == 1
    metrics = json.loads((run / "EvalMetrics.json").read_text())["metrics"]
    assert [m["crash_count"] for m in metrics] == [1]
    trace = pd.read_csv(next((run / "evaluation-simtrace").glob("*.csv")))
    assert trace["obstacle_crash_counter"].max() == 1 and (trace["episode_status"] == "crashed").sum() == 1
    assert summary["race"]["type"] == "object_avoidance" and summary["race"]["object_positions"] == [[0.5, 1]]
    # the report finds the track and the race beside the log and draws the crash map with the box
    from racerlab.analysis.report import log_race, write_report

    html = write_report(run).read_text()
    assert 'id="objects"' in html and "1 steps judged crashed" in html
    assert "and the boxes; race: object_avoidance" in html
    race, _ = log_race(run)
    assert race.object_positions == ((0.5, 1),)


def test_race_layout_is_where_the_simulator_puts_the_objects():
    from racerlab.sim import Simulator
    from racerlab.sim.objects import race_layout
    from racerlab.spec import RaceConfig

    t = load_file(aws_track_path("reInvent2019_track"))
    for race in (RaceConfig(type="object_avoidance", number_of_obstacles=4),
                 RaceConfig(type="head_to_bot", number_of_bot_cars=3)):
        layout = race_layout(race, t)
        sim = Simulator(t, 1, race=race)
        assert layout["kind"] == ("bot" if race.num_bot_cars else "box")
        assert (layout["xy"] == sim.objects.xy[0]).all() and (layout["yaw"] == sim.objects.yaw[0]).all()
    assert race_layout(RaceConfig(type="object_avoidance", number_of_obstacles=4,
                                  randomize_obstacle_locations=True), t) is None  # re-drawn every episode
    assert race_layout(RaceConfig(), t) is None


@pytest.mark.parametrize(("flags", "key"), [
    (["--object-positions", "0.5,2"], "object_positions"),
    (["--number-of-obstacles", "-1"], "number_of_obstacles"),
    (["--race-type", "drag_race"], "type"),
    (["--lower-lane-change-time", "6", "--upper-lane-change-time", "5"], "lower_lane_change_time"),
])
def test_bad_race_flags_are_one_line_naming_the_key(tmp_path, straight, monkeypatch, capsys, flags, key):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    folder = model(tmp_path, straight)
    assert cli.main(["evaluate", str(folder.path), "--race-type", "object_avoidance", *flags]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and key in err[0]


def test_head_to_model_races_two_models_in_one_world(tmp_path, straight, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    slow = model(tmp_path, straight, "slow", actions=((0.0, 1.0),))
    fast = model(tmp_path, straight, "fast", actions=((0.0, 2.0),))
    assert cli.main(["race", str(slow.path), str(fast.path), "--head-to-model", "--trials", "1",
                     "--out", str(tmp_path / "board.json")]) == 0
    out = capsys.readouterr().out
    assert "head to model" in out
    board = json.loads((tmp_path / "board.json").read_text())["leaderboard"]
    assert [r["model"] for r in board] == ["fast", "slow"] and all(r["laps_completed"] == 1 for r in board)
    traces = {}
    for name in ("slow", "fast"):
        run = sorted((tmp_path / name).glob("evaluation-*"))[-1]
        traces[name] = pd.read_csv(next((run / "evaluation-simtrace").glob("*.csv")))
    s, f = traces["slow"], traces["fast"]
    # one world: the two cars start side by side on the start line (slow on the inner lane, fast on the outer)
    # and step together, so their simulated clocks agree row by row while both drive
    n = min(len(s), len(f))
    assert (s["tstamp"].to_numpy()[:n] == f["tstamp"].to_numpy()[:n]).all()
    t = load_file(straight)
    apart = math.hypot(s["X"].iloc[0] - f["X"].iloc[0], s["Y"].iloc[0] - f["Y"].iloc[0])
    assert apart == pytest.approx(0.5 * math.hypot(*(t.inner[0] - t.outer[0])), abs=0.01)  # lane to lane
    lap_time = {k: float(v) for k, v in ((r["model"], r["best_lap"]) for r in board)}
    assert lap_time["fast"] < 0.6 * lap_time["slow"]


def test_head_to_model_needs_two_models(tmp_path, straight, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    paths = [str(model(tmp_path, straight, n).path) for n in ("a", "b", "c")]
    assert cli.main(["race", *paths, "--head-to-model"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "two models" in err[0]
