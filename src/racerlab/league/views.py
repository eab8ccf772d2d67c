"""What the service layer hands out: plain dataclasses built from rows, each with `to_json()` for the HTTP API.

No view holds a database object, a password hash or a token hash; a token or invite code appears once, in the
`Issued*` view of the call that made it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from datetime import datetime

from racerlab.league.races import iso

FINAL = ("ranked", "not_ranked", "no_lap", "refused", "failed")
STATUSES = ("queued", "evaluating", *FINAL)
STATUS_WORDS = {"queued": "queued", "evaluating": "under evaluation", "ranked": "ranked", "not_ranked": "not ranked",
                "no_lap": "no lap", "refused": "refused", "failed": "failed"}
# a result's files, relative to its evaluation folder (layouts: where the boxes or bot cars stood); "logs" is the
# .tar.gz of the attempt's folder without the video: a DRfC model folder (model_metadata.json and
# evaluation-<stamp>/) for deepracer-utils and racerlab report
FILES = {"simtrace": "evaluation-simtrace/0-iteration.csv", "metrics": "EvalMetrics.json", "summary": "summary.json",
         "video": "evaluation.mp4", "result": "league.json", "layouts": "layouts.json", "logs": "../logs.tar.gz"}


def _jsonable(obj):
    if isinstance(obj, datetime):
        return iso(obj)
    if isinstance(obj, dict):
        return {k: _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, list | tuple):
        return [_jsonable(v) for v in obj]
    return obj


class _View:
    def to_json(self) -> dict:
        return _jsonable(asdict(self))


@dataclass
class IssuedToken(_View):
    id: int
    kind: str
    token: str  # shown once
    expires_at: datetime | None


@dataclass
class IssuedInvite(_View):
    alias: str
    role: str
    code: str  # shown once
    expires_at: datetime


@dataclass
class UserView(_View):
    id: int
    alias: str
    role: str
    active: bool
    created_at: datetime


@dataclass
class TokenView(_View):
    id: int
    kind: str
    label: str
    created_at: datetime
    expires_at: datetime | None
    last_used_at: datetime | None


@dataclass
class RaceView(_View):
    id: int
    name: str
    description: str
    rules: dict  # public rules for racers (hidden track left out), all of them for staff
    rules_hash: str
    summary: str
    opens_at: datetime
    closes_at: datetime | None
    state: str  # upcoming | open | closed
    max_submissions: int
    public_videos: bool
    version: int  # changes whenever its leaderboard or a status on it changes
    submissions_used: int = 0  # by the acting user (refused ones not counted)


@dataclass
class SubmissionView(_View):
    id: int
    race: str
    alias: str
    number: int
    model_name: str
    model_hash: str
    checkpoint: str
    source: str
    created_at: datetime
    status: str
    status_text: str
    reason: str
    rules_hash: str
    attempts: int = 0
    position: int | None = None  # in the queue, 1 = next
    eta_s: float | None = None
    started_at: datetime | None = None
    finished_at: datetime | None = None
    score_ms: int | None = None
    laps_completed: int | None = None
    laps_driven: int | None = None
    off_track: int | None = None
    laps: list = field(default_factory=list)  # the per-lap table (evaluate.Lap.to_json rows)
    files: list = field(default_factory=list)  # what `League.submission_file` serves for it
    racerlab_version: str | None = None
    note: str = ""  # e.g. why an identical resubmission returned this earlier submission
    duplicate: bool = False


@dataclass
class StandingRow(_View):
    rank: int | None
    alias: str
    time_s: float | None
    gap_s: float | None
    off_track: int | None
    laps_completed: int | None
    laps_driven: int | None
    submissions: int
    status: str
    submission_id: int | None
    model_hash: str
    submitted_at: datetime | None
    video: bool


class _RowsView(_View):
    """A view whose `rows` are views themselves."""

    def to_json(self) -> dict:
        out = _jsonable({k: v for k, v in self.__dict__.items() if k != "rows"})
        out["rows"] = [r.to_json() for r in self.rows]
        return out


@dataclass
class Standings(_RowsView):
    race: str
    timing: str
    rules_hash: str
    state: str
    generated_at: datetime
    version: int
    rows: list  # StandingRow: ranked rows first (rank 1..n), then racers with no ranked result (rank None)


@dataclass
class SeasonRow(_View):
    rank: int
    alias: str
    points: int
    places: list  # the racer's place in each of the season's races, in order (None: not ranked in it)
    race_points: list  # the points each race gave (0 where not ranked)
    wins: int


@dataclass
class SeasonView(_RowsView):
    name: str
    description: str
    points: list  # points of 1st, 2nd, ... place
    races: list  # the race names, in the order they were added
    rows: list  # SeasonRow, rank 1 first


@dataclass
class FinalView(_View):
    id: int
    race: str
    status: str  # running | done | failed
    reason: str
    rules_hash: str
    entrants: list  # {"alias", "qualifying_rank", "submission_id", "model_hash"} in qualifying order
    order: list  # when done: {"place", "alias", "finished", "laps_completed", "total_s", "laps", ...}, 1st first
    created_at: datetime
    finished_at: datetime | None
    files: dict = field(default_factory=dict)  # place -> the file kinds `League.final_file` serves for that car


@dataclass
class AuditView(_View):
    id: int
    at: datetime
    actor: str
    action: str
    subject: str
    detail: dict


@dataclass
class QueueView(_View):
    queued: int
    evaluating: int
    workers: int  # seen in the last minute
    mean_eval_s: float | None


def loads(text: str | None, default=None):
    return default if not text else json.loads(text)
