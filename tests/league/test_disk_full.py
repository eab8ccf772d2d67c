"""A league whose disk fills during an evaluation: the submission fails with one clear line, nothing half-written is
kept, the store stays sound, and once there is room the racer's retry gives the undisturbed result bit for bit.

The league lives on a small tmpfs (mounting one needs root, as CI and this project's machines have; elsewhere the
test says why it does not run) with the database on the same full disk: SQLite's commits meet it too."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import sqlite3
import subprocess

import pytest

from racerlab.league import League
from racerlab.league.evaluation import evaluate_stored
from racerlab.league.rules import Rules
from racerlab.league.tables import Submission
from racerlab.league.worker import DISK_FULL_REASON, disk_full, worker_main
from tests.league.conftest import PASSWORD, features_model
from tests.league.test_queue import _wait

pytestmark = pytest.mark.skipif(os.geteuid() != 0, reason="mounting a small tmpfs (a disk that fills) needs root")
FINAL = ("ranked", "not_ranked", "no_lap", "refused", "failed")


@pytest.fixture
def small_disk(tmp_path):
    mnt = tmp_path / "disk"
    mnt.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=48m", "tmpfs", str(mnt)], capture_output=True, text=True)
    if done.returncode != 0:  # root without the right to mount (a container without CAP_SYS_ADMIN)
        pytest.skip(f"mounting a tmpfs failed: {done.stderr.strip()}")
    yield mnt
    subprocess.run(["umount", "-l", str(mnt)], check=False)


def fill(mnt, leave: int):
    """A file taking all of the disk's room but `leave` bytes (allocated, not sparse)."""
    filler = mnt / "filler"
    with open(filler, "wb") as f:
        os.posix_fallocate(f.fileno(), 0, max(0, shutil.disk_usage(mnt).free - leave))
    return filler


def _jobs(folder, n):
    worker_main(folder, None, "w-disk", max_jobs=n, poll_s=0.1)


def test_a_disk_that_fills_during_an_evaluation_fails_it_cleanly_and_a_retry_clears_it(small_disk, wide, tmp_path):
    league, _ = League.create(small_disk / "league", password=PASSWORD)
    admin = league.local_admin()
    league.create_race(admin, "wide", {"track": str(wide), "laps": 1, "time_cap_s": 60, "video": True,
                                       "off_track_penalty": 1.0})
    model = features_model(tmp_path / "m", wide, ((0.0, 1.0),), seed=3).path
    sub = league.submit(admin, "wide", model)
    filler = fill(small_disk, 96 << 10)  # room for the claim's commit, not for the evaluation's files
    worker = mp.get_context("spawn").Process(target=_jobs, args=(str(league.store.folder), 2))
    worker.start()
    try:
        failed = _wait(league, admin, sub.id, FINAL, timeout=900)  # a spawned worker imports torch first
        assert (failed.status, failed.reason) == ("failed", DISK_FULL_REASON)
        assert not (league.store.results_dir(sub.id) / "attempt-1").exists()  # nothing half-written kept
        assert worker.is_alive()  # the worker waits for the next submission
        filler.unlink()
        again = league.submit(admin, "wide", model)  # the racer's retry: the same model, queued again
        assert again.id == sub.id and "queued again" in again.note
        done = _wait(league, admin, sub.id, ("ranked", "not_ranked", "no_lap"), timeout=900)
    finally:
        worker.join(60)
        if worker.is_alive():
            worker.kill()
    with league.store.read() as s:
        row = s.get(Submission, sub.id)
        rules, stored = Rules.from_json(row.rules_json), json.loads(row.result_json)
    reference = evaluate_stored(league.store.model_dir(row.model_hash), rules, league.store.folder / "tracks",
                                tmp_path / "reference")
    assert done.laps and stored["laps"] == reference["laps"] and done.score_ms == reference["score_ms"]
    assert league.race(admin, "wide").submissions_used == 1  # the failure cost the racer nothing
    league.close()
    db = sqlite3.connect(small_disk / "league" / "league.db")
    assert db.execute("PRAGMA integrity_check").fetchone() == ("ok",)
    assert db.execute("PRAGMA foreign_key_check").fetchall() == []


def test_a_full_disk_is_told_from_the_racers_mistakes(tmp_path):
    assert disk_full(OSError(28, "No space left on device"), tmp_path)
    wrapped = RuntimeError("writing the video failed")
    wrapped.__cause__ = OSError(122, "Disk quota exceeded")
    assert disk_full(wrapped, tmp_path)
    assert disk_full(OSError("ffmpeg: [out#0] Error: No space left on device"), tmp_path)
    assert not disk_full(ValueError("reads 20 numbers and this race gives it 24"), tmp_path)
