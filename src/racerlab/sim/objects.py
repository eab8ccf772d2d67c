"""Objects on the track (object avoidance): the race settings, AWS obstacle placement, the crash rule, and the
`objects_*` reward params.

Every car of a batch has its own objects (`ObjectSet`, arrays with the car axis first), placed again at each
of its resets as the AWS simulator does (`ObstaclesCtrl.reset_agent`, reference next_capabilities §A.1):

- `object_positions` ((fraction of the lap, lane) pairs) put the boxes where they say: lane 1 is the inner
  lane, -1 the outer one;
- otherwise `number_of_obstacles` start evenly spaced at `linspace(min_d, L - 1, N)` metres of arc length,
  lanes alternating from the inner one; with `randomize_obstacle_locations` each box in a shuffled order is
  re-drawn uniformly between its neighbours (keeping `min_d` to each, the first at least `min_d` from the
  start line, the last at most `L - 1`), then every box gets a random lane;
- a box stands on its lane line (the midline between centre line and border) at the point nearest the centre
  line's point at that arc length, turned along the lane.

`min_distance_between_obstacles` is a percentage of the lap, `min_d = value / 100 * L`, every episode. AWS
converts the stored value again at every reset (the value shrinks by L/100 each episode: 0.46 m, 0.107 m,
0.025 m ... on reInvent2019), so from the third episode on its random layouts have no minimum gap; racerlab
keeps the intended minimum (the difference is written down in docs/objects.md).

Bot cars (`BotCarsCtrl`, next_capabilities §A.2) start like boxes (min distance in metres, their own
`randomize_bot_car_locations`) and drive their lane keyed by centre-line distance, changing lanes every
U(lower, upper) s over `lane_change_distance` m; they pause `penalty_seconds` after one ran into the car. In a
head-to-model race each car's one object is the other car of its pair. docs/objects.md has the details and the
differences from AWS.

Crash rule (facts §2, next_capabilities §A.4): a car has crashed when one of the four corners of its footprint
(0.32352 m long x 0.1961 m wide, centred on the base pose) lies strictly inside an object's footprint (a box's
is 0.5 m along its lane x 0.4 m across, the box plus 0.1 m; a car's is its own). Only the car's corners are
tested; a car (bot or racer) counts only when it is ahead: the car ran into it.
"""

from __future__ import annotations

import functools
import math

import numpy as np
from numba import njit

from racerlab.errors import ConfigError
from racerlab.sim import _kernels as K
from racerlab.sim import _object_kernels as OK
from racerlab.sim.sensors.geometry import AWS_CAMERA_HEIGHT_M, CAMERA_HFOV_RAD, CAMERA_PITCH_RAD, camera_position
from racerlab.spec import MODEL_POINT_AHEAD_M, RaceConfig
from racerlab.track import Track
from racerlab.track.kernels import build_road_index, contains_many

BOX_SIZE_M = (0.40, 0.30)  # the box model (along the lane, across): what the lidar and camera see
BOX_FOOTPRINT_M = (0.5, 0.4)  # (along the lane, across): ObstacleDimensions.BOX_OBSTACLE_DIMENSION (0.4, 0.5)
CAR_FOOTPRINT_M = (0.32352, 0.1961)  # (length, width): BOT_CAR_DIMENSION, the agent's crash footprint
OBSTACLE_Z_M = 0.1
END_MARGIN_M = 1.0  # the last obstacle stays this far before the end of the lap
FEATURE_OBJECTS = 2  # the `features` observation gains the nearest objects ahead, (x ahead, y left) / 2 m each
RESET_BEHIND_DIST_M = 1.0  # evaluation: after a crash the car restarts this far behind the box, other lane
CLOSEST_OBJ_GAP_M = 1.0  # a start this near an object moves to the other lane (rollout_agent_ctrl)
MOVED_STARTS_KEPT = 4096  # moved start poses remembered (the cache starts afresh when full)
CAMERA_ASPECT = 4 / 3  # 640 x 480
CAMERA_FAR_M = 300.0
CAMERA_NEAR_M = 0.02
RING_BAND_M = 0.05  # band height of the index of the centre/inner-border polygon's edges (objects_left_of_center)


def as_race(value) -> RaceConfig | None:
    """A `RaceConfig`, its keyword dict, a race type name, or None (a time trial)."""
    if value is None or isinstance(value, RaceConfig):
        return value
    if isinstance(value, str):
        return RaceConfig(type=value, number_of_obstacles=6 if value == "object_avoidance" else 0)
    return RaceConfig.from_mapping(value)


