"""Track generator: smooth closed circuits from control points, checked so that a car can drive them.

Two entry points share one construction and one set of checks:

    >>> from racerlab.track.generate import generate, from_control_points
    >>> t = generate(seed=7, length=25.0, width=1.07)          # a random circuit
    >>> t = from_control_points([(0, 0), (4, 0), (4, 2), (0, 2)], width=0.76, length=18.0)

A centre line is a periodic cubic spline through the control points (chord-length parameter),
scaled to the requested length, turned counter-clockwise, started on its straightest part and
sampled every ~0.15 m like the AWS route files. The borders are offsets of the centre line by half
the width, so the centre is exactly their midpoint and the width is constant. A track is refused
(`TrackError`) when a turn is tighter than `min_radius`, or when two parts of the road come closer
than `gap` without being the same bend (the check that also catches crossings).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.interpolate import CubicSpline

from racerlab.errors import TrackError
from racerlab.track.core import Track, from_array, ring_area, segments_cross

WAYPOINT_SPACING_M = 0.15  # the AWS route files space waypoints 0.15-0.30 m apart
CAR_MIN_RADIUS_M = 0.28  # tightest circle the car can drive (wheelbase 0.164 m, 30 degree steering)
FOLD_MARGIN_M = 0.05  # the inner border's own radius must stay at least this large
DEFAULT_GAP_M = 0.5  # grass between two different parts of the road (AWS tracks keep 0.68 m or more)
STRAIGHT_RADIUS_M = 3.0  # a part of the centre line with a larger radius counts as straight-ish
MAX_ATTEMPTS = 40  # random control polygons tried per seed before giving up
MAX_EASING = 40  # bends eased on one random polygon before it is dropped


@dataclass(frozen=True)
class _Curve:
    """A closed centre line sampled densely: parameter, points, first and second derivatives, arc length."""

    t: np.ndarray
    xy: np.ndarray
    d1: np.ndarray
    d2: np.ndarray
    s: np.ndarray  # arc length at each sample, s[0] == 0, s[-1] == length
    scale: float  # factor from spline units to metres

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @property
    def curvature(self) -> np.ndarray:
        cross = self.d1[:, 0] * self.d2[:, 1] - self.d1[:, 1] * self.d2[:, 0]
        return cross / np.hypot(*self.d1.T) ** 3


# ---- construction -----------------------------------------------------------------------------

def _spline(points: np.ndarray) -> CubicSpline:
    """Periodic cubic spline through the control points, parametrised by chord length."""
    ring = np.vstack([points, points[:1]])
    chords = np.hypot(*np.diff(ring, axis=0).T)
    if np.any(chords <= 1e-9):
        i = int(np.flatnonzero(chords <= 1e-9)[0])
        raise TrackError(f"control points {i} and {(i + 1) % len(points)} are the same point; remove one")
    knots = np.concatenate([[0.0], np.cumsum(chords)])
    return CubicSpline(knots, ring, bc_type="periodic")


def _sample(spline: CubicSpline, scale: float, samples: int) -> _Curve:
    t = np.linspace(spline.x[0], spline.x[-1], samples + 1)
    xy = spline(t) * scale
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(xy, axis=0).T))])
    return _Curve(t, xy, spline(t, 1) * scale, spline(t, 2) * scale, s, scale)


def _dense(spline: CubicSpline, length: float) -> _Curve:
    """The spline scaled so that its centre line is `length` long, sampled every ~1 cm."""
    samples = 4000
    raw = _sample(spline, 1.0, samples)
    samples = max(samples, int(length / 0.01))
    return _sample(spline, length / raw.length, samples)


def _start_s(curve: _Curve) -> float:
    """Arc length of the start line: a quarter into the longest straight-ish stretch."""
    k = np.abs(curve.curvature[:-1])
    straight = k < 1.0 / STRAIGHT_RADIUS_M
    if straight.all():
        return 0.0
    if not straight.any():
        return float(curve.s[int(np.argmin(k))])
    # runs of straight samples, scanned from a bend so that no run wraps around the end
    first_bend = int(np.flatnonzero(~straight)[0])
    order = np.roll(np.arange(len(k)), -first_bend)
    best_len, best_start, run_start = -1.0, 0, None
    for pos, i in enumerate(order):
        if straight[i] and run_start is None:
            run_start = pos
        if run_start is not None and (not straight[i] or pos == len(order) - 1):
            end = pos if not straight[i] else pos + 1
            run_len = _arc_between(curve, order[run_start], order[end - 1])
            if run_len > best_len:
                best_len, best_start = run_len, order[run_start]
            run_start = None
    return float((curve.s[best_start] + 0.25 * best_len) % curve.length)


def _arc_between(curve: _Curve, i: int, j: int) -> float:
    d = curve.s[j] - curve.s[i]
    return float(d if d >= 0 else d + curve.length)


def _waypoints(spline: CubicSpline, curve: _Curve, start_s: float, spacing: float):
    """Centre points and unit left normals every ~`spacing` m from `start_s`, counter-clockwise."""
    n = max(8, int(round(curve.length / spacing)))
    s = (start_s + np.arange(n) * curve.length / n) % curve.length
    t = np.interp(s, curve.s, curve.t)
    center = spline(t) * curve.scale
    tangent = spline(t, 1)
    tangent /= np.hypot(*tangent.T)[:, None]
    if ring_area(center) < 0:  # drive it the other way, keeping the start point first
        center = np.vstack([center[:1], center[:0:-1]])
        tangent = -np.vstack([tangent[:1], tangent[:0:-1]])
    normal = np.stack([-tangent[:, 1], tangent[:, 0]], axis=1)
    return center, normal


def _aws_array(center: np.ndarray, normal: np.ndarray, width: float) -> np.ndarray:
    """(N+1, 6) AWS layout; the centre is recomputed as the borders' midpoint and the loop is closed."""
    inner = center + normal * (width / 2)  # left of a counter-clockwise drive
    outer = center - normal * (width / 2)
    mid = 0.5 * (inner + outer)
    arr = np.hstack([mid, inner, outer])
    lo, hi = outer.min(axis=0), outer.max(axis=0)
    shift = np.round(0.5 * (lo + hi), 6)  # centre the drawing on the origin, like the newer AWS files
    arr -= np.tile(shift, 3)
    return np.vstack([arr, arr[:1]])


