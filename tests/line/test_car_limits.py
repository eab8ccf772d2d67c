"""The racing line per simulator's car (issue 24): the steering limit falls with speed, the limits stay under the
record driven in the AWS simulator."""

import math

import numpy as np
import pytest

from racerlab.line import racing_line, theoretical_limit
from racerlab.line.profile import lateral_limit, max_curvature
from racerlab.spec import car_params

RECORD_REINVENT2019_S = 7.198  # the all-time best lap in the AWS (console) simulator


@pytest.mark.parametrize("kappa", [0.3, 0.8, 1.2, 2.0])
def test_lateral_limit_inverts_the_saturating_steering(kappa):
    """The console v5 car's tyres saturate: full lock asks for κ_w = g·tan 30° / (L·√(1 + (g·tan 30° / 2)²)) and the
    car drives κ_w / √(1 + (v²κ_w / sat)²). Inverting it by hand: a curvature κ holds up to
    v² = (sat / κ_w)·√((κ_w / κ)² - 1)."""
    car = car_params("console", "5")
    assert car.slide_mps == 0 and car.tyre_sat_mps2 > 0
    L = car.wheelbase_m
    t = car.yaw_gain * math.tan(math.radians(car.max_steer_deg))
    kw = t / (L * math.sqrt(1 + 0.25 * t * t))
    v_steer = math.sqrt(car.tyre_sat_mps2 / kw * math.sqrt((kw / kappa) ** 2 - 1)) if kappa < kw else 0.0
    v_grip = math.sqrt(car.grip_mps2 / kappa)
    expect = max(min(v_steer, v_grip, car.top_speed()), car.min_speed_mps * car.ground_factor)
    assert float(lateral_limit(np.array([kappa]), car)[0]) == pytest.approx(expect, rel=1e-6)
    assert float(max_curvature(expect, car)) >= kappa * (1 - 1e-6) or expect == car.top_speed()


def test_top_speed_is_the_cap_times_the_ground_factor():
    assert car_params("droa").top_speed() == pytest.approx(3.5 * car_params("droa").ground_factor)
    assert car_params("droa", "4").top_speed() == car_params("droa").top_speed()  # no speed loop: the cap
    assert car_params("console", "4").top_speed() == pytest.approx(4.0 * car_params("console", "4").ground_factor)


def test_limits_per_simulator_stay_under_the_record(aws_track):
    t = aws_track("reInvent2019_track")
    laps = {(sim, v): racing_line(t, car=car_params(sim, v)).lap_time
            for sim, v in (("droa", "5"), ("console", "5"), ("console", "4"))}
    # the record was driven in May 2020, by a model of version 3-4 (effort control: velocity control came with
    # version 5): the console effort car's limit (the fastest lap the off-track rule allows) stays under it. The
    # console velocity car's limit need not: fitted to the 2025 logs, its acceleration fades as 1 - (v / 4.47 m/s)² and
    # its tyres saturate toward 2.85 m/s² of lateral acceleration (issue 34), and its limit is 7.333 s
    assert theoretical_limit(t, car=car_params("console", "4")).lap_time <= RECORD_REINVENT2019_S
    assert len(set(laps.values())) == 3  # each simulator's car has its own limit
    assert racing_line(t, car="console").lap_time == laps[("console", "5")]  # a simulator's name is its v5 car
