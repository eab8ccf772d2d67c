"""The league's tables (SQLAlchemy 2 declarative models): people, races, submissions, workers, the audit log.

Only portable column types are used (integers, strings, text, booleans, floats, timestamps), so the same
models run on SQLite and PostgreSQL; JSON documents are stored as text (the rules and a result are canonical
JSON the league writes and hashes itself). Times are timezone-aware UTC in Python and naive UTC in SQLite.

The migrations in `racerlab.league.migrations` create these tables; a change here needs a new migration
(tests/league/test_store.py compares the two).
"""

from __future__ import annotations

from datetime import UTC, datetime

from sqlalchemy import (
    Boolean,
    DateTime,
    Float,
    ForeignKey,
    Index,
    Integer,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column


class UTCTime(TypeDecorator):
    """A timestamp that is always timezone-aware UTC in Python (SQLite keeps it naive, PostgreSQL as timestamptz)."""

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value, dialect):
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given to the league's store; use an aware UTC time")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value, dialect):
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


def utcnow() -> datetime:
    return datetime.now(UTC)


class Base(DeclarativeBase):
    pass


class Setting(Base):
    """Store-wide settings (open sign-up, the secret CSRF tokens are made from), one JSON value per key."""

    __tablename__ = "settings"
    key: Mapped[str] = mapped_column(String(64), primary_key=True)
    value: Mapped[str] = mapped_column(Text)


class User(Base):
    __tablename__ = "users"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    alias: Mapped[str] = mapped_column(String(20), unique=True)
    role: Mapped[str] = mapped_column(String(16))
    password_hash: Mapped[str] = mapped_column(String(255))
    active: Mapped[bool] = mapped_column(Boolean, default=True)
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    invited_by: Mapped[int | None] = mapped_column(ForeignKey("users.id"), nullable=True)


class Invite(Base):
    """A one-time invite: its code is shown once and stored as a SHA-256 hash."""

    __tablename__ = "invites"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    code_hash: Mapped[str] = mapped_column(String(64), unique=True)
    alias: Mapped[str] = mapped_column(String(20))
    role: Mapped[str] = mapped_column(String(16))
    created_by: Mapped[int] = mapped_column(ForeignKey("users.id"))
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    expires_at: Mapped[datetime] = mapped_column(UTCTime)
    used_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    used_by: Mapped[int | None] = mapped_column(ForeignKey("users.id"), nullable=True)


class Token(Base):
    """An API token or a browser session: shown once, stored as a SHA-256 hash."""

    __tablename__ = "tokens"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"), index=True)
    kind: Mapped[str] = mapped_column(String(16))  # api | session
    token_hash: Mapped[str] = mapped_column(String(64), unique=True)
    label: Mapped[str] = mapped_column(String(64), default="")
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    expires_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    last_used_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    revoked_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)


class LoginAttempt(Base):
    """One password check, for throttling: `key` is "alias:<alias>" or "client:<address>"."""

    __tablename__ = "login_attempts"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    key: Mapped[str] = mapped_column(String(128))
    at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    ok: Mapped[bool] = mapped_column(Boolean)
    __table_args__ = (Index("ix_login_attempts_key_at", "key", "at"),)


class Race(Base):
    """A race: its frozen rules (canonical JSON and their hash) and the schedule that may still change."""

    __tablename__ = "races"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    description: Mapped[str] = mapped_column(String(255), default="")
    rules_json: Mapped[str] = mapped_column(Text)
    rules_hash: Mapped[str] = mapped_column(String(64))
    opens_at: Mapped[datetime] = mapped_column(UTCTime)
    closes_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    max_submissions: Mapped[int] = mapped_column(Integer)
    public_videos: Mapped[bool] = mapped_column(Boolean, default=True)
    created_by: Mapped[int] = mapped_column(ForeignKey("users.id"))
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    # bumped by every change a leaderboard or status page shows (a submission, a claim, a result)
    version: Mapped[int] = mapped_column(Integer, default=0)


