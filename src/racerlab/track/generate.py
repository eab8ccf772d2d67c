"""Track generator: smooth closed circuits, checked so that a car can drive them.

Three entry points share one construction of waypoints and borders and one set of checks:

    >>> from racerlab.track.generate import generate, from_polygon, from_control_points
    >>> t = generate(seed=7, length=25.0, width=1.07)                       # a random circuit
    >>> t = from_polygon([(0, 0), (5, 0), (5, 3), (0, 3)], radii=1.5, width=1.07, length=15.0)
    >>> t = from_control_points([(0, 0), (4, 0), (4, 2), (0, 2)], width=0.76, length=18.0)

`from_polygon` (the bundled tracks and the random ones) rounds each corner of a polygon off with a
circular bend of the given radius and eases every change of curvature over `BLEND_M` metres, like
the transition curves of a real circuit: straights stay straight and no bend is tighter than its
radius. `from_control_points` runs a periodic cubic spline through free-form points instead.

Either centre line is scaled to the requested length, turned counter-clockwise, started on its
straightest part (or where asked) and sampled every ~0.15 m like the AWS route files. The borders
are offsets of the centre line by half the width, so the centre is exactly their midpoint and the
width is constant. A track is refused (`TrackError`) when a bend is tighter than `min_radius`,
when two parts of the road come closer than `gap` without being the same bend, or when a line
crosses itself.
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
BLEND_M = 0.3  # length over which the curvature of a polygon track changes at each end of a bend
DENSE_STEP_M = 0.005  # spacing of the dense centre line that the checks and the waypoints use
MAX_LENGTH_M = 300.0  # the crowding check is quadratic in waypoints; AWS tracks are under 100 m
RADIUS_TOLERANCE = 1e-4  # relative; the dense polyline's curvature of an exact arc is a hair high
MAX_ATTEMPTS = 40  # random polygons tried per seed before giving up
MAX_EASING = 40  # bends eased on one random polygon before it is dropped


@dataclass(frozen=True)
class _Curve:
    """A closed centre line sampled densely, in metres; row M repeats row 0.

    `label` tells which design element each sample came from (a polygon corner, the nearest one
    on a straight; -1 for spline curves), so that a bend that is too tight can be eased.
    """

    xy: np.ndarray  # (M+1, 2)
    s: np.ndarray  # (M+1,) arc length, s[0] == 0, s[-1] == length
    tangent: np.ndarray  # (M+1, 2) unit
    curvature: np.ndarray  # (M+1,) signed, 1/m
    label: np.ndarray  # (M+1,) int

    @property
    def length(self) -> float:
        return float(self.s[-1])

    @classmethod
    def from_xy(cls, xy: np.ndarray, label: np.ndarray | None = None) -> _Curve:
        """Arc length, tangents and curvature (turning angle per length) of a dense closed polyline."""
        seg = np.diff(xy, axis=0)
        seg_len = np.hypot(*seg.T)
        s = np.concatenate([[0.0], np.cumsum(seg_len)])
        heading = np.arctan2(seg[:, 1], seg[:, 0])
        turn = np.angle(np.exp(1j * (heading - np.roll(heading, 1))))  # at vertex i, from segment i-1 to i
        k = turn / (0.5 * (seg_len + np.roll(seg_len, 1)))
        t = seg / seg_len[:, None] + np.roll(seg, 1, axis=0) / np.roll(seg_len, 1)[:, None]
        t /= np.hypot(*t.T)[:, None]
        lab = np.full(len(xy), -1) if label is None else label
        return cls(xy, s, np.vstack([t, t[:1]]), np.append(k, k[0]), lab)


# ---- centre lines from a spline through control points ------------------------------------------

def _spline(points: np.ndarray) -> CubicSpline:
    """Periodic cubic spline through the control points, parametrised by chord length."""
    ring = np.vstack([points, points[:1]])
    chords = np.hypot(*np.diff(ring, axis=0).T)
    if np.any(chords <= 1e-9):
        i = int(np.flatnonzero(chords <= 1e-9)[0])
        raise TrackError(f"control points {i} and {(i + 1) % len(points)} are the same point; remove one")
    knots = np.concatenate([[0.0], np.cumsum(chords)])
    return CubicSpline(knots, ring, bc_type="periodic")


def _spline_length(spline: CubicSpline) -> float:
    raw = spline(np.linspace(spline.x[0], spline.x[-1], 4001))
    return float(np.sum(np.hypot(*np.diff(raw, axis=0).T)))


def _spline_curve(spline: CubicSpline, length: float | None) -> tuple[_Curve, np.ndarray]:
    """The spline's loop scaled to `length` (its own when None), and the s of each control point."""
    natural = _spline_length(spline)
    scale = 1.0 if length is None else length / natural
    samples = max(4000, int(natural * scale / DENSE_STEP_M))
    t = np.linspace(spline.x[0], spline.x[-1], samples + 1)
    xy = spline(t) * scale
    xy[-1] = xy[0]
    curve = _Curve.from_xy(xy)
    return curve, np.interp(spline.x[:-1], t, curve.s)


