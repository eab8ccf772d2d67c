"""Numba kernels for the objects of a race: bot cars driven, every car's objects measured, in one pass over all
cars (no Python loop over cars in the step). `racerlab.sim.objects.ObjectSet` packs the track arrays once and
calls these; the results are those of its plain numpy definitions to the bit where the arithmetic allows it
(tested in tests/sim/test_object_kernels.py).

Packed geometry (built by `ObjectSet`):

- `lines` (2, N, 2), `seg_len` (2, N - 1), `cum_s` (2, N): the centre line in each driving direction (0 forward,
  1 reversed), for the projection;
- lane paths, one per (direction, lane) at index `2 * reversed + (0 if lane == 1 else 1)`: `paths` (4, 5, P) the
  centre-line distances u the lane's points are keyed by, the points' x and y, already in the form
  `np.interp(x, u, f, period=L)` sorts and pads them to, and the slopes numpy's interpolation works out from them;
  `lane_n` (4,) how many of the P are used; `lane_cell` (4, C + 2) a lookup table of the intervals
  (`lane_arrays`); `period` (2,) each direction's lap (0 on an open track);
- the polygon between centre line and inner border as edges indexed by horizontal band (`build_road_index`),
  for `objects_left_of_center`.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from racerlab.spec import MODEL_POINT_AHEAD_M
from racerlab.track.kernels import nearest_segment, point_in_road, segment_distance_sq


# ---- lane paths ------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _interp_at(paths, k, f, j, x, n):
    """numpy's compiled interpolation of path k's coordinate f (1: x, 2: y) at x, given j, the last index with
    u[j] <= x (-1 below, n above), with the slopes numpy works out first ((f[j + 1] - f[j]) / (u[j + 1] - u[j]),
    row f + 2). (numpy retries a NaN result from the other end of the interval; with finite points and
    u[j] <= x < u[j + 1] there is none.) Indexed element by element: no array views in the inner loop."""
    if j < 0:
        return paths[k, f, 0]
    if j >= n - 1 or paths[k, 0, j] == x:
        return paths[k, f, min(j, n - 1)]
    return paths[k, f + 2, j] * (x - paths[k, 0, j]) + paths[k, f, j]


@njit(cache=True, inline="always")
def lane_point(k, x, period, paths, lane_n, lane_cell, guess=-1):
    """(`np.interp(x, u, px, period)`, `np.interp(x, u, py, period)`, the path's segment the point is on) on lane
    path k, the point to the bit: on a loop x is taken modulo the period (numpy's `%`; x - period is the same for
    x in [period, 2 period)), the interval is found by a short walk from `guess` (a segment near x) or, without
    one, from a table of cells (`lane_arrays`)."""
    if period > 0.0 and not 0.0 <= x < period:
        x = x - period if period <= x < 2.0 * period else x % period
    n = lane_n[k]
    if x > paths[k, 0, n - 1]:
        j = n
    elif x < paths[k, 0, 0]:
        j = -1
    else:
        if guess >= 0:
            j = guess
        else:
            cell = min(max(int((x - paths[k, 0, 0]) * lane_cell[k, 0]), 0), lane_cell.shape[1] - 2)
            j = int(lane_cell[k, 1 + cell])
        while j > 0 and paths[k, 0, j] > x:
            j -= 1
        while j + 1 < n and paths[k, 0, j + 1] <= x:
            j += 1
    return _interp_at(paths, k, 1, j, x, n), _interp_at(paths, k, 2, j, x, n), min(max(j, 0), n - 2)


def lane_arrays(u: np.ndarray, x: np.ndarray, y: np.ndarray, size: int, cells: int) -> tuple[np.ndarray, np.ndarray]:
    """`lane_point`'s arrays for one lane path of points (u, x, y), u sorted: (5, size) u, x, y and numpy's
    slopes of x and y (padded with zeros), and the lookup table: 1 / cell width, then for each of `cells` + 1
    cells the last point at or before the cell's start (any guess will do: `lane_point` walks to the interval)."""
    out = np.zeros((5, size))
    n = u.size
    out[:3, :n] = u, x, y
    with np.errstate(divide="ignore", invalid="ignore"):  # as numpy's interp: a repeated u gives an unused slope
        out[3, :n - 1] = (x[1:] - x[:-1]) / (u[1:] - u[:-1])
        out[4, :n - 1] = (y[1:] - y[:-1]) / (u[1:] - u[:-1])
    width = (u[-1] - u[0]) / cells or 1.0
    starts = u[0] + width * np.arange(cells + 1)
    table = np.concatenate([[1.0 / width], np.clip(np.searchsorted(u, starts, side="right") - 1, 0, n - 1)])
    return out, table


@njit(cache=True)
def bot_xy(i, q, rev, clock, dd, d0, lane, change_start, speed, change_s, blend, paths, lane_n, lane_cell, p):
    """Bot q of car i (driving direction rev, lap p) at bot clock `clock`: on its lane at `d0 + speed * clock` of
    centre line (+ dd), blended into the other lane during a lane change by the smoothstep of the change's elapsed
    share (`blend`: lane changes are on)."""
    d = d0[i, q] + speed * clock + dd
    here = 2 * rev if lane[i, q] == 1 else 2 * rev + 1
    hx, hy, _ = lane_point(here, d, p, paths, lane_n, lane_cell)
    if not blend or clock <= change_start[i, q]:  # not changing lanes (yet): the blend weight is 0
        return hx, hy
    a = min(max((clock - change_start[i, q]) / change_s, 0.0), 1.0)
    w = a * a * (3.0 - 2.0 * a)
    if w == 0.0:  # on its lane (here + 0 * (there - here) is here)
        return hx, hy
    tx, ty, _ = lane_point(4 * rev + 1 - here, d, p, paths, lane_n, lane_cell)
    return hx + w * (tx - hx), hy + w * (ty - hy)


# ---- bot clocks and poses ----------------------------------------------------------------------------
@njit(cache=True)
def bots_tick(idx, dt, pause_left, clock, change_end, lane_changes, run_out, due_out):
    """One step of the bot clocks of cars `idx`: a paused car's bots wait out their penalty (a penalty of k steps
    is over after k steps, whatever the rounding), the others' clocks run on. Writes the running cars to run_out
    and their bots whose lane change has ended (or whose first change is to be drawn) as (car, bot) to due_out,
    in car-then-bot order; returns (running cars, due bots)."""
    nrun = 0
    ndue = 0
    for j in range(idx.size):
        i = idx[j]
        if pause_left[i] > 1e-9:
            left = pause_left[i] - dt
            pause_left[i] = left if left > 1e-9 else 0.0
            continue
        clock[i] += dt
        run_out[nrun] = i
        nrun += 1
        if lane_changes:
            for q in range(change_end.shape[1]):
                if clock[i] >= change_end[i, q]:
                    due_out[ndue, 0] = i
                    due_out[ndue, 1] = q
                    ndue += 1
    return nrun, ndue


@njit(cache=True)
def bots_start(idx, revs, start_d0, start_lane, lane_changes, rev, d0, lane, clock, pause_left, change_start,
               change_end, hint):
    """Cars `idx` (driving directions revs) put their bots back at the start: evenly spaced ones at
    start_d0[reversed], start_lane[reversed], clocks at 0, no pause; with lane changes the first is drawn at the
    first step (change_end 0), else never."""
    for j in range(idx.size):
        i = idx[j]
        r = 1 if revs[j] else 0
        rev[i] = revs[j]
        clock[i] = 0.0
        pause_left[i] = 0.0
        for q in range(d0.shape[1]):
            d0[i, q] = start_d0[r, q]
            lane[i, q] = start_lane[r, q]
            change_start[i, q] = np.inf
            change_end[i, q] = 0.0 if lane_changes else np.inf
            hint[i, q] = -1


@njit(cache=True)
def bots_drive(rows, due, draws, rev, clock, d0, lane, change_start, change_end, speed, change_s, blend, h, paths,
               lane_n, lane_cell, period, near_start, near, side, xy, yaw, lines, seg_len, cum_s, closed, ring_edges,
               band_start, band_edges, y0, band_h, ccw, hint, arc, dfc, left, order):
    """The bots of cars `rows` at their clocks, with their params (`measure`). First the bots `due` (car, bot)
    whose lane change ended are in the other lane and the next change of each ends draws[k] (U(lower, upper) s)
    plus the change's duration from now. The yaw is the path's direction, a central difference over the clock
    time h of 5 cm (standing bots: 5 cm of centre line either side). A bot on its lane line is projected onto
    the centre segments that can be nearest to its lane segment (`near_start`, `near`: `lane_segments`) and its
    side read from `side` where the lane segment stays clear of the polygon's edges."""
    for k in range(due.shape[0]):
        i = due[k, 0]
        q = due[k, 1]
        if change_end[i, q] > 0.0:
            lane[i, q] = -lane[i, q]
        end = clock[i] + draws[k]
        change_end[i, q] = end + change_s
        change_start[i, q] = end
    dd = 0.0 if h > 0 else 0.05
    for r in range(2):  # one direction at a time: its arrays are taken once
        line = lines[r]
        lengths = seg_len[r]
        along = cum_s[r]
        p = period[r]
        for j in range(rows.size):
            i = rows[j]
            if rev[i] != (r == 1):
                continue
            c = clock[i]
            changing = False
            for q in range(xy.shape[1]):
                if not blend or c + h <= change_start[i, q]:  # on its lane at all three clock times
                    k = 2 * r if lane[i, q] == 1 else 2 * r + 1
                    x, y, g = lane_point(k, d0[i, q] + speed * c + 0.0, p, paths, lane_n, lane_cell)
                    ax, ay, _ = lane_point(k, d0[i, q] + speed * (c + h) + dd, p, paths, lane_n, lane_cell, g)
                    bx, by, _ = lane_point(k, d0[i, q] + speed * (c - h) - dd, p, paths, lane_n, lane_cell, g)
                    s, lat, seg = _project_among(x, y, line, lengths, along, near_start, near, k, g)
                    hint[i, q] = seg
                    arc[i, q] = s
                    dfc[i, q] = abs(lat)
                    if side[k, g] == 0:
                        inner = point_in_road(x, y, ring_edges, band_start, band_edges, y0, band_h)
                    else:
                        inner = side[k, g] == 1
                    left[i, q] = inner != (not ccw[r])
                else:
                    changing = True  # measured below
                    x, y = bot_xy(i, q, r, c, 0.0, d0, lane, change_start, speed, change_s, blend, paths, lane_n,
                                  lane_cell, p)
                    ax, ay = bot_xy(i, q, r, c + h, dd, d0, lane, change_start, speed, change_s, blend, paths, lane_n,
                                    lane_cell, p)
                    bx, by = bot_xy(i, q, r, c - h, -dd, d0, lane, change_start, speed, change_s, blend, paths,
                                    lane_n, lane_cell, p)
                xy[i, q, 0] = x
                xy[i, q, 1] = y
                yaw[i, q] = math.atan2(ay - by, ax - bx)
            if changing:  # some bot is changing lanes: measure them all the general way
                _measure_car(i, r, xy, line, lengths, along, closed, ring_edges, band_start, band_edges, y0, band_h,
                             ccw, hint, arc, dfc, left, order)
            else:
                _sort_by_arc(i, arc, order)


# ---- params -----------------------------------------------------------------------------------------
@njit(cache=True, inline="always")
def _project(px, py, line, seg_len, cum_s, closed, hint):
    """(arc length, signed offset, segment) of p on the polyline as `Track.project` finds them, searching near
    `hint` first (-1: everywhere); at the closing vertex of a loop, where the last segment's end and the first's
    start are one point, the first segment wins as in a search over everything."""
    i, t, d2 = nearest_segment(px, py, line, seg_len, closed, hint)
    if closed and i == line.shape[0] - 2 and t == 1.0:
        d0, t0 = segment_distance_sq(px, py, line[0, 0], line[0, 1], line[1, 0] - line[0, 0],
                                      line[1, 1] - line[0, 1], seg_len[0] * seg_len[0])
        if d0 <= d2:
            i, t, d2 = 0, t0, d0
    ax = line[i, 0]
    ay = line[i, 1]
    cross = (line[i + 1, 0] - ax) * (py - ay) - (line[i + 1, 1] - ay) * (px - ax)
    lat = math.sqrt(d2) if cross >= 0.0 else -math.sqrt(d2)
    return cum_s[i] + t * seg_len[i], lat, i


@njit(cache=True)
def _measure_car(i, r, xy, line, lengths, along, closed, ring_edges, band_start, band_edges, y0, band_h, ccw, hint,
                 arc, dfc, left, order):
    """`measure` of car i in driving direction r, whose centre line is (line, lengths, along)."""
    m = xy.shape[1]
    for q in range(m):
        px = xy[i, q, 0]
        py = xy[i, q, 1]
        s, lat, seg = _project(px, py, line, lengths, along, closed, hint[i, q])
        hint[i, q] = seg
        arc[i, q] = s
        dfc[i, q] = abs(lat)
        inner = point_in_road(px, py, ring_edges, band_start, band_edges, y0, band_h)
        left[i, q] = inner != (not ccw[r])
    _sort_by_arc(i, arc, order)


@njit(cache=True, inline="always")
def _sort_by_arc(i, arc, order):
    """order[i]: car i's objects by arc, an insertion sort: stable, as argsort(kind="stable")."""
    for q in range(arc.shape[1]):
        order[i, q] = q
    for q in range(1, arc.shape[1]):
        k = order[i, q]
        p = q - 1
        while p >= 0 and arc[i, order[i, p]] > arc[i, k]:
            order[i, p + 1] = order[i, p]
            p -= 1
        order[i, p + 1] = k


@njit(cache=True, inline="always")
def _project_among(px, py, line, lengths, along, near_start, near, k, g):
    """`_project` of p, a point of segment g of lane path k, searching only the centre segments that can be
    nearest to that lane segment (in increasing order, so the first of equals wins as in a search over all)."""
    best_i = -1
    best_d = np.inf
    best_t = 0.0
    for e in range(near_start[k, g], near_start[k, g + 1]):
        i = near[e]
        d, t = segment_distance_sq(px, py, line[i, 0], line[i, 1], line[i + 1, 0] - line[i, 0],
                                    line[i + 1, 1] - line[i, 1], lengths[i] * lengths[i])
        if d < best_d:
            best_d = d
            best_i = i
            best_t = t
    ax = line[best_i, 0]
    ay = line[best_i, 1]
    cross = (line[best_i + 1, 0] - ax) * (py - ay) - (line[best_i + 1, 1] - ay) * (px - ax)
    lat = math.sqrt(best_d) if cross >= 0.0 else -math.sqrt(best_d)
    return along[best_i] + best_t * lengths[best_i], lat, best_i


def _segments_apart(a0, a1, b0, b1) -> np.ndarray:
    """Distance between segments a0-a1 and b0-b1 (arrays of points (..., 2), broadcast): 0 where they cross, else
    the least distance of an end point to the other segment."""
    def to_segment(p, s0, s1):
        d = s1 - s0
        ll = (d * d).sum(-1)
        t = np.clip(((p - s0) * d).sum(-1) / np.where(ll > 0, ll, 1.0), 0.0, 1.0)
        return np.hypot(*np.moveaxis(s0 + t[..., None] * d - p, -1, 0))

    def orient(p, q, r):
        u, v = q - p, r - p
        return np.sign(u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0])

    cross = (orient(a0, a1, b0) * orient(a0, a1, b1) < 0) & (orient(b0, b1, a0) * orient(b0, b1, a1) < 0)
    apart = np.minimum(np.minimum(to_segment(a0, b0, b1), to_segment(a1, b0, b1)),
                       np.minimum(to_segment(b0, a0, a1), to_segment(b1, a0, a1)))
    return np.where(cross, 0.0, apart)


