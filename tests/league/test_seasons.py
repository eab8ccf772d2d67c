"""Seasons and finals: points per place added up over a season's races (worked out by hand), the tie-break rule,
absent racers, who may change a season or start a final, and a head-to-model final that comes out the same twice.

The season tests put ranked submissions in the store directly (their scores are the input; how a score comes from
an evaluation is test_scoring's and test_results' part); the final races real stored models.
"""

from __future__ import annotations

from datetime import UTC, datetime, timedelta

import pytest

from racerlab.league import LeagueError
from racerlab.league.evaluation import PIN_ENV
from racerlab.league.seasons import DEFAULT_POINTS, Place, check_points, season_table
from racerlab.league.tables import Race, Submission, User
from racerlab.league.worker import worker_main
from tests.league.conftest import features_model, racer

T0 = datetime(2026, 5, 1, 12, 0, tzinfo=UTC)


def ranked(league, race: str, alias: str, score_ms: int | None, minute: int, status: str = "ranked") -> None:
    """A finished submission of `alias` to `race`, submitted `minute` minutes after T0, as a worker leaves it."""
    with league.store.write() as s:
        row = s.query(Race).filter_by(name=race).one()
        user = s.query(User).filter_by(alias=alias).one()
        n = s.query(Submission).filter_by(race_id=row.id, user_id=user.id).count() + 1
        s.add(Submission(race_id=row.id, user_id=user.id, number=n, model_hash=f"{alias}-{race}-{n}".ljust(64, "0"),
                         rules_json=row.rules_json, rules_hash=row.rules_hash,
                         created_at=T0 + timedelta(minutes=minute),
                         status=status, score_ms=score_ms, laps_completed=3 if score_ms else 1, laps_driven=3))


def done_final(league, race: str, alias: str) -> int:
    """A final of `race` left done with `alias` first and that car's simtrace stored (for the pages' tests)."""
    import json

    from racerlab.league.tables import Final

    with league.store.write() as s:
        row = s.query(Race).filter_by(name=race).one()
        car = {"place": 1, "car": 1, "alias": alias, "qualifying_rank": 1, "finished": True, "laps_completed": 1,
               "total_s": 9.5, "progress": 0.0, "off_track": 0, "crashed": 0, "laps": []}
        final = Final(race_id=row.id, status="done", entrants_json=json.dumps([{"alias": alias, "qualifying_rank": 1}]),
                      rules_hash=row.rules_hash, result_json=json.dumps({"order": [car]}), created_by=row.created_by,
                      result_dir="results/final-x")
        s.add(final)
        s.flush()
        final.result_dir = f"results/final-{final.id}"
        fid = final.id
    trace = league.store.folder / "results" / f"final-{fid}" / "car-1" / "evaluation-simtrace" / "0-iteration.csv"
    trace.parent.mkdir(parents=True)
    trace.write_text("episode,steps\n")
    return fid


@pytest.fixture
def season(league, admin, wide):
    """Three races of season `spring` (points 10, 6, 3) and four racers; worked out by hand:

        race   1st          2nd          3rd          not ranked / absent
        r1     ana 20.0 s   bob 21.0 s   cyd 22.0 s   dee absent
        r2     bob 19.5 s   dee 19.8 s   ana 25.0 s   cyd not ranked (1 lap of 3)
        r3     cyd 18.0 s   ana 18.5 s                bob, dee absent

        ana 10 + 3 + 6 = 19, bob 6 + 10 + 0 = 16, cyd 3 + 0 + 10 = 13, dee 0 + 6 + 0 = 6
    """
    for name in ("r1", "r2", "r3"):
        league.create_race(admin, name, {"track": str(wide), "video": False})
    people = {a: racer(league, admin, a) for a in ("ana", "bob", "cyd", "dee")}
    for race, results in {"r1": [("ana", 20000), ("bob", 21000), ("cyd", 22000)],
                          "r2": [("bob", 19500), ("dee", 19800), ("ana", 25000)],
                          "r3": [("cyd", 18000), ("ana", 18500)]}.items():
        for minute, (alias, ms) in enumerate(results):
            ranked(league, race, alias, ms, minute)
    ranked(league, "r2", "cyd", None, 9, "not_ranked")
    league.create_season(admin, "spring", points=[10, 6, 3])
    for name in ("r1", "r2", "r3"):
        league.season_add_race(admin, "spring", name)
    return people


