"""`Track`: a DeepRacer track as centre line and borders in driving direction, with arc length.

A track file is an (N, 6) float array in metres: centre x, y; inner border x, y; outer border
x, y (the AWS route format, see ../shared/tracks/README.md). Loading follows the AWS simulator
(simapp v6): consecutive duplicate centre points are dropped, a loop is a file whose last row
equals its first (and keeps that closing row, so `waypoints` has first == last), and reverse
driving reverses every line, keeping waypoint 0 where it was.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import NamedTuple

import numpy as np

from racerlab.errors import TrackError
from racerlab.track import kernels as K


class Projection(NamedTuple):
    """Batched projection of points onto a track's centre line (all arrays have the points' length)."""

    s: np.ndarray  # arc length from waypoint 0 along the driving direction, m
    lateral: np.ndarray  # signed offset from the centre line, + = left of the driving direction, m
    segment: np.ndarray  # index i of the centre segment (waypoint i to i+1)
    t: np.ndarray  # fraction along that segment
    width: np.ndarray  # local border-to-border width, m
    heading: np.ndarray  # centre-line direction at the projection, rad
    curvature: np.ndarray  # signed centre-line curvature there, 1/m (+ = turning left)


@dataclass(frozen=True, eq=False)
class Track:
    """Centre line and borders of a track, ordered in the driving direction.

    `center`, `inner`, `outer` are (N, 2); for loops row N-1 repeats row 0. `left` and `right`
    are the borders as seen by a car driving the track: for a counter-clockwise drive the
    inner border is on the left.
    """

    name: str
    center: np.ndarray
    inner: np.ndarray
    outer: np.ndarray
    closed: bool
    reversed: bool = False
    source: str = ""
    _file_ccw: bool = field(default=True, repr=False)

    # ---- basic geometry -------------------------------------------------------------------
    @cached_property
    def segment_lengths(self) -> np.ndarray:
        return np.hypot(*np.diff(self.center, axis=0).T)

    @cached_property
    def waypoint_s(self) -> np.ndarray:
        """Arc length of each waypoint from waypoint 0 (the last of a loop is `length`)."""
        return np.concatenate([[0.0], np.cumsum(self.segment_lengths)])

    @property
    def length(self) -> float:
        return float(self.waypoint_s[-1])

    @property
    def num_waypoints(self) -> int:
        return int(self.center.shape[0])

    @cached_property
    def widths(self) -> np.ndarray:
        """Border-to-border width at each waypoint (distance between the rows' border points)."""
        return np.hypot(*(self.inner - self.outer).T)

    @property
    def width(self) -> float:
        """Mean width over the waypoints, m."""
        w = self.widths[:-1] if self.closed else self.widths
        return float(w.mean())

    @property
    def is_ccw(self) -> bool:
        """True when the car drives counter-clockwise (open tracks count as CCW, as in AWS)."""
        return self._file_ccw != self.reversed

    @property
    def left(self) -> np.ndarray:
        return self.inner if self.is_ccw else self.outer

    @property
    def right(self) -> np.ndarray:
        return self.outer if self.is_ccw else self.inner

    @cached_property
    def segment_headings(self) -> np.ndarray:
        d = np.diff(self.center, axis=0)
        return np.arctan2(d[:, 1], d[:, 0])

    @cached_property
    def curvature(self) -> np.ndarray:
        """Signed curvature at each waypoint from the circle through it and its neighbours, 1/m."""
        c = self.center
        if self.closed:
            prev = np.vstack([c[-2:-1], c[:-1]])
            nxt = np.vstack([c[1:], c[1:2]])
        else:
            prev = np.vstack([c[:1], c[:-1]])
            nxt = np.vstack([c[1:], c[-1:]])
        a = c - prev
        b = nxt - c
        cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        denom = np.hypot(*a.T) * np.hypot(*b.T) * np.hypot(*(nxt - prev).T)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.where(denom > 0, 2.0 * cross / denom, 0.0)
        return k

    @property
    def waypoints(self) -> list[tuple[float, float]]:
        """Centre points as a list of (x, y) tuples in driving direction, as the reward function sees them."""
        return [tuple(p) for p in self.center.tolist()]

    # ---- projection ----------------------------------------------------------------------
    def project(self, points, hints=None) -> Projection:
        """Project (B, 2) points onto the centre line; `hints` are optional nearby segment indices."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        n = pts.shape[0]
        h = np.full(n, -1, np.int64) if hints is None else np.asarray(hints, np.int64).reshape(n)
        seg = np.empty(n, np.int64)
        t = np.empty(n)
        s = np.empty(n)
        lat = np.empty(n)
        K.project_many(pts, self.center, self.segment_lengths, self.waypoint_s, self.closed, h,
                       seg, t, s, lat)
        w = self.widths[seg] * (1 - t) + self.widths[seg + 1] * t
        k = self.curvature[seg] * (1 - t) + self.curvature[seg + 1] * t
        return Projection(s, lat, seg, t, w, self.segment_headings[seg], k)

    def point_at(self, s) -> np.ndarray:
        """Centre-line points at arc lengths `s` (wrapped for loops): (B, 2)."""
        s = np.asarray(s, dtype=np.float64)
        if self.closed:
            s = np.mod(s, self.length)
        xs = np.interp(s, self.waypoint_s, self.center[:, 0])
        ys = np.interp(s, self.waypoint_s, self.center[:, 1])
        return np.stack([xs, ys], axis=-1)

    def heading_at(self, s) -> np.ndarray:
        """Centre-line direction (rad) at arc lengths `s`."""
        s = np.asarray(s, dtype=np.float64)
        if self.closed:
            s = np.mod(s, self.length)
        seg = np.clip(np.searchsorted(self.waypoint_s, s, side="right") - 1, 0, len(self.segment_headings) - 1)
        return self.segment_headings[seg]

    # ---- road polygon ---------------------------------------------------------------------
    @cached_property
    def road_edges(self) -> np.ndarray:
        """All edges of the road polygon as (E, 4) [x1, y1, x2, y2]; even-odd inside = on the road."""
        if self.closed:
            rings = [self.outer, self.inner]
        else:
            # AWS: one ring, outer then the reversed inner border.
            ring = np.vstack([self.outer, self.inner[::-1], self.outer[:1]])
            rings = [ring]
        return np.vstack([np.hstack([r[:-1], r[1:]]) for r in rings])

    @cached_property
    def road_index(self):
        return K.build_road_index(self.road_edges)

    def contains(self, points) -> np.ndarray:
        """True for points strictly on the road surface (between the borders)."""
        pts = np.ascontiguousarray(np.asarray(points, dtype=np.float64).reshape(-1, 2))
        out = np.empty(pts.shape[0], dtype=np.bool_)
        bs, be, y0, bh = self.road_index
        K.contains_many(pts, self.road_edges, bs, be, y0, bh, out)
        return out

    # ---- variants -------------------------------------------------------------------------
    def reverse(self) -> Track:
        """The same track driven the other way: every line reversed, waypoint 0 kept in place."""
        return Track(self.name, self.center[::-1].copy(), self.inner[::-1].copy(), self.outer[::-1].copy(),
                     self.closed, not self.reversed, self.source, self._file_ccw)

    def as_array(self) -> np.ndarray:
        """The (N, 6) AWS layout of this track in its driving direction."""
        return np.hstack([self.center, self.inner, self.outer])

    def turns(self, max_radius: float = 2.0) -> int:
        """Number of distinct turns: runs of waypoints tighter than `max_radius` with the same sign."""
        k = self.curvature[:-1] if self.closed else self.curvature
        sign = np.where(np.abs(k) > 1.0 / max_radius, np.sign(k), 0).astype(int)
        if not sign.any():
            return 0
        if self.closed:
            # start the scan where no turn is running so a turn across waypoint 0 counts once
            quiet = np.flatnonzero(sign == 0)
            start = int(quiet[0]) if quiet.size else 0
            sign = np.roll(sign, -start)
        runs = 0
        prev = 0
        for v in sign:
            if v != 0 and v != prev:
                runs += 1
            prev = v
        return runs

    def __repr__(self) -> str:
        kind = "loop" if self.closed else "open"
        rev = ", reversed" if self.reversed else ""
        return (f"Track({self.name!r}, {kind}{rev}, {self.num_waypoints} waypoints, "
                f"length {self.length:.2f} m, width {self.width:.3f} m)")


# ---- construction and validation ---------------------------------------------------------------

def ring_area(ring: np.ndarray) -> float:
    """Signed shoelace area of a closed ring (last row may repeat the first); > 0 = CCW."""
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _drop_repeated(arr: np.ndarray) -> np.ndarray:
    """Drop rows whose centre point equals the previous row's (simapp v6 sanitising)."""
    keep = np.ones(len(arr), dtype=bool)
    keep[1:] = np.any(arr[1:, :2] != arr[:-1, :2], axis=1)
    return arr[keep]


def segments_cross(a: np.ndarray, b: np.ndarray, skip_adjacent: bool, chunk: int = 256) -> tuple[int, int] | None:
    """First pair (i, j) of properly intersecting segments between polylines a and b, or None.

    `chunk` segments of a at a time, each against the segments of b whose bounding boxes meet the chunk's: memory
    stays O(chunk × len(b)) at worst (a 10 000-point track took 3 GB as one matrix), time near O(len(a)) on a
    track whose borders are not tangled."""
    p_all, r_all = a[:-1], np.diff(a, axis=0)
    q, s = b[:-1], np.diff(b, axis=0)
    n = len(p_all)
    b_lo, b_hi = np.minimum(q, q + s), np.maximum(q, q + s)
    for k in range(0, n, chunk):
        p, r = p_all[k:k + chunk], r_all[k:k + chunk]
        lo, hi = np.minimum(p, p + r).min(axis=0), np.maximum(p, p + r).max(axis=0)
        near = np.flatnonzero(np.all((b_hi >= lo) & (b_lo <= hi), axis=1))
        if near.size == 0:
            continue
        hit = _crossing(p, r, q[near], s[near])
        if skip_adjacent:
            d = np.abs(np.arange(k, k + len(p))[:, None] - near[None, :])
            hit &= (d > 1) & (d < n - 1)
        idx = np.argwhere(hit)
        if idx.size:
            return k + int(idx[0, 0]), int(near[idx[0, 1]])
    return None


def _crossing(p, r, q, s) -> np.ndarray:
    """(len(p), len(q)): segment p + t·r properly crosses segment q + u·s."""
    rxs = r[:, None, 0] * s[None, :, 1] - r[:, None, 1] * s[None, :, 0]
    qp = q[None, :, :] - p[:, None, :]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s[None, :, 1] - qp[..., 1] * s[None, :, 0]) / rxs
        u = (qp[..., 0] * r[:, None, 1] - qp[..., 1] * r[:, None, 0]) / rxs
    eps = 1e-9
    return (np.abs(rxs) > 1e-15) & (t > eps) & (t < 1 - eps) & (u > eps) & (u < 1 - eps)


