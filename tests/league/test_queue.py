"""The queue: one claim per submission, leases, a killed worker's evaluation retried once, nothing counted twice."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import time
from datetime import timedelta

import pytest
from sqlalchemy import select

from racerlab.league import queue, start_workers
from racerlab.league.tables import AuditEntry, Submission, utcnow
from racerlab.league.worker import WORKER_NICE, worker_main
from tests.league.conftest import features_model, racer

STRAIGHT_AHEAD = ((0.0, 1.0),)


@pytest.fixture
def wide_race(league, admin, wide):
    # straight ahead on a loop: off the track at every bend and put back; a few seconds of evaluation
    league.create_race(admin, "wide", {"track": str(wide), "laps": 1, "time_cap_s": 60, "video": False,
                                       "off_track_penalty": 1.0})
    return "wide"


def _submit(league, actor, race, tmp_path, seed, track):
    return league.submit(actor, race, features_model(tmp_path / f"m{seed}", track, STRAIGHT_AHEAD, seed=seed).path)


def _wait(league, actor, sid, statuses, timeout=240):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        sub = league.submission(actor, sid)
        if sub.status in statuses:
            return sub
        time.sleep(0.05)
    raise AssertionError(f"submission {sid} still {league.submission(actor, sid).status} after {timeout} s")


def test_two_workers_never_claim_one_submission(league, admin, wide_race, wide, tmp_path):
    subs = [_submit(league, admin, wide_race, tmp_path, k, wide) for k in range(3)]
    claims = [queue.claim(league.store, f"w{k}") for k in range(4)]
    assert [c.submission_id for c in claims[:3]] == [s.id for s in subs] and claims[3] is None
    assert all(c.attempt == 1 for c in claims[:3])


def test_a_lost_lease_is_retried_once_then_failed_and_a_late_result_is_refused(league, admin, wide_race, wide,
                                                                                tmp_path):
    sub = _submit(league, admin, wide_race, tmp_path, 0, wide)
    first = queue.claim(league.store, "w1", lease_s=30)
    assert queue.reap(league.store, now=utcnow() + timedelta(seconds=31)) == [sub.id]
    second = queue.claim(league.store, "w2")
    assert second.attempt == 2
    assert not queue.finish(league.store, first, "ranked", "late", {"score_ms": 1})  # the first worker woke up
    assert not queue.heartbeat(league.store, first)
    queue.reap(league.store, dead_workers=("w2",))
    done = league.submission(admin, sub.id)
    assert done.status == "failed" and "interrupted 2 times" in done.reason and done.score_ms is None


def test_a_released_claim_does_not_count_an_attempt(league, admin, wide_race, wide, tmp_path):
    sub = _submit(league, admin, wide_race, tmp_path, 0, wide)
    c = queue.claim(league.store, "w1")
    assert queue.release(league.store, c)
    assert queue.claim(league.store, "w1").attempt == 1 and league.submission(admin, sub.id).attempts == 1


def _kill_when_evaluating(league, admin, sid, pool) -> int:
    _wait(league, admin, sid, ("evaluating",))
    pid = next(iter(pool.pids.values()))
    os.kill(pid, signal.SIGKILL)
    return pid


def test_a_worker_killed_during_an_evaluation_loses_nothing_and_counts_once(league, admin, wide_race, wide,
                                                                             tmp_path):
    ana = racer(league, admin, "ana")
    sub = _submit(league, ana, wide_race, tmp_path, 0, wide)
    pool = start_workers(league.store.folder, workers=1, poll_s=0.1)
    try:
        _wait(league, admin, sub.id, ("evaluating",))  # evaluations yield the CPU to the server's answers
        pid = next(iter(pool.pids.values()))
        assert os.getpriority(os.PRIO_PROCESS, pid) == min(19, os.getpriority(os.PRIO_PROCESS, 0) + WORKER_NICE)
        killed = _kill_when_evaluating(league, admin, sub.id, pool)
        done = _wait(league, admin, sub.id, ("ranked", "not_ranked", "no_lap", "failed", "refused"))
        assert killed not in pool.pids.values()
    finally:
        pool.stop()
    assert done.status in ("ranked", "no_lap") and done.attempts == 2 and done.laps
    with league.store.read() as s:
        results = s.scalars(select(AuditEntry).where(AuditEntry.action == "submission.result",
                                                     AuditEntry.subject == f"submission:{sub.id}")).all()
        retries = s.scalars(select(AuditEntry).where(AuditEntry.action == "submission.retry")).all()
        row = s.get(Submission, sub.id)
    assert len(results) == 1 and json.loads(results[0].detail)["attempt"] == 2 and len(retries) == 1
    assert "/attempt-2/evaluation-" in row.result_dir
    assert league.race(ana, wide_race).submissions_used == 1  # the retry used no second submission


@pytest.mark.one_database  # evaluation-heavy; the database part is the same as the tests' above
def test_a_restarted_server_evaluates_what_was_queued(league, admin, wide_race, wide, tmp_path):
    subs = [_submit(league, admin, wide_race, tmp_path, k, wide) for k in range(2)]
    league.close()  # the server is gone; the queue is in the database
    from racerlab.league import League

    again = League.open(league.store.folder)
    assert [again.submission(admin, s.id).status for s in subs] == ["queued", "queued"]
    assert [again.submission(admin, s.id).position for s in subs] == [1, 2]
    pool = start_workers(again.store.folder, workers=1, poll_s=0.1)
    try:
        finals = [_wait(again, admin, s.id, ("ranked", "no_lap", "not_ranked")) for s in subs]
    finally:
        pool.stop()
    assert all(f.attempts == 1 and f.files for f in finals)


def _one_job(folder, worker):
    worker_main(folder, None, worker, max_jobs=1, poll_s=0.1)


@pytest.mark.one_database  # evaluation-heavy; the database part is the same as the tests' above
def test_two_worker_processes_drive_the_same_laps_bit_for_bit(league, admin, wide_race, wide, tmp_path):
    import pandas as pd

    ana, bo = racer(league, admin, "ana"), racer(league, admin, "bob")
    model = features_model(tmp_path / "m", wide, ((0.0, 1.0), (20.0, 1.0), (-20.0, 1.0)), seed=3).path
    subs = [league.submit(who, wide_race, model) for who in (ana, bo)]  # one model, two racers: two evaluations
    ctx = mp.get_context("spawn")
    for k in range(2):  # one after the other, each in its own fresh process
        p = ctx.Process(target=_one_job, args=(str(league.store.folder), f"worker-{k}"))
        p.start()
        p.join(240)
        assert p.exitcode == 0
    a, b = (league.submission(admin, s.id) for s in subs)
    assert a.status == b.status and a.laps == b.laps and a.score_ms == b.score_ms
    traces = [pd.read_csv(league.submission_file(admin, s.id, "simtrace")).drop(columns=["wall_clock"]) for s in subs]
    pd.testing.assert_frame_equal(traces[0], traces[1], check_exact=True)
