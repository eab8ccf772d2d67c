"""The league's service layer: the one Python API the web pages, the HTTP API and the command line call.

    >>> league = League.open("club")                      # or League.create("club") (see `league init`)
    >>> admin = league.authenticate("admin", "the password", client="127.0.0.1")
    >>> league.create_race(admin, "may-cup", {"track": "reInvent2019_track", "timing": "best_lap", "laps": 3})
    >>> invite = league.invite(admin, "ana")               # invite.code is shown once
    >>> ana = league.accept_invite(invite.code, "a long password")
    >>> sub = league.submit(ana, "may-cup", "ana-model.tar.gz")   # converted, hashed, queued: sub.status, .position
    >>> league.standings(ana, "may-cup").rows

Every call that acts for someone takes the acting user (`Actor`) first and checks their role (`people.PERMISSIONS`)
before it reads anything; the user is read again inside the call's transaction, so a deactivated account stops at
once. Refusals are `LeagueError`s: one line, with the HTTP status a page answers with (400 bad input, 401 not
logged in, 403 not allowed, 404 no such thing or not yours, 409 a limit or a state, 429 throttled).
Submissions, results and files: `racerlab.league.submissions`; seasons: `racerlab.league.seasons`; head-to-model
finals: `racerlab.league.finals` (the same `League` methods, defined there).
"""

from __future__ import annotations

import json
import secrets
from datetime import datetime, timedelta

from sqlalchemy import delete, func, select, update
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from racerlab.league import audit, people
from racerlab.league.finals import FinalsMixin
from racerlab.league.people import Actor, require_role
from racerlab.league.races import RaceOptions, check_limit, check_name, race_state
from racerlab.league.rules import Rules, with_tracks
from racerlab.league.seasons import SeasonsMixin
from racerlab.league.store import LeagueError, Store
from racerlab.league.submissions import SubmissionsMixin, used_count
from racerlab.league.tables import Invite, LoginAttempt, Race, Setting, Token, User, utcnow
from racerlab.league.views import AuditView, IssuedInvite, IssuedToken, RaceView, TokenView, UserView

KEEP = object()  # `update_race`: leave this field as it is
TOKEN_SEEN_EVERY = timedelta(minutes=1)  # a token's `last_used_at` is written at most this often


def _race_changes(race: Race, now: datetime, asked: dict) -> dict:
    """Apply `update_race`'s changes (those not KEEP) to the row; what changed, for the audit log."""
    from racerlab.league.races import parse_time

    changes = {}
    if asked["opens"] is not KEEP:
        race.opens_at = parse_time(asked["opens"], now, "opens")
        changes["opens"] = race.opens_at.isoformat()
    if asked["closes"] is not KEEP:
        race.closes_at = None if asked["closes"] is None else parse_time(asked["closes"], now, "closes")
        if race.closes_at is not None and (race.closes_at <= race.opens_at or race.closes_at < now):
            raise LeagueError(f"race {race.name!r}: the close time must be after the opening and not in the past")
        changes["closes"] = race.closes_at.isoformat() if race.closes_at else None
    if asked["max_submissions"] is not KEEP:
        race.max_submissions = changes["max_submissions"] = check_limit(asked["max_submissions"])
    if asked["description"] is not KEEP:
        race.description = changes["description"] = str(asked["description"])[:255]
    if asked["public_videos"] is not KEEP:
        race.public_videos = changes["public_videos"] = bool(asked["public_videos"])
    return changes


