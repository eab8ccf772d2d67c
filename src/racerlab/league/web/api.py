"""The HTTP API under /api: JSON in and out, for `racerlab league login | submit | status | standings` and scripts.

Every route but `health`, `login`, `invites/accept` and `signup` needs a signed-in caller (an API token as
`Authorization: Bearer`, or a browser session with its CSRF token) and passes that caller to the service layer,
which checks the role before it reads. Errors are `{"error": "one line"}` with the service's status (400 bad
input, 401 not logged in, 403 not allowed, 404 no such thing or not yours, 409 a limit or state, 413 too large,
429 throttled). Views are the service's dataclasses as JSON (`to_json`).
"""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, FastAPI, Request, Response
from fastapi.responses import FileResponse, JSONResponse, PlainTextResponse, StreamingResponse
from starlette.concurrency import run_in_threadpool

from racerlab import __version__
from racerlab.console.security import flag, number
from racerlab.league.people import Actor
from racerlab.league.store import LeagueError
from racerlab.league.web import auth, forms, live
from racerlab.league.web.auth import needs, signed_in

User = Annotated[Actor, Depends(signed_in)]
FILE_TYPES = {"simtrace": ("text/csv", "csv"), "metrics": ("application/json", "json"),
              "summary": ("application/json", "json"), "video": ("video/mp4", "mp4"),
              "result": ("application/json", "json"), "layouts": ("application/json", "json"),
              "logs": ("application/gzip", "tar.gz")}
RACE_CHANGES = ("closes", "max_submissions", "opens", "description", "public_videos")


async def json_body(request: Request) -> dict:
    if not request.headers.get("content-type", "").startswith("application/json"):
        raise LeagueError("send the request body as JSON (Content-Type: application/json)", 415)
    try:
        body = await request.json()
    except ValueError:
        raise LeagueError("the request body is not valid JSON") from None
    if not isinstance(body, dict):
        raise LeagueError("the request body must be a JSON object")
    return body


def text(body: dict, key: str, required: bool = True) -> str:
    value = body.get(key)
    if value is None and not required:
        return ""
    if not isinstance(value, str) or (required and not value):
        raise LeagueError(f"{key}: give it as a string")
    return value


def issued(league, actor: Actor, label: str) -> dict:
    """A new API token for `actor`, with who it is (the answer of login, invite and sign-up)."""
    token = league.issue_token(actor, "api", label=label[:64] or "racerlab league login")
    return {**token.to_json(), "alias": actor.alias, "role": actor.role}


def register(app: FastAPI) -> None:
    _people(app)
    _races(app)
    _standings(app)
    _submissions(app)
    _staff(app)


# ---- people -------------------------------------------------------------------------------------------------
def _people(app: FastAPI) -> None:
    @app.get("/api/health")
    def health():
        return {"ok": True, "server": "racerlab league", "version": __version__}

    @app.post("/api/login")
    async def login(request: Request):
        body, league = await json_body(request), request.app.state.league
        actor = await auth.hashing(request, league.authenticate, text(body, "alias"), text(body, "password"),
                                        auth.client_address(request))
        return await run_in_threadpool(issued, league, actor, text(body, "label", False))

    @app.post("/api/invites/accept")
    async def accept(request: Request):
        body, league = await json_body(request), request.app.state.league
        actor = await auth.hashing(request, league.accept_invite, text(body, "code"), text(body, "password"))
        return JSONResponse(await run_in_threadpool(issued, league, actor, text(body, "label", False)), 201)

    @app.post("/api/signup")
    async def signup(request: Request):
        body, league = await json_body(request), request.app.state.league
        actor = await auth.hashing(request, league.sign_up, text(body, "alias"), text(body, "password"))
        return JSONResponse(await run_in_threadpool(issued, league, actor, text(body, "label", False)), 201)

    @app.get("/api/me")
    def me(request: Request, actor: User):
        return {**actor.to_json(), "open_signup": request.app.state.league.open_signup()}

    @app.post("/api/logout")
    def logout(request: Request, actor: User):
        who = request.state.caller
        token = who.session or request.headers.get("authorization", "").partition(" ")[2].strip()
        request.app.state.league.end_session(token)
        request.app.state.tokens.forget(token)
        return {"ok": True}

    @app.get("/api/tokens")
    def tokens(request: Request, actor: User):
        return {"tokens": [t.to_json() for t in request.app.state.league.tokens(actor)]}

    @app.post("/api/tokens")
    async def new_token(request: Request, actor: User):
        body = await json_body(request)
        return JSONResponse(await run_in_threadpool(issued, request.app.state.league, actor,
                                                    text(body, "label", False)), 201)

    @app.delete("/api/tokens/{token_id}")
    def revoke(request: Request, token_id: int, actor: User):
        request.app.state.league.revoke_token(actor, token_id)
        request.app.state.tokens.forget()
        return {"ok": True}


