"""Evaluation workers: processes that take submissions from the queue, evaluate them and store the outcome.

`worker_main` is one worker's loop: reap lost claims, claim the next submission (`racerlab.league.queue`), keep
its lease alive from a thread, evaluate it (`racerlab.league.evaluation.evaluate_stored` into
results/<id>/attempt-<n>/), store the outcome if the claim is still its own. Asked to stop (`WorkerPool.stop`,
SIGTERM, Ctrl-C) it gives the submission back at the next lap's end without counting the attempt; killed
(-9, a crash, the machine going down) its claim is found by the pool at once or by any worker when the lease
runs out, and the submission is evaluated again from the start, once; then it fails with the reason.

`WorkerPool(folder, url, n).start()` runs n workers as fresh processes (spawned, so that the evaluation's
environment is set before torch loads: `evaluation.PIN_ENV`) and a thread that restarts a worker that died,
after handing its claim back to the queue. A pool's worker whose parent is gone (a server killed with -9) stops
as if asked to (at its next poll or lap) instead of evaluating on beside the restarted server's workers.
A pool's workers run at a lower CPU priority than the server (`WORKER_NICE`): on a machine that serves and
evaluates, the racers' pages and polls are answered first and the evaluations take the rest of the CPU (the
results do not change: an evaluation is the same whatever its speed).
The web server calls it for `racerlab league serve DIR --workers N`.
"""

from __future__ import annotations

import errno
import multiprocessing as mp
import os
import secrets
import shutil
import signal
import socket
import threading
import time
from pathlib import Path

from racerlab.errors import RacerlabError
from racerlab.league import queue
from racerlab.league.store import Store

POLL_S = 1.0
SEEN_EVERY_S = 10.0
DB_RETRY_S = 2.0  # a worker whose database cannot write waits this long before it tries again
WORKER_NICE = 10
MIN_FREE_BYTES = 16 << 20  # an evaluation that fails with less room than this left failed for want of disk
DISK_FULL_REASON = ("the league's disk filled up during the evaluation; nothing of it was kept. Submit the same "
                    "model again to retry once staff have made room (it does not count against your limit)")


class Stopped(Exception):
    """The worker was asked to stop: the evaluation is given back to the queue."""


class Lost(Exception):
    """The claim is no longer this worker's (its lease ran out and another took it): the work is dropped."""


def new_worker_id(tag: str = "") -> str:
    host = socket.gethostname()[:40]
    return f"{host}:{os.getpid()}:{tag or secrets.token_hex(3)}"


class _Beat(threading.Thread):
    """Renews a claim's lease every lease/4 seconds; `lost` is set when the claim is no longer ours."""

    def __init__(self, store: Store, claim: queue.Claim, lease_s: float):
        super().__init__(daemon=True, name="league-lease")
        self.store, self.claim, self.lease_s = store, claim, lease_s
        self.done, self.lost = threading.Event(), threading.Event()

    def run(self) -> None:
        while not self.done.wait(self.lease_s / 4):
            try:
                if not queue.heartbeat(self.store, self.claim, self.lease_s):
                    self.lost.set()
                    return
            except Exception:  # noqa: BLE001 - a database hiccup: try again at the next beat, the lease has slack
                continue


def evaluate_claim(store: Store, claim: queue.Claim, stop=None, lost=None) -> tuple[str, str, dict]:
    """(status, reason, column values) of one claimed submission's evaluation. Raises Stopped or Lost."""
    def check(_lap) -> None:
        if lost is not None and lost.is_set():
            raise Lost()
        if stop is not None and stop.is_set():
            raise Stopped()

    return evaluate_in(store.folder, claim, attempt_folder(store, claim), on_lap=check)


