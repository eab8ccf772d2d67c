"""People of a league: roles and what each may do, passwords, one-time invites, API tokens and sessions, throttling.

- Roles (DRoA's): `admin` does everything; `facilitator` creates and runs races, invites racers and sees every
  result and the audit log; `racer` enters races and sees their own submissions and every leaderboard.
  `PERMISSIONS` is the one table of who may do what; `require` checks it.
- Passwords are hashed with Argon2id (argon2-cffi's defaults: 64 MiB, 3 passes), a memory-hard hash; at least
  `MIN_PASSWORD` characters (length, not character classes: NIST SP 800-63B). A process hashes at most
  `HASHES_AT_ONCE` passwords at a time (the others wait their turn): a crowd logging in at once would otherwise
  take every core, 64 MiB each, and the leaderboard's polls would wait behind it. An alias is 3-20 characters of
  letters, digits, `_` and `-` (DRoA's rule).
- Invites, API tokens and session tokens are random strings shown once and stored as SHA-256 hashes (they hold
  192-256 random bits, so a fast hash is enough; a stolen database gives no usable token).
- Throttling: `THROTTLE` failed password checks for one alias, or `CLIENT_THROTTLE` from one client address,
  within `THROTTLE_WINDOW` refuse further checks for that window (counted in the database, so every server
  process sees the same count).
"""

from __future__ import annotations

import hashlib
import hmac
import os
import re
import secrets
import threading
from dataclasses import dataclass
from datetime import timedelta

from racerlab.league.store import LeagueError

ROLES = ("admin", "facilitator", "racer")
ALIAS_RE = re.compile(r"^[A-Za-z0-9_-]{3,20}$")
MIN_PASSWORD = 10
MAX_PASSWORD = 1024  # longer inputs are refused before hashing (a cheap way to burn the server's CPU)
INVITE_TTL = timedelta(days=7)
SESSION_TTL = timedelta(hours=12)
THROTTLE = 5
CLIENT_THROTTLE = 30
THROTTLE_WINDOW = timedelta(minutes=15)
HASHES_AT_ONCE = max(1, (os.cpu_count() or 2) // 2)
TOKEN_PREFIX = {"api": "rla_", "session": "rls_", "invite": "rli_"}

STAFF = frozenset({"admin", "facilitator"})
EVERYONE = frozenset(ROLES)
PERMISSIONS = {
    "race.create": STAFF, "race.update": STAFF, "race.view": EVERYONE, "race.view_hidden": STAFF,
    "submission.create": EVERYONE, "submission.view_any": STAFF, "submission.requeue": STAFF,
    "standings.view": EVERYONE, "audit.view": STAFF,
    "invite.racer": STAFF, "invite.staff": frozenset({"admin"}), "settings.change": frozenset({"admin"}),
    "user.list": STAFF, "user.change": frozenset({"admin"}), "token.own": EVERYONE,
    "season.edit": STAFF, "final.start": STAFF,
}


@dataclass(frozen=True)
class Actor:
    """Who acts: the web pages get one from a session or API token, the local CLI the league's first admin."""

    id: int
    alias: str
    role: str

    @property
    def staff(self) -> bool:
        return self.role in STAFF

    def to_json(self) -> dict:
        return {"id": self.id, "alias": self.alias, "role": self.role}


def may(role: str, action: str) -> bool:
    return role in PERMISSIONS[action]


def require_role(actor: Actor, action: str) -> None:
    """Refuse (403) an action the actor's role does not allow."""
    if not may(actor.role, action):
        raise LeagueError(f"{actor.alias} ({actor.role}) may not {action.replace('.', ' ').replace('_', ' ')}; "
                          "ask the league's admin", 403)


def check_alias(alias: str) -> str:
    if not isinstance(alias, str) or not ALIAS_RE.match(alias):
        raise LeagueError(f"alias {alias!r}: use 3-20 letters, digits, '_' or '-'")
    return alias


def check_role(role: str) -> str:
    if role not in ROLES:
        raise LeagueError(f"role {role!r}: use one of {', '.join(ROLES)}")
    return role


def check_password(password: str) -> str:
    if not isinstance(password, str) or len(password) < MIN_PASSWORD:
        raise LeagueError(f"a password needs at least {MIN_PASSWORD} characters")
    if len(password) > MAX_PASSWORD:
        raise LeagueError(f"a password has at most {MAX_PASSWORD} characters")
    return password


# ---- hashes ---------------------------------------------------------------------------------------------------
_hasher = None
_hashing = threading.BoundedSemaphore(HASHES_AT_ONCE)


def _argon2():
    global _hasher
    if _hasher is None:
        from argon2 import PasswordHasher

        _hasher = PasswordHasher()
    return _hasher


def hash_password(password: str) -> str:
    password = check_password(password)
    with _hashing:
        return _argon2().hash(password)


def verify_password(stored: str, password: str) -> bool:
    from argon2.exceptions import InvalidHashError, VerificationError

    if not isinstance(password, str) or len(password) > MAX_PASSWORD:
        return False
    try:
        with _hashing:
            return _argon2().verify(stored, password)
    except (VerificationError, InvalidHashError):
        return False


def needs_rehash(stored: str) -> bool:
    return _argon2().check_needs_rehash(stored)


_DUMMY = None


def burn_verify(password: str) -> None:
    """A verification against a dummy hash, so that an unknown alias takes as long as a wrong password."""
    global _DUMMY
    if _DUMMY is None:
        _DUMMY = hash_password("not-a-real-password-" + secrets.token_hex(8))
    verify_password(_DUMMY, password)


def new_secret(kind: str) -> str:
    """A fresh invite code, API token or session token (`kind`), recognisable by its prefix."""
    return TOKEN_PREFIX[kind] + secrets.token_urlsafe(32 if kind != "invite" else 18)


def digest(secret: str) -> str:
    return hashlib.sha256(secret.encode("utf-8", "replace")).hexdigest()


def csrf_token(store_secret: str, session_token: str) -> str:
    """The CSRF token of a browser session: an HMAC of the session token under the store's secret (the same in
    every server process, never stored)."""
    return hmac.new(store_secret.encode(), b"csrf:" + session_token.encode(), hashlib.sha256).hexdigest()


def csrf_ok(store_secret: str, session_token: str, presented: str | None) -> bool:
    return bool(presented) and hmac.compare_digest(csrf_token(store_secret, session_token), str(presented))
