"""`create_app(folder)`: the league's web application (FastAPI), and the middleware every request passes.

`Guard`, a plain ASGI middleware, runs before any route:

- bound to the loopback, the Host header must name the loopback (a page whose DNS name rebinds to 127.0.0.1
  cannot talk to the server);
- a state-changing request whose Origin is another site is refused;
- a request body has a limit that is enforced before it is read: the upload routes (`UPLOAD_PATHS`) take up to
  `upload_limit` bytes and must say their length (411 otherwise), every other route `FORM_LIMIT`; a declared
  length over the limit is answered 413 at once, and the body is counted while it streams (a chunked body that
  passes the limit is cut off with 413);
- every answer gets the security headers (a strict Content-Security-Policy: scripts and styles from this server
  only, no frames; nosniff; no referrer; no-store for anything but the static files; HSTS under TLS);
- after a state-changing request the shared live boards (`live.Boards`) look at the store again at their next read
  (a racer's upload shows in their own poll at once).

Then `_check_routes` refuses to build an app with a route that neither starts with `auth.signed_in` (or
`auth.needs`) nor is one of the few public ones (`PUBLIC`): a route added without a check does not start.
"""

from __future__ import annotations

import re
from importlib import resources
from pathlib import Path
from urllib.parse import urlsplit

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse, RedirectResponse
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Mount

from racerlab.console.security import is_loopback
from racerlab.errors import RacerlabError
from racerlab.league import League
from racerlab.league.store import LeagueError
from racerlab.league.web.auth import TokenCache
from racerlab.league.web.live import Boards

STATIC = resources.files("racerlab.league.web") / "static"
UPLOAD_LIMIT = 256 * 1024 * 1024  # an AWS model archive is 20-100 MB; a racerlab camera model a few MB
FORM_LIMIT = 1024 * 1024  # every request but an upload: forms and JSON are small
UPLOAD_PATHS = re.compile(r"^(/api/races/[^/]+/submissions|/races/[^/]+/submit)$")
SAFE_METHODS = ("GET", "HEAD", "OPTIONS")
PUBLIC = {  # (method, path) of the routes a stranger may use; every other route needs a signed-in user
    ("GET", "/login"), ("POST", "/login"), ("GET", "/invite"), ("POST", "/invite"), ("GET", "/signup"),
    ("POST", "/signup"), ("GET", "/favicon.ico"), ("GET", "/api/health"), ("POST", "/api/login"),
    ("POST", "/api/invites/accept"), ("POST", "/api/signup"),
}
CSP = ("default-src 'self'; script-src 'self'; style-src 'self'; img-src 'self' data:; media-src 'self'; "
       "connect-src 'self'; object-src 'none'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'")


def create_app(folder, url: str | None = None, *, host: str = "127.0.0.1", tls: bool = False,
               public_url: str | None = None, upload_limit: int = UPLOAD_LIMIT,
               league: League | None = None) -> FastAPI:
    """The web app of the league in `folder` (or of `league`, already open). `host` is the address it is bound to
    (the loopback: the Host header is checked), `tls` whether it is served over HTTPS (Secure cookies, HSTS);
    `public_url` the address people use when a TLS proxy in front forwards to the loopback (its host is
    accepted too, its https makes cookies Secure, invite links name it)."""
    from racerlab.league.web import api, pages

    app = FastAPI(title="racerlab league", docs_url=None, redoc_url=None, openapi_url=None)
    lg = league or League.open(folder, url)
    public = urlsplit(public_url) if public_url else None
    app.state.league = lg
    app.state.secret = lg.secret()
    app.state.secure = bool(tls) or (public is not None and public.scheme == "https")
    app.state.public_url = public_url.rstrip("/") if public_url else None
    app.state.upload_limit = int(upload_limit)
    app.state.boards = Boards(lg)
    app.state.tokens = TokenCache()
    app.state.uploads = Path(lg.store.folder) / "uploads"
    app.add_middleware(Guard, loopback=is_loopback(host), upload_limit=int(upload_limit), tls=app.state.secure,
                       also=public.netloc if public else None)
    _errors(app)
    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
    api.register(app)
    pages.register(app)
    _check_routes(app)
    return app


# ---- the middleware -----------------------------------------------------------------------------------------
class BodyTooLarge(Exception):
    pass


