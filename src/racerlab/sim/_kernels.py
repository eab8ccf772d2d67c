"""Compiled step of the batched simulator: episode rules, dynamics and measurements for every car.

State lives in two tables with the car axis first and named columns (see `layout`):
`car` (float: pose, speeds, commands, start point) and `ctr` (int: steps, phase, counters,
direction, status). Measurements of a pose (everything the reward params and the rules need)
go to a table `meas` with the same column names the params use.

Order of events per step follows the AWS simulator (facts §2): the prepare step ignores the
action and holds the car; in a RUN step the rules and the params are evaluated on the pose the
observation was taken in (the measurement cached at the end of the previous step), then the
action moves the car and the new pose is measured for the next observation. With `after_action`
the car moves first and the rules and params see the new pose.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.sim.car import P_DELAY, P_MAX_SPEED, P_MAX_STEER, QUEUE, advance
from racerlab.spec import MODEL_POINT_AHEAD_M, STATUS_NAMES
from racerlab.track.kernels import measure_on_track, point_in_road

# ---- table layouts ----------------------------------------------------------------------------
# car (float64)
CX, CY, CYAW, CV, CSTEER, CBETA, CSTART, CBPX, CBPY, CCMD_STEER, CCMD_SPEED = range(11)
CYAWRATE = 11
CQUEUE = 12  # the last QUEUE commands, newest first: (steering rad, speed) pairs, for the car's delay
N_CAR = CQUEUE + 2 * QUEUE
# ctr (int64)
KSTEPS, KPHASE, KIMMOB, KREVCNT, KREV, KSTATUS, KPAUSE = range(7)
N_CTR = 7
# meas (float64): a measured pose, also the per-step params table
(MX, MY, MS, MDIST, MLEFT, MWIDTH, MWP_PREV, MWP_NEXT, MCLOSEST, MWHEELS, MPROG, MPROG_PREV, MHEADING,
 MSEG, MLAT, MTHEAD) = range(16)
N_MEAS = 16

# phases
PREPARE, RUN = 0, 1
# episode status codes: the index of the AWS name in spec.STATUS_NAMES
IN_PROGRESS, LAP_COMPLETE, CRASHED, OFF_TRACK, IMMOBILIZED, REVERSED, STATUS_PREPARE, PAUSE, TIME_UP = (
    STATUS_NAMES.index(name) for name in ("in_progress", "lap_complete", "crashed", "off_track", "immobilized",
                                          "reversed", "prepare", "pause", "time_up"))

IMMOBILE_STEPS = 15  # NUM_STEPS_TO_CHECK_STUCK
IMMOBILE_DIST_M = 0.0003
REVERSE_STEPS = 15  # NUMBER_OF_REVERSE_COUNTS


@njit(cache=True)
def aws_progress(ndist, start_ndist, prev):
    """Progress in % from the episode start, as simapp's compute_current_prog."""
    cur = 100.0 * (ndist - start_ndist)
    if cur <= 0.0:
        cur += 100.0
    if prev - cur > 50.0:
        cur += 100.0
    elif cur - prev > 50.0:
        cur -= 100.0
    return min(cur, 100.0)


@njit(cache=True)
def measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f):
    """Measure car i's pose into meas[i]: model point, projection, progress, wheels on the road."""
    rev = ctr[i, KREV] != 0
    center, seg_len, cum_s, inner, outer, wp_ndist = trk_r if rev else trk_f
    x = car[i, CX]
    y = car[i, CY]
    yaw = car[i, CYAW]
    c = math.cos(yaw)
    s = math.sin(yaw)
    mx = x + MODEL_POINT_AHEAD_M * c
    my = y + MODEL_POINT_AHEAD_M * s
    driving_ccw = ccw_f != rev
    seg, arc, lat, left, width, prv, nxt, thead = measure_on_track(
        mx, my, center, seg_len, cum_s, inner, outer, wp_ndist, closed, length, driving_ccw, int(meas[i, MSEG]))
    dprev = math.hypot(mx - center[prv, 0], my - center[prv, 1])
    dnext = math.hypot(mx - center[nxt, 0], my - center[nxt, 1])
    wheels = 0
    edges, bstart, bedges, y0, bh = road
    for k in range(4):
        wx = x + wheel_off[k, 0] * c - wheel_off[k, 1] * s
        wy = y + wheel_off[k, 0] * s + wheel_off[k, 1] * c
        if point_in_road(wx, wy, edges, bstart, bedges, y0, bh):
            wheels += 1
    prev_prog = meas[i, MPROG]
    meas[i, MX] = mx
    meas[i, MY] = my
    meas[i, MS] = arc
    meas[i, MDIST] = abs(lat)
    meas[i, MLEFT] = 1.0 if left else 0.0
    meas[i, MWIDTH] = width
    meas[i, MWP_PREV] = prv
    meas[i, MWP_NEXT] = nxt
    meas[i, MCLOSEST] = prv if dprev <= dnext else nxt
    meas[i, MWHEELS] = wheels
    meas[i, MPROG_PREV] = prev_prog
    meas[i, MPROG] = aws_progress(arc / length, car[i, CSTART], prev_prog)
    meas[i, MHEADING] = math.degrees(yaw)
    meas[i, MSEG] = seg
    meas[i, MLAT] = lat
    meas[i, MTHEAD] = thead


