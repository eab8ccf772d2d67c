"""Layouts: which tracks are one shape, so that no held-out track is ever a layout the model trained on."""

from __future__ import annotations

import numpy as np
import pytest

from racerlab.errors import RacerlabError
from racerlab.track.core import from_array, ring_area
from racerlab.track.layouts import (
    held_out_tracks,
    layout_shape,
    same_layout,
    training_tracks,
)
from tests.conftest import AWS_TRACKS


def ring(points, width=1.0) -> np.ndarray:
    """The (N, 6) AWS array of a closed centre line `points`, borders width/2 either side (the inner one is the
    one on the loop's inside, whichever way it runs)."""
    c = np.asarray(points, dtype=np.float64)
    t = np.roll(c, -1, axis=0) - np.roll(c, 1, axis=0)
    n = np.stack([-t[:, 1], t[:, 0]], axis=1) / np.hypot(*t.T)[:, None]
    left, right = c + n * width / 2, c - n * width / 2
    if abs(ring_area(left)) > abs(ring_area(right)):
        left, right = right, left
    a = np.hstack([c, left, right])
    return np.vstack([a, a[:1]])


def circle(r, cx=0.0, cy=0.0, n=120):
    u = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.stack([cx + r * np.cos(u), cy + r * np.sin(u)], axis=1)


def tee(scale=1.0):
    """A lopsided loop (a rectangle with one corner cut off), so that its mirror image is another shape."""
    corners = np.array([(0, 0), (6, 0), (6, 2), (3, 4), (0, 4)], dtype=float) * scale
    pts = [corners[k] + f * (corners[(k + 1) % 5] - corners[k]) for k in range(5) for f in np.linspace(0, 1, 40,
                                                                                                        endpoint=False)]
    return np.array(pts)


def track(points, name="t"):
    return from_array(ring(points), name)


def test_a_layout_is_its_shape_wherever_it_lies_whichever_way_and_mirrored():
    base = layout_shape(track(tee()))
    assert same_layout(base, layout_shape(track(tee() + [40.0, -7.0])))  # moved elsewhere
    assert same_layout(base, layout_shape(track(tee()[::-1])))  # driven the other way
    assert same_layout(base, layout_shape(track(tee() * [-1.0, 1.0])))  # mirrored left-right
    assert same_layout(base, layout_shape(track(tee() * [1.0, -1.0])))  # mirrored top-bottom
    assert not same_layout(base, layout_shape(track(tee(1.5))))  # half as large again: another layout
    # circles of 3 m and 3.15 m lie 0.15 m apart everywhere: one layout; 3 m and 3.3 m: two (LAYOUT_TOL_M 0.2 m)
    assert same_layout(layout_shape(track(circle(3.0))), layout_shape(track(circle(3.15, 5, 5))))
    assert not same_layout(layout_shape(track(circle(3.0))), layout_shape(track(circle(3.3))))


@pytest.fixture
def folder(tmp_path):
    """Six names and five layouts' worth of files: a (and a_cw, and its copy b elsewhere, and its mirror c), d, e,
    and an open track."""
    files = {"a": tee(), "a_cw": tee()[::-1], "b": tee() + [30.0, 0.0], "c": tee() * [-1.0, 1.0],
             "d": circle(3.0), "e": circle(4.0, 20, 20)}
    for name, pts in files.items():
        np.save(tmp_path / f"{name}.npy", ring(pts))
    open_track = np.hstack([np.stack([np.linspace(0, 5, 30), np.zeros(30)], 1)] * 3)
    open_track[:, 3] += 0.5
    open_track[:, 5] -= 0.5
    np.save(tmp_path / "straight.npy", open_track)
    return tmp_path


def test_held_out_tracks_take_no_layout_trained_on_under_any_name(folder):
    for seed in range(6):
        picked = held_out_tracks(folder, 2, exclude=["a"], seed=seed)
        assert sorted(p.stem for p in picked) == ["d", "e"]  # b and c are a's layout; straight is open
    with pytest.raises(RacerlabError, match="2 closed track layouts not excluded, fewer than the 3 asked"):
        held_out_tracks(folder, 3, exclude=["a_cw"])
    assert len(held_out_tracks(folder, 3)) == 3  # a, b, c count once
    assert [p.stem for p in held_out_tracks(folder, 1, exclude=[track(tee() * [-1, 1]), "d"])] == ["e"]
    with pytest.raises(RacerlabError, match="nowhere: a training track that does not load"):
        held_out_tracks(folder, 1, exclude=["nowhere"])


def test_training_tracks_are_one_per_layout_outside_the_held_out_ones(folder):
    assert [p.stem for p in training_tracks(folder, ["d"])] == ["a", "e"]
    assert [p.stem for p in training_tracks(folder, ["c"])] == ["d", "e"]  # a, b and c: one layout, held out
    assert len(training_tracks(folder, ["c"], count=1, seed=3)) == 1


@pytest.mark.skipif(not (AWS_TRACKS / "Monaco.npy").is_file(), reason=f"real AWS tracks not in {AWS_TRACKS}")
def test_no_held_out_aws_track_shares_a_layout_with_its_training_set():
    held = held_out_tracks(AWS_TRACKS, 20, seed=0)
    train = training_tracks(AWS_TRACKS, held)
    shapes = [layout_shape(from_array(np.load(p), p.stem)) for p in train]
    for p in held:
        h = layout_shape(from_array(np.load(p), p.stem))
        assert not any(same_layout(h, s) for s in shapes), p.stem
    # drawn again from what the training left, the held-out set is the same 20 layouts
    again = held_out_tracks(AWS_TRACKS, 20, exclude=train, seed=5)
    assert len(again) == 20
    for p in again:
        assert any(same_layout(layout_shape(from_array(np.load(p))), layout_shape(from_array(np.load(q))))
                   for q in held)
