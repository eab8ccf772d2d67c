"""Submissions, results, files and standings: the `League` methods a racer's pages and commands call.

`submit` checks the race's window and the racer's count first (a cheap refusal), converts the upload
(`racerlab.league.convert`: a locked-down child, data only), stores the model under its content hash and then, in
one transaction, checks the window, the identical model and the limit again and inserts the submission. The
counter cannot be raced: each submission takes the next `number` for (race, racer), unique in the database, so two
simultaneous requests that both read n - 1 cannot both insert n; the loser retries, reads n and is refused at the
limit. An identical model (same content hash) in the same race returns the earlier submission and says why (a
failed one is queued again instead: a retry clears a failure). Refused and failed evaluations do not count.
"""

from __future__ import annotations

import csv
import io
import secrets
import shutil
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

from sqlalchemy import func, select
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from racerlab.league import audit, scoring
from racerlab.league.people import Actor, may, require_role
from racerlab.league.races import iso, race_state
from racerlab.league.rules import Rules
from racerlab.league.store import LeagueError
from racerlab.league.tables import Race, Submission, User, Worker, utcnow
from racerlab.league.views import FILES, STATUS_WORDS, QueueView, StandingRow, Standings, SubmissionView, loads

INSERT_TRIES = 10
DEFAULT_EVAL_S = 30.0  # the ETA's guess before any evaluation has finished
WORKER_SEEN_S = 60.0
CSV_COLUMNS = ("rank", "alias", "time_s", "gap_s", "off_track", "laps_completed", "laps_driven", "submissions",
               "status", "submission_id", "model_hash", "submitted_at")


NOT_COUNTED = ("refused", "failed")  # the race refused the model, or the league failed it: no submission used


def used_count(s: Session, race_id: int, user_id: int) -> int:
    """Submissions that count against the limit: every one but those the evaluation refused or the league failed
    (a failure is the league's: its retry, the same model submitted again, must get in at the limit)."""
    return s.scalar(select(func.count()).select_from(Submission).where(
        Submission.race_id == race_id, Submission.user_id == user_id, Submission.status.not_in(NOT_COUNTED)))


def check_window(race: Race, now: datetime) -> None:
    state = race_state(race.opens_at, race.closes_at, now)
    if state == "upcoming":
        raise LeagueError(f"race {race.name!r} opens at {iso(race.opens_at)}; submit then", 409)
    if state == "closed":
        raise LeagueError(f"race {race.name!r} closed at {iso(race.closes_at)}; it takes no more submissions", 409)


def check_quota(race: Race, used: int, alias: str) -> None:
    if used >= race.max_submissions:
        raise LeagueError(f"{alias} has used all {race.max_submissions} submissions of race {race.name!r}", 409)


def csv_cell(value) -> str:
    """A CSV cell that a spreadsheet will not run as a formula (OWASP: a leading = + - @ tab or CR is quoted)."""
    text = "" if value is None else str(value)
    return "'" + text if text[:1] in ("=", "+", "-", "@", "\t", "\r") else text


