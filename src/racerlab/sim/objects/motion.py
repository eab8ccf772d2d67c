"""How the objects move: `BotMotion`, the part of `ObjectSet` that drives the bot cars along their lanes
(`BotCarsCtrl`: clocks, lane changes, the pause after a bot ran into the car; compiled in `sim._object_kernels`)
and puts each head-to-model car's object where the other car of its pair is."""

from __future__ import annotations

import functools

import numpy as np

from racerlab.sim import _object_kernels as OK
from racerlab.track.kernels import contains_many


class BotMotion:
    """`ObjectSet`'s motion: bot cars driven step by step (`advance`), held after a crash (`pause`), racers
    following the other car of their pair (`follow`)."""

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
