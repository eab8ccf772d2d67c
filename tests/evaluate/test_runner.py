"""Race rules in the driving loop, with hand-made drivers: lap timing, penalties, resets, continuous laps."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.evaluate.rules import RaceRules, pause_steps
from racerlab.evaluate.runner import run_evaluation
from racerlab.model import ContinuousActions, ModelMetadata
from racerlab.sim import StartRules, World
from racerlab.sim.pursuit import PurePursuit
from racerlab.spec import MODEL_POINT_AHEAD_M

META = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")
DT = 1.0 / 15.0


def world_on(track, reverse=False):
    return World(track, 1, META, None, "features", start=StartRules(reverse=reverse), max_episode_steps=100_000,
                 seed=0)


def pursuit(world, speed):
    """A pure-pursuit driver on the centre line, as agent actions in [-1, 1]²."""
    sim = world.sim
    pp = PurePursuit.on_centre_line(sim.track_reversed if sim.reversed[0] else sim.track, speed=speed)

    def policy(obs):
        steer, v = pp(sim)
        return np.stack([steer / 30.0, (v - 0.5) / 1.75 - 1.0], axis=1)

    return policy


def straight_ahead(obs):
    """Steering 0 at 1 m/s: leaves the road at the first corner, every time."""
    return np.array([[0.0, (1.0 - 0.5) / 1.75 - 1.0]])


@pytest.fixture
def wide(aws_track):
    return aws_track("reInvent2019_wide")


def lap_rows(run, lap_index):
    return np.flatnonzero(run.trace["episode"] == lap_index)


def test_continuous_laps_are_timed_from_lap_to_lap(wide):
    run = run_evaluation(world_on(wide), pursuit(world_on(wide), 2.0), RaceRules(trials=3))
    t = run.trace
    assert [lap.status for lap in run.laps] == ["lap_complete"] * 3
    assert t["done"].sum() == 1 and t["done"][-1] and (t["episode_status"] == "prepare").sum() == 1
    start = 0.0
    for k, lap in enumerate(run.laps):
        rows = lap_rows(run, k)
        # as in AWS's logs: laps before the episode's last end "in_progress" (done False), the last "lap_complete"
        assert t["episode_status"][rows[-1]] == ("lap_complete" if k == 2 else "in_progress") and lap.rows == rows.size
        # the lap's time is the simulated time from its start to the end of its lap-complete step
        assert lap.time == pytest.approx(rows.size * DT, abs=1e-3)
        assert lap.time == pytest.approx(t["tstamp"][rows[-1]] - start, abs=1e-3)
        start = t["tstamp"][rows[-1]]
        # progress starts again from the line: small at the lap's first row, 100 at its last
        assert t["progress"][rows[0]] < 5.0 and t["progress"][rows[-1]] == 100.0
    assert np.all(np.diff(t["steps"]) == 1)  # one episode: the step counter runs on


def test_continuous_mode_ends_after_n_laps(wide):
    run = run_evaluation(world_on(wide), pursuit(world_on(wide), 2.0), RaceRules(trials=2))
    assert len(run.laps) == 2 and run.trace["episode"].max() == 1


def test_separate_trials_each_start_from_the_line(wide):
    w = world_on(wide)
    run = run_evaluation(w, pursuit(w, 2.0), RaceRules(trials=2, continuous=False))
    t = run.trace
    assert (t["episode_status"] == "prepare").sum() == 2 and t["done"].sum() == 2
    for k, lap in enumerate(run.laps):
        rows = lap_rows(run, k)
        assert t["episode_status"][rows[0]] == "prepare" and t["steps"][rows[0]] == 1
        assert lap.completed and lap.time == pytest.approx(rows.size * DT, abs=1e-3)  # prepare step included


def test_off_track_holds_the_car_for_the_penalty_and_puts_it_on_the_nearer_lane(wide):
    w = world_on(wide)
    run = run_evaluation(w, straight_ahead, RaceRules(trials=1, off_track_penalty=2.0, max_resets=3))
    t, x = run.trace, run.extra
    off = np.flatnonzero(t["episode_status"] == "off_track")
    assert off.size == 4 and run.laps[0].status == "off_track" and run.laps[0].counts["off_track"] == 4
    n = pause_steps(2.0)
    for i in off[:3]:
        pause = np.arange(i + 1, i + 1 + n)
        assert t["pause_duration"][i] == 2.0
        assert np.all(t["episode_status"][pause] == "pause") and np.all(t["reward"][pause] == 0.0)
        assert t["pause_duration"][pause] == pytest.approx(2.0 - DT * np.arange(1, n + 1), abs=1e-9)
        assert t["episode_status"][pause[-1] + 1] == "in_progress"
        # held still where it was put back, and the clock ran on by exactly the penalty
        assert np.ptp(x["base_x"][pause]) == 0.0 and np.ptp(x["base_y"][pause]) == 0.0
        assert t["tstamp"][pause[-1]] - t["tstamp"][i] == pytest.approx(2.0, abs=1e-9)
        _check_put_back(wide, t, x, i, pause[0])
    assert off[3] == t["steps"].size - 1 and t["pause_duration"][-1] == 0.0  # resets used up: the 4th ends it


def _check_put_back(track, t, x, i, first_pause):
    """Base point on the lane (a quarter of the width from the centre) at the previous row's progress,
    aligned with the lane, on the side the car left."""
    base = np.array([[x["base_x"][first_pause], x["base_y"][first_pause]]])
    proj = track.project(base)
    assert abs(proj.lateral[0]) == pytest.approx(proj.width[0] / 4, abs=0.02)
    assert proj.s[0] == pytest.approx(t["progress"][i - 1] / 100 * track.length, abs=0.01)
    dyaw = np.angle(np.exp(1j * (x["base_yaw"][first_pause] - proj.heading[0])))
    assert abs(dyaw) < 0.15
    left = track.project([[t["X"][i], t["Y"][i]]]).lateral[0]
    assert np.sign(left) == np.sign(proj.lateral[0])
    # and the model point (what the trace reports) is 0.14 m ahead of the base
    heading = x["base_yaw"][first_pause]
    assert t["X"][first_pause] == pytest.approx(x["base_x"][first_pause] + MODEL_POINT_AHEAD_M * np.cos(heading))


def test_an_off_track_costs_exactly_the_penalty(wide):
    times = {}
    for penalty in (1.0, 4.0):
        w = world_on(wide)
        run = run_evaluation(w, pursuit(w, 4.0), RaceRules(trials=1, off_track_penalty=penalty))
        lap = run.laps[0]
        assert lap.completed and lap.counts["off_track"] >= 1
        times[penalty] = (lap.time, lap.counts["off_track"])
    (t1, n1), (t4, n4) = times[1.0], times[4.0]
    assert n1 == n4 and t4 - t1 == pytest.approx(3.0 * n1, abs=1e-3)


def test_no_resets_ends_at_the_first_incident(wide):
    run = run_evaluation(world_on(wide), straight_ahead, RaceRules(trials=3, max_resets=0))
    assert len(run.laps) == 1 and run.laps[0].status == "off_track" and "pause" not in set(run.trace["episode_status"])
    run = run_evaluation(world_on(wide), straight_ahead, RaceRules(trials=3, continuous=False, max_resets=0))
    assert [lap.status for lap in run.laps] == ["off_track"] * 3 and run.trace["done"].sum() == 3


def test_reversed_direction(wide):
    w = world_on(wide, reverse=True)
    run = run_evaluation(w, pursuit(w, 2.0), RaceRules(trials=1, reverse=True))
    assert run.laps[0].completed
    assert w.sim.reversed[0]
