"""Races: rules frozen and hashed, tracks pinned by content, only the close time and the limit change once open."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import pytest

from racerlab.league import LeagueError, RaceOptions
from racerlab.league.races import parse_time
from racerlab.league.rules import Rules
from tests.league.conftest import racer


def test_the_rules_hash_is_the_sha256_of_sorted_canonical_json():
    import hashlib

    r = Rules(track="t", track_sha256="a" * 64, laps=5, min_laps=2)
    text = r.canonical()
    assert json.loads(text)["laps"] == 5 and " " not in text
    assert list(json.loads(text)) == sorted(json.loads(text))
    assert r.hash == hashlib.sha256(text.encode()).hexdigest()
    assert Rules.from_json(text) == r and Rules.from_json(text).hash == r.hash
    assert Rules(track="t", track_sha256="a" * 64, laps=5, min_laps=2, off_track_penalty=3.5).hash != r.hash


def test_a_race_pins_its_track_and_racers_do_not_see_the_hidden_one(league, admin, wide, straight):
    ana = racer(league, admin, "ana")
    staff = league.create_race(admin, "cup", {"track": str(wide), "eval_track": str(straight)})
    seen = league.race(ana, "cup")
    assert staff.rules["eval_track"] == "Straight_track" and seen.rules["eval_track"] == "hidden"
    assert seen.rules["track"] == "reInvent2019_wide" and seen.rules_hash == staff.rules_hash
    pinned = league.store.folder / "tracks" / f"{staff.rules['track_sha256']}.npy"
    assert pinned.is_file()
    rules = Rules.from_json(json.dumps(staff.rules))
    assert rules.hash == staff.rules_hash and rules.driven_track[0] == "Straight_track"


def test_once_open_only_the_close_time_and_the_limit_change(league, admin, wide):
    league.create_race(admin, "cup", {"track": str(wide), "max_submissions": 5})
    view = league.update_race(admin, "cup", closes="+2h", max_submissions=7)
    assert view.max_submissions == 7 and view.closes_at > datetime.now(UTC)
    with pytest.raises(LeagueError, match="only its close time and submission limit") as err:
        league.update_race(admin, "cup", opens="+1h")
    assert err.value.status == 409
    assert [e.action for e in league.audit(admin)][-2:] == ["race.create", "race.update"]


def test_an_upcoming_race_can_still_move(league, admin, wide):
    league.create_race(admin, "later", {"track": str(wide), "opens": "+1d"})
    view = league.update_race(admin, "later", opens="+2d", description="moved")
    assert view.state == "upcoming" and view.description == "moved"


def test_a_racer_cannot_create_or_change_a_race(league, admin, wide):
    ana = racer(league, admin, "ana")
    with pytest.raises(LeagueError, match="may not race create") as err:
        league.create_race(ana, "mine", {"track": str(wide)})
    assert err.value.status == 403


@pytest.mark.parametrize("options, message", [
    ({"timing": "total_time", "laps": 3, "min_laps": 2}, "min laps must equal laps"),
    ({"race_type": "object_avoidance"}, "needs boxes"),
    ({"race_type": "head_to_bot"}, "needs bot cars"),
    ({"race_type": "head_to_model"}, "race type 'head_to_model'"),
    ({"timing": "fastest"}, "timing 'fastest'"),
    ({"laps": 0}, "laps must be between 1"),
    ({"min_laps": 4}, "min laps must be between 1 and the race's 3 laps"),
    ({"off_track_penalty": -1}, "off track penalty must be between 0 and 60"),
    ({"closes": "2020-01-01T00:00"}, "has no time zone"),
    ({"opens": "+2h", "closes": "+1h"}, "closes .* before it opens"),
    ({"max_submissions": 0}, "submissions per racer"),
    ({"track": "no_such_track"}, "no_such_track"),
    ({"speed": 3}, "race option 'speed' is not one of"),
])
def test_bad_race_options_are_one_line(league, admin, wide, options, message):
    with pytest.raises(LeagueError, match=message) as err:
        league.create_race(admin, "bad", {"track": str(wide), **options})
    assert "\n" not in str(err.value)


def test_object_avoidance_boxes_fixed_or_from_the_seed(league, admin, wide):
    fixed = league.create_race(admin, "boxes", {"track": str(wide), "race_type": "object_avoidance",
                                                "obstacle_positions": [[0.25, 1], [0.6, -1]]})
    drawn = league.create_race(admin, "drawn", {"track": str(wide), "race_type": "object_avoidance",
                                                "obstacles": 3, "seed": 7})
    assert fixed.rules["race"]["object_positions"] == [[0.25, 1], [0.6, -1]]
    assert drawn.rules["race"] == {"number_of_obstacles": 3, "randomize_obstacle_locations": True}
    assert "3 boxes (from the seed)" in drawn.summary


def test_times_are_iso_with_a_zone_now_or_relative():
    now = datetime(2026, 5, 1, 12, 0, tzinfo=UTC)
    assert parse_time("now", now) == now
    assert parse_time("+90m", now) == now + timedelta(minutes=90)
    assert parse_time("2026-05-01T18:00+02:00", now) == datetime(2026, 5, 1, 16, 0, tzinfo=UTC)
    assert parse_time("2026-05-01T18:00Z", now) == datetime(2026, 5, 1, 18, 0, tzinfo=UTC)
    with pytest.raises(LeagueError, match="not a time"):
        parse_time("tomorrow", now)


def test_min_laps_defaults_follow_the_timing():
    assert RaceOptions(track="t").resolved_min_laps() == 1
    assert RaceOptions(track="t", timing="average_lap", laps=5).resolved_min_laps() == 3
    assert RaceOptions(track="t", timing="total_time", laps=5).resolved_min_laps() == 5