# ---- centre lines from rounded polygons ---------------------------------------------------------

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


class _Layout(NamedTuple):
    """A rounded polygon as a curvature profile over arc length u, starting at the entry of bend 0."""

    breaks: np.ndarray  # (2n+1,) u where the pieces begin: bend 0, straight 0, bend 1, straight 1, ...
    turned: np.ndarray  # (2n+1,) heading change from u = 0 to each break, rad
    heading0: float  # direction of the path at u = 0, rad
    entry0: np.ndarray  # where bend 0 begins


def _layout(corners: np.ndarray, radii: np.ndarray) -> _Layout:
    turns = _deflections(corners)
    d = fillet_lengths(corners, radii)
    edges = np.hypot(*(np.roll(corners, -1, axis=0) - corners).T)
    pieces = np.stack([radii * np.abs(turns), edges - d - np.roll(d, -1)], axis=1).ravel()
    bends = np.stack([turns, np.zeros_like(turns)], axis=1).ravel()
    u_in = _unit(corners[0] - corners[-1])
    return _Layout(np.concatenate([[0.0], np.cumsum(pieces)]), np.concatenate([[0.0], np.cumsum(bends)]),
                   float(np.arctan2(u_in[1], u_in[0])), corners[0] - u_in * d[0])


def _polygon_curve(corners: np.ndarray, radii: np.ndarray, length: float | None) -> tuple[_Curve, _Layout]:
    """The rounded polygon's centre line with each change of curvature spread over `BLEND_M`.

    The heading is the exact heading of the straights-and-arcs path averaged over a window of
    `BLEND_M` (so the curvature ramps linearly and never exceeds a bend's 1/radius); positions are
    its integral, and the few millimetres by which the smoothed loop misses its start are spread
    evenly along it (a constant tangent shift: no added curvature).
    """
    lay = _layout(corners, radii)
    total = float(lay.breaks[-1])
    scale = 1.0 if length is None else length / total
    m = max(2000, int(round(total * scale / DENSE_STEP_M)))
    du = total / m
    half = max(1, int(round(0.5 * BLEND_M / scale / du)))
    u = np.arange(-half, m + half + 1) * du  # the loop plus half a window on either side
    turned = np.interp(np.mod(u, total), lay.breaks, lay.turned) + np.floor_divide(u, total) * lay.turned[-1]
    area = np.concatenate([[0.0], np.cumsum(0.5 * (turned[1:] + turned[:-1]) * du)])
    heading = lay.heading0 + (area[2 * half:] - area[:-2 * half]) / (2 * half * du)  # (m+1,)
    mid = 0.5 * (heading[1:] + heading[:-1])
    xy = lay.entry0 + np.vstack([[0.0, 0.0], np.cumsum(du * np.stack([np.cos(mid), np.sin(mid)], axis=1), axis=0)])
    xy -= np.linspace(0.0, 1.0, m + 1)[:, None] * (xy[-1] - xy[0])
    xy[-1] = xy[0]
    if length is not None:  # smoothing cut the bends a little short; scale to the exact length
        xy *= length / float(np.sum(np.hypot(*np.diff(xy, axis=0).T)))
    return _Curve.from_xy(xy, _corner_labels(u[half:m + half + 1], lay, len(corners))), lay


def _corner_labels(u: np.ndarray, lay: _Layout, n: int) -> np.ndarray:
    """The corner each point belongs to: its bend, or the nearer end of its straight."""
    piece = np.clip(np.searchsorted(lay.breaks, u, side="right") - 1, 0, 2 * n - 1)
    corner = piece // 2
    on_straight = piece % 2 == 1
    past_middle = u > 0.5 * (lay.breaks[piece] + lay.breaks[piece + 1])
    return np.where(on_straight & past_middle, (corner + 1) % n, corner)


# ---- waypoints and borders ----------------------------------------------------------------------

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