@njit(cache=True)
def judge(i, car, ctr, meas):
    """Update car i's reset-rule counters from its measured pose and return the episode status."""
    x = car[i, CX]
    y = car[i, CY]
    moved = math.hypot(x - car[i, CBPX], y - car[i, CBPY])
    car[i, CBPX] = x
    car[i, CBPY] = y
    ctr[i, KIMMOB] = ctr[i, KIMMOB] + 1 if moved <= IMMOBILE_DIST_M else 0
    ctr[i, KREVCNT] = ctr[i, KREVCNT] + 1 if meas[i, MPROG] < meas[i, MPROG_PREV] else 0
    if meas[i, MPROG] >= 100.0:
        return LAP_COMPLETE
    if meas[i, MWHEELS] == 0:
        return OFF_TRACK
    if ctr[i, KIMMOB] >= IMMOBILE_STEPS:
        return IMMOBILIZED
    if ctr[i, KREVCNT] >= REVERSE_STEPS:
        return REVERSED
    return IN_PROGRESS


@njit(cache=True)
def push(i, car, steer_rad, speed):
    """Car i's newest command enters its queue (the oldest leaves it)."""
    for q in range(CQUEUE + 2 * QUEUE - 1, CQUEUE + 1, -1):
        car[i, q] = car[i, q - 2]
    car[i, CQUEUE] = steer_rad
    car[i, CQUEUE + 1] = speed


@njit(cache=True)
def move(i, car, hold, car_params, dt):
    """Car i over one step of `dt` s, acting on the command its delay reaches."""
    d = int(car_params[P_DELAY])
    new = CQUEUE + 2 * d
    old = min(new + 2, CQUEUE + 2 * QUEUE - 2)
    x, y, yaw, v, steer, w, beta = advance(car[i, CX], car[i, CY], car[i, CYAW], car[i, CV], car[i, CSTEER],
                                           car[i, CYAWRATE], car[i, old], car[i, old + 1], car[i, new],
                                           car[i, new + 1], hold,
                                           car_params, dt)
    car[i, CX] = x
    car[i, CY] = y
    car[i, CYAW] = yaw
    car[i, CV] = v
    car[i, CSTEER] = steer
    car[i, CYAWRATE] = w
    car[i, CBETA] = beta


@njit(cache=True)
def step_all(active, steer_deg, speed, car, ctr, meas, params, car_params, dts, after_action, max_steps,
             truncated, trk_f, trk_r, road, wheel_off, closed, length, ccw_f):
    """One step for every active car (car i's lasting dts[i] s, with its own packed constants car_params[i]);
    params[i] receives the measurement the reward sees."""
    for i in range(car.shape[0]):
        truncated[i] = False
        if not active[i]:
            continue
        ctr[i, KSTEPS] += 1
        if ctr[i, KPHASE] == PREPARE:
            # prepare step: the action is ignored, the car is held; reward 0, no rules
            car[i, CCMD_STEER] = 0.0
            car[i, CCMD_SPEED] = 0.0
            push(i, car, 0.0, 0.0)
            params[i, :] = meas[i, :]
            move(i, car, True, car_params[i], dts[i])
            measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f)
            ctr[i, KSTATUS] = STATUS_PREPARE
            ctr[i, KPHASE] = RUN
            continue
        car[i, CCMD_STEER] = steer_deg[i]
        car[i, CCMD_SPEED] = speed[i]
        push(i, car, math.radians(steer_deg[i]), speed[i])
        if after_action:
            move(i, car, False, car_params[i], dts[i])
            measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f)
            status = judge(i, car, ctr, meas)
            params[i, :] = meas[i, :]
        else:
            status = judge(i, car, ctr, meas)
            params[i, :] = meas[i, :]
            move(i, car, False, car_params[i], dts[i])
            measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f)
        ctr[i, KSTATUS] = status
        truncated[i] = status == IN_PROGRESS and ctr[i, KSTEPS] >= max_steps