def lane_segments(path: np.ndarray, line: np.ndarray, ring: np.ndarray, inside, margin: float = 1e-6):
    """For each segment g of a lane path (points (n, 2)): (the centre segments that can be nearest to a point of
    it, in CSR form (start (n,), list), its side: 1 inside the ring, 2 outside, 0 too near an edge of the ring to
    say for all its points). A point of g is at most (D(a) + D(b) + |g|) / 2 from the centre line (D: the distance
    of g's ends a, b from it), so a centre segment further than that from g (with a margin for rounding) is never
    the nearest; the others are searched. `inside(points)` is the even-odd test of the ring, read at g's middle
    when g keeps `margin` from every ring edge."""
    a, b = path[:-1], path[1:]
    c0, c1 = line[:-1], line[1:]
    apart = _segments_apart(a[:, None], b[:, None], c0[None], c1[None])  # (n - 1, segments)
    ends = _segments_apart(path[:, None], path[:, None], c0[None], c1[None]).min(axis=1)
    reach = 0.5 * (ends[:-1] + ends[1:] + np.hypot(*(b - a).T)) + margin
    take = apart <= reach[:, None]
    start = np.zeros(path.shape[0], dtype=np.int64)
    np.cumsum(take.sum(axis=1), out=start[1:])
    edges = _segments_apart(a[:, None], b[:, None], ring[None, :], np.roll(ring, -1, axis=0)[None, :]).min(axis=1)
    side = np.where(inside(0.5 * (a + b)), 1, 2)
    return start, np.nonzero(take)[1].astype(np.int64), np.where(edges > margin, side, 0).astype(np.int64)