def _waypoints(curve: _Curve, start_s: float, spacing: float) -> tuple[np.ndarray, np.ndarray]:
    """Centre points and unit left normals every ~`spacing` m from `start_s`, counter-clockwise."""
    n = max(8, int(round(curve.length / spacing)))
    s = (start_s + np.arange(n) * curve.length / n) % curve.length
    center = np.stack([np.interp(s, curve.s, curve.xy[:, i]) for i in (0, 1)], axis=1)
    tangent = _unit(np.stack([np.interp(s, curve.s, curve.tangent[:, i]) for i in (0, 1)], axis=1))
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
    for what, v in (("width", width), ("length", length), ("min_radius", min_radius)):
        if not (isinstance(v, int | float | np.number) and np.isfinite(v) and v > 0):
            raise TrackError(f"{what} must be a positive number of metres, got {v!r}")
    if min_radius < CAR_MIN_RADIUS_M:
        raise TrackError(f"min_radius {min_radius:g} m is tighter than the car can turn "
                         f"({CAR_MIN_RADIUS_M} m); use at least {CAR_MIN_RADIUS_M}")
    if min_radius < width / 2 + FOLD_MARGIN_M:
        raise TrackError(f"min_radius {min_radius:g} m is too tight for a {width:g} m wide road: the inner "
                         f"border would fold; use min_radius >= {width / 2 + FOLD_MARGIN_M:.3f} or a narrower width")
    if not (np.isfinite(gap) and gap >= 0):
        raise TrackError(f"gap must be >= 0 m, got {gap}")
    shortest = np.pi * max(2 * min_radius, width + gap)
    if length < shortest:
        raise TrackError(f"length {length:g} m is too short for width {width:g} m and min_radius {min_radius:g} m; "
                         f"use at least {shortest:.2f} m")
    if length > MAX_LENGTH_M:
        raise TrackError(f"length {length:g} m is longer than the generator makes ({MAX_LENGTH_M:g} m at most; "
                         f"coordinates are in metres)")


def _check_design(name: str, length: float, width: float, min_radius: float, gap: float) -> None:
    try:
        _check_request(length, width, min_radius, gap)
    except TrackError as exc:
        raise TrackError(f"{name}: {exc}") from None


def _sharpest(curve: _Curve) -> int:
    return int(np.argmax(np.abs(curve.curvature)))


def _radius_problem(curve: _Curve, min_radius: float, start_s: float) -> str | None:
    i = _sharpest(curve)
    radius = 1.0 / max(abs(curve.curvature[i]), 1e-12)
    if radius >= min_radius * (1 - RADIUS_TOLERANCE):
        return None
    at = (curve.s[i] - start_s) % curve.length
    return f"a bend of radius {radius:.2f} m at {at:.1f} m from the start is tighter than min_radius {min_radius:g} m"


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
    return (f"the road at {i * spacing:.1f} m and at {j * spacing:.1f} m from the start comes within "
            f"{max(d - width, 0):.2f} m of itself (needs a gap of {gap:g} m)")


def _crossing_problem(arr: np.ndarray) -> str | None:
    for col, what in ((0, "centre line"), (2, "inner border"), (4, "outer border")):
        line = arr[:, col:col + 2]
        if segments_cross(line, line, skip_adjacent=True) is not None:
            return f"the {what} crosses itself"
    return None


# ---- one construction for every entry point -----------------------------------------------------

class _Built(NamedTuple):
    arr: np.ndarray | None  # the (N+1, 6) AWS array, None when there is a problem
    problem: str | None  # the first problem found
    sharp_label: int | None = None  # for a bend too tight: the label of its design element


def _build(curve: _Curve, width: float, min_radius: float, gap: float, start_s: float | None) -> _Built:
    """The AWS array of the track along `curve`, or the first reason it is not drivable.

    The start line goes at `start_s` along the curve, by default a quarter into the longest straight.
    """
    start_s = _start_s(curve) if start_s is None else float(start_s) % curve.length
    problem = _radius_problem(curve, min_radius, start_s)
    if problem:
        return _Built(None, problem, int(curve.label[_sharpest(curve)]))
    center, normal = _waypoints(curve, start_s, WAYPOINT_SPACING_M)
    # chords cut the bends a little short: keep the waypoints' centre line exactly as long as the curve
    center = center * (curve.length / float(np.sum(np.hypot(*(np.roll(center, -1, axis=0) - center).T))))
    problem = _crowding_problem(center, width, gap, curve.length / len(center))
    if problem:
        return _Built(None, problem)
    arr = _aws_array(center, normal, width)
    problem = _crossing_problem(arr)
    return _Built(None if problem else arr, problem)


def _track(built: _Built, name: str, hint: str) -> Track:
    if built.problem:
        raise TrackError(f"{name}: {built.problem}; {hint}")
    return from_array(built.arr, name=name, source="generated")


