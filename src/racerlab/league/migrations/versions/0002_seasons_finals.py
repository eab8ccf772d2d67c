"""Seasons (races whose standings add up by points per place) and head-to-model finals of a race.

Revision ID: 0002
Revises: 0001
"""

import sqlalchemy as sa
from alembic import op

revision = "0002"
down_revision = "0001"
branch_labels = None
depends_on = None

TIME = sa.DateTime(timezone=True)


def c(name: str, type_, *args, null: bool = False, **kw) -> sa.Column:
    """A column, NOT NULL unless `null` (as the models in racerlab.league.tables declare them)."""
    return sa.Column(name, type_, *args, nullable=null, **kw)


def upgrade() -> None:
    op.create_table(
        "seasons", c("id", sa.Integer, primary_key=True), c("name", sa.String(64), unique=True),
        c("description", sa.String(255)), c("points_json", sa.Text),
        c("created_by", sa.Integer, sa.ForeignKey("users.id")), c("created_at", TIME))
    op.create_table(
        "season_races", c("season_id", sa.Integer, sa.ForeignKey("seasons.id"), primary_key=True),
        c("race_id", sa.Integer, sa.ForeignKey("races.id"), primary_key=True), c("added_at", TIME),
        sa.UniqueConstraint("race_id", name="uq_season_race"))
    op.create_table(
        "finals", c("id", sa.Integer, primary_key=True), c("race_id", sa.Integer, sa.ForeignKey("races.id")),
        c("status", sa.String(16)), c("reason", sa.String(500)), c("entrants_json", sa.Text),
        c("rules_hash", sa.String(64)), c("result_json", sa.Text, null=True),
        c("result_dir", sa.String(255), null=True), c("created_by", sa.Integer, sa.ForeignKey("users.id")),
        c("created_at", TIME), c("finished_at", TIME, null=True))
    op.create_index("ix_finals_race_id", "finals", ["race_id"])


def downgrade() -> None:
    op.drop_index("ix_finals_race_id", "finals")
    for table in ("finals", "season_races", "seasons"):
        op.drop_table(table)
