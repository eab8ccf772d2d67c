"""Batched arc-length projection and the road test against independent brute-force computations."""

from __future__ import annotations

import numpy as np
import pytest
from matplotlib.path import Path as MplPath


def brute_projection(center, points):
    a, b = center[:-1], center[1:]
    d = b - a
    best = []
    for p in points:
        t = np.clip(((p - a) * d).sum(1) / (d * d).sum(1), 0, 1)
        q = a + t[:, None] * d
        dist = np.hypot(*(q - p).T)
        i = int(np.argmin(dist))
        s = np.hypot(*d[:i].T).sum() + t[i] * np.hypot(*d[i])
        best.append((i, s, dist[i]))
    return best


@pytest.mark.parametrize("name", ["reInvent2019_track", "2022_april_open_cw", "Straight_track", "AWS_track"])
def test_projection_matches_brute_force(aws_track, name):
    t = aws_track(name)
    rng = np.random.default_rng(0)
    s = rng.uniform(0, t.length, 300)
    pts = t.point_at(s) + rng.normal(0, 0.3, (300, 2))
    proj = t.project(pts)
    for j, (i, sb, db) in enumerate(brute_projection(t.center, pts)):
        assert proj.s[j] == pytest.approx(sb, abs=1e-9)
        assert abs(proj.lateral[j]) == pytest.approx(db, abs=1e-9)
        assert proj.segment[j] == i


def test_projection_sign_width_and_heading(aws_track):
    t = aws_track("reInvent2019_track")  # CCW: inner border on the left
    mid = (t.center[18] + t.center[19]) / 2
    d = t.center[19] - t.center[18]
    normal_left = np.array([-d[1], d[0]]) / np.hypot(*d)
    p = t.project([mid + 0.2 * normal_left, mid - 0.3 * normal_left])
    assert p.lateral == pytest.approx([0.2, -0.3], abs=1e-9)
    assert p.width == pytest.approx([1.0668, 1.0668], abs=1e-3)
    assert p.heading == pytest.approx([np.arctan2(d[1], d[0])] * 2)
    assert p.segment.tolist() == [18, 18]


def test_hints_give_the_same_answer(aws_track):
    t = aws_track("reinvent_base")
    pts = t.point_at(np.linspace(0, t.length, 50, endpoint=False)) + 0.05
    cold = t.project(pts)
    warm = t.project(pts, hints=cold.segment)
    wrong = t.project(pts, hints=(cold.segment + 40) % (t.num_waypoints - 1))
    assert np.allclose(cold.s, warm.s) and np.allclose(cold.s, wrong.s)


@pytest.mark.parametrize("name", ["reInvent2019_track", "2022_april_open_cw", "Straight_track", "China_track"])
def test_contains_matches_polygon_test(aws_track, name):
    t = aws_track(name)
    rng = np.random.default_rng(1)
    lo = np.minimum(t.outer.min(0), t.inner.min(0)) - 0.5
    hi = np.maximum(t.outer.max(0), t.inner.max(0)) + 0.5
    pts = rng.uniform(lo, hi, (5000, 2))
    if t.closed:
        expected = MplPath(t.outer).contains_points(pts) & ~MplPath(t.inner).contains_points(pts)
    else:
        expected = MplPath(np.vstack([t.outer, t.inner[::-1]])).contains_points(pts)
    assert (t.contains(pts) == expected).mean() > 0.999  # differences only within float noise of a border
    assert t.contains(t.point_at(np.linspace(0, t.length, 100, endpoint=False))).all() if t.closed else True


def test_curvature_of_a_circle():
    from racerlab.track import from_array

    th = np.linspace(0, 2 * np.pi, 201)
    c = np.stack([np.cos(th), np.sin(th)], 1) * 1.5
    arr = np.hstack([c, c * 0.8, c * 1.2])
    arr[-1] = arr[0]
    t = from_array(arr, "circle")
    assert t.curvature == pytest.approx(np.full(201, 1 / 1.5), rel=1e-3)
    assert t.turns() == 1
