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
DEFAULT_GAP_M = 0.3  # grass between two different parts of the road
STRAIGHT_RADIUS_M = 3.0  # a part of the centre line with a larger radius counts as straight-ish
MAX_ATTEMPTS = 40  # random control polygons tried per seed before giving up
MAX_EASING = 40  # bends eased on one random polygon before it is dropped
MAX_ROUNDING = 0.45  # at most this fraction of each edge next to a corner is bend


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
    sharp_at: np.ndarray | None = None  # for a bend too tight: where it is, in control-point units


def _build(points, width: float, length: float, min_radius: float, gap: float, start: float | None) -> _Built:
    """The track through these control points, or the first reason it is not drivable."""
    spline = _spline(points)
    curve = _dense(spline, length)
    problem = _radius_problem(curve, min_radius)
    if problem:
        return _Built(None, problem, spline(curve.t[_sharpest(curve)]))
    if start is None:
        start_s = _start_s(curve)
    else:
        knot = np.interp(start % (len(spline.x) - 1), np.arange(len(spline.x)), spline.x)
        start_s = float(np.interp(knot, curve.t, curve.s))
    center, normal = _waypoints(spline, curve, start_s, WAYPOINT_SPACING_M)
    spacing = curve.length / len(center)
    problem = _crowding_problem(center, width, gap, spacing)
    if problem:
        return _Built(None, problem)
    arr = _aws_array(center, normal, width)
    problem = _crossing_problem(arr)
    return _Built(None if problem else arr, problem)


def from_control_points(points, width: float = 1.07, length: float | None = None, *, name: str = "designed",
                        min_radius: float = 0.6, gap: float = DEFAULT_GAP_M,
                        start: float | None = None) -> Track:
    """A track through designed control points (metres; scaled to `length` when given).

    `start` puts the start line at control point `start` (fractions go between points); by default
    it goes on the longest straight. Raises `TrackError` with the reason when the result is not drivable.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 4 or not np.isfinite(pts).all():
        raise TrackError(f"{name}: control points must be at least 4 finite (x, y) pairs, got shape {pts.shape}")
    if length is None:
        length = _sample(_spline(pts), 1.0, 4000).length
    _check_request(length, width, min_radius, gap)
    built = _build(pts, width, length, min_radius, gap, start)
    if built.problem:
        raise TrackError(f"{name}: {built.problem}; move the control points or ask for a longer track")
    return from_array(built.arr, name=name, source="generated")


def random_polygon(rng: np.random.Generator, corners: int) -> tuple[np.ndarray, np.ndarray]:
    """Corners of a random star-shaped polygon and how much each is rounded off.

    Corner angles and radii are jittered; an occasional deep dent makes a hairpin-like bend. The
    rounding of a corner is the fraction of its two edges that the bend takes (the rest is straight).
    """
    angles = 2 * np.pi * (np.arange(corners) + rng.uniform(-0.3, 0.3, corners)) / corners
    radii = 1.0 + rng.uniform(-0.3, 0.3, corners)
    dents = rng.random(corners) < 0.25
    radii[dents] *= rng.uniform(0.3, 0.6, int(dents.sum()))
    poly = np.stack([np.cos(angles), np.sin(angles)], axis=1) * radii[:, None]
    poly[:, 0] *= rng.uniform(1.0, 2.0)
    turn = rng.uniform(0, 2 * np.pi)
    rot = np.array([[np.cos(turn), -np.sin(turn)], [np.sin(turn), np.cos(turn)]])
    return poly @ rot.T, rng.uniform(0.1, 0.3, corners)


def polygon_control_points(corners: np.ndarray, rounding: np.ndarray) -> np.ndarray:
    """Control points for a rounded polygon: each corner, then two points on its edge to the next corner.

    The spline runs nearly straight between the two edge points, so `rounding` (a fraction of the
    edge, below 0.5) sets how long the bend at each corner is.
    """
    nxt = np.roll(corners, -1, axis=0)
    edge = nxt - corners
    near = corners + rounding[:, None] * edge
    far = nxt - np.roll(rounding, -1)[:, None] * edge
    return np.stack([corners, near, far], axis=1).reshape(-1, 2)


def _ease(corners: np.ndarray, rounding: np.ndarray, at: int) -> tuple[np.ndarray, np.ndarray]:
    """Open up the bend at corner `at`: round it off more; once that is used up, flatten the corner."""
    corners, rounding = corners.copy(), rounding.copy()
    if rounding[at] < MAX_ROUNDING:
        rounding[at] = min(rounding[at] + 0.07, MAX_ROUNDING)
    else:
        mid = 0.5 * (corners[at - 1] + corners[(at + 1) % len(corners)])
        corners[at] += 0.3 * (mid - corners[at])
    return corners, rounding


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
        corners, rounding = random_polygon(rng, count + int(rng.integers(-1, 3)))
        for _ in range(MAX_EASING):
            built = _build(polygon_control_points(corners, rounding), width, length, min_radius, gap, None)
            if built.arr is not None:
                return from_array(built.arr, name=name or f"generated_{seed}", source="generated")
            problem = built.problem
            if built.sharp_at is None:
                break
            at = int(np.argmin(np.hypot(*(corners - built.sharp_at).T)))
            corners, rounding = _ease(corners, rounding, at)
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
