"""What comes back: the per-lap table, logs that deepracer-utils and racerlab report read, standings as CSV and
JSON, a replay that reproduces the laps exactly, and the command line from `league init` to the standings."""

from __future__ import annotations

import csv
import io
import json
import tarfile

import pandas as pd
import pytest

import racerlab.cli as cli
from racerlab.league import League
from racerlab.league.evaluation import PIN_ENV
from racerlab.league.worker import worker_main
from tests.league.conftest import PASSWORD, features_model, racer


@pytest.fixture
def work(monkeypatch):
    """Evaluate what is queued in this process (with the workers' environment, restored afterwards)."""
    for key, value in PIN_ENV.items():
        monkeypatch.setenv(key, value)

    def run(league, jobs):
        assert worker_main(str(league.store.folder), None, "test-worker", max_jobs=jobs, poll_s=0.05) == jobs
    return run


@pytest.fixture
def raced(league, admin, straight, tmp_path, work):
    """Two racers on Straight_track, one action straight ahead: every lap is the same (3 completed laps)."""
    league.create_race(admin, "dash", {"track": str(straight), "laps": 2, "timing": "total_time", "video": False})
    ana, bob = racer(league, admin, "ana"), racer(league, admin, "bob")
    subs = [league.submit(who, "dash", features_model(tmp_path / who.alias, straight, seed=k).path)
            for k, who in enumerate((ana, bob))]
    work(league, 2)
    return ana, bob, subs


def test_the_result_carries_its_laps_files_and_hashes(league, admin, raced):
    ana, bob, (a, b) = raced
    a = league.submission(ana, a.id)
    assert a.status == "ranked" and a.attempts == 1 and len(a.laps) == 2 and all(lap["completed"] for lap in a.laps)
    assert a.score_ms == sum(round(lap["elapsed"] * 1000) for lap in a.laps)  # total time: both laps
    assert set(a.files) == {"simtrace", "metrics", "summary", "result", "logs"}  # no video in this race
    summary = json.loads(league.submission_file(ana, a.id, "summary").read_text())
    metrics = json.loads(league.submission_file(ana, a.id, "metrics").read_text())
    for doc in (summary, metrics):
        assert doc["league"]["model_hash"] == a.model_hash and doc["league"]["rules_hash"] == a.rules_hash
    assert len(metrics["metrics"]) == 2 and metrics["metrics"][0]["episode_status"] == "Lap complete"
    audit = [e for e in league.audit(admin) if e.action == "submission.result"]
    assert [(e.subject, e.detail["status"]) for e in audit] == [(f"submission:{a.id}", "ranked"),
                                                                 (f"submission:{b.id}", "ranked")]


@pytest.mark.one_database  # evaluation-heavy; the database part is the same as the tests' above
def test_the_logs_read_as_any_evaluation(league, raced, tmp_path):
    from deepracer.logs import DeepRacerLog

    from racerlab.analysis.report import write_report

    ana, _, (a, _) = raced
    with tarfile.open(league.submission_file(ana, a.id, "logs")) as tar:
        names = tar.getnames()
        tar.extractall(tmp_path / "got", filter="data")
    folder = tmp_path / "got" / "ana-dash-1"
    assert "ana-dash-1/model_metadata.json" in names and not any(n.endswith(".mp4") for n in names)
    log = DeepRacerLog(str(folder))
    log.load_evaluation_trace()
    rows = len(pd.read_csv(league.submission_file(ana, a.id, "simtrace")))
    assert len(log.dataframe()) == rows
    track = league.store.folder / "tracks" / f"{league.race(ana, 'dash').rules['track_sha256']}.npy"
    out = write_report(folder, tmp_path / "r.html", str(track), kind="evaluation")
    assert out.is_file() and out.stat().st_size > 10_000


def test_a_tie_goes_to_the_earlier_submission(league, admin, raced):
    ana, bob, (a, b) = raced
    st = league.standings(bob, "dash")
    assert [(r.rank, r.alias) for r in st.rows] == [(1, "ana"), (2, "bob")]
    first, second = st.rows
    assert first.time_s == second.time_s and second.gap_s == 0.0  # the same laps; ana submitted first
    assert first.submissions == second.submissions == 1 and first.laps_completed == 2


def test_standings_as_csv_and_json(league, admin, raced):
    rows = list(csv.DictReader(io.StringIO(league.standings_csv(admin, "dash"))))
    assert [(r["rank"], r["alias"]) for r in rows] == [("1", "ana"), ("2", "bob")]
    doc = league.standings(admin, "dash").to_json()
    assert doc["race"] == "dash" and doc["timing"] == "total_time" and doc["rows"][0]["time_s"] == float(
        rows[0]["time_s"])


@pytest.mark.one_database  # evaluation-heavy; the database part is the same as the tests' above
def test_a_replay_reproduces_the_laps_bit_for_bit_and_sees_a_change(league, admin, raced):
    ana, _, (a, _) = raced
    report = league.replay(ana, a.id)
    assert report.identical and report.laps == 2, report.differences
    stored = league.submission_file(admin, a.id, "result")
    doc = json.loads(stored.read_text())
    doc["laps"][1]["end_time"] += 1e-9  # one lap's end moved by a nanosecond
    stored.write_text(json.dumps(doc))
    again = league.replay(admin, a.id)
    assert not again.identical and any("lap 2 end_time" in d for d in again.differences)


