"""The crash rule (facts §2, next_capabilities §A.4): a car has crashed when one of the four corners of its
footprint (0.32352 m long x 0.1961 m wide, centred on the base pose) lies strictly inside an object's footprint (a
box's is 0.5 m along its lane x 0.4 m across, the box plus 0.1 m; a car's is its own). Only the car's corners are
tested; a car (bot or racer) counts only when it is ahead: the car ran into it. The compiled corner tests and
`CrashRule`, the part of `ObjectSet` that applies them."""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.sim import _kernels as K
from racerlab.sim import _object_kernels as OK
from racerlab.spec import MODEL_POINT_AHEAD_M

BOX_FOOTPRINT_M = (0.5, 0.4)  # (along the lane, across): ObstacleDimensions.BOX_OBSTACLE_DIMENSION (0.4, 0.5)
CAR_FOOTPRINT_M = (0.32352, 0.1961)  # (length, width): BOT_CAR_DIMENSION, the agent's crash footprint


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


def base_from_model_point(mx, my, heading_deg):
    """The base pose (x, y, yaw) behind a measured model point (`MODEL_POINT_AHEAD_M` back along the heading)."""
    yaw = np.radians(heading_deg)
    return mx - MODEL_POINT_AHEAD_M * np.cos(yaw), my - MODEL_POINT_AHEAD_M * np.sin(yaw), yaw


class CrashRule:
    """`ObjectSet`'s crash rule: which cars have a corner inside one of their objects, and whether they ran into it
    or a bot ran into them."""

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
