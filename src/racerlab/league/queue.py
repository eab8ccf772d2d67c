"""The durable queue: submissions with status 'queued' are the work; a worker claims one with a lease.

- `claim`: the oldest queued submission becomes 'evaluating' for this worker, with `attempts` + 1 and a lease.
  The claim is a guarded UPDATE (`... WHERE id = :id AND status = 'queued'`): of two workers that picked the same
  row only one changes it, on SQLite and PostgreSQL alike; on PostgreSQL the pick is `FOR UPDATE SKIP LOCKED`, so
  workers do not even wait for each other.
- `heartbeat` extends the lease while the evaluation runs (guarded by worker and attempt).
- `finish` stores the result only if this worker still holds this attempt: a worker that lost its lease (it was
  stopped and resumed, or its claim was reaped) cannot write over the retry's result, so nothing counts twice.
- `reap`: a claim whose lease ran out, or whose worker is known dead, goes back to the queue once (the evaluation
  starts again from the start); after `MAX_ATTEMPTS` it fails with one line saying why.
Every change bumps the race's `version` (live pages watch it) and every result is an audit row.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from datetime import datetime, timedelta

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from racerlab.league import audit
from racerlab.league.store import Store
from racerlab.league.tables import Race, Submission, Worker, utcnow

LEASE_S = 60.0  # a live worker renews its lease every LEASE_S / 4
MAX_ATTEMPTS = 2  # the first evaluation and one retry from the start


@dataclass(frozen=True)
class Claim:
    submission_id: int
    attempt: int
    worker: str
    race: str
    model_hash: str
    rules_json: str
    rules_hash: str


def _bump(s: Session, race_id: int) -> None:
    s.execute(update(Race).where(Race.id == race_id).values(version=Race.version + 1))


def claim(store: Store, worker: str, lease_s: float = LEASE_S) -> Claim | None:
    """The next queued submission, now this worker's (None when the queue is empty)."""
    for _ in range(20):  # another worker may take the row we picked: pick again
        with store.write() as s:
            pick = select(Submission.id).where(Submission.status == "queued").order_by(Submission.id).limit(1)
            if store.dialect == "postgresql":
                pick = pick.with_for_update(skip_locked=True)
            sid = s.scalar(pick)
            if sid is None:
                return None
            now = utcnow()
            done = s.execute(update(Submission).where(Submission.id == sid, Submission.status == "queued").values(
                status="evaluating", worker=worker, lease_until=now + timedelta(seconds=lease_s),
                attempts=Submission.attempts + 1, started_at=now, reason="")).rowcount
            if done != 1:
                continue
            sub = s.get(Submission, sid)
            s.refresh(sub)
            _bump(s, sub.race_id)
            race = s.get(Race, sub.race_id)
            return Claim(sub.id, sub.attempts, worker, race.name, sub.model_hash, sub.rules_json, sub.rules_hash)
    return None


def heartbeat(store: Store, c: Claim, lease_s: float = LEASE_S) -> bool:
    """Extend the lease; False when the claim is no longer this worker's (stop and drop the work)."""
    with store.write() as s:
        return s.execute(update(Submission).where(*_held(c)).values(
            lease_until=utcnow() + timedelta(seconds=lease_s))).rowcount == 1


def _held(c: Claim) -> tuple:
    return (Submission.id == c.submission_id, Submission.status == "evaluating", Submission.worker == c.worker,
            Submission.attempts == c.attempt)


def finish(store: Store, c: Claim, status: str, reason: str, values: dict) -> bool:
    """Store the outcome of this claim's evaluation (ranked / not_ranked / no_lap / refused / failed) with its
    columns (`values`: score_ms, laps, result_json, result_dir, ...); False if the claim was lost meanwhile."""
    now = utcnow()
    with store.write() as s:
        done = s.execute(update(Submission).where(*_held(c)).values(
            status=status, reason=reason[:500], finished_at=now, lease_until=None, **values)).rowcount == 1
        if done:
            sub = s.get(Submission, c.submission_id)
            _bump(s, sub.race_id)
            audit.record(s, f"worker:{c.worker}"[:32], "submission.result", f"submission:{c.submission_id}",
                         race=c.race, status=status, reason=reason[:500], score_ms=values.get("score_ms"),
                         attempt=c.attempt, model_hash=c.model_hash, rules_hash=c.rules_hash)
        return done


def reap(store: Store, dead_workers: tuple[str, ...] = (), now: datetime | None = None) -> list[int]:
    """Claims whose lease ran out, or whose worker is in `dead_workers`: queued again, or failed after
    MAX_ATTEMPTS. Returns the submissions changed."""
    now = now or utcnow()
    changed = []
    with store.write() as s:
        lost = select(Submission).where(Submission.status == "evaluating")
        for sub in s.scalars(lost).all():
            if not (sub.worker in dead_workers or (sub.lease_until is not None and sub.lease_until < now)):
                continue
            retry = sub.attempts < MAX_ATTEMPTS
            values = {"status": "queued", "worker": None, "lease_until": None} if retry else {
                "status": "failed", "lease_until": None, "finished_at": now,
                "reason": f"its evaluation was interrupted {sub.attempts} times (the worker stopped); submit the same "
                          "model again to retry"}
            done = s.execute(update(Submission).where(
                Submission.id == sub.id, Submission.status == "evaluating", Submission.worker == sub.worker,
                Submission.attempts == sub.attempts).values(**values)).rowcount
            if done:
                changed.append(sub.id)
                _bump(s, sub.race_id)
                audit.record(s, "system", "submission.retry" if retry else "submission.result",
                             f"submission:{sub.id}", worker=sub.worker, attempt=sub.attempts,
                             status=values["status"], reason=values.get("reason", "worker lost; evaluated again"))
    return changed


# ---- workers' heartbeats ----------------------------------------------------------------------------------------
def worker_seen(store: Store, worker: str, host: str, pid: int, state: str) -> None:
    with store.write() as s:
        row = s.get(Worker, worker)
        if row is None:
            s.add(Worker(id=worker, host=host[:64], pid=pid, state=state, started_at=utcnow(), seen_at=utcnow()))
        else:
            row.state, row.seen_at = state, utcnow()


def result_values(result: dict) -> dict:
    """The submission columns of an evaluation's outcome (see `racerlab.league.evaluation.outcome`)."""
    return {"score_ms": result.get("score_ms"), "laps_completed": result.get("laps_completed"),
            "laps_driven": result.get("laps_driven"), "off_track": result.get("off_track"),
            "result_json": json.dumps(result, sort_keys=True), "result_dir": result.get("result_dir"),
            "eval_seconds": result.get("eval_seconds"), "eval_cpu_seconds": result.get("eval_cpu_seconds"),
            "racerlab_version": result.get("racerlab_version")}


def release(store: Store, c: Claim) -> bool:
    """Give a claim back without counting its attempt (the worker was asked to stop)."""
    with store.write() as s:
        done = s.execute(update(Submission).where(*_held(c)).values(
            status="queued", worker=None, lease_until=None, attempts=Submission.attempts - 1)).rowcount == 1
        if done:
            _bump(s, s.get(Submission, c.submission_id).race_id)
        return done
