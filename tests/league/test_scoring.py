"""Timing methods worked by hand: best lap over completed laps only, best average, total time, penalties, ties."""

from __future__ import annotations

import pytest

from racerlab.evaluate import Lap
from racerlab.league.rules import Rules
from racerlab.league.scoring import Entry, leaderboard, score


def lap(trial, start, end, done=True, off=0, progress=None):
    counts = {"off_track": off, "crashed": 0, "immobilized": 0, "reversed": 0}
    return Lap(trial, "lap_complete" if done else "off_track", start, end,
               100.0 if done else (progress if progress is not None else 40.0), counts)


def rules(timing="best_lap", laps=3, min_laps=1):
    return Rules(track="t", track_sha256="0" * 64, timing=timing, laps=laps, min_laps=min_laps)


# laps of one continuous run: 10.000 s, 9.733 s, then 4.2 s until the car left the track for good (40 %)
RUN = [lap(1, 0.0, 10.0), lap(2, 10.0, 19.733), lap(3, 19.733, 23.933, done=False)]


def test_best_lap_is_the_fastest_completed_lap_not_the_unfinished_one():
    s = score(RUN, rules())
    assert (s.status, s.score_ms) == ("ranked", 9733)  # DRoA would have ranked the unfinished 4.200 s
    assert (s.laps_completed, s.laps_driven) == (2, 3)
    assert s.reason == "best lap 9.733 s (2 of 3 laps)"


def test_best_lap_needs_its_minimum_of_completed_laps():
    s = score(RUN, rules(min_laps=3))
    assert (s.status, s.score_ms) == ("not_ranked", None)
    assert s.reason == "2 of the 3 completed laps the race needs (best lap 9.733 s)"


def test_best_average_over_consecutive_laps_floored_to_the_millisecond():
    laps = [lap(1, 0.0, 10.001), lap(2, 10.001, 19.001), lap(3, 19.001, 28.001)]
    assert score(laps, rules("average_lap", 3, 3)).score_ms == 9333  # 28 001 / 3 = 9 333.67 -> 9 333
    assert score(laps, rules("average_lap", 3, 2)).score_ms == 9000  # laps 2 and 3: (9 000 + 9 000) / 2
    s = score(RUN, rules("average_lap", 3, 3))
    assert s.status == "not_ranked" and s.reason.startswith("2 laps completed, not 3 in a row")


def test_an_average_skips_windows_with_an_unfinished_lap():
    laps = [lap(1, 0, 10.0), lap(2, 0, 3.0, done=False), lap(3, 0, 9.0), lap(4, 0, 9.5)]  # separate trials
    assert score(laps, rules("average_lap", 4, 2)).score_ms == 9250  # only (9.0 + 9.5) / 2 is whole


def test_total_time_adds_every_lap_and_needs_them_all():
    laps = [lap(1, 0.0, 10.0), lap(2, 10.0, 19.0), lap(3, 19.0, 28.5)]
    assert score(laps, rules("total_time", 3, 3)).score_ms == 28500
    s = score(RUN, rules("total_time", 3, 3))
    assert s.status == "not_ranked" and s.reason.startswith("2 of 3 laps completed")


def test_a_penalty_is_inside_the_lap_time_that_ranks():
    # lap 2 left the track once: the car was held 3 s, so the lap took 12.5 s although it drove 9.5 s
    laps = [lap(1, 0.0, 10.0), lap(2, 10.0, 22.5, off=1)]
    s = score(laps, rules(laps=2))
    assert (s.score_ms, s.off_track) == (10000, 1)  # the clean 10.0 s lap is the best one
    assert score(laps, rules("total_time", 2, 2)).score_ms == 22500


def test_no_completed_lap_is_no_lap():
    s = score([lap(1, 0.0, 4.0, done=False)], rules())
    assert (s.status, s.score_ms, s.reason) == ("no_lap", None, "no lap completed in 1 driven")


def test_a_tie_goes_to_the_earlier_submission_and_a_later_equal_time_does_not_replace():
    e = [Entry(3, 2, "late", 9733, 200.0), Entry(1, 1, "early", 9733, 100.0), Entry(2, 1, "early", 9733, 150.0),
         Entry(4, 3, "slow", 9800, 50.0), Entry(5, 3, "slow", None, 10.0)]
    board = leaderboard(e)
    assert [(x.alias, x.submission_id) for x in board] == [("early", 1), ("late", 3), ("slow", 4)]


@pytest.mark.parametrize("better", [True, False])
def test_a_racers_row_changes_only_for_a_strictly_better_time(better):
    e = [Entry(1, 1, "ana", 9733, 100.0), Entry(2, 1, "ana", 9732 if better else 9734, 200.0)]
    assert leaderboard(e)[0].submission_id == (2 if better else 1)
