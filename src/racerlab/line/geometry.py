"""Geometry for the racing-line solvers: closed curves resampled by arc length, normals, curvature,
and how far a point may move along a normal before the car touches a border.

Loops are stored *without* the repeated closing point: (M, 2) arrays whose row M-1 is followed by
row 0; functions that also take open paths have a `closed` flag.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import CubicSpline

from racerlab.track import Track


def arc_length(xy: np.ndarray, closed: bool = True) -> np.ndarray:
    """Arc length at each point; for a loop one more entry at the end, the loop length."""
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])


def _spacing(length: float, n: int, closed: bool) -> np.ndarray:
    return np.arange(n) * (length / n) if closed else np.linspace(0.0, length, n)


def resample_polyline(xy: np.ndarray, n: int, closed: bool = True) -> np.ndarray:
    """`n` points evenly spaced along the polygon `xy` (straight segments, so it stays inside the road)."""
    s = arc_length(xy, closed)
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    u = _spacing(s[-1], n, closed)
    return np.stack([np.interp(u, s, pts[:, 0]), np.interp(u, s, pts[:, 1])], axis=1)


def resample_smooth(xy: np.ndarray, n: int, closed: bool = True, start: np.ndarray | None = None) -> np.ndarray:
    """`n` points evenly spaced by arc length along the cubic spline through `xy` (periodic for a loop).

    With `start` (loops), the first point is the spline's point nearest to `start` (projected onto
    a dense sampling, not snapped to a sample, so that the points do not jitter along the curve
    from one call to the next), which keeps a line beginning abreast of the track's start.
    """
    s = arc_length(xy, closed)
    pts = np.vstack([xy, xy[:1]]) if closed else xy
    spline = CubicSpline(s, pts, bc_type="periodic" if closed else "natural")
    period = float(s[-1])
    u = np.linspace(0.0, period, 16 * n + 1)
    dense = spline(u)
    sd = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dense, axis=0).T))])
    s0 = _project_arc(dense, sd, start) if closed and start is not None else 0.0
    at = s0 + _spacing(sd[-1], n, closed)
    uw = np.interp(np.mod(at, sd[-1]) if closed else at, sd, u)
    return spline(uw)


def _project_arc(poly: np.ndarray, arc: np.ndarray, point: np.ndarray) -> float:
    """Arc length along the polyline `poly` (with its cumulative `arc`) of the point nearest to `point`."""
    a, d = poly[:-1], np.diff(poly, axis=0)
    dd = np.maximum(np.einsum("ij,ij->i", d, d), 1e-24)
    t = np.clip(np.einsum("ij,ij->i", point - a, d) / dd, 0.0, 1.0)
    dist = np.hypot(*(a + t[:, None] * d - point).T)
    i = int(np.argmin(dist))
    return float(arc[i] + t[i] * (arc[i + 1] - arc[i]))


def tangents(xy: np.ndarray, closed: bool = True) -> np.ndarray:
    """Unit tangents by central differences (one-sided at the ends of an open path)."""
    if closed:
        d = np.roll(xy, -1, axis=0) - np.roll(xy, 1, axis=0)
    else:
        d = np.gradient(xy, axis=0)
    return d / np.maximum(np.hypot(*d.T), 1e-12)[:, None]


def left_normals(xy: np.ndarray, closed: bool = True) -> np.ndarray:
    """Unit normals pointing to the left of the driving direction."""
    t = tangents(xy, closed)
    return np.stack([-t[:, 1], t[:, 0]], axis=1)


def menger_curvature(xy: np.ndarray, closed: bool = True) -> np.ndarray:
    """Signed curvature (1/m, + = turning left) of the circle through each point and its two neighbours.

    The two end points of an open path get their neighbour's value.
    """
    prev, nxt = np.roll(xy, 1, axis=0), np.roll(xy, -1, axis=0)
    a, b = xy - prev, nxt - xy
    cross = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    denom = np.hypot(*a.T) * np.hypot(*b.T) * np.hypot(*(nxt - prev).T)
    k = np.divide(2.0 * cross, denom, out=np.zeros_like(cross), where=denom > 0)
    if not closed and len(k) > 2:
        k[0], k[-1] = k[1], k[-2]
    return k


def border_segments(track: Track) -> tuple[np.ndarray, np.ndarray]:
    """Start points and vectors (E, 2) of every segment of both borders (an open track's ends are no border)."""
    lines = (track.inner, track.outer)
    return (np.vstack([b[:-1] for b in lines]).copy(), np.vstack([np.diff(b, axis=0) for b in lines]))


def grown_border_segments(track: Track, by: float) -> tuple[np.ndarray, np.ndarray]:
    """`border_segments` of the road grown by `by` m on both sides: each border segment moved `by` away from the
    road, consecutive ones joined by the chord across the gap at a bend that opens outward.

    At a bend that opens toward the road the moved segments cross and their ends lie less than `by` from the
    border: a few mm at the bends of a sampled border, on the side of a smaller road.
    """
    starts, vecs = [], []
    for border, other in ((track.inner, track.outer), (track.outer, track.inner)):
        d = np.diff(border, axis=0)
        n = np.stack([-d[:, 1], d[:, 0]], axis=1) / np.maximum(np.hypot(*d.T), 1e-12)[:, None]
        toward_road = 0.5 * (other[:-1] + other[1:]) - 0.5 * (border[:-1] + border[1:])
        n *= np.where(np.einsum("ij,ij->i", n, toward_road) > 0, -1.0, 1.0)[:, None]  # away from the road
        a, b = border[:-1] + by * n, border[1:] + by * n
        nxt = np.roll(np.arange(len(a)), -1) if track.closed else np.arange(1, len(a))
        ends = b[: len(nxt)]
        starts += [a, ends]
        vecs += [b - a, a[nxt] - ends]
    return np.vstack(starts).copy(), np.vstack(vecs)


def lateral_room(origin: np.ndarray, normal: np.ndarray, seg_a: np.ndarray, seg_d: np.ndarray,
                 clearance, reach: float, chunk: int = 32) -> tuple[np.ndarray, np.ndarray]:
    """How far each point may move along its normal (lo, hi in m) and keep `clearance` to every border.

    `clearance` is a scalar or (M,); `reach` bounds the room on each side (the road's width will
    do). Moving point o to o + α·n, the α within `clearance` of one border segment form an
    interval (the line meets the segment's capsule, a convex set); the free room is the gap between
    the nearest such interval on each side of α = 0, so it is exact for any border shape, corners
    and kinks included. A capsule that already holds the point (it is too close) bounds the side
    the segment lies on, so lo > hi only where the road is too narrow. Each chunk of consecutive
    points only looks at the segments that can be within `reach` + clearance of it.
    """
    m = len(origin)
    lo, hi = np.full(m, -reach), np.full(m, reach)
    clear = np.broadcast_to(np.asarray(clearance, dtype=np.float64), (m,))
    seg_len = np.maximum(np.hypot(*seg_d.T), 1e-12)
    u_dir = seg_d / seg_len[:, None]  # unit vector along each segment
    seg_lo, seg_hi = np.minimum(seg_a, seg_a + seg_d), np.maximum(seg_a, seg_a + seg_d)
    for k in range(0, m, chunk):
        o, n, c = origin[k:k + chunk], normal[k:k + chunk], clear[k:k + chunk]
        pad = reach + float(c.max())
        near = np.all((seg_hi >= o.min(axis=0) - pad) & (seg_lo <= o.max(axis=0) + pad), axis=1)
        if not near.any():
            continue
        a, d, u, ln = seg_a[near][None], seg_d[near][None], u_dir[near][None], seg_len[near][None]
        o3, n3 = o[:, None, :], n[:, None, :]
        a1, a2 = _capsule_hits(o3, n3, c[:, None], a, d, u, ln)
        # which side of the point each segment lies on: the normal component of its nearest point
        rel = a - o3
        t = np.clip(np.einsum("ijk,ijk->ij", -rel, np.broadcast_to(u, rel.shape)), 0.0, ln)
        side = np.einsum("ijk,ijk->ij", rel + t[..., None] * u, np.broadcast_to(n3, rel.shape))
        holds = (a1 <= 0) & (a2 >= 0)
        ahead = (a1 > 0) | (holds & (side > 0))
        behind = (a2 < 0) | (holds & (side <= 0))
        hi[k:k + chunk] = np.minimum(hi[k:k + chunk], np.min(np.where(ahead, a1, np.inf), axis=1))
        lo[k:k + chunk] = np.maximum(lo[k:k + chunk], np.max(np.where(behind, a2, -np.inf), axis=1))
    return lo, hi


def _capsule_hits(o, n, c, a, d, u_dir, length):
    """Interval [a1, a2] of α where o + α·n is within `c` of segment (a, a + d); (inf, -inf) if none.

    The capsule is the union of the two end discs and the band |w| < c over 0 ≤ u ≤ length (u, w
    the point's coordinates along and across the segment); it is convex, so the line meets it in
    one interval, the hull of what it meets of the three parts.
    """
    lo = np.full(np.broadcast_shapes(o.shape[:2], a.shape[:2]), np.inf)
    hi = -lo
    for centre in (a, a + d):
        rel = o - centre
        b = np.einsum("ijk,ijk->ij", rel, np.broadcast_to(n, rel.shape))
        disc = b * b - np.einsum("ijk,ijk->ij", rel, rel) + c * c
        root = np.sqrt(np.maximum(disc, 0.0))
        lo = np.where(disc >= 0, np.minimum(lo, -b - root), lo)
        hi = np.where(disc >= 0, np.maximum(hi, -b + root), hi)
    rel = o - a
    w_dir = np.stack([-u_dir[..., 1], u_dir[..., 0]], axis=-1)
    u0, un = _along(rel, n, u_dir)
    w0, wn = _along(rel, n, w_dir)
    with np.errstate(divide="ignore", invalid="ignore"):
        band_lo = np.maximum(_slab(u0, un, 0.0, length)[0], _slab(w0, wn, -c, c)[0])
        band_hi = np.minimum(_slab(u0, un, 0.0, length)[1], _slab(w0, wn, -c, c)[1])
    band = (band_lo < band_hi) & (length > 1e-12)  # a segment of (clamped) zero length is its end discs only
    return np.where(band, np.minimum(lo, band_lo), lo), np.where(band, np.maximum(hi, band_hi), hi)


def _along(rel, n, direction):
    """Coordinate of o and rate of change per unit α along `direction`."""
    return (np.einsum("ijk,ijk->ij", rel, np.broadcast_to(direction, rel.shape)),
            np.einsum("ijk,ijk->ij", np.broadcast_to(n, rel.shape), np.broadcast_to(direction, rel.shape)))


def _slab(x0, rate, low, high):
    """α interval where low < x0 + α·rate < high (all α or none when rate is 0)."""
    t1, t2 = (low - x0) / rate, (high - x0) / rate
    inside = (x0 > low) & (x0 < high)
    flat = rate == 0
    a = np.where(flat, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2))
    b = np.where(flat, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2))
    return a, b


def border_distance(points: np.ndarray, seg_a: np.ndarray, seg_d: np.ndarray, chunk: int = 256) -> np.ndarray:
    """Distance from each point to the nearest border segment, m."""
    out = np.empty(len(points))
    dd = np.maximum(np.einsum("ij,ij->i", seg_d, seg_d), 1e-24)
    for k in range(0, len(points), chunk):
        p = points[k:k + chunk]
        ap = p[:, None, :] - seg_a[None, :, :]
        t = np.clip(np.einsum("ijk,jk->ij", ap, seg_d) / dd[None, :], 0.0, 1.0)
        q = ap - t[..., None] * seg_d[None, :, :]
        out[k:k + chunk] = np.sqrt(np.min(np.einsum("ijk,ijk->ij", q, q), axis=1))
    return out