@njit(cache=True)
def measure(rows, rev, xy, lines, seg_len, cum_s, closed, ring_edges, band_start, band_edges, y0, band_h, ccw, hint,
            arc, dfc, left, order):
    """The static params of the objects of cars `rows`: centre-line arc and distance from the centre line of
    each object's projection in the car's driving direction, left of centre (inside the polygon between centre
    line and inner border, XOR not counter-clockwise in that direction) and the objects sorted by arc (stably).
    `hint` (car, object) holds the segments found last time (-1: none), updated."""
    for r in range(2):  # one direction at a time: its arrays are taken once
        line = lines[r]
        lengths = seg_len[r]
        along = cum_s[r]
        for j in range(rows.size):
            if rev[rows[j]] == (r == 1):
                _measure_car(rows[j], r, xy, line, lengths, along, closed, ring_edges, band_start, band_edges, y0,
                             band_h, ccw, hint, arc, dfc, left, order)


@njit(cache=True, inline="always")
def _front_arc(i, q, r, xy, yaw, lines, seg_len, cum_s, closed):
    """The centre-line arc of the front point (`MODEL_POINT_AHEAD_M` ahead of the base) of object q of car i
    (driving direction r): a car's progress."""
    fx = xy[i, q, 0] + MODEL_POINT_AHEAD_M * math.cos(yaw[i, q])
    fy = xy[i, q, 1] + MODEL_POINT_AHEAD_M * math.sin(yaw[i, q])
    return _project(fx, fy, lines[r], seg_len[r], cum_s[r], closed, -1)[0]