def test_a_three_race_season_adds_the_points_worked_out_by_hand(league, season):
    view = league.season(season["dee"], "spring")  # a racer sees the season as everyone does
    assert view.races == ["r1", "r2", "r3"] and view.points == [10, 6, 3]
    assert [(r.rank, r.alias, r.points, r.places, r.race_points, r.wins) for r in view.rows] == [
        (1, "ana", 19, [1, 3, 2], [10, 3, 6], 1),
        (2, "bob", 16, [2, 1, None], [6, 10, 0], 1),
        (3, "cyd", 13, [3, None, 1], [3, 0, 10], 1),
        (4, "dee", 6, [None, 2, None], [0, 6, 0], 0),
    ]
    assert view.to_json()["rows"][3]["places"] == [None, 2, None]


def test_a_better_submission_changes_the_season_and_so_does_its_points_table(league, admin, season):
    ranked(league, "r3", "bob", 17000, 30)  # bob now wins r3: cyd 2nd, ana 3rd
    rows = {r.alias: (r.points, r.places) for r in league.season(admin, "spring").rows}
    assert rows == {"ana": (10 + 3 + 3, [1, 3, 3]), "bob": (6 + 10 + 10, [2, 1, 1]), "cyd": (3 + 0 + 6, [3, None, 2]),
                    "dee": (6, [None, 2, None])}
    view = league.update_season(admin, "spring", points="5,1")  # 3rd place now earns nothing
    assert [(r.alias, r.points) for r in view.rows] == [("bob", 1 + 5 + 5), ("ana", 5), ("cyd", 1), ("dee", 1)]


def test_removing_a_race_takes_its_points_away(league, admin, season):
    view = league.season_remove_race(admin, "spring", "r3")
    assert view.races == ["r1", "r2"]
    assert [(r.alias, r.points) for r in view.rows] == [("bob", 16), ("ana", 13), ("dee", 6), ("cyd", 3)]


def test_ties_go_by_countback_then_the_earlier_result():
    pts = [10, 6, 4, 2]

    def p(uid, rank, at=0.0):
        return Place(uid, f"r{uid}", rank, at)

    # r1: a win (10); r2: 2nd + 3rd (6 + 4 = 10); r3: a win (10): the wins first, r1 and r3 then by the older
    # account (their results are equally early here)
    rows = season_table(pts, [[p(1, 1), p(2, 2)], [p(3, 1), p(4, 2), p(2, 3)]])
    assert [(r.alias, r.points, r.wins) for r in rows] == [("r1", 10, 1), ("r3", 10, 1), ("r2", 10, 0), ("r4", 6, 0)]
    # no wins: r5 2nd + 4th (6 + 2) against r6 3rd + 3rd (4 + 4): the better single place (a 2nd) first
    rows = season_table(pts, [[p(9, 1), p(5, 2), p(6, 3)], [p(8, 1), p(7, 2), p(6, 3), p(5, 4)]])
    assert [(r.alias, r.points) for r in rows] == [("r8", 10), ("r9", 10), ("r5", 8), ("r6", 8), ("r7", 6)]
    # the same places: the earlier ranked submission first, whatever the ids
    rows = season_table(pts, [[p(1, 1, at=200.0)], [p(2, 1, at=100.0)]])
    assert [r.alias for r in rows] == ["r2", "r1"] and [r.rank for r in rows] == [1, 2]


def test_a_place_past_the_points_table_earns_nothing_but_is_shown():
    rows = season_table([3, 1], [[Place(1, "a", 1, 0), Place(2, "b", 2, 0), Place(3, "c", 3, 0)]])
    assert [(r.alias, r.points, r.places) for r in rows] == [("a", 3, [1]), ("b", 1, [2]), ("c", 0, [3])]
    assert season_table(list(DEFAULT_POINTS), [[], []]) == []


@pytest.mark.parametrize("points, message", [
    ("10,x", "whole numbers"), ([3, 5], "place 2 .* more than"), ([], "1 to 100 places"), ([-1], "from 0 to"),
    ([True], "whole number"),
])
def test_bad_points_are_one_line(points, message):
    with pytest.raises(LeagueError, match=message) as err:
        check_points(points)
    assert "\n" not in str(err.value)


