"""Pages that change the league: creating and changing races, invites and accounts, the audit log (staff), and
each person's own account (API tokens, password).

An invite code and a new API token are shown once, on the page that answers the form that made them (they are
stored only as hashes).
"""

from __future__ import annotations

from typing import Annotated
from urllib.parse import quote

from fastapi import Depends, FastAPI, Request
from starlette.concurrency import run_in_threadpool

from racerlab.errors import RacerlabError
from racerlab.league.people import Actor
from racerlab.league.store import LeagueError
from racerlab.league.web import auth, forms
from racerlab.league.web.api import RACE_CHANGES, base_url, invite_answer
from racerlab.league.web.auth import needs, signed_in
from racerlab.league.web.pages import redirect, render

User = Annotated[Actor, Depends(signed_in)]
RACE_TYPES = ("time_trial", "object_avoidance", "head_to_bot")
TIMINGS = (("best_lap", "best lap"), ("average_lap", "best average of consecutive laps"),
           ("total_time", "total time of all laps"))
AUDIT_PAGE = 100


def register(app: FastAPI) -> None:
    _races(app)
    _people(app)
    _account(app)


# ---- races ----------------------------------------------------------------------------------------------------
def _race_form(request: Request, status: int = 200, error: str = "", fields: dict | None = None):
    from racerlab.spec import SIMULATORS

    return render(request, "race_new.html", status, tracks=forms.known_tracks(), race_types=RACE_TYPES,
                  timings=TIMINGS, cars=SIMULATORS, error=error, f=fields or {})


async def _create_race(request: Request, actor: Actor, fields: dict, track_file):
    league = request.app.state.league
    opts = forms.race_options(fields, fields.get("tz"))
    if track_file is not None and getattr(track_file, "filename", ""):
        async with forms.saved(track_file, request.app.state.uploads, 1 << 20, forms.TRACK_SUFFIXES,
                               "a track file") as path:
            opts["track"] = str(path)
            return await run_in_threadpool(league.create_race, actor, fields.get("name", ""), opts)
    opts["track"] = forms.check_track(fields.get("track"))
    if opts.get("eval_track") or fields.get("eval_track"):
        opts["eval_track"] = forms.check_track(fields.get("eval_track"), "evaluation track")
    return await run_in_threadpool(league.create_race, actor, fields.get("name", ""), opts)


def _races(app: FastAPI) -> None:
    @app.get("/admin/races/new")
    def new_race(request: Request, actor: Annotated[Actor, Depends(needs("race.create"))]):
        return _race_form(request)

    @app.post("/admin/races")
    async def create_race(request: Request, actor: Annotated[Actor, Depends(needs("race.create"))]):
        form = await request.form(max_files=1, max_fields=40)
        fields = {k: v for k, v in form.items() if isinstance(v, str)}
        fields.pop("csrf", None)
        try:
            view = await _create_race(request, actor, {**fields, "_checkboxes": "1"}, form.get("track_file"))
        except RacerlabError as exc:  # the service's refusal or a field's (console.security.number)
            return _race_form(request, getattr(exc, "status", 400), str(exc), fields)
        return redirect(request, f"/races/{quote(view.name, safe='')}", f"Race {view.name} created: {view.summary}")

    @app.post("/races/{name}/update")
    async def update_race(request: Request, name: str, actor: Annotated[Actor, Depends(needs("race.update"))]):
        form = await request.form()
        back = f"/races/{quote(name, safe='')}"
        changes = {}
        for key in RACE_CHANGES:
            value = str(form.get(key) or "").strip()
            if value:
                changes[key] = forms.with_zone(value, form.get("tz")) if key in ("opens", "closes") else value
        try:
            if "max_submissions" in changes:
                changes["max_submissions"] = forms.number(changes, "max_submissions", integer=True, low=1,
                                                          high=10_000)
            if not changes:
                raise LeagueError("nothing to change: give a close time or a submission limit")
            await run_in_threadpool(lambda: request.app.state.league.update_race(actor, name, **changes))
        except RacerlabError as exc:
            return redirect(request, back, str(exc), "error")
        return redirect(request, back, "Race changed: " + ", ".join(sorted(changes)))


