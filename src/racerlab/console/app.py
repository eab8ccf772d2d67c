"""The console's web app: `create_app(workspace_dir, host, token)` returns a FastAPI application.

Pages are one static HTML file with its script and style (package data, nothing fetched from the
internet); everything else is JSON under /api, server-sent events for live data, and files found by
name inside the workspace. Routes for runs (evaluation, races, reports, racing lines, uploads) are in
`racerlab.console.runs`, those for model exchange in `racerlab.console.exchange`.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Annotated

from fastapi import Body, FastAPI, Request
from fastapi.responses import HTMLResponse, JSONResponse, RedirectResponse, Response, StreamingResponse
from fastapi.staticfiles import StaticFiles

from racerlab.console import live
from racerlab.console.security import (
    COOKIE,
    CSRF_HEADER,
    MAX_UPLOAD_BYTES,
    ConsoleError,
    Guard,
    check_name,
    number,
)
from racerlab.console.texts import HYPERPARAMETER_HELP
from racerlab.console.workspace import Workspace
from racerlab.errors import RacerlabError

STATIC = resources.files("racerlab.console") / "static"
NO_STORE = {"Cache-Control": "no-store"}


def create_app(root, host: str = "127.0.0.1", token: str | None = None,
               upload_limit: int = MAX_UPLOAD_BYTES) -> FastAPI:
    """The app for the model folders in `root`. `host` is the address it will be bound to: any but the
    loopback needs `token` (one is generated when none is given: `app.state.guard.token`)."""
    app = FastAPI(title="racerlab console", docs_url=None, redoc_url=None, openapi_url=None)
    app.state.upload_limit = upload_limit
    app.state.workspace = Workspace(root)
    app.state.guard = Guard(host, token)
    _middleware(app)
    app.mount("/static", StaticFiles(directory=str(STATIC)), name="static")
    _pages(app)
    _model_routes(app)
    _live_routes(app)
    from racerlab.console import exchange, runs

    runs.register(app)
    exchange.register(app)
    return app


def ws(request: Request) -> Workspace:
    return request.app.state.workspace


# ---- security and errors ---------------------------------------------------------------------------

def _middleware(app: FastAPI) -> None:
    @app.middleware("http")
    async def guard(request: Request, call_next):
        g: Guard = request.app.state.guard
        host = request.headers.get("host", "")
        if not g.host_allowed(host):
            return JSONResponse({"error": f"host {host!r} refused: the console answers on its loopback name"}, 421)
        qtoken = request.query_params.get("token")
        bearer = request.headers.get("authorization", "").removeprefix("Bearer ").strip() or None
        if not g.authorized(request.cookies.get(COOKIE), bearer, qtoken):
            return JSONResponse({"error": "token required: open the address the console printed"}, 401)
        if _too_large(request):
            return JSONResponse({"error": f"upload larger than the limit of {request.app.state.upload_limit} bytes"},
                                413)
        if not g.csrf_ok(request.method, request.headers.get(CSRF_HEADER), request.headers.get("origin"), host):
            return JSONResponse({"error": "missing or wrong CSRF token; reload the page"}, 403)
        if qtoken and g.token and request.method == "GET" and request.url.path == "/":
            resp = RedirectResponse("/", 303)  # the token moves into a cookie and out of the address bar
            resp.set_cookie(COOKIE, g.token, httponly=True, samesite="strict")
            return resp
        response = await call_next(request)
        response.headers.setdefault("X-Content-Type-Options", "nosniff")
        response.headers.setdefault("X-Frame-Options", "SAMEORIGIN")
        return response

    @app.exception_handler(ConsoleError)
    async def console_error(request: Request, exc: ConsoleError):
        return JSONResponse({"error": str(exc)}, exc.status)

    @app.exception_handler(RacerlabError)
    async def racerlab_error(request: Request, exc: RacerlabError):
        return JSONResponse({"error": str(exc)}, 400)


def _too_large(request: Request) -> bool:
    """Uploads must say their length up front and stay under the limit (checked before a byte is read)."""
    if request.method != "POST" or request.url.path not in ("/api/uploads", "/api/imports"):
        return False
    try:
        length = int(request.headers.get("content-length", ""))
    except ValueError:
        return True
    return length > request.app.state.upload_limit + 64 * 1024  # room for the multipart headers


# ---- pages -------------------------------------------------------------------------------------------

def _pages(app: FastAPI) -> None:
    page = (STATIC / "index.html").read_text(encoding="utf-8")

    @app.get("/", response_class=HTMLResponse)
    def index(request: Request):
        csrf = request.app.state.guard.csrf
        return HTMLResponse(page.replace("{{csrf}}", csrf), headers=NO_STORE)

    icon = (STATIC / "favicon.svg").read_bytes()

    @app.get("/favicon.ico")  # browsers ask for it whatever the page's <link rel="icon"> says
    def favicon():
        return Response(icon, media_type="image/svg+xml", headers={"Cache-Control": "max-age=86400"})


# ---- models ------------------------------------------------------------------------------------------

def _model_routes(app: FastAPI) -> None:
    @app.get("/api/models")
    def models(request: Request):
        w = ws(request)
        return {"workspace": str(w.root), "models": [w.summary(n) for n in w.model_names()]}

    @app.get("/api/models/{name}")
    def model(request: Request, name: str):
        w = ws(request)
        folder = w.folder(name)
        out = w.summary(name)
        out["files"] = {p.name: _read_text(p) for p in (folder.reward_path, folder.metadata_path,
                                                         folder.hyperparameters_path, folder.config_path)}
        out["log"] = w.log_tail(name)
        out["checkpoints"] = [c.name for c in folder.checkpoints()]
        return out

    @app.post("/api/models")
    def create(request: Request, body: Annotated[dict, Body()]):
        from racerlab.console.wizard import create_model

        return ws(request).summary(create_model(ws(request), body))

    @app.post("/api/models/{name}/clone")
    def clone(request: Request, name: str, body: Annotated[dict, Body()]):
        from racerlab.console.modelapi import clone_model

        w = ws(request)
        src = w.folder(name)
        dst = w.folder(check_name(body.get("name")), must_exist=False)
        if dst.path.exists():
            raise ConsoleError(f"{dst.path.name}: already exists; choose another name", 409)
        clone_model(src.path, dst.path, str(body.get("checkpoint") or "best"))
        return w.summary(dst.path.name)

    @app.delete("/api/models/{name}")
    def delete(request: Request, name: str, confirm: str = ""):
        if confirm != name:
            raise ConsoleError(f"{name}: deleting needs ?confirm={name} (type the model's name to confirm)")
        ws(request).delete(name)
        return {"deleted": name}

    @app.post("/api/models/{name}/train")
    def train(request: Request, name: str, body: Annotated[dict | None, Body()] = None):
        body = body or {}
        limits = {k: number(body, k, integer=k != "minutes", above=0) for k in ("minutes", "episodes", "iterations")}
        pid = ws(request).start_training(name, **limits)
        return {"pid": pid, "state": "training"}

    @app.post("/api/models/{name}/stop")
    def stop(request: Request, name: str):
        if not ws(request).stop_training(name):
            raise ConsoleError(f"{name}: not training", 409)
        return {"stopping": name}

    @app.get("/api/models/{name}/log")
    def log(request: Request, name: str):
        return {"log": ws(request).log_tail(name, 200)}


def _read_text(path: Path) -> str | None:
    try:
        return path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        return None


# ---- live --------------------------------------------------------------------------------------------

def _live_routes(app: FastAPI) -> None:
    headers = {**NO_STORE, "X-Accel-Buffering": "no"}

    @app.get("/api/models/{name}/events")
    def events(request: Request, name: str):
        ws(request).folder(name)
        gen = live.metric_events(ws(request), name, request.is_disconnected)
        return StreamingResponse(gen, media_type="text/event-stream", headers=headers)

    @app.get("/api/models/{name}/live")
    def live_view(request: Request, name: str, car: int = 0):
        ws(request).folder(name)
        gen = live.live_view(ws(request), name, car, request.is_disconnected)
        return StreamingResponse(gen, media_type="text/event-stream", headers=headers)

    @app.get("/api/tracks")
    def tracks():
        from racerlab.track import registry

        return {"tracks": registry.names()}

    @app.get("/api/lines/methods")
    def line_methods():
        from racerlab.line import METHODS  # numba-heavy: loaded when the racing-line panel opens

        return {"methods": list(METHODS)}

    @app.get("/api/tracks/{name}.svg")
    def track_svg(name: str):
        from racerlab.console.pictures import track_svg as draw

        return Response(draw(_track(name)), media_type="image/svg+xml", headers={"Cache-Control": "max-age=3600"})

    @app.get("/api/defaults")
    def defaults(sensor: str = "features", action_space: str = "discrete", algorithm: str = "clipped_ppo",
                 max_speed: float = 1.0):
        from racerlab.console.modelapi import SENSORS, Hyperparameters, make_metadata
        from racerlab.reward import EXAMPLE_REWARD

        meta = make_metadata(sensor, action_space, algorithm, max_speed)
        hp = Hyperparameters().to_json()
        return {"metadata": meta.to_json(), "hyperparameters": hp, "help": HYPERPARAMETER_HELP,
                "sensors": list(SENSORS), "reward": EXAMPLE_REWARD.read_text(encoding="utf-8")}


def _track(name: str):
    from racerlab.track import registry

    if name not in registry.names():
        raise ConsoleError(f"track {name!r}: not a known track name; see /api/tracks", 404)
    from racerlab import track as tracks

    return tracks.load(name)
