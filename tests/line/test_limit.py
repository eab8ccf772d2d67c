"""The theoretical limit is a lower bound for the rule the simulator enforces: a car is off track only when none
of its wheel centres is on the road, so the limit lets the base point hang that far over a border, while the
racing line keeps the whole car inside. Hand-worked poses against the simulator's own rule, a ring's limit worked
out by hand, a real lap the simulator accepts that beat the old line-margin "limit", and the simulated car never
cornering harder than the profile assumes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.line import (
    car_clearance,
    fastest_line,
    min_margin,
    offtrack_overhang,
    racing_line,
    theoretical_limit,
)
from racerlab.line import geometry as G
from racerlab.line.profile import max_curvature
from racerlab.sim import Simulator
from racerlab.sim import _kernels as K
from racerlab.sim.pursuit import PurePursuit, drive_lap
from racerlab.spec import car_params
from racerlab.track.kernels import point_in_road
from tests.line.test_solve import ring

BIG = 50.0  # a ring this large is straight to 0.1 mm over a car's length


def wheels_on(x: float, yaw_deg: float) -> int:
    """Wheel centres on the road of a car whose base point is at (x, 0) by the big ring's outer border
    (x = BIG + 0.5, the road to the left of it: smaller x), heading yaw_deg."""
    sim = Simulator(ring(BIG, 1.0, n=2000), 1)
    sim.set_pose(0, x, 0.0, math.radians(yaw_deg))
    return int(sim.state.wheels_on_track[0])


def test_the_off_track_rule_lets_the_base_point_hang_over_the_border():
    border = BIG + 0.5
    # parallel to the border (heading +y) the left wheels are 0.08 m (half the wheel track) nearer the road
    assert wheels_on(border + 0.07, 90.0) == 2  # 0.01 m inside: on track
    assert wheels_on(border + 0.09, 90.0) == 0  # 0.01 m outside: off track
    # turned 45° toward the road, the left front wheel is 0.082·sin 45° + 0.08·cos 45° = 0.1146 m nearer
    assert wheels_on(border + 0.11, 135.0) == 1
    assert offtrack_overhang() == pytest.approx(math.hypot(0.082, 0.08)) == pytest.approx(0.1146, abs=1e-4)
    # no heading keeps a wheel centre on the road beyond that overhang
    for yaw in range(0, 360, 15):
        assert wheels_on(border + offtrack_overhang() + 0.002, float(yaw)) == 0, yaw
    # the racing line's clearance keeps the whole car inside; the limit's lets the base point out to the overhang
    assert car_clearance(margin=0.1) == pytest.approx(0.08 + 0.036 + 0.1)
    assert car_clearance(margin=min_margin()) == pytest.approx(-offtrack_overhang())


def test_the_limit_on_a_ring_hugs_the_inner_border_from_outside_it():
    # ring of radius 2 m, road 1 m wide: inner border r = 1.5 m. The fastest lap under the off-track rule circles
    # the base point at r = 1.5 - 0.1146 = 1.3854 m at the grip's speed √(4.9 · r) = 2.605 m/s (below the
    # droa car's 3.549 m/s top speed and its full-lock curvature 2.19 /m): 2π r / v = 3.341 s a lap
    car = car_params("droa")
    limit = theoretical_limit(ring(2.0, 1.0), car=car)
    r = 1.5 - offtrack_overhang(car)
    radius = np.hypot(*limit.xy.T)
    assert limit.kind == "limit" and limit.clearance_m == pytest.approx(-offtrack_overhang(car))
    assert radius.min() >= r - 1e-3 and np.median(radius) == pytest.approx(r, abs=0.01)
    assert limit.flying_lap_time == pytest.approx(2 * math.pi * r / math.sqrt(4.9 * r), rel=0.01)
    assert limit.flying_lap_time == pytest.approx(3.341, abs=0.035)
    # the racing line keeps the whole car 0.1 m inside: r = 1.5 + 0.216 m, 3.62 s
    line = racing_line(ring(2.0, 1.0), car=car)
    assert line.kind == "line" and line.flying_lap_time == pytest.approx(2 * math.pi * math.sqrt(1.716 / 4.9), rel=0.01)


def test_the_fastest_line_is_the_limits_path_at_the_racers_margin():
    # on the same ring, margin -0.1 m: clearance 0.08 + 0.036 - 0.1 = 0.016 m, so the base point circles r = 1.516 m,
    # 2π √(1.516 / 4.9) = 3.495 s a lap; at the rule's margin it is the limit itself
    car = car_params("droa")
    line = fastest_line(ring(2.0, 1.0), -0.1, car)
    assert line.kind == "line" and line.margin_m == -0.1
    assert np.median(np.hypot(*line.xy.T)) == pytest.approx(1.516, abs=0.01)
    assert line.flying_lap_time == pytest.approx(2 * math.pi * math.sqrt(1.516 / 4.9), rel=0.01)
    limit = theoretical_limit(ring(2.0, 1.0), car=car)
    at_rule = fastest_line(ring(2.0, 1.0), min_margin(car), car)
    assert (at_rule.lap_time, at_rule.flying_lap_time) == (limit.lap_time, limit.flying_lap_time)


def test_no_lap_the_simulator_accepts_beats_the_limit(aws_track):
    # pure pursuit of the line with the base point on the border (clearance 0), near the profile's full speed: the
    # simulator accepts the lap (a wheel centre stays on the road), and it beats the line-margin lap that
    # `racerlab line` used to call the theoretical best (6.667 s)
    t = aws_track("reInvent2019_track")
    car = car_params("droa")
    edge = racing_line(t, margin=-car_clearance(car, 0.0), car=car)
    sim = Simulator(t, 1, car)
    # at 0.95 of the profile's speed: the refitted droa car's lags (issue 34) leave no room at its full speed
    status, steps, lap, _ = drive_lap(sim, PurePursuit(edge.xy, 0.95 * edge.speed, closed=True, car=car,
                                                       lookahead_m=0.25))
    assert status == "lap_complete"
    assert lap < racing_line(t, car=car).lap_time
    limit = theoretical_limit(t, car=car)
    assert limit.lap_time <= lap
    # and the limit's path stays where the rule allows: on the road or at most the overhang (+ 2 mm) beyond it
    bs, be, y0, bh = t.road_index
    on_road = np.array([point_in_road(x, y, t.road_edges, bs, be, float(y0), bh) for x, y in limit.xy])
    beyond = G.border_distance(limit.xy, *G.border_segments(t))[~on_road]
    assert (~on_road).sum() > 10 and beyond.max() <= offtrack_overhang(car) + 2e-3


@pytest.mark.parametrize("simulator,version", [("droa", "5"), ("console", "5"), ("console", "4")])
def test_the_simulated_car_corners_no_harder_than_the_profile_allows(aws_track, simulator, version):
    # full lock held at each command: the circle the car settles on is the profile's tightest at that speed
    car = car_params(simulator, version)
    for command in (0.5, 1.5, 2.5, 3.5):
        sim = Simulator(aws_track("reInvent2019_track"), 1, car)
        path, speeds = [], []
        for _ in range(60):
            sim.step(np.array([30.0]), np.array([command]))
            sim.ctr[:, [K.KSTATUS, K.KIMMOB, K.KREVCNT]] = 0  # the circle may leave the road: keep driving
            path.append(sim.car[0, [K.CX, K.CY]].copy())
            speeds.append(sim.car[0, K.CV])
        p = np.array(path[30:])
        a = np.linalg.lstsq(np.c_[2 * p, np.ones(len(p))], (p**2).sum(1), rcond=None)[0]
        kappa = 1.0 / math.sqrt(a[2] + a[0] ** 2 + a[1] ** 2)
        v = float(np.mean(speeds[30:]))
        assert kappa == pytest.approx(float(max_curvature(v, car)), rel=0.01), command
        assert v * v * kappa <= car.grip_mps2 * 1.01


def test_a_blend_runs_from_the_minimum_curvature_line_to_the_shortest(aws_track):
    t = aws_track("reinvent_base")
    ends = {w: racing_line(t, blend=w) for w in (0.0, 1.0)}
    pure = {m: racing_line(t, method=m) for m in ("mincurv", "shortest")}
    assert np.abs(ends[0.0].xy - pure["mincurv"].xy).max() < 0.01 and ends[0.0].method == "blend 0"
    assert np.abs(ends[1.0].xy - pure["shortest"].xy).max() < 0.01
    middle = racing_line(t, blend=1e-3)
    assert pure["shortest"].length < middle.length < pure["mincurv"].length
