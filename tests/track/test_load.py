"""Loading real AWS track files with their quirks, and clear errors for bad files."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from racerlab.errors import TrackError
from racerlab.track import load, load_file
from tests.conftest import AWS_TRACKS

MANIFEST = AWS_TRACKS / "MANIFEST.csv"


def manifest_rows():
    if not MANIFEST.is_file():
        pytest.skip("../shared/tracks not present")
    with MANIFEST.open() as f:
        return list(csv.DictReader(f))


def test_all_aws_tracks_load_with_manifest_length_and_direction():
    rows = manifest_rows()
    assert len(rows) == 129
    for r in rows:
        t = load_file(AWS_TRACKS / r["file"])
        expected = float(r["length_m"])
        assert abs(t.length - expected) / expected < 0.005, r["file"]
        assert t.closed == (r["closed"] == "True"), r["file"]
        if t.closed:
            assert ("CCW" if t.is_ccw else "CW") == r["direction"], r["file"]
            assert np.array_equal(t.center[0], t.center[-1])
        # consecutive duplicate centre points are dropped (simapp v6)
        assert (t.segment_lengths > 0).all(), r["file"]


def test_repeated_waypoint_removed_like_simapp(aws_track):
    t = aws_track("reInvent2019_track")
    raw = np.load(AWS_TRACKS / "reInvent2019_track.npy")
    assert raw.shape[0] == 155
    assert np.array_equal(raw[38, :2], raw[39, :2])  # the documented repeat
    assert t.num_waypoints == 154
    assert np.array_equal(t.center[:39], raw[:39, :2]) and np.array_equal(t.center[39:], raw[40:, :2])


def test_open_straight_track(aws_track):
    t = aws_track("Straight_track")
    assert not t.closed
    assert t.length == pytest.approx(6.41634704 - 0.70896719, abs=1e-3)
    assert t.is_ccw  # AWS treats open tracks as counter-clockwise: inner = left
    assert t.left[0, 1] > t.center[0, 1] > t.right[0, 1]


def test_cw_file_is_reverse_of_ccw(aws_track):
    cw = aws_track("2022_april_open_cw")
    ccw = aws_track("2022_april_open_ccw")
    assert not cw.is_ccw and ccw.is_ccw
    # inner is the geometric inside: right of travel when driving clockwise
    assert cw.right is cw.inner and ccw.left is ccw.inner
    assert cw.length == pytest.approx(ccw.length, rel=1e-9)


def test_reverse_keeps_waypoint_zero_and_flips_sides(aws_track):
    t = aws_track("reinvent_base")
    r = t.reverse()
    assert np.array_equal(r.center[0], t.center[0])
    assert np.array_equal(r.center, t.center[::-1])
    assert r.reversed and r.is_ccw != t.is_ccw
    assert r.left is r.outer  # driving clockwise around a CCW loop: the outer border is on the left
    assert r.length == pytest.approx(t.length)


def test_centre_off_midpoint_tracks_load(aws_track):
    t = aws_track("AWS_track")
    mid = (t.inner + t.outer) / 2
    assert np.abs(t.center - mid).max() > 0.1  # the quirk is real and kept
    assert t.contains(t.center[:-1]).all()


@pytest.mark.parametrize(
    ("array", "message"),
    [
        (np.zeros((10, 4)), "expected an array of shape (N, 6)"),
        (np.full((10, 6), np.nan), "NaN or infinite"),
        (np.array([[0, 0, 0, 1, 0, -1], [1, 0, 1, 1, 1, -1]], float), "only 2 distinct waypoints"),
    ],
)
def test_bad_track_files_give_one_clear_line(tmp_path, array, message):
    p = tmp_path / "bad.npy"
    np.save(p, array)
    with pytest.raises(TrackError) as err:
        load_file(p)
    text = str(err.value)
    assert str(p) in text and message in text and "\n" not in text


def test_crossing_borders_are_refused(tmp_path):
    theta = np.linspace(0, 2 * np.pi, 41)
    centre = np.stack([np.cos(theta), np.sin(theta)], 1) * 3
    inner = centre * 0.9
    outer = centre * 1.1
    inner[10] = centre[10] * 1.2  # inner border pokes through the outer one
    arr = np.hstack([centre, inner, outer])
    arr[-1] = arr[0]
    p = tmp_path / "crossing.npy"
    np.save(p, arr)
    with pytest.raises(TrackError, match="borders cross"):
        load_file(p)


def test_unreadable_and_unknown(tmp_path):
    p = tmp_path / "garbage.npy"
    p.write_text("not numpy")
    with pytest.raises(TrackError, match="cannot read the track file"):
        load_file(p)
    with pytest.raises(TrackError, match="unknown track 'no_such_track'"):
        load("no_such_track")