def evaluate_in(folder: Path, claim: queue.Claim, out: Path, on_lap=None,
                tracks_dir: Path | None = None) -> tuple[str, str, dict]:
    """`evaluate_claim` on a league folder's files alone (models/<hash>/, tracks/ or `tracks_dir`), no store: what a
    Ray node runs on the copies it was sent (`racerlab.league.ray_pool`). Raises what `on_lap` raises."""
    from racerlab.league.evaluation import evaluate_stored
    from racerlab.league.rules import Rules

    rules = Rules.from_json(claim.rules_json)
    if rules.hash != claim.rules_hash:
        return "failed", "the stored rules do not match their hash; the store was changed", {}
    model_dir = folder / "models" / claim.model_hash
    try:
        outcome = evaluate_stored(model_dir, rules, tracks_dir or folder / "tracks", out, on_lap=on_lap)
    except (Stopped, Lost):
        raise
    except Exception as exc:  # noqa: BLE001 - sorted below: the disk's, the racer's or racerlab's
        return _failure(exc, folder, model_dir, out.parent)
    outcome["result_dir"] = str(out.relative_to(folder))
    return outcome["status"], outcome["reason"], queue.result_values(outcome)


def _failure(exc: Exception, folder: Path, model_dir: Path, attempt: Path) -> tuple[str, str, dict]:
    """The outcome of an evaluation that raised: a full disk fails it (nothing of it kept, a retry clears it), a
    model that does not fit the race is refused, anything else fails with its one line."""
    if disk_full(exc, folder):
        shutil.rmtree(attempt, ignore_errors=True)  # what it wrote is incomplete, and the room is needed
        return "failed", DISK_FULL_REASON, {}
    if isinstance(exc, RacerlabError):  # the model does not fit the race: the racer's to fix
        return "refused", _scrub(str(exc), model_dir, folder), {}
    why = _scrub(str(exc), model_dir, folder)  # stored as one line, not a dead worker
    return "failed", f"the evaluation failed ({type(exc).__name__}: {why}); staff can queue it again", {}


def disk_full(exc: BaseException, folder: Path) -> bool:
    """Whether an evaluation's failure is the league's disk filling up: ENOSPC or EDQUOT anywhere in the chain of
    causes, ffmpeg's 'No space left' in its message, or less than `MIN_FREE_BYTES` left under the league folder."""
    seen: BaseException | None = exc
    for _ in range(8):
        if seen is None:
            break
        if isinstance(seen, OSError) and seen.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        if "no space left" in str(seen).lower():
            return True
        seen = seen.__cause__ or seen.__context__
    try:
        return shutil.disk_usage(folder).free < MIN_FREE_BYTES
    except OSError:
        return False


def attempt_folder(store: Store, claim: queue.Claim) -> Path:
    """results/<id>/attempt-<n>/evaluation-<stamp>/: the attempt's folder is laid out as a DRfC model folder
    (model_metadata.json, also in model/, an empty training-simtrace/ and one evaluation-<stamp>/), which
    deepracer-utils and `racerlab report` read as they read any evaluation (racerlab.logs.layout)."""
    from datetime import UTC, datetime

    from racerlab.logs.layout import STAMP_FORMAT, TRAINING_SIMTRACE_DIR, export_drfc_metadata

    attempt = store.results_dir(claim.submission_id) / f"attempt-{claim.attempt}"
    shutil.rmtree(attempt, ignore_errors=True)
    attempt.mkdir(parents=True)
    shutil.copyfile(store.model_dir(claim.model_hash) / "model_metadata.json", attempt / "model_metadata.json")
    (attempt / TRAINING_SIMTRACE_DIR).mkdir()
    export_drfc_metadata(attempt)
    return attempt / f"evaluation-{datetime.now(UTC).strftime(STAMP_FORMAT)}"


def _scrub(text: str, model_dir: Path, folder: Path) -> str:
    first = (text.strip().splitlines() or [""])[0]
    return first.replace(str(model_dir / "checkpoints") + os.sep, "").replace(str(model_dir), "the model") \
        .replace(str(folder), "the league folder")[:480]


