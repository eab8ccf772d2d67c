"""Where a race's objects stand: the race settings (`as_race`), AWS's layouts of boxes and bot cars along the lap
(`obstacle_arcs`), the lane lines they stand on (`Lanes`), and `Placement`, the part of `ObjectSet` that places
every car's objects at its reset and finds the evaluation's restart behind a box (the package docstring has AWS's
rules)."""

from __future__ import annotations

import functools

import numpy as np

from racerlab.errors import ConfigError
from racerlab.sim import _object_kernels as OK
from racerlab.spec import RaceConfig
from racerlab.track import Track

END_MARGIN_M = 1.0  # the last obstacle stays this far before the end of the lap
RESET_BEHIND_DIST_M = 1.0  # evaluation: after a crash the car restarts this far behind the box, other lane


def as_race(value) -> RaceConfig | None:
    """A `RaceConfig`, its keyword dict, a race type name, or None (a time trial)."""
    if value is None or isinstance(value, RaceConfig):
        return value
    if isinstance(value, str):
        return RaceConfig(type=value, number_of_obstacles=6 if value == "object_avoidance" else 0)
    return RaceConfig.from_mapping(value)


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


class Placement:
    """`ObjectSet`'s placement: new layouts at a car's reset (random ones drawn car by car, fixed ones placed once
    per direction and copied), the nearest object and the restart behind it. Reads and writes the set's arrays."""

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
                one = type(self)(self.race, self.lanes[0].track, self.lanes[1].track, 1, self.rng)
                one._layouts = None
                one.place([0], [rev])
                self._layouts[rev] = one
            for mine, value in self._per_car_arrays(one):
                mine[rows] = value[0]
            for i in rows.tolist():
                self._lists[i] = one._lists[0]

    def _per_car_arrays(self, one) -> list:
        """(this set's array, the one-car set's array) for every per-car array (car axis first; names listed once)."""
        key = ("arrays", id(one))
        if key not in self._layouts:
            n = self.xy.shape[0]
            self._layouts[key] = [k for k, v in vars(one).items()
                                  if isinstance(v, np.ndarray) and v.shape[:1] == (1,)
                                  and getattr(self, k).shape[:1] == (n,)]
        return [(getattr(self, k), getattr(one, k)) for k in self._layouts[key]]

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
