"""The append-only audit log: every admin action and every result, one row each, never changed or removed.

Rows are only ever inserted (`record`); the migration's triggers make the database itself refuse UPDATE and
DELETE on the table, on SQLite and PostgreSQL alike.
"""

from __future__ import annotations

import json

from sqlalchemy import select
from sqlalchemy.orm import Session

from racerlab.league.people import Actor
from racerlab.league.tables import AuditEntry
from racerlab.league.views import AuditView


def record(session: Session, actor: Actor | str | None, action: str, subject: str = "", **detail) -> None:
    """One audit row in the caller's transaction (so it commits or rolls back with the change it records)."""
    if isinstance(actor, Actor):
        actor_id, name = actor.id, actor.alias
    else:
        actor_id, name = None, actor or "system"
    session.add(AuditEntry(actor_id=actor_id, actor=name[:32], action=action[:48], subject=subject[:128],
                           detail=json.dumps(detail, sort_keys=True, default=str)))


def entries(session: Session, since_id: int = 0, limit: int = 200) -> list[AuditView]:
    rows = session.scalars(select(AuditEntry).where(AuditEntry.id > since_id).order_by(AuditEntry.id)
                           .limit(max(1, min(limit, 10_000))))
    return [AuditView(r.id, r.at, r.actor, r.action, r.subject, json.loads(r.detail or "{}")) for r in rows]
