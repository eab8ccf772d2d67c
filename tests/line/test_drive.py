"""The limit is real: pure pursuit on the racing line at the profile's speed stays on the track and
laps within 3 % of the predicted time; and the car's defaults keep the reInvent2019 anchor."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.errors import TrackError
from racerlab.line import racing_line
from racerlab.sim import CarParams, Simulator
from racerlab.sim.pursuit import PurePursuit, drive_lap
from racerlab.track import load


def drive(track, line):
    sim = Simulator(track, 1)
    pp = PurePursuit(line.xy, line.speed, closed=True, car=sim.car_params)
    return drive_lap(sim, pp)


def lab_technical():
    try:
        return load("lab_technical")
    except TrackError:
        pytest.skip("the bundled track lab_technical is not there yet")


@pytest.mark.parametrize("which", ["reInvent2019_track", "lab_technical"])
def test_pursuit_on_the_line_drives_the_predicted_lap(aws_track, which):
    track = lab_technical() if which == "lab_technical" else aws_track(which)
    line = racing_line(track)
    status, steps, lap_time, traj = drive(track, line)
    assert status == "lap_complete"
    assert lap_time == pytest.approx(steps / 15.0)
    assert abs(lap_time / line.lap_time - 1.0) <= 0.03, f"driven {lap_time:.3f} s, predicted {line.lap_time:.3f} s"
    assert lap_time >= line.lap_time - 1.5 / 15.0  # never clearly faster than the limit
    assert track.contains(traj).all()  # the base point never left the road


def test_theoretical_best_lap_on_reinvent2019_is_near_the_record(aws_track):
    # all-time best human-trained lap in the AWS simulator: 7.198 s (4 m/s cap)
    t = aws_track("reInvent2019_track")
    assert CarParams().max_speed_mps == 4.0
    assert 6.5 <= racing_line(t).lap_time <= 7.2
    assert racing_line(t, margin=0.0).lap_time < racing_line(t).lap_time  # more road, faster


def test_a_faster_car_gets_a_faster_line_and_profile(aws_track):
    t = aws_track("reInvent2019_track")
    base = racing_line(t)
    grippy = racing_line(t, car=CarParams(grip_mps2=8.0, accel_mps2=5.0, brake_mps2=8.0))
    assert grippy.lap_time < base.lap_time
    assert np.max(grippy.speed**2 * np.abs(grippy.curvature)) <= 8.0 * (1 + 1e-9)