def test_a_racer_cannot_change_a_season(league, admin, season):
    ana = season["ana"]
    for call in (lambda: league.create_season(ana, "mine"), lambda: league.season_add_race(ana, "spring", "r1"),
                 lambda: league.season_remove_race(ana, "spring", "r1"),
                 lambda: league.update_season(ana, "spring", points=[1])):
        with pytest.raises(LeagueError) as err:
            call()
        assert err.value.status == 403
    assert league.season(admin, "spring").points == [10, 6, 3]


def test_a_race_counts_in_one_season_and_names_are_checked(league, admin, season):
    league.create_season(admin, "autumn")
    assert league.season(admin, "autumn").points == list(DEFAULT_POINTS) and league.season(admin, "autumn").rows == []
    with pytest.raises(LeagueError, match="already in season 'spring'") as err:
        league.season_add_race(admin, "autumn", "r1")
    assert err.value.status == 409
    with pytest.raises(LeagueError, match="exists") as err:
        league.create_season(admin, "spring")
    assert err.value.status == 409
    with pytest.raises(LeagueError, match="no season named") as err:
        league.season(admin, "winter")
    assert err.value.status == 404
    assert [s.name for s in league.seasons(season["bob"])] == ["spring", "autumn"]
    actions = [e.action for e in league.audit(admin) if e.action.startswith("season.")]
    assert actions == ["season.create", "season.add_race", "season.add_race", "season.add_race", "season.create"]


# ---- finals ---------------------------------------------------------------------------------------------------
def test_a_finals_order_laps_then_time_then_progress_then_qualifying():
    from racerlab.evaluate import Lap
    from racerlab.league.finals import final_order

    def laps(*ends):  # (end time, progress, completed) of each lap, each starting where the one before ended
        out, t = [], 0.0
        for k, (end, progress, completed) in enumerate(ends, 1):
            out.append(Lap(k, "lap_complete" if completed else "time_up", t, end, progress))
            t = end
        return out

    cars = [{"alias": "a", "qualifying_rank": 1, "laps": laps((10.0, 100, True), (20.0, 100, True))},  # 20.0 s
            {"alias": "b", "qualifying_rank": 2, "laps": laps((9.5, 100, True), (19.5, 100, True))},  # 19.5 s
            {"alias": "c", "qualifying_rank": 3, "laps": laps((10.0, 100, True), (60.0, 60.0, False))},
            {"alias": "d", "qualifying_rank": 5, "laps": laps((10.0, 100, True), (60.0, 80.0, False))},
            {"alias": "e", "qualifying_rank": 4, "laps": laps((11.0, 100, True), (60.0, 80.0, False))}]
    order = final_order(cars, 2)
    assert [(r["place"], r["alias"]) for r in order] == [(1, "b"), (2, "a"), (3, "e"), (4, "d"), (5, "c")]
    assert [r["total_s"] for r in order] == [19.5, 20.0, None, None, None]
    assert [r["progress"] for r in order] == [0.0, 0.0, 80.0, 80.0, 60.0]


@pytest.fixture
def dash(league, admin, straight, tmp_path, monkeypatch):
    """Race `dash` on Straight_track (2 laps, total time): ana's model drives straight at 1 m/s, bob's at 0.6 m/s,
    cyd's at 0.4 m/s; each evaluated, so the leaderboard is ana, bob, cyd."""
    for key, value in PIN_ENV.items():
        monkeypatch.setenv(key, value)
    league.create_race(admin, "dash", {"track": str(straight), "laps": 2, "timing": "total_time", "video": False})
    people = {}
    for k, (alias, speed) in enumerate((("ana", 1.0), ("bob", 0.6), ("cyd", 0.4))):
        people[alias] = racer(league, admin, alias)
        league.submit(people[alias], "dash", features_model(tmp_path / alias, straight, ((0.0, speed),), seed=k).path)
    assert worker_main(str(league.store.folder), league.store.url, "test-worker", max_jobs=3, poll_s=0.05) == 3
    assert [r.alias for r in league.standings(admin, "dash").rows] == ["ana", "bob", "cyd"]
    return people


