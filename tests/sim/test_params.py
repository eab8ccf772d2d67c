"""Reward params on real AWS tracks against values worked out by hand from the track files.

Each car is placed so that its model point (0.14 m ahead of the base) sits at a chosen spot;
the expected values are computed here directly from the waypoint arrays, not by racerlab.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.sim import Simulator
from racerlab.sim.params import ParamsBuilder

AHEAD = 0.14


def params_at(track, model_xy, heading_rad, start_ndist=0.0, reverse=False):
    """Place a car with its model point at `model_xy`, take the prepare step and one RUN step at 1 m/s."""
    sim = Simulator(track, 1)
    bx = model_xy[0] - AHEAD * math.cos(heading_rad)
    by = model_xy[1] - AHEAD * math.sin(heading_rad)
    sim.set_pose(0, bx, by, heading_rad, start_ndist=start_ndist, reverse=reverse)
    sim.step(0.0, 1.0)  # prepare: held in place
    sim.step(12.5, 1.7)  # RUN: params are those of the pose before this action moves the car
    return ParamsBuilder(sim).build()[0]


def seg_point(center, i, frac, offset_left):
    a, b = center[i], center[i + 1]
    d = (b - a) / np.hypot(*(b - a))
    return a + frac * (b - a) + offset_left * np.array([-d[1], d[0]]), math.atan2(d[1], d[0])


def arc(center, i, frac):
    seg = np.hypot(*np.diff(center, axis=0).T)
    return seg[:i].sum() + frac * seg[i]


def test_reinvent2019_on_centre_line(aws_track):
    t = aws_track("reInvent2019_track")
    c = t.center
    p, head = seg_point(c, 18, 0.5, 0.0)
    prm = params_at(t, p, head)
    length = np.hypot(*np.diff(c, axis=0).T).sum()
    assert prm["x"] == pytest.approx(p[0]) and prm["y"] == pytest.approx(p[1])
    assert prm["progress"] == pytest.approx(100 * arc(c, 18, 0.5) / length, abs=1e-9)
    assert prm["projection_distance"] == pytest.approx(arc(c, 18, 0.5), abs=1e-9)
    assert prm["closest_waypoints"] == [18, 19]
    assert prm["distance_from_center"] == pytest.approx(0.0, abs=1e-9)
    assert prm["track_width"] == pytest.approx(1.0668, abs=1e-3)
    assert prm["all_wheels_on_track"] is True and prm["is_offtrack"] is False
    assert prm["heading"] == pytest.approx(math.degrees(head))
    assert prm["steps"] == 2.0 and isinstance(prm["steps"], float)
    assert prm["speed"] == 1.7 and prm["steering_angle"] == 12.5  # commanded, as AWS passes them
    assert prm["track_length"] == pytest.approx(23.12, abs=0.01)
    assert prm["is_reversed"] is False
    assert len(prm["waypoints"]) == 154 and prm["waypoints"][0] == prm["waypoints"][-1]
    assert isinstance(prm["waypoints"][0], tuple)
    for key in ("objects_location", "objects_left_of_center", "objects_distance", "objects_distance_from_center",
                "objects_heading", "objects_speed"):
        assert prm[key] == []
    assert prm["closest_objects"] == [0, 0] and prm["is_crashed"] is False


@pytest.mark.parametrize(("offset", "left", "wheels"), [(0.2, True, True), (-0.3, False, True),
                                                        (0.5, True, False), (-0.5, False, False)])
def test_reinvent2019_offsets(aws_track, offset, left, wheels):
    t = aws_track("reInvent2019_track")  # counter-clockwise: the inner border is on the left
    p, head = seg_point(t.center, 18, 0.5, offset)
    prm = params_at(t, p, head)
    assert prm["distance_from_center"] == pytest.approx(abs(offset), abs=1e-9)
    assert prm["is_left_of_center"] is left
    # wheels sit ±0.08 m beside the base: with the model point 0.5 m off centre the outer pair
    # is beyond the 0.533 m half width
    assert prm["all_wheels_on_track"] is wheels
    assert prm["closest_waypoints"] == [18, 19]


def test_clockwise_track_left_is_outer(aws_track):
    t = aws_track("2022_april_open_cw")  # driving clockwise: the outer border is on the left
    c = t.center
    i = 40
    p, head = seg_point(c, i, 0.3, 0.25)
    prm = params_at(t, p, head)
    outer_side = np.dot(t.outer[i] - c[i], p - c[i]) > 0
    assert outer_side  # offset to the left of travel is toward the outer border here
    assert prm["is_left_of_center"] is True
    assert prm["distance_from_center"] == pytest.approx(0.25, abs=1e-6)
    assert prm["closest_waypoints"] == [i, i + 1]
    length = np.hypot(*np.diff(c, axis=0).T).sum()
    assert prm["progress"] == pytest.approx(100 * arc(c, i, 0.3) / length, abs=1e-6)


def test_reinvent_base_reversed(aws_track):
    t = aws_track("reinvent_base")
    r = t.reverse()
    p, head = seg_point(r.center, 30, 0.5, 0.1)
    prm = params_at(t, p, head, reverse=True)
    assert prm["is_reversed"] is True
    assert prm["waypoints"][0] == tuple(t.center[0]) and prm["waypoints"][1] == tuple(t.center[-2])
    assert prm["closest_waypoints"] == [30, 31]
    # CCW track driven clockwise: left of travel is toward the outer border
    toward_outer = np.dot(t.outer[len(t.center) - 1 - 30] - r.center[30], p - r.center[30]) > 0
    assert prm["is_left_of_center"] is True and toward_outer
    assert prm["track_width"] == pytest.approx(0.762, abs=2e-3)


def test_straight_track_progress_from_episode_start(aws_track):
    t = aws_track("Straight_track")
    x0, y0 = t.center[0]
    length = t.length
    prm = params_at(t, (x0 + 2.0, y0), 0.0, start_ndist=0.25)
    assert prm["progress"] == pytest.approx(100 * (2.0 / length - 0.25), abs=1e-6)
    assert prm["projection_distance"] == pytest.approx(2.0, abs=1e-6)
    assert prm["track_width"] == pytest.approx(0.6096, abs=1e-3)


def test_closest_waypoints_use_arc_length_not_euclid(aws_track):
    t = aws_track("reInvent2019_track")
    p, head = seg_point(t.center, 18, 0.9, 0.0)  # nearer waypoint 19, but still between 18 and 19
    prm = params_at(t, p, head)
    assert prm["closest_waypoints"] == [18, 19]


def test_reward_function_gets_its_own_copy(aws_track):
    import gymnasium as gym

    seen = []

    def greedy(params):
        seen.append(len(params["waypoints"]))
        params["waypoints"].clear()
        params["closest_waypoints"][0] = -1
        return 1.0

    env = gym.make("racerlab/DeepRacer-v0", track=aws_track("reInvent2019_track"), reward_function=greedy)
    env.reset(seed=0)
    for _ in range(4):
        env.step(2)
    assert seen == [154, 154, 154]
