"""The track generator makes valid, drivable tracks; the bundled tracks are its output and drive."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab import track
from racerlab.errors import TrackError
from racerlab.sim import Simulator
from racerlab.sim.pursuit import PurePursuit, drive_lap
from racerlab.track.bundled import DESIGNS, build, write_all
from racerlab.track.core import segments_cross
from racerlab.track.generate import (
    DEFAULT_GAP_M,
    STRAIGHT_RADIUS_M,
    crowding,
    from_control_points,
    from_polygon,
    generate,
    turn_angles,
)
from racerlab.track.registry import BUNDLED_DIR, DEFAULT_TRACK


def min_waypoint_radius(t) -> float:
    return float(1.0 / np.abs(t.curvature).max())


def assert_valid(t, length: float, width: float, min_radius: float, gap: float = DEFAULT_GAP_M) -> None:
    """Everything the generator promises, checked on the Track a user loads."""
    arr = t.as_array()
    assert t.closed and np.array_equal(arr[0], arr[-1])
    assert t.is_ccw and not t.reversed
    assert t.length == pytest.approx(length, rel=1e-6)
    np.testing.assert_allclose(t.widths, width, rtol=0, atol=1e-9)
    np.testing.assert_allclose(t.center, 0.5 * (t.inner + t.outer), rtol=0, atol=1e-12)
    assert 0.13 < t.segment_lengths.min() and t.segment_lengths.max() < 0.17  # ~0.15 m like AWS
    for line in (t.center, t.inner, t.outer):
        assert segments_cross(line, line, skip_adjacent=True) is None
    assert segments_cross(t.inner, t.outer, skip_adjacent=False) is None
    # 3-point circles through waypoints 0.15 m apart read an exact arc a hair tight
    assert min_waypoint_radius(t) >= min_radius * 0.995
    assert crowding(t.center[:-1], width + 0.95 * gap) is None


@pytest.mark.parametrize(("length", "width", "min_radius"), [
    (20.0, 1.07, 0.6), (12.0, 0.76, 0.6), (35.0, 1.07, 0.6), (18.0, 0.76, 0.45), (15.0, 1.07, 1.0),
])
def test_many_seeds_give_valid_tracks(length, width, min_radius):
    for seed in range(15):
        t = generate(seed, length=length, width=width, min_radius=min_radius)
        assert_valid(t, length, width, min_radius)
        assert t.name == f"generated_{seed}" and t.turns() >= 1


def test_start_line_on_a_straight_part():
    for seed in range(20):
        k = np.abs(generate(seed).curvature[:-1])
        assert k[0] < 1.0 / STRAIGHT_RADIUS_M or k[0] == k.min()


def test_same_seed_same_track_other_seed_other_track():
    a, b = generate(11, length=25.0), generate(11, length=25.0)
    np.testing.assert_array_equal(a.as_array(), b.as_array())
    assert not np.array_equal(a.as_array()[:5], generate(12, length=25.0).as_array()[:5])
    assert generate(11, length=25.0, name="mine").name == "mine"


@pytest.mark.parametrize(("kwargs", "message"), [
    ({"seed": -1}, "seed must be a non-negative integer"),
    ({"seed": 2.5}, "seed must be a non-negative integer"),
    ({"seed": 1, "width": 0.0}, "width must be a positive number"),
    ({"seed": 1, "length": float("nan")}, "length must be a positive number"),
    ({"seed": 1, "min_radius": 0.2}, "tighter than the car can turn"),
    ({"seed": 1, "width": 1.2, "min_radius": 0.6}, "inner border would fold"),
    ({"seed": 1, "length": 3.0}, "too short"),
    ({"seed": 1, "length": 1000.0}, "longer than the generator makes"),
])
def test_invalid_requests_are_one_clear_line(kwargs, message):
    with pytest.raises(TrackError, match=message) as exc:
        generate(**kwargs)
    assert "\n" not in str(exc.value)


# ---- designed tracks ----------------------------------------------------------------------------

SQUARE = [(0.0, 0.0), (4.0, 0.0), (4.0, 4.0), (0.0, 4.0)]


def test_polygon_bends_are_as_designed_and_straights_straight():
    t = from_polygon(SQUARE, radii=1.0, width=1.07, name="square")  # natural size: no scaling
    assert t.name == "square"
    assert_valid(t, t.length, 1.07, 1.0)
    assert min_waypoint_radius(t) == pytest.approx(1.0, rel=0.005)
    # each 2 m straight keeps 1.7 m of zero curvature once the 0.3 m blends at its ends are taken
    # (a waypoint next to a blend reads a little curvature from its neighbour)
    assert np.sum(np.abs(t.curvature[:-1]) < 1e-9) * 0.15 > 4 * 1.3
    angles = [a for _, _, a in turn_angles(t)]  # the gentle ends of the blends count as straight
    assert len(angles) == 4 and all(80 < a < 91 for a in angles)


def test_polygon_scaled_to_length_and_started_where_asked():
    t = from_polygon(SQUARE, radii=1.0, width=0.76, length=24.0, start=2.5)
    assert_valid(t, 24.0, 0.76, 1.0)
    # edge 2 runs from (4, 4) to (0, 4): leftwards, in the middle of the top straight
    assert t.heading_at(0.0) == pytest.approx(np.pi, abs=1e-6)
    assert t.center[0, 1] == pytest.approx(t.center[:, 1].max(), abs=1e-9)


def test_clockwise_designs_are_turned_counter_clockwise():
    t = from_polygon(SQUARE[::-1], radii=1.0, width=1.07)
    assert t.is_ccw and t.length == pytest.approx(from_polygon(SQUARE, radii=1.0, width=1.07).length)


@pytest.mark.parametrize(("corners", "radii", "kwargs", "message"), [
    (SQUARE, 3.0, {}, "need 6.00 m of the 4.00 m edge"),
    (SQUARE, [1.0, 1.0], {}, "one radius, or one per corner"),
    (SQUARE, 0.3, {"width": 0.76}, "a bend of radius 0.30 m .* tighter than min_radius 0.6"),
    ([(0, 0), (4, 0), (4, 3), (2.1, 0.5), (0, 3)], 0.6, {"length": 16.0}, "comes within 0.1. m of itself"),
    ([(0, 0), (4, 0), (0, 1e-4), (0, 3)], 0.6, {}, "doubles back"),
    ([(0, 0), (4, 0), (4, 0), (0, 3)], 0.6, {}, "same point"),
    ([(0, 0), (4000, 0), (4000, 3000), (0, 3000)], 600.0, {}, "longer than the generator makes"),
])
def test_bad_designs_say_what_to_change(corners, radii, kwargs, message):
    with pytest.raises(TrackError, match=f"^mine: .*{message}") as exc:
        from_polygon(corners, radii, name="mine", **kwargs)
    assert "\n" not in str(exc.value)


def test_control_points_make_a_smooth_valid_loop():
    pts = [(0, 0), (4, 0), (6, 2), (4, 4), (0, 4), (-2, 2)]  # symmetric: (6, 2) is the rightmost point
    t = from_control_points(pts, width=1.07, length=20.0, name="blob", start=2)
    assert_valid(t, 20.0, 1.07, 0.6)
    assert t.name == "blob"
    assert t.center[0, 0] == pytest.approx(t.center[:, 0].max(), abs=1e-9)
    assert t.center[1, 1] > t.center[0, 1] > t.center[-2, 1]  # going up there, counter-clockwise
    with pytest.raises(TrackError, match="^blob: a bend of radius"):
        from_control_points([(0, 0), (4, 4), (4, 0), (0, 4)], length=20.0, name="blob")
    with pytest.raises(TrackError, match="same point"):
        from_control_points([(0, 0), (0, 0), (1, 1), (0, 1)], length=8.0)


# ---- the bundled tracks -------------------------------------------------------------------------

PROMISED = {"lab_oval": (15.0, 1.07), "lab_technical": (18.0, 0.76), "lab_grand_prix": (35.0, 1.07)}


def test_bundled_files_are_what_the_designs_produce(tmp_path):
    assert set(DESIGNS) == set(PROMISED)
    for path in write_all(tmp_path):
        stored = np.load(BUNDLED_DIR / path.name, allow_pickle=False)
        np.testing.assert_allclose(stored, np.load(path), rtol=0, atol=1e-9, err_msg=path.stem)
        assert np.array_equal(stored[0], stored[-1])


@pytest.mark.parametrize("name", sorted(PROMISED))
def test_bundled_tracks_load_by_name_with_the_promised_sizes(name):
    length, width = PROMISED[name]
    t = track.load(name)
    assert name in track.names() and t.name == name
    assert_valid(t, length, width, DESIGNS[name].min_radius)
    k = np.abs(t.curvature[:-1])
    assert k[0] < 1e-6  # the start line is on a straight


def test_default_track_is_lab_technical_with_a_hairpin_and_a_chicane():
    assert DEFAULT_TRACK == "lab_technical"
    turns = turn_angles(track.load(DEFAULT_TRACK))
    assert max(abs(a) for _, _, a in turns) > 150  # the hairpin
    chicanes = [(a, b) for a, b in zip(turns, turns[1:], strict=False)
                if a[2] * b[2] < 0 and min(abs(a[2]), abs(b[2])) > 30 and b[0] - a[1] < 0.5
                and a[1] - a[0] < 1.5 and b[1] - b[0] < 1.5]
    assert chicanes, turns
    sweepers = [a for _, _, a in turns if 30 < abs(a) < 90]
    assert len(sweepers) >= 3


def test_oval_is_easy():
    t = track.load("lab_oval")
    assert t.turns() == 2 and min_waypoint_radius(t) > 1.4


@pytest.mark.parametrize("name", sorted(PROMISED))
@pytest.mark.parametrize("reverse", [False, True])
def test_pure_pursuit_laps_every_bundled_track(name, reverse):
    t = track.load(name, reverse=reverse)
    status, _, lap_time, _ = drive_lap(Simulator(t, 1), PurePursuit.on_centre_line(t, 1.5))
    assert status == "lap_complete"
    assert lap_time == pytest.approx(t.length / 1.5, rel=0.1)


def test_build_matches_load():
    np.testing.assert_allclose(build("lab_oval").as_array(), track.load("lab_oval").as_array(), atol=1e-9)


def test_generate_many_draws_valid_tracks_in_the_ranges_and_repeats():
    from racerlab.track.generate import generate_many

    tracks = generate_many(11, 5, length=(20.0, 40.0), width=(0.8, 1.0), min_radius=0.6)
    assert len(tracks) == 5 and len({t.name for t in tracks}) == 5
    for t in tracks:
        assert t.closed and 20.0 - 1e-6 <= t.length <= 40.0 + 1e-6
        assert 0.8 - 1e-6 <= t.width <= 1.0 + 1e-6
        # no bend of the centre line tighter than the radius asked (the generator's own check, 1e-4 slack)
        assert np.abs(t.curvature).max() <= 1 / 0.6 * (1 + 1e-3)
    again = generate_many(11, 5, length=(20.0, 40.0), width=(0.8, 1.0), min_radius=0.6)
    assert all(np.array_equal(a.center, b.center) for a, b in zip(tracks, again, strict=True))
    other = generate_many(12, 5, length=(20.0, 40.0), width=(0.8, 1.0), min_radius=0.6)
    assert not np.array_equal(tracks[0].center, other[0].center)