class Guard:
    """Host check, Origin check, body limits and security headers (see the module's docstring)."""

    def __init__(self, app, *, loopback: bool, upload_limit: int, tls: bool, also: str | None = None):
        self.app, self.loopback, self.upload_limit, self.tls, self.also = app, loopback, upload_limit, tls, also

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        headers = Headers(scope=scope)
        limit = self.upload_limit if UPLOAD_PATHS.match(scope["path"]) else FORM_LIMIT
        seen, started = 0, False

        async def counted():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > limit:
                    raise BodyTooLarge()
            return message

        async def guarded_send(message):
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
                message["headers"] = list(message.get("headers", [])) + self._headers(scope, message)
            await send(message)

        refusal = self._refusal(scope, headers)
        if refusal is not None:
            return await _plain(refusal[0], refusal[1], scope)(scope, receive, guarded_send)
        try:
            await self.app(scope, counted, guarded_send)
        except BodyTooLarge:
            if not started:
                await _plain(413, f"the request is larger than the limit of {limit} bytes", scope)(
                    scope, receive, guarded_send)
        finally:
            if scope["method"] not in SAFE_METHODS and "app" in scope:
                scope["app"].state.boards.touch()  # a change made here: the live boards look at once

    def _refusal(self, scope, headers: Headers) -> tuple[int, str] | None:
        host = headers.get("host", "")
        if self.loopback and not _loopback_host(host) and host != self.also:
            return 421, f"host {host!r} refused: this server answers on its loopback address"
        if scope["method"] not in SAFE_METHODS:
            origin = headers.get("origin")
            if origin and origin != "null" and origin.split("://", 1)[-1] != host:
                return 403, "a request from another site is refused"
        return _length_refusal(scope, headers, self.upload_limit)

    def _headers(self, scope, message) -> list[tuple[bytes, bytes]]:
        have = {k.lower() for k, _ in message.get("headers", [])}
        out = [(b"content-security-policy", CSP.encode()), (b"x-content-type-options", b"nosniff"),
               (b"x-frame-options", b"DENY"), (b"referrer-policy", b"no-referrer")]
        if b"cache-control" not in have and not scope["path"].startswith("/static/"):
            out.append((b"cache-control", b"no-store"))
        if self.tls:
            out.append((b"strict-transport-security", b"max-age=31536000"))
        return [(k, v) for k, v in out if k not in have]


def _length_refusal(scope, headers: Headers, upload_limit: int) -> tuple[int, str] | None:
    """A declared body length over the limit, or an upload that does not declare one (nothing is read yet)."""
    upload = UPLOAD_PATHS.match(scope["path"]) and scope["method"] == "POST"
    limit = upload_limit if upload else FORM_LIMIT
    declared = headers.get("content-length")
    if declared is None:
        return (411, "an upload must say its length (Content-Length)") if upload else None
    try:
        length = int(declared)
    except ValueError:
        return 400, "Content-Length is not a number"
    if length > limit:
        what = "upload" if upload else "request"
        return 413, f"the {what} is {length} bytes, more than the limit of {limit} bytes"
    return None


def _loopback_host(host_header: str) -> bool:
    name = host_header if host_header.endswith("]") else host_header.rsplit(":", 1)[0]
    return is_loopback(name.strip("[]"))


def _plain(status: int, message: str, scope):
    """A refusal as JSON for the API, as a line of text for a browser."""
    from fastapi.responses import PlainTextResponse

    if scope["path"].startswith("/api/"):
        return JSONResponse({"error": message}, status)
    return PlainTextResponse(message + "\n", status)


# ---- errors -------------------------------------------------------------------------------------------------
def wants_json(request: Request) -> bool:
    return request.url.path.startswith("/api/") or request.headers.get("authorization", "") != ""


def _errors(app: FastAPI) -> None:
    from racerlab.league.web import pages

    async def answer(request: Request, status: int, message: str):
        if wants_json(request):
            return JSONResponse({"error": message}, status)
        if status == 401:
            return RedirectResponse(pages.login_url(request), 303)
        return pages.error_page(request, status, message)

    @app.exception_handler(LeagueError)
    async def league_error(request: Request, exc: LeagueError):
        return await answer(request, exc.status, str(exc))

    @app.exception_handler(RacerlabError)
    async def racerlab_error(request: Request, exc: RacerlabError):
        return await answer(request, getattr(exc, "status", 400), str(exc))  # ConsoleError has one

    @app.exception_handler(StarletteHTTPException)
    async def http_error(request: Request, exc: StarletteHTTPException):
        text = "no such page" if exc.status_code == 404 else str(exc.detail)
        return await answer(request, exc.status_code, text)

    @app.exception_handler(RequestValidationError)
    async def invalid(request: Request, exc: RequestValidationError):
        first = exc.errors()[0] if exc.errors() else {}
        where = ".".join(str(p) for p in first.get("loc", ())[1:]) or "request"
        if first.get("loc", ("",))[0] == "path":
            return await answer(request, 404, "no such page")
        return await answer(request, 400, f"{where}: {first.get('msg', 'invalid')}")


# ---- every route checks who asks ----------------------------------------------------------------------------
def _signs_in(dependant) -> bool:
    return any(getattr(d.call, "signed_in", False) or _signs_in(d) for d in dependant.dependencies)


def _check_routes(app: FastAPI) -> None:
    """Refuse an app with a route that neither needs a signed-in user nor is public."""
    for route in app.routes:
        if isinstance(route, Mount):
            continue
        if not isinstance(route, APIRoute):
            raise RuntimeError(f"route {route.path}: not an API route; add it with a signed_in dependency")
        for method in route.methods:
            if (method, route.path) not in PUBLIC and not _signs_in(route.dependant):
                raise RuntimeError(f"route {method} {route.path} does not check who asks: give it "
                                   "Depends(auth.signed_in) or auth.needs(...), or add it to app.PUBLIC")


def routes(app: FastAPI) -> list[tuple[str, str]]:
    """Every (method, path) the app answers (the role walk in tests/league/test_web_roles.py visits them all)."""
    return sorted((m, r.path) for r in app.routes if isinstance(r, APIRoute) for m in r.methods)
