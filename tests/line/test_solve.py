"""Racing-line solvers: exact border clearance, the bounded QP, lines with known answers (a ring),
and every line inside the borders with the car's width and the margin on real tracks."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.optimize import lsq_linear

from racerlab.errors import TrackError
from racerlab.line import car_clearance, racing_line
from racerlab.line import geometry as G
from racerlab.line.profile import max_curvature
from racerlab.line.solve import box_qp, objective
from racerlab.track import from_array, load_file
from tests.conftest import AWS_TRACKS

# hairpins first (tightest centre-line radius 0.33-0.46 m, two only 0.6-0.65 m wide), then the
# re:Invent / championship / record tracks, the 2019 tracks, the longest track and the two on
# which the re-linearisation once circled without settling
SUBSET = [
    "Tokyo_Training_track", "red_star_open", "2022_september_pro", "2022_august_open", "Virtual_May19_Train_track",
    "jyllandsringen_pro_cw", "2022_october_pro", "Aragon", "caecer_loop", "reinvent_base", "thunder_hill_pro",
    "Austin", "morgan_open", "LGSWide", "reInvent2019_track", "2022_reinvent_champ", "2022_summit_speedway",
    "2024_reinvent_champ_cw", "2024_reinvent_champ_ccw", "Monaco", "caecer_gp", "Spain_track", "Canada_Training",
    "China_track", "Mexico_track", "New_York_Track", "Vegas_track", "Albert", "dubai_open", "penbay_pro",
    "jyllandsringen_open_cw", "hamption_pro",
]


def all_loops() -> list[str]:
    names = sorted(p.stem for p in AWS_TRACKS.glob("*.npy"))
    return [n for n in names if n != "Straight_track"]  # the one open track: no lap, no racing line


def ring(radius: float = 2.0, width: float = 1.0, n: int = 240):
    th = np.linspace(0.0, 2 * np.pi, n + 1)
    th[-1] = 0.0
    c = np.stack([np.cos(th), np.sin(th)], axis=1)
    return from_array(np.hstack([radius * c, (radius - width / 2) * c, (radius + width / 2) * c]), name="ring")


# ---- exact clearance along a normal ------------------------------------------------------------------

def corridor(half: float = 0.5):
    xs = np.linspace(-5.0, 5.0, 11)
    lower = np.stack([xs, np.full_like(xs, -half)], axis=1)
    upper = np.stack([xs, np.full_like(xs, half)], axis=1)
    return (np.vstack([lower[:-1], upper[:-1]]), np.vstack([np.diff(lower, axis=0), np.diff(upper, axis=0)]))


@pytest.mark.parametrize("angle_deg", [90.0, 60.0, 30.0])
def test_room_in_a_straight_corridor_is_the_perpendicular_gap_over_the_sine(angle_deg):
    a, d = corridor(0.5)
    y0 = np.array([0.0, 0.2, -0.3])
    pts = np.stack([np.zeros(3), y0], axis=1)
    th = math.radians(angle_deg)
    normal = np.tile([math.cos(th), math.sin(th)], (3, 1))
    lo, hi = G.lateral_room(pts, normal, a, d, 0.1, reach=5.0)
    assert hi == pytest.approx((0.5 - 0.1 - y0) / math.sin(th), abs=1e-12)
    assert lo == pytest.approx((-0.5 + 0.1 - y0) / math.sin(th), abs=1e-12)


def brute_room(o, n, seg_a, seg_d, c, reach, step=5e-4):
    """The run of α around 0 (sampled every `step`) where o + α·n keeps `c` to every segment."""
    alpha = np.arange(-reach, reach + step / 2, step)
    free = G.border_distance(o + alpha[:, None] * n, seg_a, seg_d) >= c
    i0 = int(np.argmin(np.abs(alpha)))
    assert free[i0]
    blocked = np.flatnonzero(~free)
    below, above = blocked[blocked < i0], blocked[blocked > i0]
    lo = alpha[below[-1] + 1] if below.size else alpha[0]
    hi = alpha[above[0] - 1] if above.size else alpha[-1]
    return lo, hi


def test_room_matches_a_brute_force_search_at_corners_of_a_real_track(aws_track):
    t = aws_track("2022_reinvent_champ")  # polygonal borders with sharp vertices
    segs = G.border_segments(t)
    pts = G.resample_polyline(t.center[:-1], 30)
    rng = np.random.default_rng(3)
    ang = rng.uniform(-0.6, 0.6, len(pts))  # normals tilted up to ±34° from the centre line's
    base = G.left_normals(pts)
    rot = np.stack([np.cos(ang), np.sin(ang)], axis=1)
    normal = np.stack([base[:, 0] * rot[:, 0] - base[:, 1] * rot[:, 1],
                       base[:, 0] * rot[:, 1] + base[:, 1] * rot[:, 0]], axis=1)
    lo, hi = G.lateral_room(pts, normal, *segs, 0.2, reach=1.5)
    for i in range(len(pts)):
        blo, bhi = brute_room(pts[i], normal[i], *segs, 0.2, 1.5)
        assert lo[i] == pytest.approx(blo, abs=6e-4) and hi[i] == pytest.approx(bhi, abs=6e-4)


# ---- the bounded QP ------------------------------------------------------------------------------------

@pytest.mark.parametrize("seed", [0, 1, 2])
def test_box_qp_matches_bounded_least_squares(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(60, 40))
    b = rng.normal(size=60)
    lo, hi = -0.2 * np.ones(40), 0.3 * np.ones(40)
    x = box_qp(sp.csc_matrix(a.T @ a), -(a.T @ b), lo, hi)
    ref = lsq_linear(a, b, bounds=(lo, hi), method="bvls", tol=1e-14).x
    assert np.all(x >= lo) and np.all(x <= hi)
    assert x == pytest.approx(ref, abs=1e-7)


# ---- lines with known answers -------------------------------------------------------------------------

def test_minimum_curvature_on_a_ring_is_the_inner_circle_at_grip_speed():
    # under a grip limit a circle of radius r takes 2π·√(r/a): the tightest circle is the fastest
    line = racing_line(ring(), margin=0.1)
    r = np.hypot(*line.xy.T)
    assert line.converged
    assert r == pytest.approx(np.full(len(r), 1.5 + car_clearance(margin=0.1)), abs=6e-3)  # + the 5 mm cushion
    assert line.speed == pytest.approx(np.sqrt(line.car.grip_mps2 * r), rel=1e-2)
    assert line.flying_lap_time == pytest.approx(2 * np.pi * np.sqrt(r.mean() / line.car.grip_mps2), rel=5e-3)


def test_shortest_path_on_a_ring_hugs_the_inner_border():
    line = racing_line(ring(), margin=0.0, method="shortest")
    r = np.hypot(*line.xy.T)
    assert r == pytest.approx(np.full(len(r), 1.5 + car_clearance(margin=0.0)), abs=6e-3)


def test_each_method_wins_at_its_own_objective(aws_track):
    t = aws_track("reInvent2019_track")
    mc, sh = racing_line(t, method="mincurv"), racing_line(t, method="shortest")
    assert objective(mc.xy, "mincurv") < objective(sh.xy, "mincurv")
    assert sh.length < mc.length < t.length
    assert mc.lap_time < sh.lap_time  # on this track the smooth line is the faster one


def test_a_road_too_narrow_for_the_margin_is_a_clear_error(aws_track):
    with pytest.raises(TrackError, match=r"too narrow .* smaller margin"):
        racing_line(aws_track("Virtual_May19_Train_track"), margin=0.25)


def test_an_open_track_has_no_racing_line(aws_track):
    with pytest.raises(TrackError, match="closed loop"):
        racing_line(aws_track("Straight_track"))


def test_a_reversed_track_gets_its_own_line(aws_track):
    t = aws_track("reInvent2019_track")
    fwd, rev = racing_line(t), racing_line(t.reverse())
    assert_inside(t.reverse(), rev.xy, rev.clearance_m)
    assert rev.flying_lap_time != fwd.flying_lap_time  # corners come in another order (lap_time counts whole steps)


# ---- inside the borders on real tracks ---------------------------------------------------------------

def assert_inside(track, xy, clearance):
    """Every point of the closed polyline (sampled every ~1 cm) is on the road and keeps `clearance`."""
    loop = np.vstack([xy, xy[:1]])
    seg = np.diff(loop, axis=0)
    k = np.maximum(np.ceil(np.hypot(*seg.T) / 0.01), 1).astype(int)
    dense = np.vstack([loop[i] + np.linspace(0, 1, k[i], endpoint=False)[:, None] * seg[i] for i in range(len(seg))])
    assert track.contains(dense).all()
    d = G.border_distance(dense, *G.border_segments(track))
    assert d.min() >= clearance - 1e-3, f"{track.name}: {clearance - d.min():.4f} m too close to a border"


def check_track(track, method, margin):
    line = racing_line(track, margin=margin, method=method)
    assert line.converged, f"{track.name} {method}: not converged"
    assert line.clearance_m == pytest.approx(car_clearance(margin=margin))
    assert_inside(track, line.xy, line.clearance_m)
    # within the car's limits: the grip, and the tightest bend full lock holds at that speed (a shortest path's
    # kinks, tighter than full lock at any speed, are driven on the car's tightest circle)
    bend = np.minimum(np.abs(line.curvature), max_curvature(1e-9, line.car))
    assert np.all(line.speed**2 * bend <= line.car.grip_mps2 * (1 + 1e-9))
    assert np.all(bend <= max_curvature(line.speed, line.car) * (1 + 1e-6))
    assert line.flying_lap_time < line.lap_time < 2.5 * track.length / line.car.top_speed() + 2.0


@pytest.mark.parametrize("method", ["mincurv", "shortest"])
@pytest.mark.parametrize("name", SUBSET)
def test_line_keeps_the_car_and_margin_inside_the_borders(aws_track, name, method):
    check_track(aws_track(name), method, 0.1)


@pytest.mark.parametrize("name", ["Tokyo_Training_track", "reInvent2019_track", "Aragon", "2022_reinvent_champ"])
def test_line_without_margin_keeps_the_whole_car_on_the_road(aws_track, name):
    check_track(aws_track(name), "mincurv", 0.0)


@pytest.mark.slow
@pytest.mark.parametrize("method", ["mincurv", "shortest"])
@pytest.mark.parametrize("name", all_loops())
def test_every_real_track(name, method):
    check_track(load_file(AWS_TRACKS / f"{name}.npy"), method, 0.1)