# ---- placement -----------------------------------------------------------------------------------------
def _spread(n: int, first: float, last: float, min_d: float, randomize: bool, strict: bool,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """AWS's layout of n objects: evenly spaced over [first, last] with lanes alternating from the inner one;
    randomised, each object in a shuffled order is re-drawn uniformly between its neighbours keeping `min_d` to
    each (left in place when there is no room; bots need a non-empty interval, `strict`), then every object gets
    a random lane."""
    d = np.linspace(first, last, n)
    if not randomize:
        return d, np.where(np.arange(n) % 2 == 0, 1, -1)
    for i in rng.permutation(n):
        lo = d[i - 1] + min_d if i > 0 else first
        hi = d[i + 1] - min_d if i < n - 1 else last
        if lo < hi or (lo == hi and not strict):
            d[i] = rng.uniform(lo, hi)
    return d, rng.choice(np.array([1, -1]), size=n)


def obstacle_arcs(race: RaceConfig, length: float, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(arc lengths along the centre line in m, lanes +1 inner / -1 outer) of one episode's objects."""
    last = length - END_MARGIN_M
    if race.num_bot_cars:  # BotCarsCtrl: min distance in metres
        return _spread(race.num_bot_cars, race.min_distance_between_bot_cars, last,
                       race.min_distance_between_bot_cars, race.randomize_bot_car_locations, True, rng)
    if race.object_positions:
        pos = np.array(race.object_positions, dtype=np.float64)
        return pos[:, 0] * length, pos[:, 1].astype(np.int64)
    n = race.num_obstacles
    min_d = race.min_distance_between_obstacles / 100.0 * length
    if n and min_d > last:
        raise ConfigError(f"{race.where}: min_distance_between_obstacles {race.min_distance_between_obstacles} % "
                          f"of this {length:.2f} m lap leaves no room for obstacles; use a smaller value")
    return _spread(n, min_d, last, min_d, race.randomize_obstacle_locations, False, rng)


def _lane(track: Track, border: np.ndarray) -> Track:
    """The lane line between the centre line and `border`, as a polyline with arc length and projection."""
    mid = 0.5 * (track.center + border)
    return Track("lane", mid, mid, mid, track.closed)


class Lanes:
    """The inner and outer lane lines of a track in one driving direction."""

    def __init__(self, track: Track):
        self.track = track
        self.inner = _lane(track, track.inner)
        self.outer = _lane(track, track.outer)

    @functools.cached_property
    def by_centre(self) -> dict[int, tuple[np.ndarray, np.ndarray]]:
        """Per lane (+1 inner, -1 outer): (u, xy), the lane's points keyed by the centre-line arc length of their
        projection, sorted and de-duplicated, as AWS keys the lane splines bot cars drive (`TrackSpline`)."""
        out = {}
        for flag, lane in ((1, self.inner), (-1, self.outer)):
            u, first = np.unique(self.track.project(lane.center).s, return_index=True)
            out[flag] = (u, lane.center[first])
        return out

    def interp_arrays(self, flag: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(u, x, y) of lane `flag` as `at_centre_dist`'s np.interp works on them: on a loop taken modulo the lap,
        sorted and padded with one point either side (numpy's periodic interpolation), for the compiled paths."""
        u, xy = self.by_centre[flag]
        if not self.track.closed:
            return u, xy[:, 0], xy[:, 1]
        period = self.track.length
        xp = u % period
        order = np.argsort(xp)
        xp, fx, fy = xp[order], xy[order, 0], xy[order, 1]
        return (np.concatenate((xp[-1:] - period, xp, xp[:1] + period)), np.concatenate((fx[-1:], fx, fx[:1])),
                np.concatenate((fy[-1:], fy, fy[:1])))

    def at_centre_dist(self, flag: int, d: np.ndarray) -> np.ndarray:
        """Points (k, 2) of lane `flag` at centre-line distances `d` (linear between the lane's points; on a
        loop the distances wrap around the lap)."""
        u, xy = self.by_centre[flag]
        period = self.track.length if self.track.closed else None
        return np.stack([np.interp(d, u, xy[:, 0], period=period), np.interp(d, u, xy[:, 1], period=period)], -1)

    def poses(self, arcs: np.ndarray, lanes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(xy (m, 2), yaw (m,)) of boxes at centre-line arc lengths `arcs` on `lanes` (+1 inner, -1 outer)."""
        xy = np.empty((arcs.size, 2))
        yaw = np.empty(arcs.size)
        centre = self.track.point_at(arcs).reshape(-1, 2)
        for flag, lane in ((1, self.inner), (-1, self.outer)):
            sel = lanes == flag
            if sel.any():
                proj = lane.project(centre[sel])
                xy[sel] = lane.point_at(proj.s)
                yaw[sel] = proj.heading
        return xy, yaw


@njit(cache=True, inline="always")
def _car_corners_inside(bx, by, yaw, oxy, oyaw, half_len, half_wid, out, memo):
    """out[q] = a corner of the car footprint (CAR_FOOTPRINT_M) at base pose (bx, by, yaw) lies strictly inside
    object q's footprint rectangle (half sizes half_len, half_wid around oxy[q], turned by oyaw[q]). memo (3, m)
    keeps each object's last yaw with its cos and sin (the objects of many cars stand alike)."""
    hl = 0.5 * CAR_FOOTPRINT_M[0]
    hw = 0.5 * CAR_FOOTPRINT_M[1]
    far = _crash_reach(half_len, half_wid)
    c = math.cos(yaw)
    s = math.sin(yaw)
    for q in range(oxy.shape[0]):
        ex = bx - oxy[q, 0]
        ey = by - oxy[q, 1]
        if ex * ex + ey * ey > far * far:
            continue
        if oyaw[q] != memo[0, q]:
            memo[0, q] = oyaw[q]
            memo[1, q] = math.cos(oyaw[q])
            memo[2, q] = math.sin(oyaw[q])
        co = memo[1, q]
        so = memo[2, q]
        for a, b in ((hl, hw), (hl, -hw), (-hl, hw), (-hl, -hw)):
            dx = bx + a * c - b * s - oxy[q, 0]
            dy = by + a * s + b * c - oxy[q, 1]
            if abs(dx * co + dy * so) < half_len and abs(-dx * so + dy * co) < half_wid:
                out[q] = True
                break


@njit(cache=True, inline="always")
def _crash_reach(half_len, half_wid):
    """A corner lies within the car's half diagonal of its base, a footprint point within the object's of its
    centre: an object further from the base than the two together (plus a hair) cannot hold a corner."""
    return math.hypot(0.5 * CAR_FOOTPRINT_M[0], 0.5 * CAR_FOOTPRINT_M[1]) + math.hypot(half_len, half_wid) + 1e-9


@njit(cache=True)
def _corners_inside(bx, by, yaw, rows, oxy, oyaw, half_len, half_wid):
    """(k, m) bool: a corner of the car footprint at base pose (bx[j], by[j], yaw[j]) lies strictly inside one of
    the objects oxy[rows[j]] (`_car_corners_inside`). Compiled: it runs for every car at every step."""
    out = np.zeros((bx.size, oxy.shape[1]), dtype=np.bool_)
    memo = np.full((3, oxy.shape[1]), np.nan)
    for j in range(bx.size):
        _car_corners_inside(bx[j], by[j], yaw[j], oxy[rows[j]], oyaw[rows[j]], half_len, half_wid, out[j], memo)
    return out


@njit(cache=True)
def _model_point_corners_inside(rows, meas, cx, cy, cheading, oxy, oyaw, half_len, half_wid, out, memo):
    """`_corners_inside` into out (k, m) for cars rows[j] measured at model point (meas[i, cx], meas[i, cy]) with
    heading meas[i, cheading] (°): the base pose is `MODEL_POINT_AHEAD_M` behind it (`base_from_model_point`). Cars
    with no object near the model point are passed over without working out the pose. Returns the number of (car,
    object) pairs found. (The arrays are the caller's: a new array handed back to Python costs more than the
    test.)"""
    out[:] = False
    memo[:] = np.nan
    count = 0
    near = _crash_reach(half_len, half_wid) + MODEL_POINT_AHEAD_M + 1e-6
    for j in range(rows.size):
        i = rows[j]
        mx = meas[i, cx]
        my = meas[i, cy]
        for q in range(oxy.shape[1]):
            if (mx - oxy[i, q, 0]) ** 2 + (my - oxy[i, q, 1]) ** 2 <= near * near:
                yaw = np.radians(meas[i, cheading])
                _car_corners_inside(mx - MODEL_POINT_AHEAD_M * math.cos(yaw), my - MODEL_POINT_AHEAD_M * math.sin(yaw),
                                    yaw, oxy[i], oyaw[i], half_len, half_wid, out[j], memo)
                count += out[j].sum()
                break
    return count


@njit(cache=True)
def _nearest_object(rows, oxy, pts):
    """(distance, index) of the object of car rows[j] nearest to point pts[j] (the first of equals)."""
    dist = np.empty(rows.size)
    nearest = np.zeros(rows.size, dtype=np.int64)
    for j in range(rows.size):
        dist[j] = np.inf
        for q in range(oxy.shape[1]):
            d = math.hypot(oxy[rows[j], q, 0] - pts[j, 0], oxy[rows[j], q, 1] - pts[j, 1])
            if d < dist[j]:
                dist[j] = d
                nearest[j] = q
    return dist, nearest


def _camera_constants() -> np.ndarray:
    """The camera frustum as `_object_kernels.closest_and_in_camera` takes it (HFOV 1.13 rad, 4:3, pitched down
    0.2618 rad, 0.02-300 m; the camera's place on the car, at the height the AWS look puts it; objects seen at
    OBSTACLE_Z_M)."""
    cam_ahead, cam_z = camera_position()[0], AWS_CAMERA_HEIGHT_M
    tan_h = math.tan(CAMERA_HFOV_RAD / 2)
    return np.array([cam_ahead, cam_z, OBSTACLE_Z_M, math.cos(CAMERA_PITCH_RAD), math.sin(CAMERA_PITCH_RAD), tan_h,
                     tan_h / CAMERA_ASPECT, CAMERA_NEAR_M, CAMERA_FAR_M])


CAMERA = _camera_constants()


class ObjectSet:
    """The objects of every car of a simulator: per car `m` boxes, bot cars (`bots`, driven by `advance`) or,
    in a head-to-model race (`racers`), the other car of its pair (set by `follow`), with their params.

    Arrays (car axis first): `xy` (n, m, 2), `yaw` (n, m), `arc` (n, m: centre-line projection in the car's
    driving direction, the param `objects_distance`), `dfc` (n, m), `left` (n, m).
    """

    def __init__(self, race: RaceConfig, track: Track, track_reversed: Track, num_cars: int, rng):
        self.race = race
        self.rng = rng
        self.lanes = (Lanes(track), Lanes(track_reversed))
        self._ccw = (track.is_ccw, track_reversed.is_ccw)
        self.bots = race.num_bot_cars > 0
        self.racers = race.head_to_model  # each car's one object is the other car of its pair
        if self.racers and num_cars % 2:
            raise ConfigError(f"{race.where}: a head_to_model race pairs the cars; use an even number of cars, "
                              f"not {num_cars}")
        m = race.num_bot_cars if self.bots else 1 if self.racers else race.num_obstacles
        self.num_objects = m
        cars = self.bots or self.racers
        foot = CAR_FOOTPRINT_M if cars else BOX_FOOTPRINT_M
        self.half = (0.5 * foot[0], 0.5 * foot[1])
        self.box_size_m = np.array(CAR_FOOTPRINT_M if cars else BOX_SIZE_M)
        self.speed = race.bot_car_speed if self.bots else 0.0
        self.rev = np.zeros(num_cars, dtype=np.bool_)
        self.xy = np.zeros((num_cars, m, 2))
        self.yaw = np.zeros((num_cars, m))
        self.arc = np.zeros((num_cars, m))
        self.dfc = np.zeros((num_cars, m))
        self.left = np.zeros((num_cars, m), dtype=np.bool_)
        self.lane = np.zeros((num_cars, m), dtype=np.int64)  # a bot's lane (the one it leaves in a lane change)
        self.order = np.zeros((num_cars, m), dtype=np.int64)  # objects sorted by `arc`
        self._lists: list = [None] * num_cars
        self._moved_starts = MovedStarts()  # (reversed, box lane, x, y) of a start near a box -> its moved pose
        # bot cars: start distance along the centre line, the bots' clock (s driven, pauses excluded), the pause
        # left after a bot rear-ended the car, the current lane change (clock times; inf: none)
        self.d0 = np.zeros((num_cars, m))
        self.clock = np.zeros(num_cars)
        self.pause_left = np.zeros(num_cars)
        self.change_start = np.full((num_cars, m), np.inf)
        self.change_end = np.full((num_cars, m), np.inf)
        # the centre-line segment each object's projection found last: the next search starts there (-1: search
        # everywhere)
        self._hint = np.full((num_cars, m), -1, dtype=np.int64)
        self._bot_cache: dict = {}
        self._no_due, self._no_draws = np.zeros((0, 2), dtype=np.int64), np.zeros(0)
        speed = self.speed
        self.change_s = race.lane_change_distance / speed if speed > 0 else np.inf
        self.lane_changes = self.bots and race.is_lane_change and speed > 0
        # fixed and evenly spaced boxes stand in the same places every episode: each direction's layout is
        # placed once and then copied, so that a reset costs microseconds instead of a millisecond per car
        self._layouts: dict | None = ({} if (race.object_positions or not race.randomize_obstacle_locations)
                                      and not (self.bots or self.racers) else None)

    def place(self, idx: np.ndarray, reversed_: np.ndarray) -> None:
        """New layouts for cars `idx` (each in its driving direction `reversed_`)."""
        idx = np.asarray(idx, dtype=np.int64)
        if self._layouts is not None:
            self._copy_layouts(idx, np.asarray(reversed_, dtype=bool))
            return
        revs = np.asarray(reversed_, dtype=bool)
        if self.bots and not self.race.randomize_bot_car_locations:  # evenly spaced: the same start every reset
            OK.bots_start(idx, revs, *self._bot_starts, self.lane_changes, self.rev, self.d0, self.lane, self.clock,
                          self.pause_left, self.change_start, self.change_end, self._hint)
            self._drive(idx)
            return
        self.rev[idx] = revs
        self._hint[idx] = -1
        if self.racers:  # the other car is placed by the simulator (`follow`)
            return
        for i, rev in zip(idx.tolist(), revs.tolist(), strict=True):  # random layouts, drawn car by car
            lanes = self.lanes[int(rev)]
            arcs, lane = obstacle_arcs(self.race, lanes.track.length, self.rng)
            self.lane[i] = lane
            if self.bots:
                self.d0[i] = arcs
            else:
                self.xy[i], self.yaw[i] = lanes.poses(arcs, lane)
                self._measure(i)
        if self.bots:
            self.clock[idx] = 0.0
            self.pause_left[idx] = 0.0
            self.change_start[idx] = np.inf
            self.change_end[idx] = 0.0 if self.lane_changes else np.inf  # 0: the first change is drawn at once
            self._drive(idx)

    @functools.cached_property
    def _bot_starts(self) -> tuple[np.ndarray, np.ndarray]:
        """(centre-line distances, lanes) (2, m) where evenly spaced bots start in each driving direction (no
        randomness in them: worked out once)."""
        starts = [obstacle_arcs(self.race, lanes.track.length, self.rng) for lanes in self.lanes]
        return np.stack([a for a, _ in starts]), np.stack([b for _, b in starts]).astype(np.int64)

    def advance(self, idx, dt: float) -> None:
        """The bot cars of cars `idx` one step of `dt` s on (BotCarsCtrl): paused bots wait out their penalty,
        the others drive their lane at `bot_car_speed` and change lanes when their next change comes. They never
        react to the car. One compiled pass for the clocks, the random draws of the lane changes that came due
        (in car-then-bot order), one compiled pass for the poses and params."""
        idx = np.asarray(idx, dtype=np.int64)
        run, due = self._buffers(idx.size)
        nrun, ndue = OK.bots_tick(idx, dt, self.pause_left, self.clock, self.change_end, self.lane_changes, run, due)
        if nrun:
            self._drive(run[:nrun], due[:ndue])

    def _buffers(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Scratch arrays for `bots_tick`: k running cars and their k * m due bots."""
        run, due = self._bot_cache.get("buffers", (np.empty(0, dtype=np.int64), None))
        if run.size < k:
            run, due = np.empty(k, dtype=np.int64), np.empty((k * self.num_objects, 2), dtype=np.int64)
            self._bot_cache["buffers"] = (run, due)
        return run, due

    @functools.cached_property
    def _paths(self) -> tuple:
        """The bots' lane paths as the kernels take them (`_object_kernels`): for (direction, lane) 2 * reversed +
        (0 inner, 1 outer) the path arrays (4, 5, P), their lengths and lookup tables, and each direction's period
        (0 on an open track)."""
        arrays = [lanes.interp_arrays(flag) for lanes in self.lanes for flag in (1, -1)]
        size = max(a[0].size for a in arrays)
        packed = [OK.lane_arrays(*a, size, size) for a in arrays]
        period = np.array([lanes.track.length if lanes.track.closed else 0.0 for lanes in self.lanes])
        # per lane segment: the centre segments that can be nearest to its points, and its side of the polygon
        edges, band_start, band_edges, y0, band_h = self._geometry[4:9]

        def inside(pts):
            out = np.empty(pts.shape[0], dtype=np.bool_)
            contains_many(np.ascontiguousarray(pts), edges, band_start, band_edges, y0, band_h, out)
            return out

        near_start, side = np.zeros((4, size + 1), dtype=np.int64), np.zeros((4, size), dtype=np.int64)
        near = []
        for k, (_, x, y) in enumerate(arrays):
            start, lst, sides = OK.lane_segments(np.column_stack([x, y]), self.lanes[k // 2].track.center,
                                                 self._ring, inside)
            offset = sum(v.size for v in near)
            near_start[k, :start.size] = start + offset
            near_start[k, start.size:] = start[-1] + offset
            side[k, :sides.size] = sides
            near.append(lst)
        return (np.stack([p[0] for p in packed]), np.array([a[0].size for a in arrays], dtype=np.int64),
                np.stack([p[1] for p in packed]), period, near_start, np.concatenate(near), side)

    def _drive(self, run: np.ndarray, due: np.ndarray | None = None) -> None:
        """Poses of the bots of cars `run` at their clocks: on their lane at `d0 + speed * clock` of centre line,
        blended into the other lane during a lane change (smoothstep of the change's elapsed share, so the path
        leaves and joins the lane lines tangentially); the yaw is the path's direction (a central difference over
        +-5 cm of centre line); then their params (`_measure`), all in one compiled pass. Bots `due` (car, bot)
        first end their lane change, if one ended, and get the next: it ends U(lower, upper) s plus the change's
        duration (`lane_change_distance / bot_car_speed`) from now (AWS's timers; drawn in car-then-bot order)."""
        r = self.race
        if due is None or due.shape[0] == 0:
            due, draws = self._no_due, self._no_draws
        else:
            draws = self.rng.uniform(r.lower_lane_change_time, r.upper_lane_change_time, due.shape[0])
        h = 0.05 / self.speed if self.speed > 0 else 0.0  # the clock time of 5 cm
        OK.bots_drive(run, due, draws, self.rev, self.clock, self.d0, self.lane, self.change_start, self.change_end,
                      self.speed, self.change_s, self.lane_changes, h, *self._paths, self.xy, self.yaw,
                      *self._geometry, self._hint, self.arc, self.dfc, self.left, self.order)

    def follow(self, x, y, yaw, rows=None) -> None:
        """Head-to-model: each car's object is the other car of its pair, at base pose (x, y, yaw) (per car of
        the simulator); `rows` (all by default) are the cars whose object is updated."""
        rows = np.arange(x.size) if rows is None else np.asarray(rows, dtype=np.int64)
        other = rows ^ 1
        self.xy[rows, 0, 0] = x[other]
        self.xy[rows, 0, 1] = y[other]
        self.yaw[rows, 0] = yaw[other]
        self._measure(rows)

    def pause(self, rows) -> None:
        """The bots of cars `rows` stop for `penalty_seconds` (one of them rear-ended the car): AWS holds all bot
        cars, moving their clock and lane-change timers on by the penalty."""
        if not self.bots:
            return
        rows = np.asarray(rows, dtype=np.int64)
        rows = rows[self.pause_left[rows] <= 0.0]
        self.pause_left[rows] = self.race.penalty_seconds

    @functools.cached_property
    def _ring(self) -> np.ndarray:
        """The polygon between centre line and inner border (AWS's test for `objects_left_of_center`)."""
        track = self.lanes[0].track
        return np.vstack([track.center, track.inner[::-1]])

    @functools.cached_property
    def _geometry(self) -> tuple:
        """The track arrays `_object_kernels.measure` takes: both directions' centre lines (points, segment
        lengths, arc lengths), the polygon between centre line and inner border as edges by horizontal band, and
        each direction's counter-clockwise flag."""
        tracks = [lanes.track for lanes in self.lanes]
        ring = self._ring
        edges = np.column_stack([ring, np.roll(ring, -1, axis=0)])
        edges = np.ascontiguousarray(edges[edges[:, 1] != edges[:, 3]])  # a level edge is never crossed
        return (np.stack([t.center for t in tracks]), np.stack([t.segment_lengths for t in tracks]),
                np.stack([t.waypoint_s for t in tracks]), tracks[0].closed, edges,
                *build_road_index(edges, RING_BAND_M), np.array(self._ccw))

    def _measure(self, rows) -> None:
        """The static params of the objects of cars `rows` (an index, or an array of them) at their current poses
        in one compiled pass: centre-line arc and distance of their projection in the car's driving direction, left
        of centre as AWS has it (inside the polygon between centre line and inner border, XOR not counter-clockwise
        in the driving direction) and the order by arc."""
        rows = np.atleast_1d(np.asarray(rows, dtype=np.int64))
        OK.measure(rows, self.rev, self.xy, *self._geometry, self._hint, self.arc, self.dfc, self.left, self.order)
        if not (self.bots or self.racers):  # boxes keep their params lists between resets
            for i in rows.tolist():
                self._lists[i] = None

    def _params_lists(self, idx: np.ndarray) -> tuple[list, ...]:
        """The per-object params of cars `idx` as columns of lists, one list per car: location, left of centre,
        distance, distance from centre, heading (AWS fills it for bots only). Moving objects' lists are made for
        the batch at once; boxes make theirs once per layout (they stand still between resets) and the locations
        are copied (the params dicts own their lists)."""
        if self.bots or self.racers:
            heading = self.yaw[idx].tolist() if self.bots else [[0.0] * self.num_objects for _ in range(idx.size)]
            return (self.xy[idx].tolist(), self.left[idx].tolist(), self.arc[idx].tolist(), self.dfc[idx].tolist(),
                    heading)
        cars = []
        for i in idx.tolist():
            if self._lists[i] is None:
                self._lists[i] = (self.xy[i].tolist(), self.left[i].tolist(), self.arc[i].tolist(),
                                  self.dfc[i].tolist(), [0.0] * self.num_objects)
            cars.append(self._lists[i])
        return ([[[*p] for p in t[0]] for t in cars], *([t[k] for t in cars] for k in range(1, 5)))

    def _copy_layouts(self, idx: np.ndarray, reversed_: np.ndarray) -> None:
        """Give cars `idx` the layout of their direction, placed once by a one-car ObjectSet (every per-car array).
        A car that already holds its direction's layout keeps it: nothing moves boxes between resets."""
        holds = self._layouts.get("holds")
        if holds is None:
            holds = self._layouts["holds"] = np.full(self.xy.shape[0], -1, dtype=np.int64)
        if (holds[idx] == reversed_).all():  # every car holds its direction's layout already (most resets)
            return
        for rev in (False, True):
            rows = idx[(reversed_ == rev) & (holds[idx] != int(rev))]
            if rows.size == 0:
                continue
            holds[rows] = int(rev)
            one = self._layouts.get(rev)
            if one is None:
                one = ObjectSet(self.race, self.lanes[0].track, self.lanes[1].track, 1, self.rng)
                one._layouts = None
                one.place([0], [rev])
                self._layouts[rev] = one
            for mine, value in self._per_car_arrays(one):
                mine[rows] = value[0]
            for i in rows.tolist():
                self._lists[i] = one._lists[0]

    def _per_car_arrays(self, one: ObjectSet) -> list:
        """(this set's array, the one-car set's array) for every per-car array (car axis first; names listed once)."""
        key = ("arrays", id(one))
        if key not in self._layouts:
            n = self.xy.shape[0]
            self._layouts[key] = [k for k, v in vars(one).items()
                                  if isinstance(v, np.ndarray) and v.shape[:1] == (1,)
                                  and getattr(self, k).shape[:1] == (n,)]
        return [(getattr(self, k), getattr(one, k)) for k in self._layouts[key]]

    def clear_starts(self, idx, reversed_, pts: np.ndarray, yaw: np.ndarray) -> None:
        """Move start poses (centre-line points `pts`, headings `yaw`, in place) that are within 1 m of one of
        the car's objects onto the lane on the other side of that object, as AWS starts a training episode."""
        if self.num_objects == 0 or len(idx) == 0:
            return
        # where a start moves depends on the track alone (the start point, direction and lane): each is worked
        # out once, as training restarts from the same few points over and over; one compiled pass looks them up
        idx = np.asarray(idx, dtype=np.int64)
        revs = np.asarray(reversed_, dtype=np.bool_)
        cache = self._moved_starts
        found = cache.apply(idx, revs, self.xy, self.lane, pts, yaw)
        if found is None:  # (most resets)
            return
        new, box_lane = found
        moved_pts, moved_yaw = self._moved(revs[new], box_lane, pts[new], yaw[new])
        cache.add(revs[new], box_lane, pts[new], moved_pts, moved_yaw)
        pts[new], yaw[new] = moved_pts, moved_yaw

    def _moved(self, revs, box_lane, pts, yaw) -> tuple[np.ndarray, np.ndarray]:
        """Start points `pts` (k, 2) with headings `yaw` moved onto the lane on the other side of their box (in
        driving direction `revs`, the box on lane `box_lane`): the nearest point of that lane and its heading."""
        pts, yaw = pts.copy(), yaw.copy()
        for rev in (False, True):
            lanes = self.lanes[int(rev)]
            for flag, lane in ((1, lanes.outer), (-1, lanes.inner)):  # the lane on the box's other side
                sel = (revs == rev) & (box_lane == flag)
                if sel.any():
                    proj = lane.project(pts[sel])
                    pts[sel] = lane.point_at(proj.s).reshape(-1, 2)
                    yaw[sel] = proj.heading
        return pts, yaw

    def features_ahead(self, rows, car: np.ndarray, meas: np.ndarray, length: float, out: np.ndarray,
                       column: int) -> None:
        """Fill out[i, column:column + 2 * FEATURE_OBJECTS] for each car i of `rows`, at its base pose and centre-line
        arc in the simulator's arrays `car` and `meas`: its nearest objects ahead along the lap, in the car's frame
        (x ahead, y left) divided by 2 m, as the centre points of `features`; with fewer objects the list repeats
        from the nearest."""
        OK.features_ahead(np.asarray(rows, dtype=np.int64), car, meas, K.CX, K.CY, K.CYAW, K.MS, float(length),
                          self.arc, self.xy, out, column, FEATURE_OBJECTS)

    def nearest(self, i: int, mx: float, my: float) -> int:
        """The index of car i's object nearest to the point (mx, my)."""
        return int(np.argmin(np.hypot(self.xy[i, :, 0] - mx, self.xy[i, :, 1] - my)))

    def reset_behind(self, i: int, reversed_: bool, mx: float, my: float,
                     along: float = -RESET_BEHIND_DIST_M) -> tuple[float, float, float, float]:
        """AWS's evaluation reset after car i (model point mx, my) hit a box: (x, y, yaw) on the lane opposite
        the nearest box, `RESET_BEHIND_DIST_M` of centre line behind it (`along` m from it: a mercy reset passes
        its `reset_ahead_dist`), and that point's centre-line arc."""
        k = self.nearest(i, mx, my)
        lanes = self.lanes[int(reversed_)]
        t = lanes.track
        s = self.arc[i, k] + along
        s = s % t.length if t.closed else max(s, 0.0)
        lane = lanes.outer if self.lane[i, k] == 1 else lanes.inner
        proj = lane.project(t.point_at(s).reshape(1, 2))
        x, y = lane.point_at(proj.s)[0]
        return float(x), float(y), float(proj.heading[0]), float(s)

    def crashed(self, bx, by, yaw, rows=None, car_arc=None, length: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Per car (`rows`, all by default) at base pose (bx, by, yaw): (crashed, rear_ended). A corner of the car
        inside one of its objects' footprints is a crash; with bot cars only when the bot is ahead of the car (its
        front point within half a lap ahead of the car's centre-line arc `car_arc`): the car ran into it. A bot
        behind the car ran into the car: `rear_ended`, not the car's crash (AWS compares the two progresses)."""
        rows = np.arange(bx.size) if rows is None else np.asarray(rows, dtype=np.int64)
        inside = _corners_inside(np.asarray(bx, dtype=np.float64), np.asarray(by, dtype=np.float64),
                                 np.asarray(yaw, dtype=np.float64), rows, self.xy, self.yaw, *self.half)  # (k, m)
        return self._judge(inside, rows, car_arc, length)

    def crashed_at_model_point(self, meas, rows, length: float) -> tuple[np.ndarray, np.ndarray] | None:
        """`crashed` for cars `rows` measured as the simulator's measurement rows `meas` (n, N_MEAS) give them: the
        model point, heading (°) and centre-line arc; the base pose as `base_from_model_point` gives it. None when
        no corner of any of these cars is inside an object (neither crashed nor rear-ended)."""
        rows = np.asarray(rows, dtype=np.int64)
        inside = np.empty((rows.size, self.num_objects), dtype=np.bool_)
        count = _model_point_corners_inside(rows, meas, K.MX, K.MY, K.MHEADING, self.xy, self.yaw, *self.half, inside,
                                            np.empty((3, self.num_objects)))
        if count == 0:  # no car touches an object (most steps)
            return None
        car_arc = meas[rows, K.MS] if self.bots or self.racers else None
        return self._judge(inside, rows, car_arc, length)

    def _judge(self, inside, rows, car_arc, length) -> tuple[np.ndarray, np.ndarray]:
        """(crashed, rear_ended) per car from `inside` (k, m): which objects hold a corner of the car."""
        if not (self.bots or self.racers) or car_arc is None:
            return inside.any(axis=1), np.zeros(rows.size, dtype=bool)
        crashed, rear = np.empty(rows.size, dtype=bool), np.empty(rows.size, dtype=bool)
        OK.judge_cars(inside, rows, np.asarray(car_arc, dtype=np.float64), float(length), self.rev, self.xy, self.yaw,
                      *self._geometry[:4], crashed, rear)
        return crashed, rear

    def params_columns(self, idx, model_xy, model_s, base_pose) -> dict:
        """The `objects_*` params columns for cars `idx`: the model point's xy (k, 2) and centre-line arc (k,),
        and the base pose (x, y, yaw) for the camera test (the next object's centre or a footprint corner, at box
        height, inside the camera frustum)."""
        idx = np.asarray(idx, dtype=np.int64)
        prev_obj = np.empty(idx.size, dtype=np.int64)
        next_obj = np.empty(idx.size, dtype=np.int64)
        in_cam = np.empty(idx.size, dtype=np.bool_)
        bx, by, byaw = (np.asarray(v, dtype=np.float64) for v in base_pose)
        OK.closest_and_in_camera(idx, np.asarray(model_s, dtype=np.float64), bx, by, byaw, self.arc, self.order,
                                 self.xy, self.yaw, *self.half, CAMERA, prev_obj, next_obj, in_cam)
        location, left, distance, dfc, heading = self._params_lists(idx)
        return {
            "closest_objects": (prev_obj.tolist(), next_obj.tolist()),
            "objects_location": location,
            "objects_left_of_center": left,
            "objects_distance": distance,
            "objects_distance_from_center": dfc,
            "objects_heading": heading,
            "objects_speed": [[float(self.speed)] * self.num_objects] * idx.size,
            "object_in_camera": in_cam.tolist(),
        }


class MovedStarts:
    """Start poses moved away from a box, remembered by (driving direction, the box's lane, start point): an open
    hash table in arrays (up to `MOVED_STARTS_KEPT` entries; it starts afresh when full) that `_apply_moved` reads
    in one compiled pass."""

    def __init__(self):
        size = 2 * MOVED_STARTS_KEPT  # a power of two, never more than half full
        self.keys = np.zeros((size, 3))  # (2 * reversed + (lane == 1), x, y)
        self.values = np.zeros((size, 3))  # moved (x, y, yaw)
        self.used = np.zeros(size, dtype=np.bool_)
        self.count = 0
        self._missing = np.empty((0, 2), dtype=np.int64)

    def apply(self, idx, revs, oxy, lane, pts, yaw) -> tuple[np.ndarray, np.ndarray] | None:
        """Starts `pts`, `yaw` (of cars idx, in directions revs) within 1 m of one of the car's objects (`oxy`,
        on `lane`) take their remembered moved pose, in place; returns the rows of those not remembered yet and
        the lanes of their boxes, or None when there are none."""
        if self._missing.shape[0] < idx.size:
            self._missing = np.empty((idx.size, 2), dtype=np.int64)
        n = _apply_moved(idx, revs, oxy, lane, pts, yaw, CLOSEST_OBJ_GAP_M, self.keys, self.values, self.used,
                         self._missing)
        return (self._missing[:n, 0].copy(), self._missing[:n, 1].copy()) if n else None

    def add(self, revs, box_lane, pts, moved_pts, moved_yaw) -> None:
        """Remember the moved poses of starts `pts` (directions revs, next to a box on box_lane)."""
        if self.count + revs.size > MOVED_STARTS_KEPT:
            self.used[:] = False
            self.count = 0
        self.count += _remember_moved(revs, box_lane, pts, np.column_stack([moved_pts, moved_yaw]), self.keys,
                                      self.values, self.used)


@njit(cache=True, inline="always")
def _moved_slot(code, x, y, keys, used):
    """The slot of key (code, x, y) in the open hash table (keys, used): where it is, or the free slot where it
    goes; and whether it is there."""
    mask = used.size - 1
    h = (np.int64(x * 1e4) * 73856093) ^ (np.int64(y * 1e4) * 19349663) ^ (np.int64(code) * 83492791)
    s = h & mask
    while used[s] and not (keys[s, 0] == code and keys[s, 1] == x and keys[s, 2] == y):
        s = (s + 1) & mask
    return s, used[s]


@njit(cache=True)
def _apply_moved(idx, revs, oxy, lane, pts, yaw, gap, keys, values, used, missing):
    """`MovedStarts.apply`: the remembered moved poses of the starts within `gap` of an object, in place; the
    (row, box lane) of those not remembered go to `missing`; returns their number."""
    dist, nearest = _nearest_object(idx, oxy, pts)
    n = 0
    for j in range(idx.size):
        if dist[j] < gap:
            flag = lane[idx[j], nearest[j]]
            s, found = _moved_slot(2.0 * revs[j] + (flag == 1), pts[j, 0], pts[j, 1], keys, used)
            if found:
                pts[j, 0] = values[s, 0]
                pts[j, 1] = values[s, 1]
                yaw[j] = values[s, 2]
            else:
                missing[n, 0] = j
                missing[n, 1] = flag
                n += 1
    return n


@njit(cache=True)
def _remember_moved(revs, box_lane, pts, moved, keys, values, used):
    """Put the moved poses (k, 3) of starts `pts` in the table; returns the number of new keys."""
    added = 0
    for j in range(revs.size):
        code = 2.0 * revs[j] + (box_lane[j] == 1)
        s, found = _moved_slot(code, pts[j, 0], pts[j, 1], keys, used)
        keys[s, 0] = code
        keys[s, 1] = pts[j, 0]
        keys[s, 2] = pts[j, 1]
        values[s] = moved[j]
        used[s] = True
        added += not found
    return added


def base_from_model_point(mx, my, heading_deg):
    """The base pose (x, y, yaw) behind a measured model point (`MODEL_POINT_AHEAD_M` back along the heading)."""
    yaw = np.radians(heading_deg)
    return mx - MODEL_POINT_AHEAD_M * np.cos(yaw), my - MODEL_POINT_AHEAD_M * np.sin(yaw), yaw


def race_layout(race: RaceConfig, track: Track) -> dict | None:
    """Where a race's objects stand at an episode's start, for pictures: {"kind": "box" | "bot", "xy" (m, 2),
    "yaw" (m,), "size" (length, width) m, "lane" (m,)}; None in a time trial, a head-to-model race or when the
    layout is random (re-drawn at every reset)."""
    if not race.has_objects or race.head_to_model:
        return None
    if (race.num_bot_cars and race.randomize_bot_car_locations) or \
            (race.num_obstacles and race.randomize_obstacle_locations and not race.object_positions):
        return None
    sim_objects = ObjectSet(race, track, track.reverse(), 1, np.random.default_rng(0))
    sim_objects.place(np.zeros(1, dtype=np.int64), np.zeros(1, dtype=bool))
    return {"kind": "bot" if sim_objects.bots else "box", "xy": sim_objects.xy[0].copy(),
            "yaw": sim_objects.yaw[0].copy(), "size": tuple(sim_objects.box_size_m), "lane": sim_objects.lane[0].copy()}
