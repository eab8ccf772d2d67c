"""Who asks: a browser's session cookie (with a CSRF token on every state-changing request) or a script's API token.

- A browser logs in with its alias and password (or accepts an invite) and gets a session token in the cookie
  `SESSION_COOKIE`: HTTP-only, SameSite=Lax, Secure when the server speaks TLS, expiring with the session
  (`people.SESSION_TTL`). Every POST, PUT, PATCH and DELETE that rides on the cookie carries the session's CSRF
  token (`people.csrf_token`, an HMAC of the session under the store's secret) in the `X-CSRF-Token` header, the
  `csrf` query parameter (multipart uploads: checked before the body is read) or the `csrf` form field.
- Forms shown before anyone is logged in (login, invite, sign-up) carry a pre-session token: an HMAC of a random
  value the browser holds in `PRE_COOKIE` (a forged login from another site has neither).
- A script sends `Authorization: Bearer rla_...` (an API token from `POST /api/login` or `/api/invites/accept`);
  a bearer request needs no CSRF token (no browser adds that header by itself). A wrong bearer token is a 401,
  never a fall-back to the cookie.
- A token is looked up in the store at most every `TokenCache.TTL_S` (5 s) per server process (a crowd's polls
  would otherwise each take the store's write lock). Logging out, revoking a token, a password change or an
  account change made through this server forget the cached tokens before it answers (a lookup that was under way
  meanwhile is not kept); one made elsewhere (the command line, another server on the same database) takes effect
  within the TTL. Every service call checks the account itself again (active, same role); the shared board reads
  (`live.Boards`) check the role of the cached account.
- `signed_in` is the dependency every route but the login forms and the static files starts with; `needs(action)`
  adds the role check of a page that reads nothing from the service (a form for staff). The service checks the
  role again in each call.
"""

from __future__ import annotations

import functools
import hashlib
import hmac
import secrets
import threading
import time
from dataclasses import dataclass

from fastapi import Request
from starlette.concurrency import run_in_threadpool

from racerlab.league import people
from racerlab.league.people import Actor
from racerlab.league.store import LeagueError

SESSION_COOKIE = "racerlab_league"
PRE_COOKIE = "racerlab_league_pre"
CSRF_HEADER = "X-CSRF-Token"
CSRF_FIELD = "csrf"
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
FORM_TYPE = "application/x-www-form-urlencoded"


@dataclass(frozen=True)
class Caller:
    """Who a request comes from: `actor` None for a stranger; `via` bearer | session | ""."""

    actor: Actor | None
    via: str = ""
    session: str = ""


class TokenCache:
    """Actors of recently seen tokens (by the token's hash), for `TTL_S` seconds."""

    TTL_S = 5.0
    MAX = 20_000

    def __init__(self):
        self._lock = threading.Lock()
        self._held: dict[str, tuple[Actor, float]] = {}
        self._generation = 0  # moves with every forget: a lookup that began before one is not kept

    def actor(self, league, token: str, kind: str, lookup: bool = True) -> Actor:
        """The token's actor; with `lookup` False, `NeedsLookup` when only the store can say (nothing cached)."""
        key, now = f"{kind}:{people.digest(token)}", time.monotonic()
        with self._lock:
            hit, generation = self._held.get(key), self._generation
        if hit is not None and now - hit[1] < self.TTL_S:
            return hit[0]
        if not lookup:
            raise NeedsLookup()
        actor = league.actor_for_token(token, kind)  # 401 for an unknown, revoked or expired one
        with self._lock:
            if generation == self._generation:
                if len(self._held) >= self.MAX:
                    self._held.clear()
                self._held[key] = (actor, now)
        return actor

    def forget(self, token: str | None = None) -> None:
        """Forget one token (logging out) or all of them (a revoked token, a changed password or account)."""
        with self._lock:
            self._generation += 1
            if token is None:
                self._held.clear()
            else:
                for kind in people.TOKEN_PREFIX:
                    self._held.pop(f"{kind}:{people.digest(token)}", None)


class NeedsLookup(Exception):
    """The token is not in the cache: asking the store means leaving the event loop."""


def _identify(request: Request, lookup: bool = True) -> Caller:
    league, cache = request.app.state.league, request.app.state.tokens
    header = request.headers.get("authorization", "")
    if header:
        scheme, _, token = header.partition(" ")
        if scheme.lower() != "bearer" or not token.strip():
            raise LeagueError("Authorization: send 'Bearer <token>' (racerlab league login stores one)", 401)
        return Caller(cache.actor(league, token.strip(), "api", lookup), "bearer")
    token = request.cookies.get(SESSION_COOKIE, "")
    if token:
        try:
            return Caller(cache.actor(league, token, "session", lookup), "session", token)
        except LeagueError:
            pass  # an expired or revoked session: a stranger, who is sent to the login page
    return Caller(None)


async def identify(request: Request) -> Caller:
    """Who asks: from the token cache on the event loop, the store (in a thread) only on a miss. A crowd's polls
    would otherwise each take a thread of the pool, and wait for one when logins hold them."""
    try:
        return _identify(request, lookup=False)
    except NeedsLookup:
        return await run_in_threadpool(_identify, request)


