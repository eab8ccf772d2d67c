"""The league's first schema: settings, people, invites, tokens, login attempts, races, submissions (the queue),
workers and the append-only audit log (triggers refuse UPDATE and DELETE on both SQLite and PostgreSQL).

Revision ID: 0001
Revises:
"""

import sqlalchemy as sa
from alembic import op

revision = "0001"
down_revision = None
branch_labels = None
depends_on = None

TIME = sa.DateTime(timezone=True)


def c(name: str, type_, *args, null: bool = False, **kw) -> sa.Column:
    """A column, NOT NULL unless `null` (as the models in racerlab.league.tables declare them)."""
    return sa.Column(name, type_, *args, nullable=null, **kw)


def _people() -> None:
    op.create_table("settings", c("key", sa.String(64), primary_key=True), c("value", sa.Text))
    op.create_table(
        "users", c("id", sa.Integer, primary_key=True), c("alias", sa.String(20), unique=True),
        c("role", sa.String(16)), c("password_hash", sa.String(255)), c("active", sa.Boolean),
        c("created_at", TIME), c("invited_by", sa.Integer, sa.ForeignKey("users.id"), null=True))
    op.create_table(
        "invites", c("id", sa.Integer, primary_key=True), c("code_hash", sa.String(64), unique=True),
        c("alias", sa.String(20)), c("role", sa.String(16)),
        c("created_by", sa.Integer, sa.ForeignKey("users.id")), c("created_at", TIME),
        c("expires_at", TIME), c("used_at", TIME, null=True),
        c("used_by", sa.Integer, sa.ForeignKey("users.id"), null=True))
    op.create_table(
        "tokens", c("id", sa.Integer, primary_key=True),
        c("user_id", sa.Integer, sa.ForeignKey("users.id"), index=True), c("kind", sa.String(16)),
        c("token_hash", sa.String(64), unique=True), c("label", sa.String(64)),
        c("created_at", TIME), c("expires_at", TIME, null=True),
        c("last_used_at", TIME, null=True), c("revoked_at", TIME, null=True))
    op.create_table(
        "login_attempts", c("id", sa.Integer, primary_key=True), c("key", sa.String(128)),
        c("at", TIME), c("ok", sa.Boolean))
    op.create_index("ix_login_attempts_key_at", "login_attempts", ["key", "at"])


def _races() -> None:
    op.create_table(
        "races", c("id", sa.Integer, primary_key=True), c("name", sa.String(64), unique=True),
        c("description", sa.String(255)), c("rules_json", sa.Text),
        c("rules_hash", sa.String(64)), c("opens_at", TIME), c("closes_at", TIME, null=True),
        c("max_submissions", sa.Integer), c("public_videos", sa.Boolean),
        c("created_by", sa.Integer, sa.ForeignKey("users.id")), c("created_at", TIME),
        c("version", sa.Integer))
    op.create_table(
        "submissions", c("id", sa.Integer, primary_key=True),
        c("race_id", sa.Integer, sa.ForeignKey("races.id")),
        c("user_id", sa.Integer, sa.ForeignKey("users.id")), c("number", sa.Integer),
        c("model_hash", sa.String(64)), c("model_name", sa.String(64)),
        c("checkpoint", sa.String(64)), c("source", sa.String(32)), c("rules_json", sa.Text),
        c("rules_hash", sa.String(64)), c("created_at", TIME), c("status", sa.String(16)),
        c("reason", sa.String(500)), c("attempts", sa.Integer),
        c("worker", sa.String(128), null=True), c("lease_until", TIME, null=True),
        c("started_at", TIME, null=True), c("finished_at", TIME, null=True),
        c("score_ms", sa.Integer, null=True), c("laps_completed", sa.Integer, null=True),
        c("laps_driven", sa.Integer, null=True), c("off_track", sa.Integer, null=True),
        c("result_json", sa.Text, null=True), c("result_dir", sa.String(255), null=True),
        c("eval_seconds", sa.Float, null=True), c("eval_cpu_seconds", sa.Float, null=True),
        c("racerlab_version", sa.String(32), null=True),
        sa.UniqueConstraint("race_id", "user_id", "number", name="uq_submission_number"),
        sa.UniqueConstraint("race_id", "user_id", "model_hash", name="uq_submission_model"))
    op.create_index("ix_submissions_status_id", "submissions", ["status", "id"])
    op.create_index("ix_submissions_race_status", "submissions", ["race_id", "status"])
    op.create_table(
        "workers", c("id", sa.String(128), primary_key=True), c("host", sa.String(64)),
        c("pid", sa.Integer), c("started_at", TIME), c("seen_at", TIME),
        c("state", sa.String(16)))


SQLITE_GUARDS = [
    "CREATE TRIGGER audit_no_update BEFORE UPDATE ON audit BEGIN SELECT RAISE(ABORT, 'the audit log is append-only'); "
    "END",
    "CREATE TRIGGER audit_no_delete BEFORE DELETE ON audit BEGIN SELECT RAISE(ABORT, 'the audit log is append-only'); "
    "END",
]
POSTGRES_GUARDS = [
    "CREATE FUNCTION audit_append_only() RETURNS trigger LANGUAGE plpgsql AS $$ BEGIN RAISE EXCEPTION "
    "'the audit log is append-only'; END $$",
    "CREATE TRIGGER audit_no_change BEFORE UPDATE OR DELETE ON audit FOR EACH ROW EXECUTE FUNCTION audit_append_only()",
]


def _audit() -> None:
    op.create_table(
        "audit", c("id", sa.Integer, primary_key=True), c("at", TIME),
        c("actor_id", sa.Integer, sa.ForeignKey("users.id"), null=True), c("actor", sa.String(32)),
        c("action", sa.String(48)), c("subject", sa.String(128)), c("detail", sa.Text))
    dialect = op.get_bind().dialect.name
    for statement in SQLITE_GUARDS if dialect == "sqlite" else POSTGRES_GUARDS if dialect == "postgresql" else []:
        op.execute(statement)


def upgrade() -> None:
    _people()
    _races()
    _audit()


def downgrade() -> None:
    dialect = op.get_bind().dialect.name
    if dialect == "postgresql":
        op.execute("DROP TRIGGER IF EXISTS audit_no_change ON audit")
        op.execute("DROP FUNCTION IF EXISTS audit_append_only()")
    for table in ("audit", "workers", "submissions", "races", "login_attempts", "tokens", "invites", "users",
                  "settings"):
        op.drop_table(table)
