"""The compiled bot-car and object-params passes (`racerlab.sim._object_kernels`) against a straightforward
numpy computation, step by step on real AWS tracks: bot positions on their lane lines keyed by centre-line
distance (`np.interp`), the yaw as the path's central difference, the lane-change timers and their random draws,
the smoothstep blend between the lanes, pauses, and the `objects_*` params (global projection onto the centre
line, the even-odd polygon test for left of centre, the order by arc, closest objects, the camera test and the
`features` objects ahead)."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from racerlab.sim import Simulator
from racerlab.sim import _kernels as K
from racerlab.sim import _object_kernels as OK
from racerlab.sim.core import StartRules
from racerlab.sim.objects import CAMERA_HFOV_RAD, CAMERA_PITCH_RAD, FEATURE_OBJECTS, OBSTACLE_Z_M, RaceConfig
from racerlab.sim.sensors.geometry import camera_position
from racerlab.sim.sensors.look import TrackLook
from racerlab.spec import MODEL_POINT_AHEAD_M

DT = 1 / 15


def point_in_ring(px, py, ring):
    """Even-odd test of points against the closed ring (AWS's shapely `Polygon.contains` off the boundary)."""
    x1, y1 = ring[:, 0], ring[:, 1]
    x2, y2 = np.roll(x1, -1), np.roll(y1, -1)
    px, py = px[:, None], py[:, None]
    crosses = (y1 > py) != (y2 > py)
    with np.errstate(divide="ignore", invalid="ignore"):
        xint = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
    return (crosses & (px < xint)).sum(axis=1) % 2 == 1


class Reference:
    """Bot cars computed the plain way, one car and one bot at a time, from the race settings, each car's start
    layout and the random draws the simulator's generator gives (read from a copy of it)."""

    def __init__(self, sim: Simulator):
        o = sim.objects
        self.sim, self.o, self.race = sim, o, sim.race
        self.speed = self.race.bot_car_speed
        self.change_s = self.race.lane_change_distance / self.speed
        self.d0, self.lane, self.rev = o.d0.copy(), o.lane.copy(), o.rev.copy()
        n, m = o.d0.shape
        self.clock = np.zeros(n)
        self.pause_left = np.zeros(n)
        self.change_start = np.full((n, m), np.inf)
        self.change_end = np.zeros((n, m))  # the first change is drawn at the first step

    def lane_xy(self, i, flag, d):
        lanes = self.o.lanes[int(self.rev[i])]
        return lanes.at_centre_dist(int(flag), np.array([d]))[0]  # np.interp, periodic, on the lane keyed by centre

    def bot_xy(self, i, q, clock, dd=0.0):
        d = self.d0[i, q] + self.speed * clock + dd
        here = self.lane_xy(i, self.lane[i, q], d)
        there = self.lane_xy(i, -self.lane[i, q], d)
        a = min(max((clock - self.change_start[i, q]) / self.change_s, 0.0), 1.0)
        w = a * a * (3 - 2 * a)
        return here + w * (there - here)

    def step(self, rng_before):
        """One bot step of every car; the lane-change draws come from `rng_before`, the simulator's generator as
        it was before the step."""
        due = []
        for i in range(self.clock.size):
            if self.pause_left[i] > 1e-9:
                left = self.pause_left[i] - DT
                self.pause_left[i] = left if left > 1e-9 else 0.0
                continue
            self.clock[i] += DT
            due += [(i, q) for q in range(self.d0.shape[1]) if self.clock[i] >= self.change_end[i, q]]
        draws = rng_before.uniform(self.race.lower_lane_change_time, self.race.upper_lane_change_time, len(due))
        for (i, q), u in zip(due, draws, strict=True):
            if self.change_end[i, q] > 0:
                self.lane[i, q] *= -1
            self.change_start[i, q] = self.clock[i] + u
            self.change_end[i, q] = self.change_start[i, q] + self.change_s

    def poses(self):
        h = 0.05 / self.speed
        n, m = self.d0.shape
        xy, yaw = np.zeros((n, m, 2)), np.zeros((n, m))
        for i in range(n):
            for q in range(m):
                xy[i, q] = self.bot_xy(i, q, self.clock[i])
                ahead = self.bot_xy(i, q, self.clock[i] + h) - self.bot_xy(i, q, self.clock[i] - h)
                yaw[i, q] = math.atan2(ahead[1], ahead[0])
        return xy, yaw

    def params(self, xy):
        """(arc, distance from centre, left of centre, order by arc) of objects at xy, each car in its direction."""
        o = self.o
        n, m = xy.shape[:2]
        arc, dfc, left = np.zeros((n, m)), np.zeros((n, m)), np.zeros((n, m), dtype=bool)
        ring = np.vstack([o.lanes[0].track.center, o.lanes[0].track.inner[::-1]])
        for i in range(n):
            track = o.lanes[int(self.rev[i])].track
            proj = track.project(xy[i])  # a search over every segment
            arc[i], dfc[i] = proj.s, np.abs(proj.lateral)
            left[i] = point_in_ring(xy[i, :, 0], xy[i, :, 1], ring) ^ (not track.is_ccw)
        return arc, dfc, left, np.argsort(arc, axis=1, kind="stable")


def h2b(track, cars=6, **kw):
    race = RaceConfig(type="head_to_bot", number_of_bot_cars=3, bot_car_speed=1.0, is_lane_change=True,
                      lower_lane_change_time=0.3, upper_lane_change_time=1.2, lane_change_distance=0.6, **kw)
    return Simulator(track, cars, race=race, seed=5, start=StartRules(alternate_direction=True))


@pytest.mark.parametrize("name", ["reInvent2019_track", "Spain_track"])
def test_bots_step_as_the_plain_computation(aws_track, name):
    sim = h2b(aws_track(name))
    o = sim.objects
    assert o.rev.any() and not o.rev.all()  # both driving directions
    ref = Reference(sim)
    still = np.zeros(sim.num_cars, dtype=bool)  # the cars stand (not stepped): only the bots move
    changes = paused = 0
    for k in range(300):
        if k in (40, 41, 150):  # a bot ran into car 1 (twice: the pause is not restarted) and into car 4
            car = 4 if k == 150 else 1
            o.pause([car])
            if ref.pause_left[car] <= 0:
                ref.pause_left[car] = sim.race.penalty_seconds
        rng_before = copy.deepcopy(sim.rng)
        sim.step(0.0, 0.0, still)
        ref.step(rng_before)
        xy, yaw = ref.poses()
        np.testing.assert_array_equal(o.clock, ref.clock)
        np.testing.assert_array_equal(o.lane, ref.lane)
        np.testing.assert_array_equal(o.change_start, ref.change_start)
        np.testing.assert_array_equal(o.xy, xy)  # to the bit
        np.testing.assert_allclose(o.yaw, yaw, rtol=0, atol=1e-12)
        arc, dfc, left, order = ref.params(o.xy)
        np.testing.assert_array_equal(o.arc, arc)
        np.testing.assert_array_equal(o.dfc, dfc)
        np.testing.assert_array_equal(o.left, left)
        np.testing.assert_array_equal(o.order, order)
        changes += int(((o.clock[:, None] > o.change_start) & (o.clock[:, None] < o.change_end)).sum())
        paused += int((o.pause_left > 0).sum())
    assert changes > 100 and paused > 30  # lane changes blended and pauses waited out, many times over
    assert o.left.any() and not o.left.all()


def test_lane_point_is_numpy_interp_to_the_bit(aws_track):
    sim = h2b(aws_track("reInvent2019_track"), cars=2)
    o = sim.objects
    paths, lane_n, cells, period = o._paths[:4]
    x = np.random.default_rng(0).uniform(-2 * period[0], 4 * period[0], 4000)
    x[:4] = [0.0, period[0], 2 * period[0], -0.0]
    for k in range(4):
        lanes, flag = o.lanes[k // 2], (1, -1)[k % 2]
        want = lanes.at_centre_dist(flag, x)
        got = np.array([OK.lane_point(k, v, period[k // 2], paths, lane_n, cells)[:2] for v in x])
        np.testing.assert_array_equal(got, want)


def test_params_columns_and_features_as_the_plain_computation(aws_track):
    t = aws_track("reInvent2019_track")
    sim = h2b(t, cars=8)
    rng = np.random.default_rng(1)
    seen = 0
    for _ in range(120):
        sim.step(rng.uniform(-30, 30, 8), rng.uniform(0.5, 2.0, 8))
        o, p = sim.objects, sim.params
        idx = np.arange(8)
        mx, my, ms, head = p[:, K.MX], p[:, K.MY], p[:, K.MS], p[:, K.MHEADING]
        yaw = np.radians(head)
        base = (mx - MODEL_POINT_AHEAD_M * np.cos(yaw), my - MODEL_POINT_AHEAD_M * np.sin(yaw), yaw)
        cols = o.params_columns(idx, p[:, K.MX:K.MY + 1], ms, base)
        # closest objects: bisect_right of the model point's arc in the sorted arcs, wrapping around
        for i in idx:
            arcs = o.arc[i][o.order[i]]
            nxt = int(np.searchsorted(arcs, ms[i], side="right"))
            assert cols["closest_objects"][0][i] == o.order[i][(nxt - 1) % 3]
            assert cols["closest_objects"][1][i] == o.order[i][nxt % 3]
            q = cols["closest_objects"][1][i]
            assert cols["object_in_camera"][i] == in_camera(base[0][i], base[1][i], base[2][i], o.xy[i, q],
                                                            o.yaw[i, q], o.half)
            seen += cols["object_in_camera"][i]
        assert cols["objects_location"] == o.xy.tolist() and cols["objects_heading"] == o.yaw.tolist()
        assert cols["objects_left_of_center"] == o.left.tolist() and cols["objects_distance"] == o.arc.tolist()
        feats = sim.features()[:, -2 * FEATURE_OBJECTS:]
        c = sim.car
        for i in idx:
            ahead = np.mod(o.arc[i] - sim.meas[i, K.MS], t.length)
            pick = np.argsort(ahead, kind="stable")[:FEATURE_OBJECTS]
            d = o.xy[i, pick] - c[i, [K.CX, K.CY]]
            cy, sy = math.cos(c[i, K.CYAW]), math.sin(c[i, K.CYAW])
            want = np.column_stack([d[:, 0] * cy + d[:, 1] * sy, -d[:, 0] * sy + d[:, 1] * cy]).ravel() * 0.5
            np.testing.assert_allclose(feats[i], want, rtol=0, atol=1e-12)
    assert seen > 0


def in_camera(bx, by, byaw, oxy, oyaw, half):
    """The next object's centre or a footprint corner at box height inside the camera frustum (by hand), the camera
    at the height the AWS look renders it from (0.163 m), so the param agrees with the frame the model sees."""
    cam_ahead, cam_z = camera_position()[0], TrackLook().camera_z
    cx, cy = bx + cam_ahead * math.cos(byaw), by + cam_ahead * math.sin(byaw)
    tan_h = math.tan(CAMERA_HFOV_RAD / 2)
    for du, dv in ((0, 0), (half[0], half[1]), (half[0], -half[1]), (-half[0], half[1]), (-half[0], -half[1])):
        px = oxy[0] + du * math.cos(oyaw) - dv * math.sin(oyaw) - cx
        py = oxy[1] + du * math.sin(oyaw) + dv * math.cos(oyaw) - cy
        fwd = px * math.cos(byaw) + py * math.sin(byaw)
        left = -px * math.sin(byaw) + py * math.cos(byaw)
        dz = OBSTACLE_Z_M - cam_z
        depth = fwd * math.cos(CAMERA_PITCH_RAD) - dz * math.sin(CAMERA_PITCH_RAD)
        up = fwd * math.sin(CAMERA_PITCH_RAD) + dz * math.cos(CAMERA_PITCH_RAD)
        if 0.02 < depth < 300 and abs(left) <= depth * tan_h and abs(up) <= depth * tan_h * 3 / 4:
            return True
    return False