# ---- people ---------------------------------------------------------------------------------------------------
def _people_page(request: Request, actor: Actor, status: int = 200, invite: dict | None = None, error: str = ""):
    league = request.app.state.league
    return render(request, "people.html", status, users=league.users(actor), invite=invite, error=error,
                  open_signup=league.open_signup())


def _people(app: FastAPI) -> None:
    @app.get("/admin/people")
    def people_page(request: Request, actor: Annotated[Actor, Depends(needs("user.list"))]):
        return _people_page(request, actor)

    @app.post("/admin/invites")
    async def invite(request: Request, actor: Annotated[Actor, Depends(needs("invite.racer"))]):
        form = await request.form()
        alias, role = str(form.get("alias") or "").strip(), str(form.get("role") or "racer")
        try:
            made = await run_in_threadpool(request.app.state.league.invite, actor, alias, role)
        except LeagueError as exc:
            return await run_in_threadpool(_people_page, request, actor, exc.status, None, str(exc))
        return await run_in_threadpool(_people_page, request, actor, 200, invite_answer(request, made))

    @app.post("/admin/users/{alias}")
    async def change_user(request: Request, alias: str, actor: Annotated[Actor, Depends(needs("user.change"))]):
        form = await request.form()
        active = {"enable": True, "disable": False}.get(str(form.get("active") or ""))
        role = str(form.get("role") or "") or None
        try:
            await run_in_threadpool(lambda: request.app.state.league.set_user(actor, alias, active=active, role=role))
            request.app.state.tokens.forget()
        except LeagueError as exc:
            return redirect(request, "/admin/people", str(exc), "error")
        return redirect(request, "/admin/people", f"{alias} changed")

    @app.post("/admin/settings")
    async def settings(request: Request, actor: Annotated[Actor, Depends(needs("settings.change"))]):
        on = str((await request.form()).get("open_signup") or "") == "on"
        await run_in_threadpool(request.app.state.league.set_open_signup, actor, on)
        return redirect(request, "/admin/people", f"Open sign-up is {'on' if on else 'off'}")

    @app.get("/admin/audit")
    def audit(request: Request, actor: Annotated[Actor, Depends(needs("audit.view"))], since_id: int = 0):
        entries = request.app.state.league.audit(actor, since_id, AUDIT_PAGE)
        more = entries[-1].id if len(entries) == AUDIT_PAGE else None
        return render(request, "audit.html", entries=entries, since_id=since_id, more=more)


# ---- one's own account ----------------------------------------------------------------------------------------
def _account_page(request: Request, actor: Actor, status: int = 200, token: dict | None = None, error: str = ""):
    return render(request, "account.html", status, tokens=request.app.state.league.tokens(actor), token=token,
                  error=error, base=base_url(request))


def _account(app: FastAPI) -> None:
    @app.get("/account")
    def account(request: Request, actor: User):
        return _account_page(request, actor)

    @app.post("/account/tokens")
    async def new_token(request: Request, actor: User):
        label = str((await request.form()).get("label") or "").strip()[:64] or "API token"
        made = await run_in_threadpool(request.app.state.league.issue_token, actor, "api", label)
        return await run_in_threadpool(_account_page, request, actor, 200, made.to_json())

    @app.post("/account/tokens/{token_id}/revoke")
    def revoke(request: Request, token_id: int, actor: User):
        request.app.state.league.revoke_token(actor, token_id)
        request.app.state.tokens.forget()
        return redirect(request, "/account", f"Token {token_id} revoked")

    @app.post("/account/password")
    async def password(request: Request, actor: User):
        form = await request.form()
        old, new = str(form.get("old") or ""), str(form.get("new") or "")
        try:
            if new != str(form.get("new2") or ""):
                raise LeagueError("the two new passwords differ; type the same password twice")
            await auth.hashing(request, request.app.state.league.change_password, actor, old, new)
            request.app.state.tokens.forget()
        except LeagueError as exc:
            return await run_in_threadpool(_account_page, request, actor, exc.status, None, str(exc))
        return redirect(request, "/login", "Password changed: log in again with the new one")