# ---- races --------------------------------------------------------------------------------------------------
def _races(app: FastAPI) -> None:
    @app.get("/api/races")
    def races(request: Request, actor: User):
        return {"races": [r.to_json() for r in request.app.state.league.races(actor)]}

    @app.post("/api/races")
    async def create(request: Request, actor: Annotated[Actor, Depends(needs("race.create"))]):
        body = await json_body(request)
        name, opts = text(body, "name"), forms.json_race_options(body)
        view = await run_in_threadpool(request.app.state.league.create_race, actor, name, opts)
        return JSONResponse(view.to_json(), 201)

    @app.get("/api/races/{name}")
    def race(request: Request, name: str, actor: User):
        return request.app.state.league.race(actor, name).to_json()

    @app.patch("/api/races/{name}")
    async def update(request: Request, name: str, actor: Annotated[Actor, Depends(needs("race.update"))]):
        body = await json_body(request)
        unknown = sorted(set(body) - set(RACE_CHANGES))
        if unknown:
            raise LeagueError(f"{unknown[0]!r}: a race changes only its {', '.join(RACE_CHANGES)}")
        changes = {k: body[k] for k in RACE_CHANGES if k in body}
        if "max_submissions" in changes:
            changes["max_submissions"] = number(changes, "max_submissions", integer=True, low=1, high=10_000)
        if "public_videos" in changes:
            changes["public_videos"] = flag(changes, "public_videos", True)
        view = await run_in_threadpool(request.app.state.league.update_race, actor, name, **changes)
        return view.to_json()