class Submission(Base):
    """One model entered in one race by one racer, and its place in the queue.

    `number` is the racer's n-th submission to the race: unique per (race, racer), so two requests that both
    read n - 1 cannot both insert n, and the limit is `number <= max_submissions` in the same transaction.
    `model_hash` is unique per (race, racer) too: an identical model is one submission. The queue is the
    rows with status 'queued'; a worker claims one by a guarded UPDATE (status, worker, lease, attempt)."""

    __tablename__ = "submissions"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    race_id: Mapped[int] = mapped_column(ForeignKey("races.id"))
    user_id: Mapped[int] = mapped_column(ForeignKey("users.id"))
    number: Mapped[int] = mapped_column(Integer)
    model_hash: Mapped[str] = mapped_column(String(64))
    model_name: Mapped[str] = mapped_column(String(64), default="")
    checkpoint: Mapped[str] = mapped_column(String(64), default="")
    source: Mapped[str] = mapped_column(String(32), default="")  # racerlab | aws-checkpoint | aws-pb
    rules_json: Mapped[str] = mapped_column(Text)  # the rules copied in at submission
    rules_hash: Mapped[str] = mapped_column(String(64))
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    status: Mapped[str] = mapped_column(String(16), default="queued")
    reason: Mapped[str] = mapped_column(String(500), default="")
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    worker: Mapped[str | None] = mapped_column(String(128), nullable=True)
    lease_until: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    started_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    finished_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
    score_ms: Mapped[int | None] = mapped_column(Integer, nullable=True)  # the timing method's figure, ranked only
    laps_completed: Mapped[int | None] = mapped_column(Integer, nullable=True)
    laps_driven: Mapped[int | None] = mapped_column(Integer, nullable=True)
    off_track: Mapped[int | None] = mapped_column(Integer, nullable=True)
    result_json: Mapped[str | None] = mapped_column(Text, nullable=True)
    result_dir: Mapped[str | None] = mapped_column(String(255), nullable=True)  # relative to the league folder
    eval_seconds: Mapped[float | None] = mapped_column(Float, nullable=True)
    eval_cpu_seconds: Mapped[float | None] = mapped_column(Float, nullable=True)
    racerlab_version: Mapped[str | None] = mapped_column(String(32), nullable=True)
    __table_args__ = (
        UniqueConstraint("race_id", "user_id", "number", name="uq_submission_number"),
        UniqueConstraint("race_id", "user_id", "model_hash", name="uq_submission_model"),
        Index("ix_submissions_status_id", "status", "id"),
        Index("ix_submissions_race_status", "race_id", "status"),
    )


class Worker(Base):
    """An evaluation worker's heartbeat: the queue's ETA counts the live ones."""

    __tablename__ = "workers"
    id: Mapped[str] = mapped_column(String(128), primary_key=True)  # host:pid:nonce
    host: Mapped[str] = mapped_column(String(64))
    pid: Mapped[int] = mapped_column(Integer)
    started_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    seen_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    state: Mapped[str] = mapped_column(String(16), default="idle")  # idle | evaluating | stopped


class AuditEntry(Base):
    """One line of the append-only audit log (the migration adds triggers that refuse UPDATE and DELETE)."""

    __tablename__ = "audit"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    actor_id: Mapped[int | None] = mapped_column(ForeignKey("users.id"), nullable=True)
    actor: Mapped[str] = mapped_column(String(32), default="")  # alias, or "worker:<id>" / "system"
    action: Mapped[str] = mapped_column(String(48))
    subject: Mapped[str] = mapped_column(String(128), default="")
    detail: Mapped[str] = mapped_column(Text, default="{}")


class Season(Base):
    """A season: races whose standings add up, by the points each place earns (`points_json`: a JSON list, the
    points of 1st, 2nd, ... place; a place past its end earns 0)."""

    __tablename__ = "seasons"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    name: Mapped[str] = mapped_column(String(64), unique=True)
    description: Mapped[str] = mapped_column(String(255), default="")
    points_json: Mapped[str] = mapped_column(Text)
    created_by: Mapped[int] = mapped_column(ForeignKey("users.id"))
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)


class SeasonRace(Base):
    """A race of a season (a race is in at most one season), in the order it was added."""

    __tablename__ = "season_races"
    season_id: Mapped[int] = mapped_column(ForeignKey("seasons.id"), primary_key=True)
    race_id: Mapped[int] = mapped_column(ForeignKey("races.id"), primary_key=True)
    added_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    __table_args__ = (UniqueConstraint("race_id", name="uq_season_race"),)


class Final(Base):
    """A head-to-model final of a race: its entrants (the top racers' ranked submissions, frozen when it starts),
    its state (running | done | failed) and its result (the order, each car's laps) as canonical JSON."""

    __tablename__ = "finals"
    id: Mapped[int] = mapped_column(Integer, primary_key=True)
    race_id: Mapped[int] = mapped_column(ForeignKey("races.id"), index=True)
    status: Mapped[str] = mapped_column(String(16), default="running")
    reason: Mapped[str] = mapped_column(String(500), default="")
    entrants_json: Mapped[str] = mapped_column(Text)
    rules_hash: Mapped[str] = mapped_column(String(64))
    result_json: Mapped[str | None] = mapped_column(Text, nullable=True)
    result_dir: Mapped[str | None] = mapped_column(String(255), nullable=True)  # relative to the league folder
    created_by: Mapped[int] = mapped_column(ForeignKey("users.id"))
    created_at: Mapped[datetime] = mapped_column(UTCTime, default=utcnow)
    finished_at: Mapped[datetime | None] = mapped_column(UTCTime, nullable=True)