def run_claim(store: Store, claim: queue.Claim, lease_s: float, stop) -> str:
    """Evaluate one claim and store its outcome; what happened (a status, 'released' or 'lost')."""
    beat = _Beat(store, claim, lease_s)
    beat.start()
    try:
        status, reason, values = evaluate_claim(store, claim, stop, beat.lost)
    except Stopped:
        queue.release(store, claim)
        return "released"
    except Lost:
        return "lost"
    finally:
        beat.done.set()
    return status if _finish(store, claim, status, reason, values) else "lost"


def _finish(store: Store, claim: queue.Claim, status: str, reason: str, values: dict, tries: int = 5) -> bool:
    """queue.finish, tried again while the database cannot write (a full disk being cleared, a restarting
    PostgreSQL); after the last try the error goes up and the lease's expiry gives the submission back."""
    from sqlalchemy.exc import OperationalError

    for k in range(tries):
        try:
            return queue.finish(store, claim, status, reason, values)
        except OperationalError:
            if k == tries - 1:
                raise
            time.sleep(DB_RETRY_S)
    return False


def worker_main(folder: str, url: str | None, worker: str, stop=None, lease_s: float = queue.LEASE_S,
                poll_s: float = POLL_S, max_jobs: int | None = None) -> int:
    """One worker: evaluate queued submissions until `stop` is set (or `max_jobs` are done); the jobs done."""
    from racerlab.league.evaluation import pin_environment

    pin_environment()
    stop = stop if stop is not None else threading.Event()
    previous = signal.signal(signal.SIGTERM, lambda *_: stop.set())
    try:
        return _work(folder, url, worker, stop, lease_s, poll_s, max_jobs)
    finally:
        signal.signal(signal.SIGTERM, previous)


def _work(folder, url, worker, stop, lease_s, poll_s, max_jobs) -> int:
    from sqlalchemy.exc import OperationalError

    store = Store.open(folder, url, upgrade=False)
    host, pid = socket.gethostname()[:64], os.getpid()
    queue.worker_seen(store, worker, host, pid, "idle")
    done, seen = 0, time.monotonic()
    try:
        while not stop.is_set() and (max_jobs is None or done < max_jobs):
            try:
                ran = _one_turn(store, worker, host, pid, lease_s, stop)
            except OperationalError:  # the database cannot write now (its disk is full, it restarts): wait
                stop.wait(DB_RETRY_S)
                continue
            if not ran:
                if time.monotonic() - seen > SEEN_EVERY_S:
                    queue.worker_seen(store, worker, host, pid, "idle")
                    seen = time.monotonic()
                stop.wait(poll_s)
                continue
            done += 1
            seen = time.monotonic()
    finally:
        queue.worker_seen(store, worker, host, pid, "stopped")
        store.dispose()
    return done


def _one_turn(store: Store, worker: str, host: str, pid: int, lease_s: float, stop) -> bool:
    """Reap lost claims, claim the next submission and evaluate it; whether there was one."""
    queue.reap(store)
    claim = queue.claim(store, worker, lease_s)
    if claim is None:
        return False
    queue.worker_seen(store, worker, host, pid, "evaluating")
    run_claim(store, claim, lease_s, stop)
    queue.worker_seen(store, worker, host, pid, "idle")
    return True


def _spawned(folder, url, worker, stop, lease_s, poll_s, parent: int | None = None) -> None:
    os.nice(WORKER_NICE)
    try:
        worker_main(folder, url, worker, _PoolStop(stop, parent), lease_s, poll_s)
    except KeyboardInterrupt:
        pass


