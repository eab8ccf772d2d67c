"""Pages and API routes of seasons (overall standings by points per place) and head-to-model finals.

Everyone signed in sees seasons and finals (as they see every leaderboard); staff create and change seasons and
start finals (`season.edit`, `final.start`), each route checked by `auth.needs` and again by the service. A final
started from a page runs in its own process and the page that follows shows it running until its result is in.
"""

from __future__ import annotations

from typing import Annotated
from urllib.parse import quote

from fastapi import Depends, FastAPI, Request
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from racerlab.league.people import Actor
from racerlab.league.store import LeagueError
from racerlab.league.web.api import FILE_TYPES, json_body
from racerlab.league.web.auth import needs, signed_in
from racerlab.league.web.pages import redirect, render

User = Annotated[Actor, Depends(signed_in)]
Editor = Annotated[Actor, Depends(needs("season.edit"))]
Starter = Annotated[Actor, Depends(needs("final.start"))]


def register(app: FastAPI) -> None:
    _season_pages(app)
    _season_forms(app)
    _final_pages(app)
    _api(app)


def _back(name: str) -> str:
    return f"/seasons/{quote(name, safe='')}"


def _season_pages(app: FastAPI) -> None:
    @app.get("/seasons")
    def seasons(request: Request, actor: User):
        league = request.app.state.league
        return render(request, "seasons.html", seasons=league.seasons(actor))

    @app.get("/seasons/{name}")
    def season(request: Request, name: str, actor: User):
        league = request.app.state.league
        view = league.season(actor, name)
        others = [r.name for r in league.races(actor) if r.name not in view.races]
        return render(request, "season.html", season=view, others=others)


def _season_forms(app: FastAPI) -> None:
    @app.post("/admin/seasons")
    async def create(request: Request, actor: Editor):
        form = await request.form()
        name = str(form.get("name") or "").strip()
        points = str(form.get("points") or "").strip() or None
        try:
            view = await run_in_threadpool(request.app.state.league.create_season, actor, name, points,
                                           str(form.get("description") or ""))
        except LeagueError as exc:
            return redirect(request, "/seasons", str(exc), "error")
        return redirect(request, _back(view.name), f"Season {view.name} created")

    @app.post("/seasons/{name}/races")
    async def races(request: Request, name: str, actor: Editor):
        form = await request.form()
        race, action = str(form.get("race") or ""), str(form.get("action") or "add")
        league = request.app.state.league
        call = league.season_remove_race if action == "remove" else league.season_add_race
        try:
            await run_in_threadpool(call, actor, name, race)
        except LeagueError as exc:
            return redirect(request, _back(name), str(exc), "error")
        return redirect(request, _back(name), f"Race {race} {'taken out of' if action == 'remove' else 'added to'} "
                                              f"the season")

    @app.post("/seasons/{name}/points")
    async def points(request: Request, name: str, actor: Editor):
        form = await request.form()
        try:
            await run_in_threadpool(lambda: request.app.state.league.update_season(
                actor, name, points=str(form.get("points") or "")))
        except LeagueError as exc:
            return redirect(request, _back(name), str(exc), "error")
        return redirect(request, _back(name), "Points per place changed")


def _final_pages(app: FastAPI) -> None:
    @app.post("/races/{name}/final")
    async def start(request: Request, name: str, actor: Starter):
        league = request.app.state.league
        try:
            view = await run_in_threadpool(lambda: league.start_final(actor, name, wait=False))
        except LeagueError as exc:
            return redirect(request, f"/races/{quote(name, safe='')}", str(exc), "error")
        return redirect(request, f"/finals/{view.id}", "The final is running")

    @app.get("/finals/{fid}")
    def final(request: Request, fid: int, actor: User):
        return render(request, "final.html", final=request.app.state.league.final(actor, fid))

    @app.get("/finals/{fid}/files/{place}/{kind}")
    def final_file(request: Request, fid: int, place: int, kind: str, actor: User):
        path = request.app.state.league.final_file(actor, fid, place, kind)
        media, ext = FILE_TYPES[kind]
        return FileResponse(path, media_type=media, filename=f"final-{fid}-{place}-{kind}.{ext}",
                            content_disposition_type="inline" if kind == "video" else "attachment")


def _api(app: FastAPI) -> None:
    @app.get("/api/seasons")
    def api_seasons(request: Request, actor: User):
        return [s.to_json() for s in request.app.state.league.seasons(actor)]

    @app.get("/api/seasons/{name}")
    def api_season(request: Request, name: str, actor: User):
        return request.app.state.league.season(actor, name).to_json()

    @app.get("/api/races/{name}/finals")
    def api_finals(request: Request, name: str, actor: User):
        return [f.to_json() for f in request.app.state.league.finals(actor, name)]

    @app.post("/api/races/{name}/finals")
    async def api_start(request: Request, name: str, actor: Starter):
        body = await json_body(request) if request.headers.get("content-type") else {}
        wait = body.get("wait") is True
        view = await run_in_threadpool(lambda: request.app.state.league.start_final(actor, name, wait=wait))
        return view.to_json()

    @app.get("/api/finals/{fid}")
    def api_final(request: Request, fid: int, actor: User):
        return request.app.state.league.final(actor, fid).to_json()