# ---- checks -----------------------------------------------------------------------------------

def _check_request(length: float, width: float, min_radius: float, gap: float) -> None:
    if not (np.isfinite(width) and width > 0):
        raise TrackError(f"width must be a positive number of metres, got {width}")
    if not (np.isfinite(length) and length > 0):
        raise TrackError(f"length must be a positive number of metres, got {length}")
    if min_radius < CAR_MIN_RADIUS_M:
        raise TrackError(f"min_radius {min_radius:g} m is tighter than the car can turn "
                         f"({CAR_MIN_RADIUS_M} m); use at least {CAR_MIN_RADIUS_M}")
    if min_radius < width / 2 + FOLD_MARGIN_M:
        raise TrackError(f"min_radius {min_radius:g} m is too tight for a {width:g} m wide road: the inner "
                         f"border would fold; use min_radius >= {width / 2 + FOLD_MARGIN_M:.3f} or a narrower width")
    if gap < 0:
        raise TrackError(f"gap must be >= 0 m, got {gap}")
    shortest = np.pi * max(2 * min_radius, width + gap)
    if length < shortest:
        raise TrackError(f"length {length:g} m is too short for width {width:g} m and min_radius {min_radius:g} m; "
                         f"use at least {shortest:.2f} m")


def _sharpest(curve: _Curve) -> int:
    return int(np.argmax(np.abs(curve.curvature)))


