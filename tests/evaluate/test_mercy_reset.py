"""The mercy reset (simapp ENABLE_MERCY_RESET, next_capabilities §A.4): a car that keeps driving into the same box
is put ahead of it on the `max_resets_after_crash`-th crash in a row, instead of behind it again."""

from __future__ import annotations

import json

import numpy as np
import pytest

import racerlab.cli as cli
from racerlab.errors import RacerlabError
from racerlab.evaluate.rules import RaceRules, pause_steps
from racerlab.evaluate.runner import run_evaluation
from racerlab.model import ContinuousActions, ModelMetadata
from racerlab.sim import World
from racerlab.sim.pursuit import PurePursuit
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model
from tests.sim.test_objects import TRACK, box_pose, nearest_on, point_at


def _run(aws_track, rules):
    """A car that follows the centre line at 1 m/s: the line passes 0.27 m from the box at half the lap (inner
    lane), inside its footprint, so the car drives into the box every time it comes back to the line."""
    t = aws_track(TRACK)
    meta = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")
    w = World(t, 1, meta, None, "features", max_episode_steps=100_000, seed=0,
              race={"type": "object_avoidance", "object_positions": [[0.5, 1]]})
    pp = PurePursuit.on_centre_line(t, speed=1.0)

    def policy(obs):
        steer, v = pp(w.sim)
        return np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1)

    return t, run_evaluation(w, policy, rules)


def _restart_point(t, along):
    """Where the car is put back (worked out from the track alone): the outer lane's point nearest the centre
    line's point `along` m of centre line from the box's projection."""
    s_box = nearest_on(t.center, box_pose(t, 0.5, 1)[0])[1]
    return nearest_on(0.5 * (t.center + t.outer), point_at(t.center, s_box + along))[0]


def test_without_mercy_the_car_crashes_into_the_box_until_its_resets_run_out(aws_track):
    t, run = _run(aws_track, RaceRules(trials=1, collision_penalty=0.5, max_resets=4))
    tr, x = run.trace, run.extra
    crash = np.flatnonzero(tr["episode_status"] == "crashed")
    assert crash.size == 5 and run.laps[0].status == "crashed"
    assert tr["obstacle_crash_counter"][crash].tolist() == [1, 2, 3, 4, 4]  # the last one ends the episode: no reset
    behind = _restart_point(t, -1.0)
    for i in crash[:-1]:  # every restart is 1 m behind the box
        np.testing.assert_allclose([x["base_x"][i + 1], x["base_y"][i + 1]], behind, atol=1e-9)


def test_the_third_crash_in_a_row_into_the_box_restarts_the_car_ahead_of_it(aws_track):
    rules = RaceRules(trials=1, collision_penalty=0.5, max_resets=10, enable_mercy_reset=True,
                      max_resets_after_crash=3, reset_ahead_dist=1.5)
    t, run = _run(aws_track, rules)
    tr, x = run.trace, run.extra
    crash = np.flatnonzero(tr["episode_status"] == "crashed")
    # crashes 1 and 2 restart 1 m behind the box; the 3rd restarts 1.5 m ahead of it; then the lap is clear
    assert crash.size == 3 and run.laps[0].status == "lap_complete" and run.laps[0].counts["crashed"] == 3
    assert tr["obstacle_crash_counter"][crash].tolist() == [1, 2, 3]
    behind, ahead = _restart_point(t, -1.0), _restart_point(t, 1.5)
    for i in crash[:2]:
        np.testing.assert_allclose([x["base_x"][i + 1], x["base_y"][i + 1]], behind, atol=1e-9)
    i = crash[2]
    pause = np.arange(i + 1, i + 1 + pause_steps(0.5))
    assert np.all(tr["episode_status"][pause] == "pause")
    np.testing.assert_allclose([x["base_x"][pause[0]], x["base_y"][pause[0]]], ahead, atol=1e-9)
    # progress jumps on by the centre-line distance from the last driven point to 1.5 m past the box
    assert tr["progress"][pause[0]] > tr["progress"][i - 1]


def test_mercy_reset_flags_of_evaluate(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    folder = write_model(tmp_path / "m", aws_track_path("Straight_track"), ((0.0, 1.0),), "lidar")
    write_checkpoint(folder)
    assert cli.main(["evaluate", str(folder.path), "--trials", "1", "--race-type", "object_avoidance",
                     "--object-positions", "0.5,1", "--enable-mercy-reset", "--max-resets-after-crash", "2",
                     "--reset-ahead-dist", "0.5"]) == 0
    run = sorted(folder.path.glob("evaluation-*"))[-1]
    rules = json.loads((run / "summary.json").read_text())["rules"]
    assert rules["enable_mercy_reset"] is True and rules["max_resets_after_crash"] == 2
    assert rules["reset_ahead_dist"] == 0.5
    with pytest.raises(RacerlabError, match="max resets after crash"):
        RaceRules(max_resets_after_crash=0)
