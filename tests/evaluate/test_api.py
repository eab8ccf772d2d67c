"""`evaluate` and `race` on model folders: files written, numbers that agree with the simtrace, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest

import racerlab.cli as cli
from racerlab.errors import RacerlabError
from racerlab.evaluate import evaluate, race
from racerlab.logs import EVAL_METRICS_KEYS, SIMTRACE_COLUMNS
from racerlab.sim.observations import OBSERVATIONS
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model

DT = 1.0 / 15.0


@pytest.fixture
def straight():
    return aws_track_path("Straight_track")


@pytest.fixture
def wide():
    return aws_track_path("reInvent2019_wide")


def model(tmp_path, track, name="m", actions=((0.0, 1.0),), sensor="features", algorithm="clipped_ppo"):
    folder = write_model(tmp_path / name, track, actions, sensor, algorithm)
    write_checkpoint(folder)
    return folder


def test_straight_track_laps_and_files(tmp_path, straight):
    # one action, straight ahead: whatever the weights, the car drives the open track to its end
    folder = model(tmp_path, straight)
    res = evaluate(folder.path, trials=2)
    assert res.text.startswith("2 laps, average") and res.result.best_lap == pytest.approx(res.laps[0].time)
    out = res.out_dir
    assert out.parent == folder.path and out.name.startswith("evaluation-")
    trace = pd.read_csv(out / "evaluation-simtrace" / "0-iteration.csv")
    assert tuple(trace.columns) == SIMTRACE_COLUMNS and len(trace) == res.steps
    metrics = json.loads((out / "EvalMetrics.json").read_text())["metrics"]
    assert [tuple(m) for m in metrics] == [EVAL_METRICS_KEYS] * 2
    summary = json.loads((out / "summary.json").read_text())
    assert summary["result"]["text"] == res.text and summary["checkpoint"] == "1_Step-100.pt"
    # an open track: every trial is an episode from the line, its time counts every row
    for k, (m, lap) in enumerate(zip(metrics, summary["laps"], strict=True)):
        rows = trace[trace.episode == k]
        assert rows.episode_status.iloc[0] == "prepare" and rows.episode_status.iloc[-1] == "lap_complete"
        assert m["elapsed_time_in_milliseconds"] == round(len(rows) * DT * 1000) == round(lap["elapsed"] * 1000)
        assert m["trial"] == k + 1 and m["completion_percentage"] == 100


def test_summary_agrees_with_the_simtrace_after_off_tracks(tmp_path, wide):
    folder = model(tmp_path, wide)  # straight ahead on a loop: off the road at each corner
    res = evaluate(folder.path, trials=2, off_track_penalty=1.0, max_resets=4)
    trace = pd.read_csv(res.files["simtrace"])
    metrics = json.loads(res.files["eval_metrics"].read_text())["metrics"]
    assert len(metrics) == 1 and res.text == "no lap completed"  # continuous: resets ran out in lap 1
    m = metrics[0]
    offs = int((trace.episode_status == "off_track").sum())
    assert m["off_track_count"] == offs == 5 and m["reset_count"] == 5 and m["episode_status"] == "Off track"
    assert (trace.episode_status == "pause").sum() == 4 * 15
    assert m["elapsed_time_in_milliseconds"] == round(len(trace) * DT * 1000)
    assert m["completion_percentage"] == int(trace.progress.iloc[-1])
    assert trace.done.sum() == 1 and bool(trace.done.iloc[-1])
    summary = json.loads(res.files["summary"].read_text())
    assert summary["result"]["off_track"] == offs and summary["steps"] == len(trace)


def test_missing_checkpoint_is_one_line(tmp_path, wide):
    folder = write_model(tmp_path / "m", wide)
    with pytest.raises(RacerlabError, match="no checkpoints yet") as err:
        evaluate(folder.path)
    assert "\n" not in str(err.value)


def test_checkpoint_of_another_action_space_is_one_line(tmp_path, wide):
    folder = write_model(tmp_path / "m", wide, actions=((0.0, 1.0), (10.0, 1.0)))
    write_checkpoint(folder)
    meta = json.loads(folder.metadata_path.read_text())
    meta["action_space"] = meta["action_space"][:1]
    folder.metadata_path.write_text(json.dumps(meta))
    with pytest.raises(RacerlabError, match="does not match .*number of actions 2 → 1") as err:
        evaluate(folder.path)
    assert "\n" not in str(err.value)


def test_weights_that_do_not_fit_are_one_line(tmp_path, wide):
    folder = write_model(tmp_path / "m", wide)
    info = write_checkpoint(folder)
    import torch

    path = folder.checkpoints_dir / info.name
    state = torch.load(path, weights_only=False)
    first = next(iter(state["agent"]["policy"]))
    state["agent"]["policy"][first] = torch.zeros(3, 3)
    torch.save(state, path)
    with pytest.raises(RacerlabError, match="weights do not fit") as err:
        evaluate(folder.path)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("algorithm", ["clipped_ppo", "sac"])
def test_continuous_actions_are_logged_as_commanded_values(tmp_path, straight, algorithm):
    narrow = {"steering_angle": {"low": -1.0, "high": 1.0}, "speed": {"low": 0.8, "high": 1.2}}
    folder = model(tmp_path, straight, actions=narrow, algorithm=algorithm)
    res = evaluate(folder.path, trials=1)
    assert res.laps[0].completed
    trace = pd.read_csv(res.files["simtrace"])
    steer, speed = np.array([a.strip("[]").split(" ") for a in trace.action], dtype=float).T
    run = trace.episode_status == "in_progress"
    assert np.allclose(steer[run], trace.steer[run], atol=0.006)
    assert np.allclose(speed[run], trace.throttle[run], atol=0.006)
    assert np.all((speed[run] >= 0.8) & (speed[run] <= 1.2))


@pytest.mark.parametrize("sensor", ["features", "lidar", "camera", "stereo", "camera+lidar"])
def test_any_sensor_on_a_track_it_never_trained_on(tmp_path, straight, wide, sensor):
    for part in sensor.split("+"):
        if part not in OBSERVATIONS:
            pytest.skip(f"the {part} observation is not available yet")
    folder = model(tmp_path, wide, sensor=sensor)
    res = evaluate(folder.path, track=str(straight), trials=1, write=False)
    assert res.track == "Straight_track" and res.laps[0].completed


def test_race_ranks_the_faster_model_first(tmp_path, straight):
    slow = model(tmp_path, straight, "slow", actions=((0.0, 1.0),))
    fast = model(tmp_path, straight, "fast", actions=((0.0, 2.0),))
    board = race([slow.path, fast.path], out=tmp_path / "board.json")
    assert [e.model for e in board.entries] == ["fast", "slow"]
    data = json.loads((tmp_path / "board.json").read_text())
    assert [r["model"] for r in data["leaderboard"]] == ["fast", "slow"] and data["track"] == "Straight_track"
    assert data["leaderboard"][0]["ranking_average"] < data["leaderboard"][1]["ranking_average"]
    assert "fast" in board.table().splitlines()[1]


def test_cli_evaluate_and_its_errors(tmp_path, straight, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    folder = model(tmp_path, straight)
    assert cli.main(["evaluate", str(folder.path), "--trials", "2", "--no-continuous", "--off-track-penalty", "2"]) == 0
    out = capsys.readouterr().out
    assert "2 trials, separate laps, off-track penalty 2 s" in out and "result: 2 laps, average" in out
    assert "lap complete" in out and "EvalMetrics.json" in out
    empty = write_model(tmp_path / "empty", straight)
    assert cli.main(["evaluate", str(empty.path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no checkpoints yet" in err[0]


def test_video(tmp_path, straight):
    imageio = pytest.importorskip("imageio.v2")
    pytest.importorskip("imageio_ffmpeg")
    folder = model(tmp_path, straight)
    res = evaluate(folder.path, trials=1, video=True)
    frames = imageio.mimread(res.files["video"], memtest=False)
    assert len(frames) == res.steps and frames[0].shape[1] % 16 == 0 and frames[0].shape[2] == 3
    assert np.asarray(frames[-1]).std() > 10  # a picture, not a blank frame
    assert json.loads(res.files["summary"].read_text())["files"]["video"] == "evaluation.mp4"