def _radius_problem(curve: _Curve, min_radius: float) -> str | None:
    i = _sharpest(curve)
    radius = 1.0 / abs(curve.curvature[i])
    if radius >= min_radius:
        return None
    return (f"a bend of radius {radius:.2f} m at {curve.s[i]:.1f} m along the spline from control point 0 "
            f"is tighter than min_radius {min_radius:g} m")


def crowding(center: np.ndarray, reach: float) -> tuple[int, int, float] | None:
    """The closest pair of centre points (i, j, distance) from different parts of the road, or None.

    `center` is an open ring (no repeated closing row). Two points belong to the same part of the
    road when the centre line between them stays within `reach` of the first one (the two legs of a
    hairpin near its apex); any other pair closer than `reach` means the road runs into itself.
    """
    n = len(center)
    dist = np.hypot(*(center[:, None, :] - center[None, :, :]).transpose(2, 0, 1))
    rows = np.arange(n)[:, None]
    rolled = dist[rows, (rows + np.arange(n)[None, :]) % n]  # rolled[i, k] = dist(i, i + k)
    out = rolled > reach
    out[:, 0] = False
    # first offset that leaves the ball, going forward and going backward from each point
    fwd = np.where(out.any(axis=1), out.argmax(axis=1), n)
    back = np.where(out.any(axis=1), out[:, ::-1].argmax(axis=1) + 1, n)
    k = np.arange(n)[None, :]
    remote = (k >= fwd[:, None]) & (k <= (n - back)[:, None])
    close = np.where(remote, rolled, np.inf)
    i, kk = np.unravel_index(np.argmin(close), close.shape)
    if close[i, kk] >= reach:
        return None
    return int(i), int((i + kk) % n), float(close[i, kk])


def _crowding_problem(center: np.ndarray, width: float, gap: float, spacing: float) -> str | None:
    hit = crowding(center, width + gap)
    if hit is None:
        return None
    i, j, d = hit
    return (f"the road at {i * spacing:.1f} m and at {j * spacing:.1f} m along the centre line comes within "
            f"{max(d - width, 0):.2f} m of itself (needs a gap of {gap:g} m)")


def _crossing_problem(arr: np.ndarray) -> str | None:
    for col, what in ((0, "centre line"), (2, "inner border"), (4, "outer border")):
        line = arr[:, col:col + 2]
        if segments_cross(line, line, skip_adjacent=True) is not None:
            return f"the {what} crosses itself"
    return None


# ---- entry points -----------------------------------------------------------------------------

class _Built(NamedTuple):
    arr: np.ndarray | None  # the (N+1, 6) AWS array, None when there is a problem
    problem: str | None  # the first problem found
    sharp_at: np.ndarray | None = None  # for a bend too tight: where it is (x, y in control-point units)


def _build(points, width: float, length: float, min_radius: float, gap: float,
           start_xy: np.ndarray | None) -> _Built:
    """The track through these control points, or the first reason it is not drivable.

    The start line goes at the centre-line point nearest `start_xy` (in control-point units), by
    default on the longest straight.
    """
    spline = _spline(points)
    curve = _dense(spline, length)
    problem = _radius_problem(curve, min_radius)
    if problem:
        return _Built(None, problem, spline(curve.t[_sharpest(curve)]))
    if start_xy is None:
        start_s = _start_s(curve)
    else:
        start_s = float(curve.s[np.argmin(np.hypot(*(curve.xy / curve.scale - start_xy).T))])
    center, normal = _waypoints(spline, curve, start_s, WAYPOINT_SPACING_M)
    spacing = curve.length / len(center)
    problem = _crowding_problem(center, width, gap, spacing)
    if problem:
        return _Built(None, problem)
    arr = _aws_array(center, normal, width)
    problem = _crossing_problem(arr)
    return _Built(None if problem else arr, problem)