@njit(cache=True, inline="always")
def _put(i, px, py, yaw, car):
    """Car i standing still at a base pose (also the reference for the immobilized rule)."""
    car[i, CX] = px
    car[i, CY] = py
    car[i, CYAW] = yaw
    car[i, CV] = 0.0
    car[i, CSTEER] = 0.0
    car[i, CBETA] = 0.0
    car[i, CYAWRATE] = 0.0
    car[i, CBPX] = px
    car[i, CBPY] = py
    for q in range(CQUEUE, CQUEUE + 2 * QUEUE):
        car[i, q] = 0.0


@njit(cache=True)
def place(i, px, py, yaw, start_ndist, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f):
    """Put car i at a start pose (zero speed) and begin a new episode in the prepare phase."""
    _put(i, px, py, yaw, car)
    car[i, CSTART] = start_ndist
    car[i, CCMD_STEER] = 0.0
    car[i, CCMD_SPEED] = 0.0
    ctr[i, KSTEPS] = 0
    ctr[i, KPHASE] = PREPARE
    ctr[i, KIMMOB] = 0
    ctr[i, KREVCNT] = 0
    ctr[i, KSTATUS] = IN_PROGRESS
    meas[i, MPROG] = 0.0
    meas[i, MSEG] = -1.0
    measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f)


@njit(cache=True)
def features(rows, car, ctr, meas, trk_f, trk_r, closed, length, lookahead, car_params, out):
    """`features` observation of cars `rows`: speed, steering, offset, heading error, centre points ahead.

    out[i] = [v / vmax, steer / max_steer, lateral / (width / 2), sin(heading error),
    cos(heading error), width, then for each lookahead distance d the centre point at arc
    length s + d in the car's frame (x ahead, y left), divided by 2 m].
    """
    vmax = car_params[0, P_MAX_SPEED]
    smax = car_params[0, P_MAX_STEER]
    nla = lookahead.shape[0]
    for i in rows:
        rev = ctr[i, KREV] != 0
        center, seg_len, cum_s, inner, outer, wp_ndist = trk_r if rev else trk_f
        x = car[i, CX]
        y = car[i, CY]
        yaw = car[i, CYAW]
        c = math.cos(yaw)
        s = math.sin(yaw)
        half_w = max(0.5 * meas[i, MWIDTH], 1e-3)
        err = yaw - meas[i, MTHEAD]
        out[i, 0] = car[i, CV] / vmax
        out[i, 1] = car[i, CSTEER] / smax
        out[i, 2] = meas[i, MLAT] / half_w
        out[i, 3] = math.sin(err)
        out[i, 4] = math.cos(err)
        out[i, 5] = meas[i, MWIDTH]
        for k in range(nla):
            sa = meas[i, MS] + lookahead[k]
            if closed:
                sa = sa % length
            else:
                sa = min(sa, length)
            j = np.searchsorted(cum_s, sa, side="right") - 1
            if j < 0:
                j = 0
            if j > seg_len.shape[0] - 1:
                j = seg_len.shape[0] - 1
            f = (sa - cum_s[j]) / seg_len[j] if seg_len[j] > 0 else 0.0
            qx = center[j, 0] + f * (center[j + 1, 0] - center[j, 0]) - x
            qy = center[j, 1] + f * (center[j + 1, 1] - center[j, 1]) - y
            out[i, 6 + 2 * k] = (qx * c + qy * s) * 0.5
            out[i, 7 + 2 * k] = (-qx * s + qy * c) * 0.5


@njit(cache=True)
def place_many(idx, px, py, yaw, start_ndist, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length,
               ccw_f):
    for j in range(idx.shape[0]):
        place(idx[j], px[j], py[j], yaw[j], start_ndist[j], car, ctr, meas, trk_f, trk_r, road, wheel_off, closed,
              length, ccw_f)


@njit(cache=True)
def relocate(i, px, py, yaw, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f):
    """Move car i within its episode (an evaluation reset after an incident): stopped, counters cleared,
    progress continuing from where it was."""
    _put(i, px, py, yaw, car)
    ctr[i, KIMMOB] = 0
    ctr[i, KREVCNT] = 0
    ctr[i, KSTATUS] = IN_PROGRESS
    meas[i, MSEG] = -1.0
    measure(i, car, ctr, meas, trk_f, trk_r, road, wheel_off, closed, length, ccw_f)
    meas[i, MPROG_PREV] = meas[i, MPROG]
