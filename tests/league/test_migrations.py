"""Migrations: a store made by an earlier release opens in this one, upgraded in place, with everything in it.

`data/store-0001.json` holds the rows of a league that racerlab wrote at schema 0001 (its first release of the
league): an admin, two racers who each had a submission ranked in race `cup`, an API token, the audit log. The
test builds a database at that revision with that revision's own migration, puts the rows back, and opens it
with today's racerlab: the schema must then be exactly today's models, and the league must work as before (the
login, the standings, new rows after the old ones). When a migration 0002 lands, this keeps checking that a
0001 store upgrades; a store of a later release gets a dump of its own beside it.
"""

from __future__ import annotations

import json
from datetime import datetime
from pathlib import Path

import pytest
from sqlalchemy import DateTime, MetaData, text

from racerlab.league import League, LeagueError, Store
from racerlab.league.store import _alembic_config, head_revision
from racerlab.league.tables import Base
from tests.league.conftest import PASSWORD

DUMPS = sorted((Path(__file__).parent / "data").glob("store-*.json"))


def _rows(table, rows: list[dict]) -> list[dict]:
    times = {c.name for c in table.columns if isinstance(c.type, DateTime)}
    return [{k: datetime.fromisoformat(v) if k in times and v else v for k, v in r.items()} for r in rows]


def old_store(folder: Path, url: str | None, dump: dict) -> None:
    """A league folder whose database is at the dump's revision, holding its rows (as that release left it)."""
    from alembic import command

    store = Store(folder, url)
    folder.mkdir(parents=True)
    for sub in ("tracks", "models", "results", "uploads"):
        (folder / sub).mkdir()
    with store.writer.begin() as conn:
        command.upgrade(_alembic_config(conn), dump["revision"])
    meta = MetaData()
    meta.reflect(store.writer)
    with store.writer.begin() as conn:
        for table in meta.sorted_tables:
            if table.name != "alembic_version" and dump["tables"].get(table.name):
                conn.execute(table.insert(), _rows(table, dump["tables"][table.name]))
        if store.dialect == "postgresql":  # rows put back with their ids: the sequences go on after them
            for table in meta.sorted_tables:
                if "id" in table.columns and dump["tables"].get(table.name):
                    conn.execute(text(f"SELECT setval(pg_get_serial_sequence('{table.name}', 'id'), "
                                      f"(SELECT max(id) FROM {table.name}))"))
    store.dispose()


@pytest.mark.parametrize("dump_path", DUMPS, ids=[p.stem for p in DUMPS])
def test_a_store_of_an_earlier_release_upgrades_and_keeps_everything(tmp_path, db_url, dump_path):
    from alembic.autogenerate import compare_metadata
    from alembic.migration import MigrationContext

    dump = json.loads(dump_path.read_text())
    folder = tmp_path / "club"
    old_store(folder, db_url, dump)
    if db_url:
        (folder / "league.toml").write_text(f'db = "{db_url}"\n')
    league = League.open(folder)
    try:
        assert league.store.revision() == head_revision()
        with league.store.writer.connect() as conn:
            assert compare_metadata(MigrationContext.configure(conn, opts={"compare_type": True}), Base.metadata) == []
        admin = league.authenticate("admin", PASSWORD)
        ana = league.authenticate("ana", PASSWORD)
        assert [[r.alias, r.rank, r.time_s] for r in league.standings(ana, "cup").rows] == dump["standings"]
        assert len(league.audit(admin)) == len(dump["tables"]["audit"])
        assert [t.label for t in league.tokens(ana)] == ["laptop"]
        cy = league.accept_invite(league.invite(admin, "cyd").code, PASSWORD)  # new ids after the old ones
        assert cy.id == max(u["id"] for u in dump["tables"]["users"]) + 1
    finally:
        league.close()


def test_a_store_of_a_later_release_is_refused_in_one_line(league):
    with league.store.writer.begin() as conn:
        conn.execute(text("UPDATE alembic_version SET version_num = '9999'"))
    with pytest.raises(LeagueError) as err:
        League.open(league.store.folder, league.store.url if league.store.dialect == "postgresql" else None)
    assert "9999" in str(err.value) and "\n" not in str(err.value)