async def hashing(request: Request, call, *args):
    """`call(*args)` (a login, invite, sign-up or password change: an Argon2id hash inside) in a thread, at most
    `people.HASHES_AT_ONCE` at a time; the others wait on the event loop, not in the thread pool the other routes
    need."""
    return await in_turn(request, "hash_limiter", people.HASHES_AT_ONCE, functools.partial(call, *args))


async def in_turn(request: Request, name: str, at_once: int, call):
    """`call()` in a thread of its own pool of `at_once` (the app's limiter `name`); the calls past it wait on the
    event loop, holding no thread of the pool that the other routes share."""
    import anyio

    state = request.app.state
    if getattr(state, name, None) is None:
        setattr(state, name, anyio.CapacityLimiter(at_once))
    return await anyio.to_thread.run_sync(call, limiter=getattr(state, name))


async def recheck(request: Request, actor: Actor) -> None:
    """A long request (a live board's stream) asks again who it comes from: 401 once its token was revoked or
    logged out, or the account disabled or changed (through this server: at once; elsewhere: within the TTL)."""
    if (await identify(request)).actor != actor:
        raise LeagueError("the session ended or the account changed; log in again", 401)


async def caller(request: Request) -> Caller:
    """Who asks (looked up once per request; the token lookup runs off the event loop)."""
    found = getattr(request.state, "caller", None)
    if found is None:
        found = await identify(request)
        request.state.caller = found
    return found


async def signed_in(request: Request) -> Actor:
    """The acting user of a request that needs one: 401 for a stranger, 403 for a cookie request without its
    CSRF token."""
    who = await caller(request)
    if who.actor is None:
        raise LeagueError("not logged in; log in first", 401)
    if request.method not in SAFE_METHODS and who.via == "session":
        await check_csrf(request, people.csrf_token(request.app.state.secret, who.session))
    return who.actor


def needs(action: str):
    """A dependency: `signed_in` and the role that may `action` (`people.PERMISSIONS`)."""

    async def dependency(request: Request) -> Actor:
        actor = await signed_in(request)
        people.require_role(actor, action)
        return actor

    dependency.__name__ = f"needs_{action.replace('.', '_')}"
    dependency.signed_in = True  # seen by app._check_routes
    return dependency


signed_in.signed_in = True


async def check_csrf(request: Request, expected: str) -> None:
    presented = request.headers.get(CSRF_HEADER) or request.query_params.get(CSRF_FIELD)
    if not presented and request.headers.get("content-type", "").startswith(FORM_TYPE):
        presented = (await request.form()).get(CSRF_FIELD)
    if not presented or not hmac.compare_digest(str(presented), expected):
        raise LeagueError("missing or wrong CSRF token; reload the page and try again", 403)


def session_csrf(request: Request) -> str:
    """The CSRF token for the pages of a signed-in browser ('' for bearer requests)."""
    who = getattr(request.state, "caller", None)
    if who is None or not who.session:
        return ""
    return people.csrf_token(request.app.state.secret, who.session)


# ---- forms before a session: login, invite, sign-up ---------------------------------------------------------
def _pre_digest(secret: str, value: str) -> str:
    return hmac.new(secret.encode(), b"pre:" + value.encode(), hashlib.sha256).hexdigest()


def pre_token(request: Request) -> tuple[str, str | None]:
    """(the form's token, a new cookie value to set or None): the browser's pre-session value, made if missing."""
    value = request.cookies.get(PRE_COOKIE, "")
    fresh = None
    if len(value) < 20:
        value = fresh = secrets.token_urlsafe(24)
    return _pre_digest(request.app.state.secret, value), fresh


async def check_pre_form(request: Request) -> None:
    """A login, invite or sign-up form from this site's own page (its pre-session token matches the cookie)."""
    value = request.cookies.get(PRE_COOKIE, "")
    form = await request.form()
    presented = str(form.get(CSRF_FIELD) or "")
    if not value or not presented or not hmac.compare_digest(presented, _pre_digest(request.app.state.secret, value)):
        raise LeagueError("this form has expired (or came from another site); reload the page and try again", 403)


def set_session(response, token: str, secure: bool) -> None:
    response.set_cookie(SESSION_COOKIE, token, max_age=int(people.SESSION_TTL.total_seconds()), httponly=True,
                        samesite="lax", secure=secure, path="/")


def set_pre(response, value: str | None, secure: bool) -> None:
    if value:
        response.set_cookie(PRE_COOKIE, value, max_age=24 * 3600, httponly=True, samesite="lax", secure=secure,
                            path="/")


def clear_session(response, secure: bool) -> None:
    response.delete_cookie(SESSION_COOKIE, path="/", httponly=True, samesite="lax", secure=secure)


def client_address(request: Request) -> str:
    """The address failed logins are counted against (the peer: a proxy in front should pass one per client)."""
    return request.client.host if request.client else ""