def test_a_final_races_the_top_two_and_comes_out_the_same_twice(league, admin, dash):
    first = league.start_final(admin, "dash")
    assert first.status == "done", first.reason
    assert [e["alias"] for e in first.entrants] == ["ana", "bob"]  # the top two; cyd is third
    ana, bob = first.order
    assert (ana["place"], ana["alias"], bob["place"], bob["alias"]) == (1, "ana", 2, "bob")
    for car in first.order:
        assert car["finished"] and car["laps_completed"] == 2 and len(car["laps"]) == 2
        assert car["total_s"] == pytest.approx(sum(lap["elapsed"] for lap in car["laps"]), abs=1e-9)
    assert ana["total_s"] < bob["total_s"]
    again = league.start_final(admin, "dash")
    assert again.id != first.id and again.order == first.order  # every lap, bit for bit
    assert [f.id for f in league.finals(dash["cyd"], "dash")] == [again.id, first.id]
    seen = league.final(dash["bob"], first.id)  # a racer sees the order, their own car's files, not the other's
    assert seen.order == first.order and "summary" in seen.files[2] and seen.files[1] == []
    assert league.final_file(dash["bob"], first.id, 2, "summary").is_file()
    with pytest.raises(LeagueError) as err:
        league.final_file(dash["bob"], first.id, 1, "summary")
    assert err.value.status == 404


def test_a_racer_cannot_start_a_final_and_a_final_needs_two_ranked(league, admin, wide):
    league.create_race(admin, "empty", {"track": str(wide), "video": False})
    ana = racer(league, admin, "ana")
    with pytest.raises(LeagueError) as err:
        league.start_final(ana, "empty")
    assert err.value.status == 403
    ranked(league, "empty", "ana", 20000, 0)
    with pytest.raises(LeagueError, match="1 ranked racer") as err:
        league.start_final(admin, "empty")
    assert err.value.status == 409 and league.finals(admin, "empty") == []
    with pytest.raises(LeagueError, match="races 2 models head to head"):
        league.start_final(admin, "empty", size=3)


def test_the_command_line_shows_and_changes_a_season_and_a_final_that_cannot_run_says_why(league, season, capsys):
    import racerlab.cli as cli

    folder = str(league.store.folder)
    db = ["--db", league.store.url] if league.store.dialect == "postgresql" else []
    assert cli.main(["league", "season", "show", folder, "spring", *db]) == 0
    rows = [line.split() for line in capsys.readouterr().out.splitlines()[2:]]
    assert rows == [["1", "ana", "19", "1", "1", "3", "2"], ["2", "bob", "16", "1", "2", "1", "-"],
                    ["3", "cyd", "13", "1", "3", "-", "1"], ["4", "dee", "6", "0", "-", "2", "-"]]
    assert cli.main(["league", "season", "points", folder, "spring", "3,5", *db]) == 2
    err = capsys.readouterr().err
    assert "a lower place cannot earn more" in err and err.count("\n") == 1
    # r1's submissions were put in the store without their models: the final fails, and says so in one line
    assert cli.main(["league", "final", "start", folder, "r1", *db]) == 1
    out = capsys.readouterr().out
    assert "final 1 of r1: ana (#1) vs bob (#2): failed (" in out and folder not in out
    assert league.finals(season["ana"], "r1")[0].status == "failed"


def test_a_final_that_lost_its_process_holds_the_race_only_for_a_while(league, admin, season):
    from racerlab.league.tables import Final

    fid = done_final(league, "r1", "ana")
    with league.store.write() as s:
        s.get(Final, fid).status = "running"  # as a server stopped under it leaves it
    with pytest.raises(LeagueError, match="has a final running") as err:
        league.start_final(admin, "r1")
    assert err.value.status == 409
    with league.store.write() as s:
        s.get(Final, fid).created_at = datetime.now(UTC) - timedelta(hours=1)
    league.start_final(admin, "r1")  # its models are not in the store: it fails, but it ran
    old, new = league.final(admin, fid), league.finals(admin, "r1")[0]
    assert old.status == "failed" and "ended without a result" in old.reason
    assert new.id != fid and new.status == "failed" and "model_metadata.json" in new.reason
