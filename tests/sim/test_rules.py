"""Episode rules as the AWS simulator applies them (facts §2), on real tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.sim import CarParams, Simulator, StartRules
from racerlab.sim.pursuit import PurePursuit, drive_lap


def run_until_done(sim, steer, speed, limit=2000):
    for _ in range(limit):
        codes = sim.step(steer, speed)
        if sim.terminated_mask(codes)[0] or sim.truncated[0]:
            return sim.status_names(codes)[0]
    return "still running"


def test_first_step_is_prepare_and_holds_the_car(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 1)
    before = sim.pose.copy()
    codes = sim.step(30.0, 4.0)
    assert sim.status_names(codes) == ["prepare"]
    assert np.array_equal(sim.pose, before) and sim.speed[0] == 0.0
    assert sim.steps[0] == 1
    sim.step(0.0, 1.0)
    assert sim.status_names() == ["in_progress"] and sim.steps[0] == 2


def test_driving_straight_ends_off_track(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 1)
    assert run_until_done(sim, 0.0, 1.0) == "off_track"
    # off-track means no wheel centre on the road, judged on the pose before the last action
    wheels = sim.judged.wheels_on_track[0]
    assert wheels == 0


def test_a_car_that_stops_is_immobilized(aws_track):
    # AWS clips speed to >= 0.1 m/s, so a stop needs a car that may stand still
    sim = Simulator(aws_track("reInvent2019_track"), 1, CarParams(min_speed_mps=0.0))
    assert run_until_done(sim, 0.0, 0.0) == "immobilized"
    # prepare step + 15 RUN steps of standing still
    assert sim.steps[0] == 1 + 15


def test_driving_backwards_ends_reversed(aws_track):
    t = aws_track("Straight_track")
    sim = Simulator(t, 1)
    x_end, y = t.center[-1]
    sim.set_pose(0, x_end - 0.5, y, math.pi)
    status = run_until_done(sim, 0.0, 1.0)
    assert status == "reversed"
    # progress equal on the first RUN step (the car was held), then falling for 15 steps
    assert sim.steps[0] == 1 + 1 + 15


def test_lap_by_a_simple_controller_completes_at_100(aws_track):
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 1)
    status, steps, lap_time, traj = drive_lap(sim, PurePursuit.on_centre_line(t, 1.5))
    assert status == "lap_complete"
    assert sim.judged.progress[0] == 100.0
    # roughly the length over the ground speed (the command times the car's ground factor), plus the prepare step
    # and the start from rest; at least the path the car drove (pursuit cuts the corners) over that speed
    v = 1.5 * sim.car_params.ground_factor
    driven = float(np.hypot(*np.diff(traj, axis=0).T).sum())
    assert driven / v < lap_time < t.length / v + 1.0


def test_open_track_lap(aws_track):
    t = aws_track("Straight_track")
    sim = Simulator(t, 1)
    status, steps, lap_time, _ = drive_lap(sim, PurePursuit.on_centre_line(t, 2.0))
    assert status == "lap_complete" and sim.judged.progress[0] == 100.0


def test_round_robin_starts_advance_five_percent(aws_track):
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 1)
    starts = []
    for _ in range(4):
        starts.append(sim.pose[0, :2].copy())
        sim.reset()
    for k, p in enumerate(starts):
        assert np.allclose(p, t.point_at(0.05 * k * t.length), atol=1e-12)
    assert sim.state.start[0] == pytest.approx(0.20)


def test_round_robin_wraps_and_alternates_direction(aws_track):
    t = aws_track("reinvent_base")
    sim = Simulator(t, 3, start=StartRules(advance=0.4, offset=0.1, alternate_direction=True))
    assert sim.state.start == pytest.approx([0.1, 0.5, 0.9])
    assert sim.reversed.tolist() == [False, True, False]
    sim.reset([True, False, False])
    assert sim.state.start[0] == pytest.approx(0.3)  # (0.1 + 3 * 0.4) mod 1
    assert sim.reversed[0]
    # a reversed car starts on the reversed centre line, heading along it
    r = t.reverse()
    assert np.allclose(sim.pose[0, :2], r.point_at(0.3 * t.length))
    assert sim.pose[0, 2] == pytest.approx(r.heading_at(0.3 * t.length))


def test_training_start_heading_points_to_next_waypoint(aws_track):
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 1)
    d = t.center[1] - t.center[0]
    assert sim.pose[0, 2] == pytest.approx(math.atan2(d[1], d[0]))
    assert sim.progress[0] == pytest.approx(100 * 0.14 / t.length, rel=0.05)


def test_step_cap_truncates_without_terminating(aws_track):
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 1, max_episode_steps=30)
    pp = PurePursuit.on_centre_line(t, 1.0)
    for _ in range(30):
        codes = sim.step(*pp(sim))
    assert sim.truncated[0] and not sim.terminated_mask(codes)[0]
    assert sim.status_names(codes) == ["in_progress"]


def test_reward_order_switch(aws_track):
    t = aws_track("reInvent2019_track")
    aws = Simulator(t, 1)
    after = Simulator(t, 1, reward_order="after_action")
    for sim in (aws, after):
        sim.step(0, 2.0)
        sim.step(0, 2.0)
    # AWS judges the pose the observation was taken in (the start pose, held by the prepare step);
    # after_action judges the pose the action produced
    assert aws.judged.model_x[0] == pytest.approx(aws.track.center[0, 0] + 0.14 * math.cos(aws.pose[0, 2]), abs=1e-9)
    assert after.judged.model_x[0] == pytest.approx(after.state.model_x[0])
    assert after.judged.progress[0] > aws.judged.progress[0]


def test_grip_limit_makes_a_fast_corner_run_wide(aws_track):
    """Same steering, different speeds: the slow car turns tighter; the fast one slides outward. The grip alone:
    no delay, no lag, full kinematic steering, ground speed = command, no cap below 4 m/s."""
    t = aws_track("reInvent2019_track")
    sim = Simulator(t, 2, CarParams(delay_steps=0.0, steer_tau_s=0.0, yaw_tau_s=0.0, yaw_gain=1.0, ground_factor=1.0,
                                    wheel_cap_mps=4.0))
    sim.step(0, 1)  # the prepare step holds both cars; then give them speed and full lock
    sim.state.speed[:] = [1.0, 4.0]
    sim.state.steering[:] = math.radians(30)
    yaw0 = sim.pose[:, 2].copy()
    sim.step([30, 30], [1.0, 4.0])
    turned = sim.pose[:, 2] - yaw0
    dist = 1.0 * sim.dt, 4.0 * sim.dt
    kappa = turned / np.array(dist)
    wb = 0.164
    kin = math.cos(math.atan(0.5 * math.tan(math.radians(30)))) * math.tan(math.radians(30)) / wb
    assert kappa[0] == pytest.approx(kin, rel=0.02)  # 1 m/s: v²κ = 3.4 m/s² is within grip
    assert kappa[1] == pytest.approx(CarParams().grip_mps2 / 16.0, rel=0.05)  # capped at grip / v²