def from_control_points(points, width: float = 1.07, length: float | None = None, *, name: str = "designed",
                        min_radius: float = 0.6, gap: float = DEFAULT_GAP_M, start: int | None = None) -> Track:
    """A track whose centre line is a smooth loop through `points` (metres; all scaled to `length`).

    `start` puts the start line at control point `start`; by default it goes on the longest
    straight. Raises `TrackError` with the reason when the result is not drivable.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 4 or not np.isfinite(pts).all():
        raise TrackError(f"{name}: control points must be at least 4 finite (x, y) pairs, got shape {pts.shape}")
    return _finish(pts, width, length, name, min_radius, gap, None if start is None else pts[int(start) % len(pts)])


def _finish(points: np.ndarray, width: float, length: float | None, name: str, min_radius: float, gap: float,
            start_xy: np.ndarray | None) -> Track:
    if length is None:
        length = _sample(_spline(points), 1.0, 4000).length
    _check_request(length, width, min_radius, gap)
    built = _build(points, width, length, min_radius, gap, start_xy)
    if built.problem:
        raise TrackError(f"{name}: {built.problem}; move the points or ask for a longer track")
    return from_array(built.arr, name=name, source="generated")


# ---- rounded polygons: the designed and the random tracks ---------------------------------------

def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.hypot(*v.T)[..., None]


def _deflections(corners: np.ndarray) -> np.ndarray:
    """Signed turn at each corner of a closed polygon, rad (+ = left)."""
    u_in = _unit(corners - np.roll(corners, 1, axis=0))
    u_out = _unit(np.roll(corners, -1, axis=0) - corners)
    cross = u_in[:, 0] * u_out[:, 1] - u_in[:, 1] * u_out[:, 0]
    return np.arctan2(cross, np.sum(u_in * u_out, axis=1))


def fillet_lengths(corners: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """How much of each adjacent edge the circular bend of radius `radii` at each corner takes, m."""
    return radii * np.tan(np.abs(_deflections(corners)) / 2)


def _fillet(corner, prev, nxt, radius: float, turn: float) -> np.ndarray:
    """Points on the circular bend of `radius` that rounds off `corner`: entry, 3 inside, exit."""
    u_in, u_out = _unit(corner - prev), _unit(nxt - corner)
    d = radius * np.tan(abs(turn) / 2)
    entry = corner - u_in * d
    centre = entry + np.sign(turn) * radius * np.array([-u_in[1], u_in[0]])
    arm = entry - centre
    angles = turn * np.array([0.25, 0.5, 0.75])
    rot = np.stack([np.cos(angles), -np.sin(angles), np.sin(angles), np.cos(angles)], axis=1).reshape(-1, 2, 2)
    return np.vstack([entry, centre + rot @ arm, corner + u_out * d])


def polygon_control_points(corners, radii, straight_step: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """Spline control points for a polygon whose corners are rounded off by circular bends.

    Each corner gives its bend (entry, three points on the arc, exit); each straight between two
    bends gets a point every `straight_step` so the spline stays straight there. Returns the points
    and, for each edge, the index of the point where its straight begins. The caller makes sure the
    bends fit (`fillet_lengths`).
    """
    corners = np.asarray(corners, dtype=np.float64)
    n = len(corners)
    turns = _deflections(corners)
    pieces, starts, count = [], [], 0
    for v in range(n):
        prev, nxt = corners[v - 1], corners[(v + 1) % n]
        bend = corners[v][None, :] if abs(turns[v]) < 1e-9 else _fillet(corners[v], prev, nxt, radii[v], turns[v])
        pieces.append(bend)
        count += len(bend)
        starts.append(count - 1)
        nxt_entry = nxt - _unit(nxt - corners[v]) * fillet_lengths(corners, radii)[(v + 1) % n]
        gap = float(np.hypot(*(nxt_entry - bend[-1])))
        k = int(gap // straight_step)
        if k > 0:
            f = np.arange(1, k + 1)[:, None] / (k + 1)
            pieces.append(bend[-1] + f * (nxt_entry - bend[-1]))
            count += k
    pts = np.vstack(pieces)
    keep = np.hypot(*(pts - np.roll(pts, 1, axis=0)).T) > 1e-9  # bends that meet share a point
    return pts[keep], np.cumsum(keep)[np.asarray(starts)] - 1


def _fit_problem(corners: np.ndarray, radii: np.ndarray) -> str | None:
    """Why the bends do not fit on the polygon's edges, or None."""
    d = fillet_lengths(corners, radii)
    edges = np.hypot(*(np.roll(corners, -1, axis=0) - corners).T)
    over = d + np.roll(d, -1) - edges
    if np.all(over <= 1e-9):
        return None
    v = int(np.argmax(over))
    return (f"the bends at corners {v} and {(v + 1) % len(corners)} need {d[v] + d[(v + 1) % len(d)]:.2f} m of "
            f"the {edges[v]:.2f} m edge between them; use smaller radii or move the corners apart")


