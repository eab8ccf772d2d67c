"""The league's pages: server-rendered HTML (Jinja2 with autoescaping on: aliases, model names, descriptions and
reasons are strangers' text and are only ever shown as text), plain forms, a small script for the live parts.

People: /login, /invite (accept an invite), /signup (when the league has open sign-up), /logout, /account (API
tokens, password). Racing: / (the races), /races/NAME (rules and their hash, the live leaderboard, the caller's
submissions there, the upload form), /submissions (the caller's; staff: everyone's), /submissions/ID (status, the
per-lap table, downloads). Staff: /admin/races/new, /admin/people (invites, accounts, sign-up), /admin/audit.

A form posts, the handler acts through the service and redirects (303) to the page that shows the outcome, with a
one-line message in a signed cookie; a refused form is shown again with the reason. Forms carry the session's
CSRF token (`auth`); multipart forms carry it in their action's query string, so it is checked before the upload
is read.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
from datetime import datetime
from importlib import resources
from typing import Annotated
from urllib.parse import quote

from fastapi import Depends, FastAPI, Request
from fastapi.responses import HTMLResponse, RedirectResponse, Response
from jinja2 import Environment, PackageLoader, StrictUndefined, select_autoescape
from starlette.concurrency import run_in_threadpool

from racerlab import __version__
from racerlab.league.people import ROLES, Actor, may
from racerlab.league.store import LeagueError
from racerlab.league.views import FILES, FINAL
from racerlab.league.web import auth
from racerlab.league.web.auth import needs, signed_in

User = Annotated[Actor, Depends(signed_in)]
FLASH_COOKIE = "racerlab_league_flash"
FILE_LABELS = {"logs": "all logs (.tar.gz)", "simtrace": "simtrace (CSV)", "metrics": "EvalMetrics.json",
               "summary": "summary.json", "result": "league result (JSON)", "layouts": "boxes and bots (JSON)",
               "video": "video (MP4)"}


def _environment() -> Environment:
    env = Environment(loader=PackageLoader("racerlab.league.web", "templates"),
                      autoescape=select_autoescape(default=True, default_for_string=True), undefined=StrictUndefined,
                      trim_blocks=True, lstrip_blocks=True)
    env.filters.update(when=when, laptime=laptime, gap=gap, eta=eta, url=lambda s: quote(str(s), safe=""),
                       compact=lambda d: json.dumps(d, sort_keys=True, separators=(", ", ": "))[:400])
    env.globals.update(may=may, version=__version__, FILE_LABELS=FILE_LABELS, ROLES=ROLES, FINAL=FINAL)
    return env


# ---- what the templates show ---------------------------------------------------------------------------------
def when(t) -> str:
    """An ISO time (the page's script shows it in the reader's zone; without script it reads as UTC)."""
    if t is None or t == "":
        return "—"
    if isinstance(t, datetime):
        from racerlab.league.races import iso

        t = iso(t)
    return str(t)


def laptime(seconds) -> str:
    """12.345 -> 0:12.345 (a lap or race time as the League showed it)."""
    if seconds is None:
        return "—"
    ms = int(round(float(seconds) * 1000))
    return f"{ms // 60000}:{ms % 60000 / 1000:06.3f}"


def gap(seconds) -> str:
    if seconds is None:
        return "—"
    return "leader" if seconds == 0 else f"+{seconds:.3f}"


def eta(seconds) -> str:
    if seconds is None:
        return "waiting for a worker"
    s = int(round(seconds))
    return f"about {s} s" if s < 90 else f"about {round(s / 60)} min"


_ENV = None


def render(request: Request, template: str, status: int = 200, **ctx) -> HTMLResponse:
    global _ENV
    if _ENV is None:
        _ENV = _environment()
    who = getattr(request.state, "caller", None)
    message = read_flash(request)
    html = _ENV.get_template(template).render(me=who.actor if who else None, csrf=auth.session_csrf(request),
                                              flash=message, path=request.url.path, **ctx)
    response = HTMLResponse(html, status)
    if message:
        response.delete_cookie(FLASH_COOKIE, path="/")
    return response


def error_page(request: Request, status: int, message: str) -> HTMLResponse:
    return render(request, "error.html", status, code=status, message=message)


def login_url(request: Request) -> str:
    target = request.url.path + (f"?{request.url.query}" if request.url.query else "")
    return "/login" if target in ("/", "/login") else f"/login?next={quote(target, safe='')}"


def safe_next(target: str | None) -> str:
    """Where to go after logging in: a path on this site only (never //host or a scheme)."""
    t = str(target or "/")
    return t if t.startswith("/") and not t.startswith("//") and "\\" not in t else "/"


# ---- one-line messages across a redirect ------------------------------------------------------------------------
def _sign(secret: str, data: str) -> str:
    return hmac.new(secret.encode(), b"flash:" + data.encode(), hashlib.sha256).hexdigest()[:32]


def redirect(request: Request, to: str, message: str = "", kind: str = "ok") -> RedirectResponse:
    response = RedirectResponse(to, 303)
    if message:
        data = base64.urlsafe_b64encode(json.dumps([kind, message[:600]]).encode()).decode()
        response.set_cookie(FLASH_COOKIE, f"{data}.{_sign(request.app.state.secret, data)}", max_age=60,
                            httponly=True, samesite="lax", secure=request.app.state.secure, path="/")
    return response


def read_flash(request: Request) -> tuple[str, str] | None:
    raw = request.cookies.get(FLASH_COOKIE, "")
    data, _, sig = raw.partition(".")
    if not data or not hmac.compare_digest(sig, _sign(request.app.state.secret, data)):
        return None
    try:
        kind, text = json.loads(base64.urlsafe_b64decode(data.encode()))
    except (ValueError, TypeError):
        return None
    return str(kind), str(text)


def register(app: FastAPI) -> None:
    from racerlab.league.web import manage, seasons

    _people(app)
    _joining(app)
    _leaving(app)
    _racing(app)
    manage.register(app)
    seasons.register(app)


# ---- people ---------------------------------------------------------------------------------------------------
def _pre_form(request: Request, template: str, status: int = 200, **ctx) -> HTMLResponse:
    token, fresh = auth.pre_token(request)
    response = render(request, template, status, pre=token, **ctx)
    auth.set_pre(response, fresh, request.app.state.secure)
    return response


def _signed_in_as(request: Request, actor: Actor, to: str, message: str) -> RedirectResponse:
    session = request.app.state.league.issue_token(actor, "session", label="browser")
    response = redirect(request, to, message)
    auth.set_session(response, session.token, request.app.state.secure)
    return response


def _people(app: FastAPI) -> None:
    @app.get("/login")
    async def login_page(request: Request, next: str = "/"):
        if (await auth.caller(request)).actor is not None:
            return RedirectResponse(safe_next(next), 303)
        signup = await run_in_threadpool(request.app.state.league.open_signup)
        return _pre_form(request, "login.html", next=safe_next(next), error="", alias="", signup=signup)

    @app.post("/login")
    async def login(request: Request):
        await auth.check_pre_form(request)
        form, league = await request.form(), request.app.state.league
        alias, target = str(form.get("alias") or ""), safe_next(form.get("next"))
        try:
            actor = await auth.hashing(request, league.authenticate, alias, str(form.get("password") or ""),
                                            auth.client_address(request))
        except LeagueError as exc:
            signup = await run_in_threadpool(league.open_signup)
            return _pre_form(request, "login.html", exc.status, next=target, error=str(exc), alias=alias[:40],
                             signup=signup)
        return await run_in_threadpool(_signed_in_as, request, actor, target, "")



def _joining(app: FastAPI) -> None:
    @app.get("/invite")
    def invite_page(request: Request, code: str = ""):
        return _pre_form(request, "invite.html", code=code[:200], error="")

    @app.post("/invite")
    async def accept(request: Request):
        await auth.check_pre_form(request)
        form, league = await request.form(), request.app.state.league
        code, password = str(form.get("code") or "").strip(), str(form.get("password") or "")
        try:
            if password != str(form.get("password2") or ""):
                raise LeagueError("the two passwords differ; type the same password twice")
            actor = await auth.hashing(request, league.accept_invite, code, password)
        except LeagueError as exc:
            return _pre_form(request, "invite.html", exc.status, code=code[:200], error=str(exc))
        return await run_in_threadpool(_signed_in_as, request, actor, "/",
                                       f"Welcome, {actor.alias}: you are a {actor.role} of this league")

    @app.get("/signup")
    async def signup_page(request: Request):
        signup = await run_in_threadpool(request.app.state.league.open_signup)
        return _pre_form(request, "signup.html", 200 if signup else 403, signup=signup, alias="", error="")

    @app.post("/signup")
    async def signup(request: Request):
        await auth.check_pre_form(request)
        form, league = await request.form(), request.app.state.league
        alias, password = str(form.get("alias") or ""), str(form.get("password") or "")
        try:
            if password != str(form.get("password2") or ""):
                raise LeagueError("the two passwords differ; type the same password twice")
            actor = await auth.hashing(request, league.sign_up, alias, password)
        except LeagueError as exc:
            return _pre_form(request, "signup.html", exc.status, signup=True, alias=alias[:40], error=str(exc))
        return await run_in_threadpool(_signed_in_as, request, actor, "/", f"Welcome, {actor.alias}")



def _leaving(app: FastAPI) -> None:
    @app.post("/logout")
    def logout(request: Request, actor: User):
        request.app.state.league.end_session(request.state.caller.session)
        request.app.state.tokens.forget(request.state.caller.session)
        response = redirect(request, "/login", "You are logged out")
        auth.clear_session(response, request.app.state.secure)
        return response

    icon = (resources.files("racerlab.console") / "static" / "favicon.svg").read_bytes()  # one icon for both

    @app.get("/favicon.ico")
    def favicon():
        return Response(icon, media_type="image/svg+xml", headers={"Cache-Control": "max-age=86400"})


# ---- racing ---------------------------------------------------------------------------------------------------
def _racing(app: FastAPI) -> None:
    @app.get("/")
    def races(request: Request, actor: User):
        league = request.app.state.league
        views = league.races(actor)
        boards = {r.name: league.standings(actor, r.name) for r in views}  # a club has a handful of races
        return render(request, "races.html", races=views, boards=boards)

    @app.get("/races/{name}")
    def race(request: Request, name: str, actor: User):
        league = request.app.state.league
        view = league.race(actor, name)
        return render(request, "race.html", race=view, standings=league.standings(actor, name),
                      mine=league.submissions(actor, name), finals=league.finals(actor, name))

    @app.get("/races/{name}/track.svg")
    def track_svg(request: Request, name: str, actor: User):
        from racerlab.console.pictures import track_svg as draw
        from racerlab.league.rules import load_pinned

        league = request.app.state.league
        rules = league.race(actor, name).rules  # the public rules: the advertised track, never a hidden one
        track = load_pinned(league.store.folder / "tracks", rules["track"], rules["track_sha256"])
        svg = draw(track.reverse() if rules.get("reverse") else track, 360)
        return Response(svg, media_type="image/svg+xml", headers={"Cache-Control": "private, max-age=3600"})

    @app.post("/races/{name}/submit")
    async def submit(request: Request, name: str, actor: Annotated[Actor, Depends(needs("submission.create"))]):
        from racerlab.league.web.api import submit_upload

        back = f"/races/{quote(name, safe='')}"
        try:
            view = await submit_upload(request, actor, name)
        except LeagueError as exc:
            return redirect(request, back, str(exc), "error")
        text = view.note or f"Submission #{view.number} is {view.status_text}"
        return redirect(request, f"/submissions/{view.id}", text)

    @app.get("/submissions")
    def submissions(request: Request, actor: User, race: str = "", everyone: bool = False):
        league = request.app.state.league
        everyone = everyone and may(actor.role, "submission.view_any")
        subs = league.submissions(actor, race or None, everyone=everyone)
        return render(request, "submissions.html", submissions=subs, everyone=everyone, race_filter=race,
                      races=[r.name for r in league.races(actor)])

    @app.get("/submissions/{sid}")
    def submission(request: Request, sid: int, actor: User):
        league = request.app.state.league
        sub = league.submission(actor, sid)
        return render(request, "submission.html", sub=sub, race=league.race(actor, sub.race),
                      files=[k for k in FILE_LABELS if k in sub.files and k in FILES])

    @app.post("/submissions/{sid}/requeue")
    def requeue(request: Request, sid: int, actor: Annotated[Actor, Depends(needs("submission.requeue"))]):
        try:
            view = request.app.state.league.requeue(actor, sid)
        except LeagueError as exc:
            return redirect(request, f"/submissions/{sid}", str(exc), "error")
        return redirect(request, f"/submissions/{sid}", f"Submission #{view.number} is queued again")
