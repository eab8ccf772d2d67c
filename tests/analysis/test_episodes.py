"""Aggregations on a tiny hand-made simtrace whose every number is worked out by hand below."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest

from racerlab.analysis import load
from racerlab.analysis.episodes import episode_summary, iteration_summary, step_kinematics

HEADER = ("episode,steps,X,Y,yaw,steer,throttle,action,reward,done,all_wheels_on_track,progress,closest_waypoint,"
          "track_len,tstamp,episode_status,pause_duration")

# iteration 0, episode 0: a lap of three moving steps along +x, heading along the motion (no slide)
IT0 = """0,1,0.0,0.0,0.0,0.00,0.00,3,0.0000,False,True,0.5000,7,10.00,0.067,prepare,0.00
0,2,0.0,0.0,0.0,0.00,1.00,5,1.0000,False,True,0.5000,7,10.00,0.133,in_progress,0.00
0,3,0.1,0.0,0.0,15.00,1.00,7,2.0000,False,True,50.0000,8,10.00,0.200,in_progress,0.00
0,4,0.2,0.0,0.0,-15.00,2.00,2,3.0000,True,True,100.0000,9,10.00,0.267,lap_complete,0.00
"""
# iteration 1: episode 1 slides (heading 0 deg while moving at 45 deg) and leaves the track; episode 2 is a lap
IT1 = """1,1,1.0,1.0,0.0,0.00,0.00,3,0.0000,False,True,0.5000,20,10.00,5.000,prepare,0.00
1,2,1.0,1.0,0.0,0.00,1.00,5,0.5000,False,True,0.5000,20,10.00,5.067,in_progress,0.00
1,3,1.1,1.1,0.0,30.00,1.00,9,0.2500,True,False,2.5000,21,10.00,5.133,off_track,0.00
2,1,3.0,0.0,90.0,0.00,0.00,3,0.0000,False,True,0.5000,40,10.00,9.067,prepare,0.00
2,2,3.0,0.0,90.0,0.00,2.00,4,1.0000,False,True,0.5000,40,10.00,9.133,in_progress,0.00
2,3,3.0,0.2,90.0,0.00,2.00,4,1.2500,True,True,100.0000,41,10.00,9.200,lap_complete,0.00
"""


@pytest.fixture
def frame(tmp_path):
    folder = tmp_path / "model" / "training-simtrace"
    folder.mkdir(parents=True)
    (folder / "0-iteration.csv").write_text(HEADER + "\n" + IT0)
    (folder / "1-iteration.csv").write_text(HEADER + "\n" + IT1)
    return load(tmp_path / "model", cache=False)


def test_step_kinematics_by_hand(frame):
    k = step_kinematics(frame)
    # first row of each episode has no previous row
    assert k.loc[[0, 4, 7]].isna().all().all()
    # the prepare step holds the car: distance 0, speed 0, no direction of travel
    assert k.loc[1, "step_distance"] == 0 and k.loc[1, "true_speed"] == 0 and math.isnan(k.loc[1, "bearing"])
    # 0.1 m in 0.067 s along +x, heading 0: no slide
    assert k.loc[2, "step_distance"] == pytest.approx(0.1)
    assert k.loc[2, "true_speed"] == pytest.approx(0.1 / 0.067)
    assert k.loc[2, "bearing"] == pytest.approx(0.0) and k.loc[2, "slide"] == pytest.approx(0.0)
    # moving at 45 deg with the heading at 0 deg: slide = heading - bearing = -45
    assert k.loc[6, "bearing"] == pytest.approx(45.0) and k.loc[6, "slide"] == pytest.approx(-45.0)
    assert k.loc[6, "true_speed"] == pytest.approx(math.hypot(0.1, 0.1) / 0.066)
    # straight up at heading 90
    assert k.loc[9, "bearing"] == pytest.approx(90.0) and k.loc[9, "slide"] == pytest.approx(0.0)


def test_episode_summary_by_hand(frame):
    e = episode_summary(frame)
    assert e.index.tolist() == [0, 1, 2]
    assert e["outcome"].tolist() == ["lap_complete", "off_track", "lap_complete"]
    assert e["complete"].tolist() == [True, False, True]
    assert e["iteration"].tolist() == [0, 1, 1]
    assert e["start_waypoint"].tolist() == [7, 20, 40]
    assert e["steps"].tolist() == [4, 3, 3]
    assert e["reward"].tolist() == pytest.approx([6.0, 0.75, 2.25])
    assert e["progress"].tolist() == pytest.approx([100.0, 2.5, 100.0])
    # time: last tstamp - first + one step (median logged step 0.067 s): the prepare step is logged after it ran
    assert e["time"].tolist() == pytest.approx([0.2 + 0.067, 0.133 + 0.067, 0.133 + 0.067])
    assert e.loc[0, "lap_time"] == pytest.approx(0.267) and math.isnan(e.loc[1, "lap_time"])
    assert e.loc[1, "time_if_complete"] == pytest.approx(0.2 * 100 / 2.5)
    assert e.loc[1, "reward_if_complete"] == pytest.approx(0.75 * 40)
    assert e["distance"].tolist() == pytest.approx([0.2, math.hypot(0.1, 0.1), 0.2])
    assert e.loc[0, "true_speed"] == pytest.approx(0.2 / 0.267)
    assert e.loc[0, "max_true_speed"] == pytest.approx(0.1 / 0.067)
    assert e.loc[0, "speed"] == pytest.approx((0 + 1 + 1 + 2) / 4)  # mean commanded, prepare row included
    assert e.loc[1, "mean_abs_slide"] == pytest.approx(45.0) and e.loc[1, "max_abs_slide"] == pytest.approx(45.0)
    assert e["off_track"].tolist() == [0, 1, 0]


def test_iteration_summary_with_metrics_by_hand(frame):
    e = episode_summary(frame)
    tm = pd.DataFrame({
        "iteration": [0, 0, 1, 1, 1],
        "phase": ["training", "evaluation", "training", "training", "evaluation"],
        "completion_percentage": [100, 40, 2, 100, 100],
        "episode_status": ["Lap complete", "Off track", "Off track", "Lap complete", "Lap complete"],
        "elapsed_time_in_milliseconds": [267, 1000, 200, 200, 9500],
    })
    jsonl = [{"iteration": 1, "losses/entropy": 2.0, "losses/approx_kl": 0.02},
             {"iteration": 2, "losses/entropy": 1.5, "losses/approx_kl": 0.01}]
    it = iteration_summary(e, tm, jsonl)
    assert it.index.tolist() == [0, 1]
    assert it["episodes"].tolist() == [1, 2]
    assert it["reward_mean"].tolist() == pytest.approx([6.0, 1.5])
    assert it["reward_std"].tolist() == pytest.approx([0.0, 0.75])  # population std of 0.75 and 2.25
    assert it["completion_rate"].tolist() == pytest.approx([1.0, 0.5])
    assert it["lap_time_min"].tolist() == pytest.approx([0.267, 0.2])
    assert it["train_completion"].tolist() == pytest.approx([100.0, 51.0])
    assert it["eval_completion"].tolist() == pytest.approx([40.0, 100.0])
    assert it["eval_lap_rate"].tolist() == pytest.approx([0.0, 1.0])
    assert np.isnan(it.loc[0, "eval_lap_time_min"]) and it.loc[1, "eval_lap_time_min"] == pytest.approx(9.5)
    # metrics.jsonl iteration 1 is the iteration that wrote 0-iteration.csv
    assert it["entropy"].tolist() == [2.0, 1.5] and it["approx_kl"].tolist() == [0.02, 0.01]


def test_iteration_summary_without_metrics(frame):
    it = iteration_summary(episode_summary(frame))
    assert "entropy" not in it and "eval_completion" not in it
    assert it["laps"].tolist() == [1, 1]