def from_control_points(points, width: float = 1.07, length: float | None = None, *, name: str = "designed",
                        min_radius: float = 0.6, gap: float = DEFAULT_GAP_M, start: int | None = None) -> Track:
    """A track whose centre line is a smooth loop through `points` (metres; all scaled to `length`).

    `start` puts the start line at control point `start`; by default it goes on the longest
    straight. Raises `TrackError` with the reason when the result is not drivable.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 4 or not np.isfinite(pts).all():
        raise TrackError(f"{name}: control points must be at least 4 finite (x, y) pairs, got shape {pts.shape}")
    try:
        spline = _spline(pts)
    except TrackError as exc:
        raise TrackError(f"{name}: {exc}") from None
    _check_design(name, _spline_length(spline) if length is None else length, width, min_radius, gap)
    curve, knot_s = _spline_curve(spline, length)
    start_s = None if start is None else knot_s[int(start) % len(pts)]
    return _track(_build(curve, width, min_radius, gap, start_s), name, "move the points or ask for a longer track")


def _check_polygon(name: str, corners, radii) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(corners, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3 or not np.isfinite(pts).all():
        raise TrackError(f"{name}: a polygon needs at least 3 finite (x, y) corners, got shape {pts.shape}")
    try:
        r = np.broadcast_to(np.asarray(radii, dtype=np.float64), (len(pts),)).copy()
    except ValueError:
        raise TrackError(f"{name}: give one radius, or one per corner ({len(pts)}), got {np.shape(radii)}") from None
    if np.any(np.hypot(*(np.roll(pts, -1, axis=0) - pts).T) <= 1e-9):
        raise TrackError(f"{name}: two consecutive corners are the same point; remove one")
    if not np.all(np.isfinite(r) & (r > 0)):
        raise TrackError(f"{name}: every corner radius must be a positive number, got {r.tolist()}")
    if np.any(np.abs(_deflections(pts)) > np.radians(179)):
        raise TrackError(f"{name}: the polygon doubles back on itself at corner "
                         f"{int(np.argmax(np.abs(_deflections(pts))))}; make a hairpin of two corners")
    if problem := _fit_problem(pts, r):
        raise TrackError(f"{name}: {problem}")
    return pts, r


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
    pts, r = _check_polygon(name, corners, radii)
    _check_design(name, _layout(pts, r).breaks[-1] if length is None else length, width, min_radius, gap)
    curve, lay = _polygon_curve(pts, r, length)
    start_s = None
    if start is not None:
        e = int(start) % len(pts)
        u = lay.breaks[2 * e + 1] + (start - int(start)) * (lay.breaks[2 * e + 2] - lay.breaks[2 * e + 1])
        start_s = u / lay.breaks[-1] * curve.length
    return _track(_build(curve, width, min_radius, gap, start_s), name,
                  "use larger radii, move the corners or ask for a longer track")


# ---- random tracks ------------------------------------------------------------------------------

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


def _try_polygon(corners, radii, length, width, min_radius, gap) -> _Built:
    """Build one random polygon, easing its tightest bend until it is wide enough or it fails otherwise."""
    built = _Built(None, "no attempt made")
    for _ in range(MAX_EASING):
        if np.any(np.abs(_deflections(corners)) > np.radians(179)) or _fit_problem(corners, radii):
            return _Built(None, "the random polygon folded back on itself")
        built = _build(_polygon_curve(corners, radii, length)[0], width, min_radius, gap, None)
        if built.arr is not None or built.sharp_label is None:
            return built
        corners, radii = _ease(corners, radii, built.sharp_label)
    return built


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
        built = _try_polygon(corners, radii, length, width, min_radius, gap)
        if built.arr is not None:
            return from_array(built.arr, name=name or f"generated_{seed}", source="generated")
        problem = built.problem
    raise TrackError(f"no valid track for seed {seed} (length {length:g} m, width {width:g} m, min_radius "
                     f"{min_radius:g} m) after {MAX_ATTEMPTS} attempts; last problem: {problem}. "
                     f"Try another seed, a longer length or a narrower width")


def generate_many(seed: int, count: int, length=(20.0, 60.0), width=(0.76, 1.07), min_radius: float = 0.5,
                  *, prefix: str = "generated") -> list[Track]:
    """`count` random circuits drawn from one seed, the same for the same arguments: each length and width
    uniform in its (low, high) range, bends no tighter than `min_radius` (raised where a wide road needs
    it). A draw that yields no valid track is replaced by the next draw."""
    rng = np.random.default_rng(int(seed))
    tracks: list[Track] = []
    for _ in range(MAX_ATTEMPTS * max(count, 1)):
        if len(tracks) == count:
            return tracks
        w = float(rng.uniform(*width))
        radius = max(min_radius, w / 2 + FOLD_MARGIN_M + 0.05)
        try:
            tracks.append(generate(int(rng.integers(2**31)), float(rng.uniform(*length)), w, radius,
                                   name=f"{prefix}_{seed}_{len(tracks)}"))
        except TrackError:
            continue
    if len(tracks) < count:
        raise TrackError(f"only {len(tracks)} of {count} generated tracks are valid (length {length}, width {width}, "
                         f"min_radius {min_radius:g}); widen the length range or lower the width")
    return tracks


# ---- describing a track -------------------------------------------------------------------------

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