@njit(cache=True)
def judge_cars(inside, rows, car_arc, length, rev, xy, yaw, lines, seg_len, cum_s, closed, crashed, rear_ended):
    """Per car rows[j] with a corner inside the objects marked in inside[j]: crashed where such an object (a car)
    is ahead (its front point less than half a lap ahead of the car's centre-line arc car_arc[j]: the car ran into
    it), rear-ended where one is behind (it ran into the car)."""
    for j in range(rows.size):
        crashed[j] = False
        rear_ended[j] = False
        for q in range(inside.shape[1]):
            if inside[j, q]:
                i = rows[j]
                front = _front_arc(i, q, 1 if rev[i] else 0, xy, yaw, lines, seg_len, cum_s, closed)
                if (front - car_arc[j]) % length < 0.5 * length:
                    crashed[j] = True
                else:
                    rear_ended[j] = True


@njit(cache=True)
def closest_and_in_camera(idx, model_s, bx, by, byaw, arc, order, xy, yaw, half_len, half_wid, camera, prev_out,
                          next_out, in_camera_out):
    """Per car idx[j] measured at centre-line arc model_s[j] with base pose (bx[j], by[j], byaw[j]): the objects
    before and after it by arc (`closest_objects`: bisect_right in the sorted arcs, wrapping around) and whether
    the next one (its centre or a footprint corner, half sizes half_len x half_wid, at the objects' height) is in
    the camera frustum. `camera`: the camera's x ahead of the base and height, the objects' height, cos and sin of
    the pitch, tan of half the horizontal and vertical fields of view, near and far distance."""
    m = arc.shape[1]
    ahead, cam_z, obj_z, cp, sp, tan_h, tan_v, near, far = camera
    for j in range(idx.size):
        i = idx[j]
        count = 0
        for k in range(m):
            if arc[i, order[i, k]] <= model_s[j]:
                count += 1
        prev_out[j] = order[i, count - 1 if count > 0 else m - 1]
        q = order[i, count if count < m else 0]
        next_out[j] = q
        c = math.cos(byaw[j])
        s = math.sin(byaw[j])
        cam_x = bx[j] + ahead * c
        cam_y = by[j] + ahead * s
        co = math.cos(yaw[i, q])
        so = math.sin(yaw[i, q])
        seen = False
        for corner in range(5):  # the centre, then the four corners
            du = 0.0 if corner == 0 else (half_len if corner < 3 else -half_len)
            dv = 0.0 if corner == 0 else (half_wid if corner % 2 == 1 else -half_wid)
            dx = xy[i, q, 0] + du * co - dv * so - cam_x
            dy = xy[i, q, 1] + du * so + dv * co - cam_y
            dz = obj_z - cam_z
            fwd = dx * c + dy * s
            left = -dx * s + dy * c
            depth = fwd * cp - dz * sp  # along the optical axis (pitched down)
            up = fwd * sp + dz * cp
            if near < depth < far and abs(left) <= depth * tan_h and abs(up) <= depth * tan_v:
                seen = True
                break
        in_camera_out[j] = seen


