"""Numba kernels for track geometry: projection onto a polyline and the point-in-road test.

They work on plain arrays so that the simulator can call them inside its own compiled step
without Python in between. `Track` wraps them with a friendly batched API.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# Segments examined on either side of a hint before falling back to a full search.
LOCAL_WINDOW = 6
LOCAL_MAX_DIST_M = 0.5


@njit(cache=True, inline="always")
def segment_distance_sq(px, py, ax, ay, dx, dy, seg_len_sq):
    """Squared distance from p to segment a + t*d, t in [0, 1]; returns (dist_sq, t)."""
    t = 0.0
    if seg_len_sq > 0.0:  # clamped to [0, 1] before dividing: the same t (division rounds monotonically), cheaper
        dot = (px - ax) * dx + (py - ay) * dy
        if dot >= seg_len_sq:
            t = 1.0
        elif dot > 0.0:
            t = dot / seg_len_sq
    qx = ax + t * dx - px
    qy = ay + t * dy - py
    return qx * qx + qy * qy, t


@njit(cache=True)
def nearest_segment(px, py, line, seg_len, closed, hint):
    """Nearest segment of polyline `line` (N x 2, N-1 segments) to point p.

    Searches `LOCAL_WINDOW` segments around `hint` first (the car moves little between steps)
    and searches the whole line when the hint is negative or the best candidate lies on the
    window's edge, so the result always equals the global nearest segment for a car that
    moved less than the window. Returns (segment, t, dist_sq).
    """
    nseg = line.shape[0] - 1
    best_i = -1
    best_d = np.inf
    best_t = 0.0
    if 0 <= hint < nseg and nseg > 2 * LOCAL_WINDOW + 1:
        for k in range(-LOCAL_WINDOW, LOCAL_WINDOW + 1):
            i = hint + k
            if closed:  # i % nseg (the hint is a segment, so at most one lap out)
                if i < 0:
                    i += nseg
                elif i >= nseg:
                    i -= nseg
            elif i < 0 or i >= nseg:
                continue
            ax = line[i, 0]
            ay = line[i, 1]
            d, t = segment_distance_sq(px, py, ax, ay, line[i + 1, 0] - ax, line[i + 1, 1] - ay,
                                        seg_len[i] * seg_len[i])
            if d < best_d:
                best_d = d
                best_i = i
                best_t = t
        edge_lo = hint - LOCAL_WINDOW
        edge_hi = hint + LOCAL_WINDOW
        if closed:
            edge_lo = edge_lo % nseg
            edge_hi = edge_hi % nseg
        # a hit inside the window and close to the line is the global nearest for any track whose
        # separate parts are further apart than LOCAL_MAX_DIST_M; otherwise search everything
        if best_i != edge_lo and best_i != edge_hi and best_d < LOCAL_MAX_DIST_M * LOCAL_MAX_DIST_M:
            return best_i, best_t, best_d
    best_d = np.inf
    for i in range(nseg):
        ax = line[i, 0]
        ay = line[i, 1]
        d, t = segment_distance_sq(px, py, ax, ay, line[i + 1, 0] - ax, line[i + 1, 1] - ay,
                                    seg_len[i] * seg_len[i])
        if d < best_d:
            best_d = d
            best_i = i
            best_t = t
    return best_i, best_t, best_d


@njit(cache=True)
def project_many(points, line, seg_len, cum_s, closed, hints, out_seg, out_t, out_s, out_lat):
    """Project each point onto the polyline: segment, fraction, arc length and signed offset (+ left)."""
    for j in range(points.shape[0]):
        px = points[j, 0]
        py = points[j, 1]
        i, t, d2 = nearest_segment(px, py, line, seg_len, closed, hints[j])
        ax = line[i, 0]
        ay = line[i, 1]
        dx = line[i + 1, 0] - ax
        dy = line[i + 1, 1] - ay
        cross = dx * (py - ay) - dy * (px - ax)
        out_seg[j] = i
        out_t[j] = t
        out_s[j] = cum_s[i] + t * seg_len[i]
        out_lat[j] = np.sqrt(d2) if cross >= 0.0 else -np.sqrt(d2)


@njit(cache=True, inline="always")
def point_in_road(px, py, edges, band_start, band_edges, y0, band_h):
    """Even-odd test of p against all road border edges that share its horizontal band.

    `edges` is (E, 4) [x1, y1, x2, y2] holding both borders (or the single ring of an open
    track); `band_start`/`band_edges` index them by y band in CSR form. Equivalent to
    shapely's `Polygon(outer, [inner]).contains(p)` away from the measure-zero boundary.
    """
    nb = band_start.shape[0] - 1
    b = int(np.floor((py - y0) / band_h))
    if b < 0 or b >= nb:
        return False
    inside = False
    for k in range(band_start[b], band_start[b + 1]):
        e = band_edges[k]
        x1 = edges[e, 0]
        y1 = edges[e, 1]
        x2 = edges[e, 2]
        y2 = edges[e, 3]
        if (y1 > py) != (y2 > py):
            xint = x1 + (py - y1) * (x2 - x1) / (y2 - y1)
            if px < xint:
                inside = not inside
    return inside


@njit(cache=True)
def contains_many(points, edges, band_start, band_edges, y0, band_h, out):
    for j in range(points.shape[0]):
        out[j] = point_in_road(points[j, 0], points[j, 1], edges, band_start, band_edges, y0, band_h)


@njit(cache=True)
def nearest_on_polyline_near(px, py, line, seg, closed, reach):
    """Nearest point of `line` to p among segments seg-reach..seg+reach; returns (x, y)."""
    nseg = line.shape[0] - 1
    best_d = np.inf
    bx = line[0, 0]
    by = line[0, 1]
    for k in range(-reach, reach + 1):
        i = seg + k
        if closed:
            i = i % nseg
        elif i < 0 or i >= nseg:
            continue
        ax = line[i, 0]
        ay = line[i, 1]
        dx = line[i + 1, 0] - ax
        dy = line[i + 1, 1] - ay
        d, t = segment_distance_sq(px, py, ax, ay, dx, dy, dx * dx + dy * dy)
        if d < best_d:
            best_d = d
            bx = ax + t * dx
            by = ay + t * dy
    return bx, by


@njit(cache=True, inline="always")
def measure_on_track(mx, my, center, seg_len, cum_s, inner, outer, wp_ndist, closed, length, driving_ccw, hint):
    """The track-derived reward params of one model point (mx, my), as simapp builds them (facts §1).

    The one measurement both the simulator (`sim._kernels.measure`) and re-scoring from logs
    (`analysis.rescore`) use. `center`, `seg_len`, `cum_s`, `inner`, `outer` and `wp_ndist` (waypoint arc
    fractions) are of the direction driven; `hint` is the previous nearest segment (-1: none).
    Returns (segment, arc length, signed lateral offset (+ left of the centre segment), is_left_of_center,
    track_width, previous waypoint, next waypoint, centre segment heading in rad).
    """
    seg, t, d2 = nearest_segment(mx, my, center, seg_len, closed, hint)
    ax = center[seg, 0]
    ay = center[seg, 1]
    dx = center[seg + 1, 0] - ax
    dy = center[seg + 1, 1] - ay
    arc = cum_s[seg] + t * seg_len[seg]
    dist = math.sqrt(d2)
    cross = dx * (my - ay) - dy * (mx - ax)
    # is_left_of_center and track_width: the centre projection point's nearest points on each border,
    # then which of the two the model point is nearer to
    cpx = ax + t * dx
    cpy = ay + t * dy
    ix, iy = nearest_on_polyline_near(cpx, cpy, inner, seg, closed, 2)
    ox, oy = nearest_on_polyline_near(cpx, cpy, outer, seg, closed, 2)
    nearer_inner = math.hypot(mx - ix, my - iy) < math.hypot(mx - ox, my - oy)
    # closest_waypoints by arc length: next = bisect_right(waypoint positions, arc fraction)
    nxt = np.searchsorted(wp_ndist, arc / length, side="right")
    prv = max(nxt - 1, 0)
    if nxt >= wp_ndist.shape[0]:
        nxt = 0
    lateral = dist if cross >= 0.0 else -dist
    left = nearer_inner != (not driving_ccw)
    return seg, arc, lateral, left, math.hypot(ix - ox, iy - oy), prv, nxt, math.atan2(dy, dx)


def build_road_index(edges: np.ndarray, band_h: float = 0.25):
    """CSR index of edges by horizontal band: (band_start, band_edges, y0, band_h)."""
    ylo = np.minimum(edges[:, 1], edges[:, 3])
    yhi = np.maximum(edges[:, 1], edges[:, 3])
    y0 = float(ylo.min()) - band_h
    nb = int(np.ceil((float(yhi.max()) - y0) / band_h)) + 2
    first = np.floor((ylo - y0) / band_h).astype(np.int64)
    last = np.floor((yhi - y0) / band_h).astype(np.int64)
    counts = np.zeros(nb, dtype=np.int64)
    for f, la in zip(first, last, strict=True):
        counts[f:la + 1] += 1
    band_start = np.zeros(nb + 1, dtype=np.int64)
    np.cumsum(counts, out=band_start[1:])
    band_edges = np.empty(band_start[-1], dtype=np.int64)
    fill = band_start[:-1].copy()
    for e, (f, la) in enumerate(zip(first, last, strict=True)):
        for b in range(f, la + 1):
            band_edges[fill[b]] = e
            fill[b] += 1
    return band_start, band_edges, y0, band_h
