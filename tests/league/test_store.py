"""The store: migrations that build exactly the models' tables, the append-only audit log, one-line errors."""

from __future__ import annotations

import pytest
from sqlalchemy import text

from racerlab.league import League, LeagueError, Store
from racerlab.league.tables import Base


def test_the_migrations_build_the_models_tables(league):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    with league.store.writer.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), Base.metadata)
    assert diff == []


def test_the_audit_log_refuses_updates_and_deletes_in_the_database(league, admin):
    league.invite(admin, "ana")
    with league.store.writer.begin() as conn:
        assert conn.execute(text("SELECT count(*) FROM audit")).scalar() == 2  # league.create, invite.create
    for statement in ("UPDATE audit SET action = 'x'", "DELETE FROM audit"):
        with pytest.raises(Exception, match="append-only"), league.store.writer.begin() as conn:
            conn.execute(text(statement))
    assert [e.action for e in league.audit(admin)] == ["league.create", "invite.create"]


def test_a_second_init_and_a_missing_folder_are_one_line(tmp_path, league):
    with pytest.raises(LeagueError, match="already holds a league"):
        League.create(league.store.folder)
    with pytest.raises(LeagueError, match="league init") as err:
        Store.open(tmp_path / "nowhere")
    assert "\n" not in str(err.value)
    with pytest.raises(LeagueError, match="not a league folder"):
        Store.open(tmp_path)


def test_a_reopened_store_keeps_everything(league, admin):
    league.invite(admin, "ana")
    again = League.open(league.store.folder)
    assert [e.action for e in again.audit(again.local_admin())][-1] == "invite.create"
    again.close()


def test_a_bad_database_url_is_one_line(tmp_path):
    with pytest.raises(LeagueError, match="not a database URL"):
        Store.create(tmp_path / "x", "not a url")