@njit(cache=True)
def features_ahead(rows, car, meas, cx, cy, cyaw, ms, length, arc, xy, out, column, f):
    """out[i, column:column + 2 f] for each car i of `rows` at base pose (car[i, cx], car[i, cy], car[i, cyaw]) on
    centre-line arc meas[i, ms]: its f nearest objects ahead along the lap (the first of equals first), (x ahead,
    y left) in the car's frame divided by 2 m; with fewer objects than f the list repeats from the nearest."""
    m = arc.shape[1]
    ahead = np.empty(m)
    taken = np.empty(m, dtype=np.bool_)
    pick = np.empty(f, dtype=np.int64)
    for j in range(rows.size):
        i = rows[j]
        for q in range(m):
            ahead[q] = (arc[i, q] - meas[i, ms]) % length
            taken[q] = False
        for k in range(min(f, m)):
            best = -1
            for q in range(m):
                if not taken[q] and (best < 0 or ahead[q] < ahead[best]):
                    best = q
            taken[best] = True
            pick[k] = best
        for k in range(m, f):
            pick[k] = pick[k % m]
        c = math.cos(car[i, cyaw])
        sn = math.sin(car[i, cyaw])
        for k in range(f):
            dx = xy[i, pick[k], 0] - car[i, cx]
            dy = xy[i, pick[k], 1] - car[i, cy]
            out[i, column + 2 * k] = (dx * c + dy * sn) * 0.5
            out[i, column + 2 * k + 1] = (-dx * sn + dy * c) * 0.5
