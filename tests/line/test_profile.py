"""Speed profile: grip, acceleration and braking limits on hand-made paths with known answers."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from racerlab.line import profile as P
from racerlab.line.core import steering_for_curvature
from racerlab.spec import STEP_S, CarParams

# the grip, traction and lag mechanisms alone (full kinematic steering, no cap below the 4 m/s clip, ground speed =
# command): the hand-made answers below follow from them; tests/line/test_car_limits.py has the steering limit
CAR = CarParams(yaw_gain=1.0, speed_tau_s=0.1, accel_mps2=3.0, brake_mps2=4.9, ground_factor=1.0, wheel_cap_mps=4.0)


@pytest.mark.parametrize("radius", [0.4, 0.8, 1.5, 3.0])
def test_a_circle_is_driven_at_the_square_root_of_grip_times_radius(radius):
    n = 400
    k = np.full(n, 1.0 / radius)
    ds = np.full(n, 2 * math.pi * radius / n)
    prof = P.speed_profile(k, ds, CAR)
    v = min(math.sqrt(CAR.grip_mps2 * radius), CAR.max_speed_mps)
    assert prof.speed == pytest.approx(np.full(n, v), rel=1e-12)
    assert prof.lap_time == pytest.approx(2 * math.pi * radius / v, rel=1e-12)


def test_a_wide_circle_is_capped_at_the_top_speed():
    k = np.full(100, 1.0 / 10.0)  # √(4.9 · 10) = 7 m/s > 4
    prof = P.speed_profile(k, np.full(100, 0.1), CAR)
    assert np.all(prof.speed == CAR.max_speed_mps)


def test_standing_start_on_a_straight_follows_v2_equals_2ad_without_lag():
    car = replace(CAR, speed_tau_s=0.0, accel_mps2=2.0)
    n, ds = 200, 0.01  # 2 m: reaches √(2 · 2 · 2) = 2.83 m/s, below the cap
    prof = P.speed_profile(np.zeros(n), np.full(n - 1, ds), car, closed=False, v_start=0.0)
    s = np.arange(n) * ds
    assert prof.speed == pytest.approx(np.sqrt(2 * 2.0 * s), rel=1e-9, abs=1e-9)
    assert prof.lap_time == pytest.approx(math.sqrt(2 * 1.99 / 2.0), rel=1e-6)  # t = √(2d/a)


def test_the_speed_lag_slows_the_approach_to_the_cap():
    # with the lag the usable acceleration is min(accel, (cap - v)/τ): never quite at the cap on a short run
    prof = P.speed_profile(np.zeros(300), np.full(299, 0.01), CAR, closed=False, v_start=0.0)
    assert prof.speed.max() < CAR.max_speed_mps
    no_lag = P.speed_profile(np.zeros(300), np.full(299, 0.01), replace(CAR, speed_tau_s=0.0), closed=False,
                             v_start=0.0)
    assert prof.lap_time > no_lag.lap_time


def test_braking_into_a_corner_starts_in_time():
    # 3 m straight, then a tight arc: the speed before the arc falls at most at the braking limit
    car = replace(CAR, speed_tau_s=0.0)
    k = np.concatenate([np.zeros(300), np.full(100, 1.0 / 0.5)])
    ds = np.full(399, 0.01)
    prof = P.speed_profile(k, ds, car, closed=False, v_start=0.0)
    v_arc = math.sqrt(car.grip_mps2 * 0.5)
    assert prof.speed[300:] == pytest.approx(np.full(100, v_arc))
    dv2 = np.diff(prof.speed**2) / (2 * ds)
    assert dv2.min() >= -car.brake_mps2 * (1 + 1e-9)
    assert dv2.max() <= car.accel_mps2 * (1 + 1e-9)
    # the last straight point is exactly as fast as full braking over one segment allows
    assert prof.speed[299] == pytest.approx(math.sqrt(v_arc**2 + 2 * car.brake_mps2 * 0.01), rel=1e-9)


def test_flying_lap_is_periodic_and_faster_than_a_standing_start():
    theta = np.linspace(0, 2 * np.pi, 300, endpoint=False)
    k = 1.0 + 0.9 * np.sin(3 * theta)  # three corners
    ds = np.full(300, 0.1)
    fly = P.speed_profile(k, ds, CAR)
    stand = P.speed_profile(k, ds, CAR, v_start=0.0)
    assert stand.speed[0] == 0.0 and stand.lap_time > fly.lap_time
    assert np.all(stand.speed <= fly.speed + 1e-12)
    # a flying lap keeps the limits across the closing point too
    assert np.all(fly.speed <= P.lateral_limit(k, CAR) + 1e-12)


def test_timer_counts_the_prepare_step_and_one_step_of_detection():
    assert P.timer_lap_time(1.0) == pytest.approx(17 * STEP_S)  # 15 steps of driving + 2
    assert P.timer_lap_time(15 * STEP_S) == pytest.approx(17 * STEP_S)
    assert P.timer_lap_time(15 * STEP_S + 1e-3) == pytest.approx(18 * STEP_S)


@pytest.mark.parametrize("gain", [1.0, 0.632])
@pytest.mark.parametrize("deg", [-30.0, -12.5, 0.0, 3.0, 29.0])
def test_steering_from_curvature_inverts_the_simulators_bicycle(deg, gain):
    wb = CAR.wheelbase_m
    tan_d = gain * math.tan(math.radians(deg))
    kappa = tan_d / math.sqrt(1 + 0.25 * tan_d**2) / wb  # car.advance: κ = cos β · g · tan δ / L
    assert float(steering_for_curvature(kappa, wb, gain)) == pytest.approx(deg, abs=1e-9)
