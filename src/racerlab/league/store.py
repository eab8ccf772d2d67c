"""The league's store: the database (SQLite in the league folder by default, PostgreSQL by URL), its migrations,
and the folder beside it that holds what is too big for a row (tracks, converted models, evaluation files).

    DIR/league.db          the SQLite database (absent with --db postgresql://...)
    DIR/league.toml        db = "postgresql://..." when the store lives on a server (written by `league init --db`)
    DIR/tracks/<sha>.npy   every race's track, pinned by content
    DIR/models/<hash>/     converted submissions: weights.safetensors, model_metadata.json, training.toml, model.json
    DIR/results/<id>/      each submission's evaluation (simtrace, EvalMetrics.json, summary.json, MP4)

Transactions: `write()` is one transaction that may change rows; on SQLite it starts with BEGIN IMMEDIATE, so
writers queue on the file's lock (busy timeout) instead of failing half-way, and what a writer reads it may act
on. `read()` is a plain transaction. On PostgreSQL both are READ COMMITTED transactions and what must not
happen twice is guarded by unique constraints and guarded UPDATEs (racerlab.league.queue, .service).
"""

from __future__ import annotations

import os
import tomllib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from sqlalchemy import create_engine, event, inspect, text
from sqlalchemy.engine import Engine, make_url
from sqlalchemy.exc import ArgumentError, OperationalError, SQLAlchemyError
from sqlalchemy.orm import Session, sessionmaker

from racerlab.errors import RacerlabError
from racerlab.logs import atomic_write_text

DB_NAME = "league.db"
CONFIG_NAME = "league.toml"
MIGRATIONS = Path(__file__).resolve().parent / "migrations"
BUSY_TIMEOUT_MS = 60_000  # a writer waits this long for SQLite's lock before giving up


class LeagueError(RacerlabError):
    """A request the league refuses, in one line; `status` is the HTTP status a web page answers with."""

    def __init__(self, message: str, status: int = 400):
        super().__init__(message)
        self.status = status


def sqlite_url(folder: Path) -> str:
    return f"sqlite:///{(folder / DB_NAME).resolve()}"


def configured_url(folder: Path, url: str | None = None) -> str:
    """The database of a league folder: `url` when given, else league.toml's `db`, else the SQLite file in it."""
    if url:
        return url
    cfg = folder / CONFIG_NAME
    if cfg.is_file():
        try:
            db = tomllib.loads(cfg.read_text()).get("db", "")
        except tomllib.TOMLDecodeError as exc:
            raise LeagueError(f"{cfg}: invalid TOML ({exc}); fix it or remove it to use {DB_NAME}") from None
        if db:
            return str(db)
    return sqlite_url(folder)


def _engines(url: str) -> tuple[Engine, Engine]:
    """(writer, reader) engines: on SQLite two pools over one file whose transactions begin IMMEDIATE and DEFERRED,
    elsewhere one engine for both."""
    try:
        parsed = make_url(url)
    except ArgumentError:
        raise LeagueError(f"{url!r}: not a database URL; give sqlite:///path or postgresql://user@host/db") from None
    if parsed.get_backend_name() == "postgresql" and parsed.drivername == "postgresql":
        url = str(parsed.set(drivername="postgresql+psycopg"))  # psycopg 3, the `league` extra's driver
    if parsed.get_backend_name() != "sqlite":
        engine = create_engine(url, pool_pre_ping=True)
        return engine, engine
    return _sqlite_engine(url, "IMMEDIATE"), _sqlite_engine(url, "DEFERRED")


def _sqlite_engine(url: str, begin: str) -> Engine:
    engine = create_engine(url, connect_args={"timeout": BUSY_TIMEOUT_MS / 1000, "check_same_thread": False})

    @event.listens_for(engine, "connect")
    def _on_connect(dbapi_conn, _record):
        dbapi_conn.isolation_level = None  # the driver's own BEGIN handling off: ours below
        cur = dbapi_conn.cursor()
        cur.execute("PRAGMA journal_mode=WAL")  # readers never block the writer
        cur.execute(f"PRAGMA busy_timeout={BUSY_TIMEOUT_MS}")
        cur.execute("PRAGMA foreign_keys=ON")
        cur.execute("PRAGMA synchronous=FULL")  # a committed result survives a power cut
        cur.close()

    @event.listens_for(engine, "begin")
    def _on_begin(conn):
        conn.exec_driver_sql(f"BEGIN {begin}")

    return engine


def _alembic_config(connection):
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    cfg.attributes["connection"] = connection
    return cfg


def _scripts():
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(MIGRATIONS))
    return ScriptDirectory.from_config(cfg)


def head_revision() -> str:
    return _scripts().get_current_head()


def known_revision(revision: str) -> bool:
    """Whether this racerlab's migrations hold `revision` (a later release's store holds one it does not)."""
    return any(r.revision == revision for r in _scripts().walk_revisions())