@dataclass(frozen=True)
class QueuePicture:
    """The queued submissions' places (1 = next), the live workers and the mean evaluation time, read once."""
    places: dict[int, int]
    workers: int
    mean_s: float

    def place(self, submission_id: int) -> tuple[int, float | None]:
        """(place in the queue, seconds until its result or None with no worker up)."""
        position = self.places.get(submission_id, len(self.places) + 1)
        if not self.workers:
            return position, None
        rounds = -(-position // self.workers)  # ceil: the evaluations ahead of it, shared by the workers
        return position, round(rounds * self.mean_s, 1)


class SubmissionsMixin:
    """`League`'s submission, result and standings calls (see `racerlab.league.service.League`)."""

    # ---- submitting ----------------------------------------------------------------------------------------
    def submit(self, actor: Actor, race: str, upload, *, checkpoint: str = "best", name: str = "",
               deadline_s: float | None = None) -> SubmissionView:
        """Enter the model in `upload` (a folder or archive on this machine) in `race`, as `actor`."""
        from racerlab.league.convert import DEADLINE_S, convert_upload, store_converted

        require_role(actor, "submission.create")
        now = utcnow()
        with self.store.read() as s:
            self._acting(s, actor, "submission.create")
            row = self._race_row(s, race)
            check_window(row, now)
            check_quota(row, used_count(s, row.id, actor.id), actor.alias)
        work = self.store.folder / "uploads" / f"convert-{secrets.token_hex(8)}"
        try:
            conv = convert_upload(upload, work, checkpoint or "best", name, deadline_s=deadline_s or DEADLINE_S)
            store_converted(conv, self.store.folder / "models")
        finally:
            shutil.rmtree(work, ignore_errors=True)
        return self.enter(actor, race, conv, now)

    def enter(self, actor: Actor, race: str, conv, now: datetime) -> SubmissionView:
        """Insert a converted model (`convert.Converted`, stored) as `actor`'s submission to `race`, as of `now`:
        the window, the identical model and the limit checked in the insert's transaction. On PostgreSQL two such
        transactions can both read n - 1; the second insert of number n then breaks the unique constraint and
        this tries again, reading n. The racer's row is locked for the transaction, so two of their submissions
        take turns between the limit's count and the insert (PostgreSQL reads each statement afresh: without it,
        another's #3 committed between this count and this max would make this #4, past a limit of 3)."""
        for _ in range(INSERT_TRIES):
            try:
                return self._insert(actor, race, conv, now)
            except IntegrityError:
                continue  # another request took this number (or this model) first: read again
        raise LeagueError("the league is busy; submit again in a moment", 503)

    def _insert(self, actor: Actor, race: str, conv, now: datetime) -> SubmissionView:
        with self.store.write() as s:
            self._acting(s, actor, "submission.create", lock=True)
            row = self._race_row(s, race)
            check_window(row, now)
            earlier = s.scalars(select(Submission).where(Submission.race_id == row.id, Submission.user_id == actor.id,
                                                         Submission.model_hash == conv.model_hash)).first()
            if earlier is not None:
                return self._resubmitted(s, actor, row, earlier)
            check_quota(row, used_count(s, row.id, actor.id), actor.alias)
            number = (s.scalar(select(func.max(Submission.number)).where(
                Submission.race_id == row.id, Submission.user_id == actor.id)) or 0) + 1
            sub = Submission(race_id=row.id, user_id=actor.id, number=number, model_hash=conv.model_hash,
                             model_name=conv.name, checkpoint=conv.checkpoint, source=conv.source,
                             rules_json=row.rules_json, rules_hash=row.rules_hash, created_at=now, status="queued",
                             reason="", attempts=0)
            s.add(sub)
            row.version += 1
            s.flush()
            audit.record(s, actor, "submission.create", f"submission:{sub.id}", race=row.name, number=number,
                         model_hash=conv.model_hash, source=conv.source, checkpoint=conv.checkpoint)
            return self._view(s, sub, row, actor.alias, utcnow())

    def _resubmitted(self, s: Session, actor: Actor, race: Race, earlier: Submission) -> SubmissionView:
        if earlier.status == "failed":
            check_quota(race, used_count(s, race.id, actor.id), actor.alias)  # it counts again once queued
            earlier.status, earlier.reason, earlier.attempts = "queued", "", 0
            earlier.worker = earlier.lease_until = earlier.started_at = earlier.finished_at = None
            race.version += 1
            audit.record(s, actor, "submission.retry", f"submission:{earlier.id}", race=race.name)
            view = self._view(s, earlier, race, actor.alias, utcnow())
            view.note = f"the same model as your submission #{earlier.number}, which had failed: it is queued again"
            return view
        view = self._view(s, earlier, race, actor.alias, utcnow())
        view.duplicate = True
        view.note = (f"identical to your submission #{earlier.number} of {iso(earlier.created_at)} (model "
                     f"{earlier.model_hash[:12]}): the same model always scores the same, so its result stands and "
                     "no submission was used")
        return view

    # ---- reading submissions ------------------------------------------------------------------------------
    def _view(self, s: Session, sub: Submission, race: Race, alias: str, now: datetime,
              queue: QueuePicture | None = None) -> SubmissionView:
        """`sub` as a racer sees it; a list of views shares one `queue` picture (else it is read for this one)."""
        result = loads(sub.result_json, {})
        view = SubmissionView(
            sub.id, race.name, alias, sub.number, sub.model_name, sub.model_hash, sub.checkpoint, sub.source,
            sub.created_at, sub.status, STATUS_WORDS[sub.status], sub.reason, sub.rules_hash, sub.attempts,
            started_at=sub.started_at, finished_at=sub.finished_at, score_ms=sub.score_ms,
            laps_completed=sub.laps_completed, laps_driven=sub.laps_driven, off_track=sub.off_track,
            laps=result.get("laps", []), files=self._files(sub), racerlab_version=sub.racerlab_version)
        if sub.status == "queued":
            view.position, view.eta_s = (queue or self._queue_picture(s)).place(sub.id)
            if view.eta_s is None:
                view.reason = "waiting for an evaluation worker to start"
        return view

    def _queue_picture(self, s: Session) -> QueuePicture:
        """The queue as the ETAs need it, in three reads (once per list of views, not once per queued row)."""
        queued = s.scalars(select(Submission.id).where(Submission.status == "queued").order_by(Submission.id)).all()
        return QueuePicture({sid: k + 1 for k, sid in enumerate(queued)}, self._live_workers(s),
                            self._mean_eval_s(s) or DEFAULT_EVAL_S)

    def _queue_picture_for(self, s: Session, subs: list[Submission]) -> QueuePicture | None:
        """The queue picture a list of views shares: read only when one of them is queued."""
        return self._queue_picture(s) if any(sub.status == "queued" for sub in subs) else None

    def _live_workers(self, s: Session) -> int:
        """Workers seen in the last minute, or holding a claim whose lease still runs (a long evaluation)."""
        now = utcnow()
        since = now.timestamp() - WORKER_SEEN_S
        seen = {w.id for w in s.scalars(select(Worker).where(Worker.state != "stopped"))
                if w.seen_at.timestamp() >= since}
        busy = s.scalars(select(Submission.worker).where(Submission.status == "evaluating",
                                                         Submission.lease_until > now)).all()
        return len(seen | set(busy))

    def _mean_eval_s(self, s: Session) -> float | None:
        recent = select(Submission.eval_seconds).where(Submission.eval_seconds.is_not(None)) \
            .order_by(Submission.finished_at.desc()).limit(50).subquery()
        return s.scalar(select(func.avg(recent.c.eval_seconds)))

    def _files(self, sub: Submission) -> list[str]:
        if not sub.result_dir:
            return []
        folder = self.store.path(sub.result_dir)
        return [kind for kind, rel in FILES.items() if kind == "logs" or (folder / rel).is_file()]

    def _owned(self, s: Session, actor: Actor, submission_id: int) -> tuple[Submission, Race, str]:
        sub = s.get(Submission, int(submission_id))
        if sub is None or (sub.user_id != actor.id and not may(actor.role, "submission.view_any")):
            raise LeagueError(f"no submission {submission_id} of yours", 404)
        return sub, s.get(Race, sub.race_id), s.get(User, sub.user_id).alias

    def submission(self, actor: Actor, submission_id: int) -> SubmissionView:
        """One submission with its status, queue place, per-lap table and files (the racer's own, or any for staff)."""
        with self.store.read() as s:
            self._acting(s, actor, "submission.create")
            sub, race, alias = self._owned(s, actor, submission_id)
            return self._view(s, sub, race, alias, utcnow())

    def submissions(self, actor: Actor, race: str | None = None, everyone: bool = False) -> list[SubmissionView]:
        """The actor's submissions (newest first), in one race or all; staff with `everyone` see every racer's."""
        with self.store.read() as s:
            self._acting(s, actor, "submission.view_any" if everyone else "submission.create")
            q = select(Submission, Race, User).join(Race, Race.id == Submission.race_id) \
                .join(User, User.id == Submission.user_id)
            if not everyone:
                q = q.where(Submission.user_id == actor.id)
            if race is not None:
                q = q.where(Submission.race_id == self._race_row(s, race).id)
            rows, now = s.execute(q.order_by(Submission.id.desc())).all(), utcnow()
            queue = self._queue_picture_for(s, [sub for sub, _r, _u in rows])
            return [self._view(s, sub, r, u.alias, now, queue) for sub, r, u in rows]

    def race_submissions(self, race: str) -> dict[int, list[SubmissionView]]:
        """Every racer's submissions in `race` (newest first), by user id, in one read: for the web server's shared
        boards (`web.live.Boards`), which hand each asker their own list alone once the route has checked who
        asks. A hundred racers' status polls each reading their own list cost the server a core on race day."""
        with self.store.read() as s:
            row = self._race_row(s, race)
            rows = s.execute(select(Submission, User.alias).join(User, User.id == Submission.user_id)
                             .where(Submission.race_id == row.id).order_by(Submission.id.desc())).all()
            now, queue, by_user = utcnow(), self._queue_picture_for(s, [sub for sub, _alias in rows]), {}
            for sub, alias in rows:
                by_user.setdefault(sub.user_id, []).append(self._view(s, sub, row, alias, now, queue))
            return by_user

    def submission_file(self, actor: Actor, submission_id: int, kind: str) -> Path:
        """The path of a submission's `kind` file (`views.FILES`: simtrace, metrics, summary, video, result): the
        racer's own, any for staff, and the video of a ranked submission when the race shows videos."""
        if kind not in FILES:
            raise LeagueError(f"file {kind!r}: one of {', '.join(FILES)}", 404)
        with self.store.read() as s:
            self._acting(s, actor, "race.view")
            sub = s.get(Submission, int(submission_id))
            race = s.get(Race, sub.race_id) if sub is not None else None
            public = kind == "video" and race is not None and race.public_videos and sub.status == "ranked"
            if sub is None or not (public or sub.user_id == actor.id or may(actor.role, "submission.view_any")):
                raise LeagueError(f"no submission {submission_id} of yours", 404)
            path = self.store.path(sub.result_dir) / FILES[kind] if sub.result_dir else None
        if kind == "logs" and path is not None and not path.is_file():
            logs_bundle(path.resolve().parent, path, f"{alias_of(self, sub)}-{race.name}-{sub.number}")
        if path is None or not path.is_file():
            raise LeagueError(f"submission {submission_id} has no {kind} (yet)", 404)
        return path

    def queue(self, actor: Actor) -> QueueView:
        """How the queue stands: queued and evaluating submissions (all races), live workers, mean evaluation."""
        with self.store.read() as s:
            self._acting(s, actor, "race.view")
            counts = dict(s.execute(select(Submission.status, func.count()).where(
                Submission.status.in_(("queued", "evaluating"))).group_by(Submission.status)).all())
            mean = self._mean_eval_s(s)
            return QueueView(counts.get("queued", 0), counts.get("evaluating", 0), self._live_workers(s),
                             None if mean is None else round(mean, 2))

    def requeue(self, actor: Actor, submission_id: int) -> SubmissionView:
        """Staff put a failed submission back in the queue (it is evaluated again from the start)."""
        with self.store.write() as s:
            self._acting(s, actor, "submission.requeue")
            sub = s.get(Submission, int(submission_id))
            if sub is None:
                raise LeagueError(f"no submission {submission_id}", 404)
            if sub.status != "failed":
                raise LeagueError(f"submission {submission_id} is {STATUS_WORDS[sub.status]}, not failed", 409)
            race = s.get(Race, sub.race_id)
            sub.status, sub.reason, sub.attempts, sub.worker, sub.lease_until = "queued", "", 0, None, None
            race.version += 1
            audit.record(s, actor, "submission.requeue", f"submission:{sub.id}", race=race.name)
            return self._view(s, sub, race, s.get(User, sub.user_id).alias, utcnow())

    def replay(self, actor: Actor, submission_id: int):
        """Evaluate a stored result again and compare it bit for bit (`racerlab.league.replay.ReplayReport`)."""
        from racerlab.league.replay import replay

        with self.store.read() as s:
            self._acting(s, actor, "submission.create")
            sub, _, _ = self._owned(s, actor, submission_id)
            if not sub.result_dir:
                raise LeagueError(f"submission {submission_id} is {STATUS_WORDS[sub.status]}: no result to replay", 409)
            args = (sub.id, sub.model_hash, sub.rules_json, sub.result_dir)
        return replay(self.store, *args)

    # ---- standings ----------------------------------------------------------------------------------------
    def standings(self, actor: Actor, race: str) -> Standings:
        """The leaderboard: each racer's best ranked submission, best first (ties: the earlier submission), then the
        racers with no ranked result yet, by their most laps."""
        with self.store.read() as s:
            self._acting(s, actor, "standings.view")
            row = self._race_row(s, race)
            rules = Rules.from_json(row.rules_json)
            rows = race_rows(s, row)
            return Standings(row.name, rules.timing, row.rules_hash, race_state(row.opens_at, row.closes_at, utcnow()),
                             utcnow(), row.version, rows)

    def standings_csv(self, actor: Actor, race: str) -> str:
        out = io.StringIO()
        w = csv.writer(out, lineterminator="\n")
        w.writerow(CSV_COLUMNS)
        for r in self.standings(actor, race).rows:
            data = r.to_json()
            w.writerow([csv_cell(data[c]) for c in CSV_COLUMNS])
        return out.getvalue()


def alias_of(league, sub: Submission) -> str:
    with league.store.read() as s:
        return s.get(User, sub.user_id).alias


def logs_bundle(attempt: Path, dest: Path, name: str) -> Path:
    """The attempt's folder (model_metadata.json, evaluation-<stamp>/ without the video) as `dest` (.tar.gz),
    under the folder name `name`; written whole or not at all."""
    import os
    import tarfile

    from racerlab.logs.atomic import temp_path_for

    tmp = temp_path_for(dest)
    with tarfile.open(tmp, "w:gz") as tar:
        for p in sorted(attempt.rglob("*")):
            keep = p.is_dir() or (p.suffix != ".mp4" and p != dest)
            if keep and not p.name.startswith("."):
                tar.add(p, f"{name}/{p.relative_to(attempt).as_posix()}", recursive=False)
    os.replace(tmp, dest)
    return dest


def race_rows(s: Session, race: Race) -> list[StandingRow]:
    """A race's leaderboard rows (`standings`): ranked rows first (rank 1..n), then the racers not ranked."""
    subs = s.execute(select(Submission, User.alias).join(User, User.id == Submission.user_id)
                     .where(Submission.race_id == race.id)).all()
    return _standing_rows(subs, race)


def _standing_rows(subs, race: Race) -> list[StandingRow]:
    entries = [scoring.Entry(sub.id, sub.user_id, alias, sub.score_ms if sub.status == "ranked" else None,
                             sub.created_at.timestamp(), sub.laps_completed or 0, sub.laps_driven or 0,
                             sub.off_track or 0, sub.status) for sub, alias in subs]
    by_id = {sub.id: sub for sub, _ in subs}
    used: dict[int, int] = {}
    for sub, _ in subs:
        used[sub.user_id] = used.get(sub.user_id, 0) + (sub.status not in NOT_COUNTED)
    board = scoring.leaderboard(entries)
    first = board[0].score_ms if board else None
    rows = [_row(rank, e, by_id[e.submission_id], used, first, race) for rank, e in enumerate(board, 1)]
    ranked = {e.user_id for e in board}
    rest: dict[int, scoring.Entry] = {}
    for e in entries:
        if e.user_id not in ranked:
            held = rest.get(e.user_id)
            if held is None or (e.laps_completed, -e.submission_id) > (held.laps_completed, -held.submission_id):
                rest[e.user_id] = e
    for e in sorted(rest.values(), key=lambda e: (-e.laps_completed, e.alias)):
        rows.append(_row(None, e, by_id[e.submission_id], used, None, race))
    return rows


def _row(rank, e: scoring.Entry, sub: Submission, used: dict, first: int | None, race: Race) -> StandingRow:
    time_s = None if e.score_ms is None else e.score_ms / 1000
    gap = None if first is None or e.score_ms is None else (e.score_ms - first) / 1000
    return StandingRow(rank, e.alias, time_s, gap, sub.off_track, sub.laps_completed, sub.laps_driven,
                       used.get(e.user_id, 0), sub.status, sub.id, sub.model_hash, sub.created_at,
                       bool(race.public_videos and rank is not None and sub.result_dir))