def _standings(app: FastAPI) -> None:
    @app.get("/api/races/{name}/standings")
    async def standings(request: Request, name: str, actor: User, format: str = "json"):
        league, boards = request.app.state.league, request.app.state.boards
        if format == "csv":
            return csv_response(await run_in_threadpool(league.standings_csv, actor, name), name)
        if format != "json":
            raise LeagueError(f"format {format!r}: json or csv")
        body = boards.standings_json_held(actor, name)  # read and encoded once per change, sent from memory
        if body is None:
            body = await run_in_threadpool(boards.standings_json, actor, name)
        return Response(body, media_type="application/json")

    @app.get("/api/races/{name}/standings.csv")
    def standings_csv(request: Request, name: str, actor: User):
        return csv_response(request.app.state.league.standings_csv(actor, name), name)

    @app.get("/api/races/{name}/standings.json")
    def standings_json(request: Request, name: str, actor: User):
        body = request.app.state.league.standings(actor, name).to_json()
        filename = forms.clean_filename(f"{name}-standings.json", (".json",), "a JSON file")
        return JSONResponse(body, headers={"Content-Disposition": f'attachment; filename="{filename}"'})

    @app.get("/api/races/{name}/events")
    def events(request: Request, name: str, actor: User):
        request.app.state.league.race(actor, name)  # 404 before the stream starts
        return StreamingResponse(live.board_events(request, actor, name), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store", "X-Accel-Buffering": "no"})


def csv_response(body: str, race: str) -> PlainTextResponse:
    filename = forms.clean_filename(f"{race}-standings.csv", (".csv",), "a CSV")
    return PlainTextResponse(body, media_type="text/csv; charset=utf-8",
                             headers={"Content-Disposition": f'attachment; filename="{filename}"'})


# ---- submissions --------------------------------------------------------------------------------------------
async def submit_upload(request: Request, actor: Actor, race: str):
    """The upload of a model to `race` (multipart: `model` file, `checkpoint`, `name`) as a SubmissionView."""
    league = request.app.state.league
    await run_in_threadpool(league.race, actor, race)  # an unknown race before the upload is stored
    form = await request.form(max_files=1, max_fields=8)
    checkpoint = str(form.get("checkpoint") or "best").strip() or "best"
    name = str(form.get("name") or "")[:64]
    async with forms.saved(form.get("model"), request.app.state.uploads, request.app.state.upload_limit,
                           forms.ARCHIVE_SUFFIXES, "a model archive") as path:
        return await converting(request, lambda: league.submit(actor, race, path, checkpoint=checkpoint, name=name))


async def converting(request: Request, call):
    """`call()` (a submission: the model's conversion in a child inside) in a thread, at most
    `convert.CONVERSIONS_AT_ONCE` at a time; the others wait on the event loop. A crowd's uploads at the same
    moment held every thread of the pool while they waited for their turn to convert, and the leaderboard and
    status polls that needed a read waited seconds for a thread (p50 2.9 s in benchmarks/league_web.py)."""
    from racerlab.league import convert

    return await auth.in_turn(request, "upload_limiter", convert.CONVERSIONS_AT_ONCE, call)


def _submissions(app: FastAPI) -> None:
    @app.post("/api/races/{name}/submissions")
    async def submit(request: Request, name: str, actor: Annotated[Actor, Depends(needs("submission.create"))]):
        view = await submit_upload(request, actor, name)
        return JSONResponse(view.to_json(), 200 if view.duplicate else 201)

    @app.get("/api/submissions")
    async def submissions(request: Request, actor: User, race: str | None = None, everyone: bool = False):
        boards = request.app.state.boards
        if race is not None and not everyone:  # a racer's poll of one race: shared with their board
            mine = boards.mine_held(actor, race)
            if mine is None:
                mine = await run_in_threadpool(boards.mine, actor, race)
            return JSONResponse({"submissions": mine})
        subs = await run_in_threadpool(request.app.state.league.submissions, actor, race, everyone=everyone)
        return JSONResponse({"submissions": [s.to_json() for s in subs]})

    @app.get("/api/submissions/{sid}")
    def submission(request: Request, sid: int, actor: User):
        return JSONResponse(request.app.state.league.submission(actor, sid).to_json())

    @app.get("/api/submissions/{sid}/files/{kind}")
    def download(request: Request, sid: int, kind: str, actor: User, download: bool = False):
        league = request.app.state.league
        path = league.submission_file(actor, sid, kind)
        media, ext = FILE_TYPES.get(kind, ("application/octet-stream", "bin"))
        inline = kind == "video" and not download
        return FileResponse(path, media_type=media, filename=f"submission-{sid}-{kind}.{ext}",
                            content_disposition_type="inline" if inline else "attachment")

    @app.post("/api/submissions/{sid}/requeue")
    def requeue(request: Request, sid: int, actor: Annotated[Actor, Depends(needs("submission.requeue"))]):
        return request.app.state.league.requeue(actor, sid).to_json()


# ---- staff --------------------------------------------------------------------------------------------------
def base_url(request: Request) -> str:
    """The address people reach the server at (the public one behind a proxy)."""
    return request.app.state.public_url or str(request.base_url).rstrip("/")


def invite_answer(request: Request, invite) -> dict:
    base = base_url(request)
    return {**invite.to_json(), "url": f"{base}/invite?code={invite.code}",
            "command": f"racerlab league login {base} --invite {invite.code}"}


def _staff(app: FastAPI) -> None:
    @app.post("/api/invites")
    async def invite(request: Request, actor: Annotated[Actor, Depends(needs("invite.racer"))]):
        body = await json_body(request)
        role = text(body, "role", False) or "racer"
        made = await run_in_threadpool(request.app.state.league.invite, actor, text(body, "alias"), role)
        return JSONResponse(invite_answer(request, made), 201)

    @app.get("/api/users")
    def users(request: Request, actor: Annotated[Actor, Depends(needs("user.list"))]):
        return {"users": [u.to_json() for u in request.app.state.league.users(actor)]}

    @app.patch("/api/users/{alias}")
    async def change_user(request: Request, alias: str, actor: Annotated[Actor, Depends(needs("user.change"))]):
        body = await json_body(request)
        active = flag(body, "active", None) if "active" in body else None
        role = text(body, "role") if "role" in body else None
        await run_in_threadpool(lambda: request.app.state.league.set_user(actor, alias, active=active, role=role))
        request.app.state.tokens.forget()
        return {"ok": True}

    @app.get("/api/audit")
    def audit(request: Request, actor: Annotated[Actor, Depends(needs("audit.view"))], since_id: int = 0,
              limit: int = 200):
        return {"entries": [e.to_json() for e in request.app.state.league.audit(actor, since_id, limit)]}

    @app.put("/api/settings")
    async def settings(request: Request, actor: Annotated[Actor, Depends(needs("settings.change"))]):
        body = await json_body(request)
        if set(body) != {"open_signup"}:
            raise LeagueError("settings: send {\"open_signup\": true | false}")
        on = flag(body, "open_signup", False)
        await run_in_threadpool(request.app.state.league.set_open_signup, actor, on)
        return {"open_signup": on}