def from_polygon(corners, radii, width: float = 1.07, length: float | None = None, *,
                 name: str = "designed", min_radius: float = 0.6, gap: float = DEFAULT_GAP_M,
                 start: float | None = None) -> Track:
    """A track drawn as a polygon (metres) whose corners are rounded off by circular bends of `radii`.

    A hairpin is two close corners of about 90 degrees each; a chicane, two small opposite corners.
    `start` puts the start line on edge int(start) (from corner i to corner i+1), that fraction of
    the way along its straight part; by default it goes on the longest straight. With `length`
    everything, radii too, is scaled to that length.
    """
    pts = np.asarray(corners, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.isfinite(pts).all():
        raise TrackError(f"{name}: a polygon needs at least 3 finite (x, y) corners, got shape {pts.shape}")
    r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(pts),))
    if np.any(np.hypot(*(np.roll(pts, -1, axis=0) - pts).T) <= 1e-9):
        raise TrackError(f"{name}: two consecutive corners are the same point; remove one")
    if not np.all(r > 0):
        raise TrackError(f"{name}: every corner radius must be positive, got {r.tolist()}")
    if problem := _fit_problem(pts, r):
        raise TrackError(f"{name}: {problem}")
    control, straight_starts = polygon_control_points(pts, r)
    start_xy = None
    if start is not None:
        e = int(start) % len(pts)
        a, b = control[straight_starts[e]], _straight_end(pts, r, e)
        start_xy = a + (start - int(start)) * (b - a)
    return _finish(control, width, length, name, min_radius, gap, start_xy)


def _straight_end(corners: np.ndarray, radii: np.ndarray, e: int) -> np.ndarray:
    """Where the straight part of edge e ends: the entry of the bend at corner e + 1."""
    nxt = (e + 1) % len(corners)
    return corners[nxt] - _unit(corners[nxt] - corners[e]) * fillet_lengths(corners, radii)[nxt]


def random_polygon(rng: np.random.Generator, count: int, length: float, min_radius: float):
    """Corners of a random star-shaped polygon about `length` round, and a radius for each bend.

    Corner angles and radii are jittered; an occasional deep dent makes a hairpin-like bend. Each
    bend's radius is drawn between 1.2 and 4 times `min_radius` and shrunk to fit its edges.
    """
    angles = 2 * np.pi * (np.arange(count) + rng.uniform(-0.3, 0.3, count)) / count
    dist = 1.0 + rng.uniform(-0.3, 0.3, count)
    dents = rng.random(count) < 0.25
    dist[dents] *= rng.uniform(0.3, 0.6, int(dents.sum()))
    poly = np.stack([np.cos(angles), np.sin(angles)], axis=1) * dist[:, None]
    poly[:, 0] *= rng.uniform(1.0, 2.0)
    turn = rng.uniform(0, 2 * np.pi)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    poly = poly @ rot.T
    poly *= length / np.sum(np.hypot(*(np.roll(poly, -1, axis=0) - poly).T))
    return poly, _fitted(poly, rng.uniform(1.2, 4.0, count) * min_radius)