def from_array(arr, name: str = "track", source: str = "") -> Track:
    """Build a `Track` from an (N, 6) array, checking it; errors name `source` (or `name`)."""
    where = source or name
    a = np.asarray(arr)
    if a.ndim != 2 or a.shape[1] != 6:
        raise TrackError(f"{where}: expected an array of shape (N, 6) [centre x, y, inner x, y, outer x, y], "
                         f"got shape {a.shape}; export the waypoints in the AWS route format")
    if not np.issubdtype(a.dtype, np.number):
        raise TrackError(f"{where}: waypoints must be numbers, got dtype {a.dtype}")
    a = a.astype(np.float64)
    bad = ~np.isfinite(a).all(axis=1)
    if bad.any():
        rows = np.flatnonzero(bad)[:5].tolist()
        raise TrackError(f"{where}: NaN or infinite coordinates in rows {rows}; fix or remove those rows")
    closed = a.shape[0] > 1 and bool(np.array_equal(a[0], a[-1]))
    a = _drop_repeated(a)
    distinct = a.shape[0] - (1 if closed else 0)
    if distinct < 3:
        raise TrackError(f"{where}: only {distinct} distinct waypoints; a track needs at least 3")
    center, inner, outer = a[:, 0:2].copy(), a[:, 2:4].copy(), a[:, 4:6].copy()
    _check_borders(where, inner, outer, closed)
    file_ccw = ring_area(center) > 0 if closed else True
    return Track(name, center, inner, outer, closed, False, source, file_ccw)


