"""Race rules' settings, where a car is put back, and the race-result numbers, on hand-made inputs."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.errors import RacerlabError
from racerlab.evaluate.results import (
    Lap,
    best_consecutive_average,
    completed_streak,
    race_result,
    rank_key,
    result_text,
)
from racerlab.evaluate.rules import Lanes, RaceRules, pause_steps
from racerlab.logs import EVAL_METRICS_KEYS
from racerlab.track import from_array


def lap(trial, seconds, done=True, off=0):
    counts = {"off_track": off, "crashed": 0, "immobilized": 0, "reversed": 0}
    return Lap(trial, "lap_complete" if done else "off_track", 10.0, 10.0 + seconds, 100.0 if done else 40.0, counts)


def test_defaults_are_drfc():
    r = RaceRules()
    assert (r.trials, r.continuous, r.off_track_penalty, r.collision_penalty, r.max_resets) == (3, True, 5.0, 5.0, 100)
    assert r.penalty("reversed") == 5.0 and r.penalty("immobilized") == 0.0 and r.penalty("crashed") == 5.0


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"trials": 0}, "trials must be"), ({"off_track_penalty": -1.0}, "off track penalty"),
    ({"max_resets": -2}, "max resets"), ({"off_track_penalty": math.nan}, "off track penalty"),
])
def test_bad_rules_are_one_line(kwargs, message):
    with pytest.raises(RacerlabError, match=message) as err:
        RaceRules(**kwargs)
    assert "\n" not in str(err.value)


def test_pause_steps():
    # simapp resumes on the step where the remaining penalty reaches 0 (still a pause row)
    assert pause_steps(5.0) == 75 and pause_steps(2.0) == 30 and pause_steps(1.0) == 15
    assert pause_steps(0.0) == 1 and pause_steps(0.1) == 2


def straight_track(width=1.0):
    x = np.linspace(0.0, 10.0, 11)
    c = np.stack([x, np.zeros_like(x)], 1)
    return from_array(np.hstack([c, c + [0, width / 2], c - [0, width / 2]]), "straight")


def test_reset_pose_is_on_the_nearer_lane_aligned_with_it():
    lanes = Lanes(straight_track())
    x, y, yaw = lanes.reset_pose(4.3, near_xy=(5.0, 0.9))  # the car left on the +y side
    assert (x, y, yaw) == pytest.approx((4.3, 0.25, 0.0))
    x, y, yaw = lanes.reset_pose(7.0, near_xy=(6.0, -3.0))
    assert (x, y, yaw) == pytest.approx((7.0, -0.25, 0.0))


def test_best_consecutive_average_is_droa_ranking():
    laps = [lap(1, 10.0), lap(2, 9.0, done=False), lap(3, 9.5), lap(4, 9.0), lap(5, 8.0), lap(6, 12.0)]
    # windows of 3 with all completed: (3,4,5) = 26.5/3, (4,5,6) = 29/3; floor of ms
    assert best_consecutive_average(laps, 3) == math.floor(26500 / 3) / 1000 == 8.833
    assert best_consecutive_average(laps, 1) == 8.0
    assert best_consecutive_average(laps[:3], 3) is None
    assert completed_streak(laps) == 4


def test_result_text_in_the_leagues_words():
    assert result_text([lap(1, 10, done=False)]) == "no lap completed"
    assert result_text([lap(1, 10, done=False), lap(2, 12.3456)]) == "one lap: 12.346 s"
    assert result_text([lap(1, 10.0), lap(2, 11.0), lap(3, 12.0, done=False)]) == "2 laps, average 10.500 s"


def test_ranking_prefers_a_full_average_then_more_laps():
    full_slow = race_result([lap(1, 12.0), lap(2, 12.0), lap(3, 12.0)])
    full_fast = race_result([lap(1, 10.0), lap(2, 10.0), lap(3, 10.0)])
    two_fastest = race_result([lap(1, 7.0), lap(2, 7.0), lap(3, 7.0, done=False)])
    one = race_result([lap(1, 6.0), lap(2, 9.0, done=False), lap(3, 9.0, done=False)])
    none = race_result([lap(1, 9.0, done=False)] * 3)
    ranked = sorted([none, one, two_fastest, full_slow, full_fast], key=rank_key)
    assert ranked == [full_fast, full_slow, two_fastest, one, none]
    assert full_fast.ranking_average == 10.0 and two_fastest.ranking_average is None and two_fastest.best_lap == 7.0


def test_eval_metrics_entry_has_the_aws_schema():
    e = lap(2, 9.5, off=3).eval_metrics_entry()
    assert tuple(e) == EVAL_METRICS_KEYS
    assert e["elapsed_time_in_milliseconds"] == 9500 and e["start_time"] == 10000 and e["metric_time"] == 19500
    assert e["off_track_count"] == 3 and e["reset_count"] == 3 and e["trial"] == 2
    assert e["episode_status"] == "Lap complete" and e["completion_percentage"] == 100