class League(SubmissionsMixin, SeasonsMixin, FinalsMixin):
    """A league: its store and every action on it."""

    def __init__(self, store: Store):
        self.store = store

    # ---- opening ---------------------------------------------------------------------------------------------
    @classmethod
    def open(cls, folder, url: str | None = None) -> League:
        return cls(Store.open(folder, url))

    @classmethod
    def create(cls, folder, url: str | None = None, admin: str = "admin",
               password: str | None = None) -> tuple[League, str]:
        """A new league with its first admin account; returns the league and the admin's password (generated
        when not given: show it once)."""
        people.check_alias(admin)
        password = password or secrets.token_urlsafe(15)
        hashed = people.hash_password(password)
        league = cls(Store.create(folder, url))
        with league.store.write() as s:
            s.add(Setting(key="secret", value=json.dumps(secrets.token_hex(32))))
            s.add(Setting(key="open_signup", value="false"))
            user = User(alias=admin, role="admin", password_hash=hashed, active=True)
            s.add(user)
            s.flush()
            audit.record(s, Actor(user.id, admin, "admin"), "league.create", str(folder))
        return league, password

    def close(self) -> None:
        self.store.dispose()

    # ---- who acts ----------------------------------------------------------------------------------------------
    def _acting(self, s: Session, actor: Actor, action: str, *, lock: bool = False) -> User:
        """The actor's row, checked again inside this transaction (active, same role, allowed `action`); with
        `lock`, held until the transaction ends (PostgreSQL's FOR UPDATE; SQLite's writers take turns anyway)."""
        require_role(actor, action)
        user = s.get(User, actor.id, with_for_update=lock)
        if user is None or not user.active or user.role != actor.role or user.alias != actor.alias:
            raise LeagueError(f"{actor.alias}: the account is disabled or changed; log in again", 401)
        return user

    def local_admin(self, alias: str | None = None) -> Actor:
        """Who the command line acts as on a league folder it can write: the named admin, else the first one."""
        with self.store.read() as s:
            q = select(User).where(User.role == "admin", User.active.is_(True)).order_by(User.id)
            if alias:
                q = q.where(User.alias == alias)
            user = s.scalars(q.limit(1)).first()
        if user is None:
            raise LeagueError(f"{self.store.folder}: no active admin{' ' + alias if alias else ''} in this league")
        return Actor(user.id, user.alias, user.role)

    # ---- logging in --------------------------------------------------------------------------------------------
    def authenticate(self, alias: str, password: str, client: str = "") -> Actor:
        """The account whose alias and password these are; 401 when they are not, 429 after too many failures
        for this alias or this client within `people.THROTTLE_WINDOW` (the attempt is then not even checked)."""
        keys = [f"alias:{str(alias)[:40]}"] + ([f"client:{client[:100]}"] if client else [])
        now = utcnow()
        with self.store.read() as s:
            self._throttle(s, keys, now)
            user = s.scalars(select(User).where(User.alias == str(alias))).first()
            stored = user.password_hash if user is not None and user.active else None
        ok = people.verify_password(stored, password) if stored else (people.burn_verify(password) or False)
        with self.store.write() as s:
            s.add_all(LoginAttempt(key=k, at=now, ok=ok) for k in keys)
            if ok and people.needs_rehash(stored):
                s.get(User, user.id).password_hash = people.hash_password(password)
        if not ok:
            raise LeagueError("wrong alias or password", 401)
        return Actor(user.id, user.alias, user.role)

    def _throttle(self, s: Session, keys: list[str], now: datetime) -> None:
        since = now - people.THROTTLE_WINDOW
        for key in keys:
            limit = people.THROTTLE if key.startswith("alias:") else people.CLIENT_THROTTLE
            failed = s.scalar(select(func.count()).select_from(LoginAttempt).where(
                LoginAttempt.key == key, LoginAttempt.at >= since, LoginAttempt.ok.is_(False)))
            if failed >= limit:
                minutes = int(people.THROTTLE_WINDOW.total_seconds() // 60)
                raise LeagueError(f"too many failed logins ({failed} in {minutes} minutes); wait and try again",
                                  429)

    def issue_token(self, actor: Actor, kind: str = "api", label: str = "",
                    ttl: timedelta | None = None) -> IssuedToken:
        """A new API token (`kind` api, no expiry unless `ttl`) or browser session (`kind` session, expires after
        `people.SESSION_TTL` unless `ttl`); the token is in the answer only."""
        if kind not in ("api", "session"):
            raise LeagueError(f"token kind {kind!r}: api or session")
        secret = people.new_secret(kind)
        ttl = ttl if ttl is not None else (people.SESSION_TTL if kind == "session" else None)
        with self.store.write() as s:
            self._acting(s, actor, "token.own")
            expires = utcnow() + ttl if ttl else None
            row = Token(user_id=actor.id, kind=kind, token_hash=people.digest(secret), label=str(label)[:64],
                        expires_at=expires)
            s.add(row)
            s.flush()
            if kind == "api":
                audit.record(s, actor, "token.create", f"token:{row.id}", label=row.label)
        return IssuedToken(row.id, kind, secret, expires)

    def actor_for_token(self, token: str, kind: str = "api") -> Actor:
        """The account an API token or session token belongs to; 401 when it is unknown, revoked or expired."""
        if not isinstance(token, str) or not token.startswith(people.TOKEN_PREFIX.get(kind, "?")):
            raise LeagueError("not logged in (no valid token); log in again", 401)
        now, hashed = utcnow(), people.digest(token)
        with self.store.read() as s:  # a read: a crowd's lookups never queue on the writer's lock
            row = s.scalars(select(Token).where(Token.token_hash == hashed, Token.kind == kind)).first()
            if row is None or row.revoked_at is not None or (row.expires_at is not None and row.expires_at <= now):
                raise LeagueError("not logged in (the token is unknown, revoked or expired); log in again", 401)
            user = s.get(User, row.user_id)
            if user is None or not user.active:
                raise LeagueError("the account is disabled", 401)
            stale = row.last_used_at is None or now - row.last_used_at > TOKEN_SEEN_EVERY
        if stale:  # the token's last use, kept to the minute: one write a minute per token, not one a lookup
            with self.store.write() as s:
                s.execute(update(Token).where(Token.token_hash == hashed).values(last_used_at=now))
        return Actor(user.id, user.alias, user.role)

    def revoke_token(self, actor: Actor, token_id: int) -> None:
        """Revoke one of the actor's tokens (an admin may revoke anyone's)."""
        with self.store.write() as s:
            self._acting(s, actor, "token.own")
            row = s.get(Token, token_id)
            if row is None or (row.user_id != actor.id and actor.role != "admin"):
                raise LeagueError(f"no token {token_id} of yours", 404)
            if row.revoked_at is None:
                row.revoked_at = utcnow()
                audit.record(s, actor, "token.revoke", f"token:{row.id}", kind=row.kind)

    def end_session(self, token: str) -> None:
        """Log a browser session out (its token stops working)."""
        with self.store.write() as s:
            row = s.scalars(select(Token).where(Token.token_hash == people.digest(str(token)))).first()
            if row is not None and row.revoked_at is None:
                row.revoked_at = utcnow()

    def tokens(self, actor: Actor) -> list[TokenView]:
        with self.store.read() as s:
            self._acting(s, actor, "token.own")
            rows = s.scalars(select(Token).where(Token.user_id == actor.id, Token.revoked_at.is_(None))
                             .order_by(Token.id))
            return [TokenView(r.id, r.kind, r.label, r.created_at, r.expires_at, r.last_used_at) for r in rows]

    def secret(self) -> str:
        """The store's secret (CSRF tokens are HMACs under it: `people.csrf_token`)."""
        with self.store.read() as s:
            return json.loads(s.get(Setting, "secret").value)

    def prune_logins(self, older_than: timedelta = timedelta(days=1)) -> int:
        """Forget login attempts older than `older_than` (they only matter within the throttle window)."""
        with self.store.write() as s:
            return s.execute(delete(LoginAttempt).where(LoginAttempt.at < utcnow() - older_than)).rowcount

    # ---- invites and accounts ----------------------------------------------------------------------------------
    def invite(self, actor: Actor, alias: str, role: str = "racer",
               ttl: timedelta = people.INVITE_TTL) -> IssuedInvite:
        """A one-time invite for `alias` as `role`; facilitators invite racers, admins anyone."""
        people.check_role(role)
        require_role(actor, "invite.racer" if role == "racer" else "invite.staff")
        people.check_alias(alias)
        code = people.new_secret("invite")
        with self.store.write() as s:
            self._acting(s, actor, "invite.racer" if role == "racer" else "invite.staff")
            if s.scalars(select(User).where(User.alias == alias)).first() is not None:
                raise LeagueError(f"alias {alias!r} is taken; invite another alias", 409)
            expires = utcnow() + ttl
            s.add(Invite(code_hash=people.digest(code), alias=alias, role=role, created_by=actor.id,
                         expires_at=expires))
            audit.record(s, actor, "invite.create", f"user:{alias}", role=role, expires=expires.isoformat())
        return IssuedInvite(alias, role, code, expires)

    def accept_invite(self, code: str, password: str) -> Actor:
        """The invited account, created with `password`; an invite works once and until it expires."""
        hashed = people.hash_password(password)
        now = utcnow()
        try:
            with self.store.write() as s:
                inv = s.scalars(select(Invite).where(Invite.code_hash == people.digest(str(code)))).first()
                if inv is None or inv.used_at is not None or inv.expires_at <= now:
                    raise LeagueError("this invite is unknown, used or expired; ask for a new one", 404)
                user = User(alias=inv.alias, role=inv.role, password_hash=hashed, active=True,
                            invited_by=inv.created_by)
                s.add(user)
                s.flush()
                inv.used_at, inv.used_by = now, user.id
                audit.record(s, Actor(user.id, user.alias, user.role), "invite.accept", f"user:{user.alias}",
                             role=user.role)
        except IntegrityError:
            raise LeagueError("alias taken meanwhile; ask for an invite with another alias", 409) from None
        return Actor(user.id, user.alias, user.role)

    def sign_up(self, alias: str, password: str) -> Actor:
        """A racer account without an invite, when the league has open sign-up (off by default)."""
        people.check_alias(alias)
        hashed = people.hash_password(password)
        try:
            with self.store.write() as s:
                if not self._open_signup(s):
                    raise LeagueError("this league takes new racers by invite only; ask a facilitator", 403)
                user = User(alias=alias, role="racer", password_hash=hashed, active=True)
                s.add(user)
                s.flush()
                audit.record(s, Actor(user.id, alias, "racer"), "user.sign_up", f"user:{alias}")
        except IntegrityError:
            raise LeagueError(f"alias {alias!r} is taken; choose another", 409) from None
        return Actor(user.id, alias, "racer")

    def _open_signup(self, s: Session) -> bool:
        row = s.get(Setting, "open_signup")
        return bool(row and json.loads(row.value))

    def open_signup(self) -> bool:
        with self.store.read() as s:
            return self._open_signup(s)

    def set_open_signup(self, actor: Actor, on: bool) -> None:
        with self.store.write() as s:
            self._acting(s, actor, "settings.change")
            row = s.get(Setting, "open_signup")
            if row is None:
                s.add(Setting(key="open_signup", value=json.dumps(bool(on))))
            else:
                row.value = json.dumps(bool(on))
            audit.record(s, actor, "settings.open_signup", "league", on=bool(on))

    def change_password(self, actor: Actor, old: str, new: str) -> None:
        hashed = people.hash_password(new)
        with self.store.write() as s:
            user = self._acting(s, actor, "token.own")
            if not people.verify_password(user.password_hash, old):
                raise LeagueError("the current password is wrong", 401)
            user.password_hash = hashed
            s.execute(Token.__table__.update().where(Token.user_id == user.id, Token.kind == "session",
                                                     Token.revoked_at.is_(None)).values(revoked_at=utcnow()))
            audit.record(s, actor, "user.password", f"user:{user.alias}")

    def users(self, actor: Actor) -> list[UserView]:
        with self.store.read() as s:
            self._acting(s, actor, "user.list")
            return [UserView(u.id, u.alias, u.role, u.active, u.created_at)
                    for u in s.scalars(select(User).order_by(User.id))]

    def set_user(self, actor: Actor, alias: str, *, active: bool | None = None, role: str | None = None) -> None:
        """An admin disables or enables an account, or changes its role (not their own)."""
        with self.store.write() as s:
            self._acting(s, actor, "user.change")
            user = s.scalars(select(User).where(User.alias == alias)).first()
            if user is None:
                raise LeagueError(f"no account {alias!r}", 404)
            if user.id == actor.id:
                raise LeagueError("an admin cannot disable or demote themselves; ask another admin", 409)
            if active is not None:
                user.active = bool(active)
            if role is not None:
                user.role = people.check_role(role)
            audit.record(s, actor, "user.change", f"user:{alias}", active=user.active, role=user.role)

    # ---- races -------------------------------------------------------------------------------------------------
    def create_race(self, actor: Actor, name: str, options: RaceOptions | dict) -> RaceView:
        """A new race from `options` (`RaceOptions` or its dict): its rules frozen and hashed, tracks pinned."""
        require_role(actor, "race.create")
        check_name(name)
        opts = options if isinstance(options, RaceOptions) else RaceOptions.from_mapping(dict(options))
        check_limit(opts.max_submissions)
        description = str(opts.description or "")[:255]
        now = utcnow()
        opens, closes = opts.schedule(now)
        rules = with_tracks(opts.rules(), self.store.folder / "tracks", opts.track, opts.eval_track or None)
        try:
            with self.store.write() as s:
                self._acting(s, actor, "race.create")
                race = Race(name=name, description=description, rules_json=rules.canonical(), rules_hash=rules.hash,
                            opens_at=opens, closes_at=closes, max_submissions=opts.max_submissions,
                            public_videos=bool(opts.public_videos), created_by=actor.id, version=0)
                s.add(race)
                s.flush()
                audit.record(s, actor, "race.create", f"race:{name}", rules_hash=rules.hash, rules=rules.to_json(),
                             opens=opens.isoformat(), closes=closes.isoformat() if closes else None,
                             max_submissions=opts.max_submissions)
        except IntegrityError:
            raise LeagueError(f"a race named {name!r} exists; choose another name", 409) from None
        return self.race(actor, name)

    def update_race(self, actor: Actor, name: str, *, closes=KEEP, max_submissions=KEEP, opens=KEEP,
                    description=KEEP, public_videos=KEEP) -> RaceView:
        """Change a race. Once it is open only the close time and the submission limit change (DRoA's rule); the
        rules never do (create a new race instead). A new close time must be after the opening and not past."""
        with self.store.write() as s:
            self._acting(s, actor, "race.update")
            race = self._race_row(s, name)
            now = utcnow()
            if race.opens_at <= now and any(v is not KEEP for v in (opens, description, public_videos)):
                raise LeagueError(f"race {name!r} is open: only its close time and submission limit can change", 409)
            changes = _race_changes(race, now, {"opens": opens, "closes": closes, "max_submissions": max_submissions,
                                                "description": description, "public_videos": public_videos})
            race.version += 1
            audit.record(s, actor, "race.update", f"race:{name}", **changes)
        return self.race(actor, name)

    def _race_row(self, s: Session, name: str) -> Race:
        race = s.scalars(select(Race).where(Race.name == str(name))).first()
        if race is None:
            raise LeagueError(f"no race named {name!r}; `racerlab league race list DIR` lists them", 404)
        return race

    def _race_view(self, s: Session, race: Race, actor: Actor, now: datetime) -> RaceView:
        rules = Rules.from_json(race.rules_json)
        used = used_count(s, race.id, actor.id)
        shown = rules.to_json() if people.may(actor.role, "race.view_hidden") else rules.public_json()
        return RaceView(race.id, race.name, race.description, shown, race.rules_hash, rules.describe(),
                        race.opens_at, race.closes_at, race_state(race.opens_at, race.closes_at, now),
                        race.max_submissions, race.public_videos, race.version, used)

    def race(self, actor: Actor, name: str) -> RaceView:
        with self.store.read() as s:
            self._acting(s, actor, "race.view")
            return self._race_view(s, self._race_row(s, name), actor, utcnow())

    def races(self, actor: Actor) -> list[RaceView]:
        with self.store.read() as s:
            self._acting(s, actor, "race.view")
            now = utcnow()
            return [self._race_view(s, r, actor, now) for r in s.scalars(select(Race).order_by(Race.id))]

    def race_version(self, actor: Actor, name: str) -> int:
        """A number that changes whenever the race's leaderboard or one of its statuses changes (for live pages:
        poll this, fetch the standings when it moved)."""
        with self.store.read() as s:
            self._acting(s, actor, "race.view")
            return self._race_row(s, name).version

    # ---- the audit log -----------------------------------------------------------------------------------------
    def audit(self, actor: Actor, since_id: int = 0, limit: int = 200) -> list[AuditView]:
        with self.store.read() as s:
            self._acting(s, actor, "audit.view")
            return audit.entries(s, since_id, limit)