def _check_borders(where: str, inner: np.ndarray, outer: np.ndarray, closed: bool) -> None:
    hit = segments_cross(inner, outer, skip_adjacent=False)
    if hit is not None:
        raise TrackError(f"{where}: the inner and outer borders cross (inner segment {hit[0]}, outer segment "
                         f"{hit[1]}); columns 2-3 and 4-5 must be two separate borders")
    if closed and abs(ring_area(outer)) <= abs(ring_area(inner)):
        raise TrackError(f"{where}: the outer border (columns 4-5) encloses no more area than the inner border "
                         f"(columns 2-3); swap the two column pairs")


def load_file(path, name: str | None = None) -> Track:
    """Load an AWS-format `.npy` track file (also `.csv`/`.txt` with 6 comma-separated columns)."""
    p = Path(path)
    nm = name or _track_name(p)
    if not p.is_file():
        raise TrackError(f"{p}: no such track file")
    try:
        if p.suffix.lower() in (".csv", ".txt"):
            arr = np.loadtxt(p, delimiter=",", ndmin=2)
        else:
            arr = np.load(p, allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - any read failure is the user's file
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        if "pickle" in first:  # NumPy's wording for a file that is not a .npy array at all
            first = "not a NumPy .npy array file"
        raise TrackError(f"{p}: cannot read the track file ({first}); expected a NumPy .npy of shape (N, 6)") from None
    return from_array(arr, name=nm, source=str(p))


def _track_name(p: Path) -> str:
    return p.name[: -len(p.suffix)] if p.suffix else p.name