class _PoolStop:
    """A pool worker's stop: the pool's event is set, or the worker's parent is gone (a server killed with -9,
    which sets nothing). It looks at the event and never waits on it: a process killed while waiting on a
    multiprocessing Event stays counted as a sleeper, and the pool's `set()` would then wait for it for ever."""

    def __init__(self, event, parent: int | None):
        self.event, self.parent, self.local = event, parent, threading.Event()

    def is_set(self) -> bool:
        if not self.local.is_set() and (self.event.is_set() or (self.parent is not None
                                                                 and os.getppid() != self.parent)):
            self.local.set()
        return self.local.is_set()

    def set(self) -> None:
        self.local.set()

    def wait(self, timeout: float) -> bool:
        end = time.monotonic() + timeout
        while not self.is_set() and time.monotonic() < end:
            self.local.wait(min(0.1, max(0.0, end - time.monotonic())))
        return self.is_set()


class WorkerPool:
    """`workers` local worker processes on one league, restarted when they die."""

    def __init__(self, folder, url: str | None = None, workers: int = 1, *, lease_s: float = queue.LEASE_S,
                 poll_s: float = POLL_S, restart: bool = True):
        if workers < 1:
            raise RacerlabError(f"--workers must be at least 1, got {workers}")
        self.folder, self.url, self.n = str(Path(folder).resolve()), url, int(workers)
        self.lease_s, self.poll_s, self.restart = lease_s, poll_s, restart
        self.ctx = mp.get_context("spawn")
        self.stop_event = self.ctx.Event()
        self.procs: dict[str, mp.Process] = {}
        self._stopping = threading.Event()
        self._watch: threading.Thread | None = None

    def start(self) -> WorkerPool:
        self.store = Store.open(self.folder, self.url)
        reap_dead_local(self.store)
        for _ in range(self.n):
            self._spawn()
        self._watch = threading.Thread(target=self._supervise, daemon=True, name="league-workers")
        self._watch.start()
        return self

    def _spawn(self) -> None:
        worker = f"{socket.gethostname()[:40]}:pool{os.getpid()}:{secrets.token_hex(3)}"
        p = self.ctx.Process(target=_spawned, args=(self.folder, self.url, worker, self.stop_event, self.lease_s,
                                                    self.poll_s, os.getpid()), daemon=True,
                             name=f"racerlab-league-{worker}")
        p.start()
        self.procs[worker] = p

    @property
    def pids(self) -> dict[str, int]:
        return {w: p.pid for w, p in self.procs.items() if p.is_alive()}

    def _supervise(self) -> None:
        while not self._stopping.wait(0.5):
            for worker, p in list(self.procs.items()):
                if p.is_alive() or self._stopping.is_set():
                    continue
                del self.procs[worker]
                try:
                    queue.reap(self.store, dead_workers=(worker,))  # its claim goes back (or fails) at once
                    queue.worker_seen(self.store, worker, "", 0, "stopped")
                except Exception:  # noqa: BLE001 - the lease expiry catches it later
                    pass
                if self.restart:
                    self._spawn()

    def stop(self, timeout: float = 60.0) -> None:
        """Ask every worker to stop (an evaluation under way is given back at its next lap), then end them."""
        self._stopping.set()
        self.stop_event.set()
        deadline = time.monotonic() + timeout
        for p in self.procs.values():
            p.join(max(0.1, deadline - time.monotonic()))
        for worker, p in self.procs.items():
            if p.is_alive():
                p.kill()
                p.join(5)
                queue.reap(self.store, dead_workers=(worker,))
        if self._watch is not None:
            self._watch.join(5)
        self.store.dispose()


def reap_dead_local(store: Store) -> list[int]:
    """Claims of workers on this machine whose process is gone (a server that was killed): queued again now,
    rather than when their lease runs out."""
    from sqlalchemy import select

    from racerlab.league.tables import Worker
    from racerlab.logs.scratch import pid_alive

    host = socket.gethostname()[:64]
    with store.read() as s:
        rows = s.scalars(select(Worker).where(Worker.host == host, Worker.state != "stopped")).all()
    dead = tuple(w.id for w in rows if not pid_alive(w.pid))
    return queue.reap(store, dead_workers=dead) if dead else []