class Store:
    """A league folder and its database: sessions, migrations, the paths of stored files."""

    def __init__(self, folder, url: str | None = None):
        self.folder = Path(folder)
        self.url = configured_url(self.folder, url)
        self.is_sqlite = self.url.startswith("sqlite")
        self.writer, self.reader = _engines(self.url)
        self._write_sessions = sessionmaker(self.writer, expire_on_commit=False)
        self._read_sessions = sessionmaker(self.reader, expire_on_commit=False)

    @property
    def dialect(self) -> str:
        return self.writer.dialect.name

    # ---- creating and opening ------------------------------------------------------------------------------
    @classmethod
    def create(cls, folder, url: str | None = None) -> Store:
        """A new store in `folder` (created): the database's tables at the newest migration, the file folders."""
        folder = Path(folder)
        if (folder / DB_NAME).exists() or (folder / CONFIG_NAME).exists():
            raise LeagueError(f"{folder}: already holds a league; open it, or choose a new folder")
        folder.mkdir(parents=True, exist_ok=True)
        for sub in ("tracks", "models", "results", "uploads"):
            (folder / sub).mkdir(exist_ok=True)
        if url:
            atomic_write_text(folder / CONFIG_NAME, f"db = {_toml_string(url)}\n")
            os.chmod(folder / CONFIG_NAME, 0o600)  # it may hold the database's password
        store = cls(folder, url)
        if store.revision() is not None:
            raise LeagueError(f"{_safe_url(store.url)}: already holds a league's tables; use another database")
        store.upgrade()
        return store

    @classmethod
    def open(cls, folder, url: str | None = None, upgrade: bool = True) -> Store:
        """The store of an existing league folder, migrated to this racerlab's schema when `upgrade`."""
        folder = Path(folder)
        if not folder.is_dir():
            raise LeagueError(f"{folder}: no such league folder; create one with `racerlab league init {folder}`")
        if url is None and not (folder / DB_NAME).exists() and not (folder / CONFIG_NAME).exists():
            raise LeagueError(f"{folder}: not a league folder (no {DB_NAME}); create one with "
                              f"`racerlab league init {folder}`")
        store = cls(folder, url)
        current = store.revision()
        if current is None:
            raise LeagueError(f"{_safe_url(store.url)}: holds no league; create one with `racerlab league init`")
        if current != head_revision():
            if not known_revision(current):
                raise LeagueError(f"{_safe_url(store.url)}: the store is at schema {current}, written by a later "
                                  f"racerlab (this one knows up to {head_revision()}); upgrade racerlab to open it")
            if not upgrade:
                raise LeagueError(f"{_safe_url(store.url)}: the store is at schema {current}, this racerlab "
                                  f"needs {head_revision()}; open it with upgrade")
            store.upgrade()
        return store

    def revision(self) -> str | None:
        """The migration the database is at (None: no league tables)."""
        try:
            with self.writer.connect() as conn:
                if not inspect(conn).has_table("alembic_version"):
                    return None
                return conn.execute(text("SELECT version_num FROM alembic_version")).scalar()
        except OperationalError as exc:
            raise LeagueError(f"{_safe_url(self.url)}: cannot reach the database "
                              f"({str(exc.orig).strip().splitlines()[0]}); check the URL and that it is running"
                              ) from None

    def upgrade(self) -> None:
        from alembic import command

        with self.writer.begin() as conn:
            command.upgrade(_alembic_config(conn), "head")

    def dispose(self) -> None:
        self.writer.dispose()
        if self.reader is not self.writer:
            self.reader.dispose()

    # ---- transactions --------------------------------------------------------------------------------------
    @contextmanager
    def write(self) -> Iterator[Session]:
        """One transaction that may change rows: committed at the end of the block, rolled back on an error."""
        with self._write_sessions() as session, session.begin():
            yield session

    @contextmanager
    def read(self) -> Iterator[Session]:
        with self._read_sessions() as session, session.begin():
            yield session

    # ---- files ----------------------------------------------------------------------------------------------
    def path(self, relative: str) -> Path:
        """A stored file's path from its name relative to the league folder (never outside it)."""
        p = Path(relative)
        if p.is_absolute() or ".." in p.parts:
            raise LeagueError(f"{relative}: not a path inside the league folder", 500)
        return self.folder / p

    def model_dir(self, model_hash: str) -> Path:
        return self.folder / "models" / model_hash

    def results_dir(self, submission_id: int) -> Path:
        return self.folder / "results" / str(submission_id)


def _toml_string(value: str) -> str:
    return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'


def _safe_url(url: str) -> str:
    """A database URL without its password, for messages."""
    try:
        return make_url(url).render_as_string(hide_password=True)
    except (ArgumentError, SQLAlchemyError):
        return "the database"