def _fitted(corners: np.ndarray, radii: np.ndarray) -> np.ndarray:
    """The radii shrunk where needed so that each bend takes at most half of each edge next to it."""
    edges = np.hypot(*(np.roll(corners, -1, axis=0) - corners).T)
    room = 0.5 * np.minimum(edges, np.roll(edges, 1))
    tan = np.tan(np.abs(_deflections(corners)) / 2)
    with np.errstate(divide="ignore"):
        limit = np.where(tan > 1e-9, room / tan, np.inf)
    return np.minimum(radii, limit)


def _ease(corners: np.ndarray, radii: np.ndarray, at: int) -> tuple[np.ndarray, np.ndarray]:
    """Open up the bend at corner `at`: a larger radius if it fits, else a flatter corner."""
    corners, radii = corners.copy(), radii.copy()
    wider = radii.copy()
    wider[at] *= 1.25
    if _fitted(corners, wider)[at] > radii[at] * 1.01:
        radii[at] = _fitted(corners, wider)[at]
    else:
        mid = 0.5 * (corners[at - 1] + corners[(at + 1) % len(corners)])
        corners[at] += 0.3 * (mid - corners[at])
        radii = _fitted(corners, radii)
    return corners, radii


def generate(seed: int, length: float = 20.0, width: float = 1.07, min_radius: float = 0.6, *,
             gap: float = DEFAULT_GAP_M, name: str | None = None) -> Track:
    """A random valid circuit, the same for the same arguments.

    A random rounded polygon whose bends are too tight is eased, bend by bend; a polygon whose road
    runs into itself is dropped for the next one. After `MAX_ATTEMPTS` polygons the error says what
    went wrong last.
    """
    _check_request(length, width, min_radius, gap)
    if isinstance(seed, bool) or not isinstance(seed, int | np.integer) or seed < 0:
        raise TrackError(f"seed must be a non-negative integer, got {seed!r}")
    rng = np.random.default_rng(int(seed))
    count = int(np.clip(round(length / 4.0), 5, 12))
    problem = "no attempt made"
    for _ in range(MAX_ATTEMPTS):
        corners, radii = random_polygon(rng, count + int(rng.integers(-1, 3)), length, min_radius)
        for _ in range(MAX_EASING):
            built = _build(polygon_control_points(corners, radii)[0], width, length, min_radius, gap, None)
            if built.arr is not None:
                return from_array(built.arr, name=name or f"generated_{seed}", source="generated")
            problem = built.problem
            if built.sharp_at is None:
                break
            at = int(np.argmin(np.hypot(*(corners - built.sharp_at).T)))
            corners, radii = _ease(corners, radii, at)
    raise TrackError(f"no valid track for seed {seed} (length {length:g} m, width {width:g} m, min_radius "
                     f"{min_radius:g} m) after {MAX_ATTEMPTS} attempts; last problem: {problem}. "
                     f"Try another seed, a longer length or a narrower width")


def turn_angles(track: Track, max_radius: float = 2.0) -> list[tuple[float, float, float]]:
    """The turns of a track as (start s, end s, heading change in degrees, + = left), in driving order.

    A turn is a run of waypoints tighter than `max_radius` bending the same way (as `Track.turns`).
    """
    k = track.curvature[:-1] if track.closed else track.curvature
    sign = np.where(np.abs(k) > 1.0 / max_radius, np.sign(k), 0).astype(int)
    n = len(sign)
    quiet = np.flatnonzero(sign == 0)
    first = int(quiet[0]) if (track.closed and quiet.size) else 0
    seg_len = track.segment_lengths
    turns = []
    i = 0
    while i < n:
        j = (first + i) % n
        if sign[j] == 0:
            i += 1
            continue
        run = [j]
        while i + 1 < n and sign[(first + i + 1) % n] == sign[j]:
            i += 1
            run.append((first + i) % n)
        ds = 0.5 * (seg_len[np.array(run)] + seg_len[np.array(run) - 1])
        angle = float(np.degrees(np.sum(k[run] * ds)))
        turns.append((float(track.waypoint_s[run[0]]), float(track.waypoint_s[run[-1]]), angle))
        i += 1
    return turns