def test_a_penalty_costs_its_seconds_in_the_lap_time(league, admin, wide, tmp_path, work):
    """The same model in two races that differ only in the off-track penalty: every lap's time differs by exactly
    off-tracks x the difference (pause rows of 1/15 s: 1 s = 15 rows, 3 s = 45 rows)."""
    model = features_model(tmp_path / "m", wide, seed=4).path
    subs = {}
    for penalty in (1.0, 3.0):
        league.create_race(admin, f"p{penalty:g}", {"track": str(wide), "laps": 1, "time_cap_s": 120,
                                                    "off_track_penalty": penalty, "video": False})
        subs[penalty] = league.submit(admin, f"p{penalty:g}", model)
    work(league, 2)
    one, three = (league.submission(admin, subs[p].id) for p in (1.0, 3.0))
    (lap1,), (lap3,) = one.laps, three.laps
    assert lap1["off_track"] == lap3["off_track"] > 0
    assert lap3["elapsed"] - lap1["elapsed"] == pytest.approx(2.0 * lap1["off_track"], abs=1e-6)


def test_a_race_with_video_serves_its_mp4(league, admin, straight, tmp_path, work):
    import imageio.v2 as imageio

    league.create_race(admin, "film", {"track": str(straight), "laps": 1})
    sub = league.submit(admin, "film", features_model(tmp_path / "m", straight).path)
    work(league, 1)
    done = league.submission(admin, sub.id)
    assert "video" in done.files
    reader = imageio.get_reader(league.submission_file(admin, sub.id, "video"))
    rows = len(pd.read_csv(league.submission_file(admin, sub.id, "simtrace")))
    assert reader.get_meta_data()["fps"] == 7.5 and reader.count_frames() == (rows + 1) // 2


def _layouts(league, sub):
    return json.loads(league.submission_file(league.local_admin(), sub.id, "layouts").read_text())["layouts"]


def test_boxes_from_the_seed_stand_where_they_stood_for_every_racer(league, admin, wide, tmp_path, work):
    for seed in (7, 8):
        league.create_race(admin, f"boxes{seed}", {"track": str(wide), "race_type": "object_avoidance", "obstacles": 3,
                                                   "seed": seed, "laps": 1, "time_cap_s": 20, "video": False})
    ana, bob = racer(league, admin, "ana"), racer(league, admin, "bob")
    subs = [league.submit(ana, "boxes7", features_model(tmp_path / "a", wide, seed=1, race="object_avoidance").path),
            league.submit(bob, "boxes7", features_model(tmp_path / "b", wide, seed=2, race="object_avoidance").path),
            league.submit(bob, "boxes8", features_model(tmp_path / "c", wide, seed=3, race="object_avoidance").path),
            league.submit(ana, "boxes7", features_model(tmp_path / "t", wide, seed=4).path)]  # trained without boxes
    work(league, 4)
    a, b, c, t = (league.submission(admin, s.id) for s in subs)
    assert _layouts(league, a) == _layouts(league, b) != _layouts(league, c)  # one layout per race seed
    assert len(_layouts(league, a)[0]["xy"]) == 3
    assert t.status == "refused" and "reads" in t.reason and "boxes" in t.reason and "the model" in t.reason
    assert str(league.store.folder) not in t.reason
    assert league.race(ana, "boxes7").submissions_used == 1  # a refused model did not use a submission


def test_a_head_to_bot_race_drives_among_bot_cars(league, admin, wide, tmp_path, work):
    league.create_race(admin, "bots", {"track": str(wide), "race_type": "head_to_bot", "bots": 2, "bot_speed": 0.4,
                                       "laps": 1, "time_cap_s": 20, "video": False})
    sub = league.submit(admin, "bots", features_model(tmp_path / "m", wide, race="head_to_bot").path)
    work(league, 1)
    done = league.submission(admin, sub.id)
    assert done.status in ("ranked", "not_ranked", "no_lap") and done.laps
    assert json.loads(league.submission_file(admin, sub.id, "layouts").read_text())["kind"] == "bot"


def test_the_command_line_runs_a_race_from_init_to_the_standings(tmp_path, straight, capsys):
    club = tmp_path / "club"
    pw = tmp_path / "pw"
    pw.write_text(PASSWORD + "\n")
    assert cli.main(["league", "init", str(club), "--password-file", str(pw)]) == 0
    assert "admin account: admin" in capsys.readouterr().out
    assert cli.main(["league", "race", "create", str(club), "dash", "--track", str(straight), "--laps", "2",
                     "--timing", "best_lap", "--no-video", "--max-submissions", "5", "--closes", "+1d"]) == 0
    assert "dash (open): Straight_track, time trial, best lap of 2 laps" in capsys.readouterr().out
    assert cli.main(["league", "invite", str(club), "ana"]) == 0
    code = next(w for w in capsys.readouterr().out.split() if w.startswith("rli_"))
    league = League.open(club)
    ana = league.accept_invite(code, PASSWORD)
    sub = league.submit(ana, "dash", features_model(tmp_path / "m", straight).path)
    assert cli.main(["league", "status", str(club)]) == 0
    assert "queued" in capsys.readouterr().out
    assert cli.main(["league", "work", str(club), "--until-empty"]) == 0
    capsys.readouterr()
    assert cli.main(["league", "standings", str(club), "dash", "--csv"]) == 0
    assert capsys.readouterr().out.splitlines()[1].startswith("1,ana,")
    assert cli.main(["league", "replay", str(club), str(sub.id)]) == 0
    assert "identical bit for bit" in capsys.readouterr().out
    assert cli.main(["league", "race", "update", str(club), "dash", "--max-submissions", "9"]) == 0
    assert cli.main(["league", "standings", str(club), "nope"]) == 2
    err = capsys.readouterr().err
    assert "no race named 'nope'" in err and "Traceback" not in err
