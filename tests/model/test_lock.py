"""The training lock: exactly one taker when several start at once, recovery from a dead holder whatever PID
its file names, and the same rules without OS file locks (PID and start time)."""

from __future__ import annotations

import multiprocessing as mp
import os
import subprocess
import sys

import pytest

from racerlab.errors import RacerlabError
from racerlab.model import ModelFolder

ROUNDS = 60
RACERS = 3


def _race(path, start, done, results):
    start.wait()
    lock = ModelFolder(path).lock()
    try:
        lock.acquire()
        results.put("won")
    except RacerlabError:
        results.put("refused")
    except Exception as exc:  # noqa: BLE001 - any other outcome fails the test
        results.put(f"error {type(exc).__name__}: {exc}")
    done.wait()  # hold it until every racer has tried
    lock.release()


def _dead_pid() -> int:
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    return gone.pid


@pytest.mark.skipif(sys.platform == "win32", reason="fork start method")
@pytest.mark.parametrize("stale", [False, True], ids=["no-lock", "stale-lock"])
def test_racers_released_at_the_same_instant_never_both_take_the_lock(tmp_path, stale):
    """With a stale lock in the folder (its trainer killed) every racer sees it stale: on e958da9 each removed the
    file and created its own, the later removing the earlier's, and two took the lock (302 of 600 in issue 28)."""
    ctx = mp.get_context("fork")
    wins = []
    dead = _dead_pid()
    for n in range(ROUNDS):
        folder = tmp_path / f"m{n}"
        folder.mkdir()
        if stale:
            (folder / "training.lock").write_text(f"{dead}\n")
        start, done, results = ctx.Event(), ctx.Event(), ctx.Queue()
        procs = [ctx.Process(target=_race, args=(folder, start, done, results)) for _ in range(RACERS)]
        for p in procs:
            p.start()
        start.set()
        outcomes = sorted(results.get(timeout=30) for _ in procs)
        done.set()
        for p in procs:
            p.join(30)
        wins.append(outcomes.count("won"))
        assert outcomes == ["refused"] * (RACERS - 1) + ["won"], f"round {n}: {outcomes}"
        assert not (folder / "training.lock").exists()  # the winner gave it back
    assert wins == [1] * ROUNDS


def test_a_stale_lock_naming_a_live_unrelated_process_is_taken_over(tmp_path):
    folder = ModelFolder(tmp_path)
    other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        folder.lock_path.write_text(f"{other.pid}\n")  # a dead trainer's PID, reused by another program
        assert folder.lock().holder() is None
        with folder.lock():
            assert folder.lock().holder() == os.getpid()
    finally:
        other.kill()
        other.wait()
    assert not folder.lock_path.exists()


def test_a_stale_lock_naming_our_own_pid_is_taken_over(tmp_path):
    """A restarted container: the trainer gets the PID its predecessor wrote."""
    folder = ModelFolder(tmp_path)
    folder.lock_path.write_text(f"{os.getpid()}\n")
    with folder.lock() as lock:
        assert lock.held
    assert not folder.lock_path.exists()


def test_a_held_lock_names_its_holder_and_how_to_stop_it(tmp_path):
    folder = ModelFolder(tmp_path)
    with folder.lock():
        with pytest.raises(RacerlabError) as err:
            folder.lock().acquire()
    msg = str(err.value)
    assert f"process {os.getpid()}" in msg and str(folder.lock_path) in msg and "\n" not in msg
    assert "kill" not in msg  # never "kill <our own pid>"


def test_without_os_file_locks_the_lock_recovers_by_pid_and_start_time(tmp_path, monkeypatch):
    from racerlab.model import lock as lockmod

    monkeypatch.setattr(lockmod, "_try_os_lock", lambda fd: None)  # a file system without flock
    folder = ModelFolder(tmp_path)
    me, start = os.getpid(), lockmod.process_start(os.getpid())
    with folder.lock():
        with pytest.raises(RacerlabError, match="being trained by process"):
            folder.lock().acquire()
        assert folder.lock().holder() == me
    assert not folder.lock_path.exists()
    if start is None:
        pytest.skip("no process start times on this system")
    folder.lock_path.write_text(f"{os.getppid()} 1\n")  # a live PID that started at another time: stale
    assert folder.lock().holder() is None
    with folder.lock():
        assert folder.lock_path.read_text().split()[:2] == [str(me), start]
    folder.lock_path.write_text(f"{os.getppid()} {lockmod.process_start(os.getppid())}\n")  # really live
    with pytest.raises(RacerlabError, match=f"process {os.getppid()}"):
        folder.lock().acquire()
