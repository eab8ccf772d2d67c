"""Routes that run racerlab's own functions in the background and show their files: evaluations and
races (`racerlab.evaluate`), reports (`racerlab.analysis.report`), racing lines (`racerlab.line`),
uploaded log archives, and the reward check and map of the wizard."""

from __future__ import annotations

import base64
import io
import json
import re
import threading
import time
from pathlib import Path
from typing import Annotated

from fastapi import Body, FastAPI, File, Request, UploadFile
from fastapi.responses import FileResponse
from starlette.concurrency import run_in_threadpool

from racerlab import logs
from racerlab.console.isolate import run_isolated
from racerlab.console.security import (
    ConsoleError,
    check_archive,
    check_name,
    flag,
    inside,
    number,
    plain_file,
    save_upload,
)

EVAL_RE = re.compile(r"^evaluation-\d{14}(-\d+)?$")
UPLOAD_SUFFIXES = (".tar.gz", ".tgz", ".tar")
# the report is racerlab's own HTML, but it is shown as a document of no origin: scripts in it (if any)
# cannot reach the console
MAX_TRIALS = 100
MAX_RACE_MODELS = 32  # a race's cars share one world; more would run for hours with no way to stop it
REWARD_CHECK_S = 60.0  # the whole reward check, the import of reward_function.py included
REWARD_CALL_S = 3.0  # one reward call in the check: the training's default run.reward_budget_s
SANDBOX = {"Content-Security-Policy": "sandbox allow-popups", "Cache-Control": "no-store"}


def ws(request: Request):
    return request.app.state.workspace


_RULE_NUMBERS = {"trials": {"integer": True, "low": 1, "high": MAX_TRIALS},
                 "off_track_penalty": {"low": 0, "high": 3600}, "collision_penalty": {"low": 0, "high": 3600},
                 "max_resets": {"integer": True, "low": 0, "high": 10_000}}
_RULE_FLAGS = ("continuous", "reverse")  # what the page may set; the rest (and what it leaves out) are RaceRules'


def _rules(body: dict):
    from racerlab.evaluate import RaceRules

    given = {k: number(body, k, **limits) for k, limits in _RULE_NUMBERS.items() if body.get(k) not in (None, "")}
    given.update({k: flag(body, k, False) for k in _RULE_FLAGS if body.get(k) not in (None, "")})
    try:
        return RaceRules(**given)
    except (TypeError, ValueError) as exc:
        raise ConsoleError(f"race rules: {exc}") from None


def _track_arg(body: dict):
    from racerlab.track import registry

    name = body.get("track") or None
    if name is not None and name not in registry.names():
        raise ConsoleError(f"track {name!r}: not a known track name")
    return name


def register(app: FastAPI) -> None:
    _evaluation_routes(app)
    _race_routes(app)
    _analysis_routes(app)
    _upload_routes(app)

    @app.get("/api/tasks")
    def tasks(request: Request):
        return {"tasks": [t.to_json() for t in ws(request).tasks.values()]}

    @app.get("/api/tasks/{key}")
    def task(request: Request, key: str):
        t = ws(request).tasks.get(key)
        if t is None:
            raise ConsoleError(f"no task {key!r}", 404)
        return t.to_json()

    @app.post("/api/tasks/{key}/cancel")
    def cancel_task(request: Request, key: str):
        return ws(request).cancel_task(key).to_json()


# ---- evaluations ----------------------------------------------------------------------------------------

def _evaluation_routes(app: FastAPI) -> None:
    @app.post("/api/models/{name}/evaluate")
    def evaluate(request: Request, name: str, body: Annotated[dict | None, Body()] = None):
        from racerlab.evaluate import evaluate as run

        body = body or {}
        w = ws(request)
        folder = w.folder(name)
        if w.state(name) == "training":
            raise ConsoleError(f"{name}: training; stop it first (its checkpoints change under the evaluation)", 409)
        rules, track = _rules(body), _track_arg(body)
        checkpoint, video = str(body.get("checkpoint") or "best"), flag(body, "video", True)

        def job():
            res = run(folder.path, track=track, rules=rules, checkpoint=checkpoint, video=video, progress=False)
            return {"evaluation": res.out_dir.name, "text": res.text, "table": res.table()}

        return w.run_task("evaluate", f"evaluate:{name}", job).to_json()

    @app.get("/api/models/{name}/evaluations")
    def evaluations(request: Request, name: str):
        folder = ws(request).folder(name)
        return {"evaluations": [_eval_summary(p) for p in reversed(logs.evaluation_dirs(folder.path))]}

    @app.get("/api/models/{name}/evaluations/{ev}/video")
    def video(request: Request, name: str, ev: str):
        from racerlab.evaluate.api import VIDEO_NAME

        path = _eval_dir(request, name, ev) / VIDEO_NAME
        if not plain_file(path):
            raise ConsoleError(f"{name}/{ev}: no video (evaluate with video on)", 404)
        return FileResponse(path, media_type="video/mp4")


def _eval_dir(request: Request, name: str, ev: str) -> Path:
    if not EVAL_RE.match(ev):
        raise ConsoleError(f"{ev!r}: not an evaluation folder name", 404)
    path = inside(ws(request).folder(name).path, ev)
    if not path.is_dir():
        raise ConsoleError(f"{name}/{ev}: no such evaluation", 404)
    return path


def _eval_summary(path: Path) -> dict:
    from racerlab.evaluate.api import SUMMARY_NAME, VIDEO_NAME

    try:
        summary = json.loads((path / SUMMARY_NAME).read_text())
    except (OSError, json.JSONDecodeError):
        summary = None
    return {"name": path.name, "summary": summary, "video": (path / VIDEO_NAME).is_file()}


# ---- races ---------------------------------------------------------------------------------------------

def _races_dir(request: Request) -> Path:
    return ws(request).state_root / "races"


def _race_routes(app: FastAPI) -> None:
    @app.post("/api/races")
    def start_race(request: Request, body: Annotated[dict, Body()]):
        from racerlab.evaluate import head_to_model, race

        w = ws(request)
        names = body.get("models") or []
        if not isinstance(names, list) or len(names) < 1:
            raise ConsoleError("a race needs at least one model")
        pair = body.get("head_to_model") is True  # both cars on the track at once
        if pair and len(names) != 2:
            raise ConsoleError(f"models: {len(names)} entries; a head-to-model race takes two")
        if len(names) > MAX_RACE_MODELS:
            raise ConsoleError(f"models: {len(names)} entries; a race takes at most {MAX_RACE_MODELS}")
        folders = [w.folder(check_name(n)).path for n in names]
        rules, track = _rules(body), _track_arg(body)
        out = _races_dir(request) / f"race-{time.strftime('%Y%m%d%H%M%S')}.json"
        cancel = threading.Event()

        def job():
            if pair:
                board = head_to_model(*folders, track=track, rules=rules, out=out, progress=False, cancel=cancel)
            else:
                board = race(folders, track=track, rules=rules, out=out, progress=False, cancel=cancel)
            return {"race": out.name, "table": board.table()}

        return w.run_task("race", "race", job, cancel=cancel, models=[check_name(n) for n in names]).to_json()

    @app.get("/api/races")
    def races(request: Request):
        out = []
        folder = _races_dir(request)
        for p in sorted(folder.glob("race-*.json"), reverse=True) if folder.is_dir() else []:
            try:
                out.append({"name": p.name, **json.loads(p.read_text())})
            except (OSError, json.JSONDecodeError):
                continue
        return {"races": out}


# ---- reports, racing lines, reward check -------------------------------------------------------------------

def _limit_summary(track) -> dict:
    """The theoretical best lap of `track` (`line.theoretical_limit`), or the one line saying why it is not solved."""
    from racerlab.errors import TrackError
    from racerlab.line import theoretical_limit

    try:
        return theoretical_limit(track).summary()
    except TrackError as exc:
        return {"error": str(exc)}


def _analysis_routes(app: FastAPI) -> None:
    @app.post("/api/models/{name}/report")
    def make_report(request: Request, name: str):
        from racerlab.analysis.report import write_report

        w = ws(request)
        folder = w.folder(name)
        return w.run_task("report", f"report:{name}", lambda: {"report": write_report(folder.path).name},
                          models=[name]).to_json()

    @app.api_route("/api/models/{name}/report", methods=["GET", "HEAD"])  # the page asks with HEAD if there is one
    def report(request: Request, name: str):
        from racerlab.analysis.report import report_path

        path = report_path(ws(request).folder(name).path)
        if not plain_file(path):
            raise ConsoleError(f"{name}: no report yet; make one first", 404)
        return FileResponse(path, media_type="text/html", headers=SANDBOX)

    @app.post("/api/lines")
    def make_line(request: Request, body: Annotated[dict, Body()]):
        from racerlab import track as tracks
        from racerlab.line import DEFAULT_MARGIN_M, METHODS, racing_line
        from racerlab.line.export import write_all

        track = _track_arg(body)
        if track is None:
            raise ConsoleError("choose a track for the racing line")
        method = body.get("method", METHODS[0])
        if method not in METHODS:
            raise ConsoleError(f"method {method!r}: use {' or '.join(METHODS)}")
        margin = number(body, "margin", DEFAULT_MARGIN_M, low=0, high=1)
        out = ws(request).state_root / "lines" / f"{track}_{method}"

        def job():
            t = tracks.load(track)
            line = racing_line(t, margin=margin, method=method)
            paths = write_all(line, t, out)
            return {"summary": line.summary(), "limit": _limit_summary(t), "png": paths["png"].name,
                    "python": paths["py"].read_text()}

        return ws(request).run_task("line", f"line:{track}:{method}", job).to_json()

    @app.get("/api/lines/{track}/{method}.png")
    def line_png(request: Request, track: str, method: str):
        from racerlab.line import METHODS

        if method not in METHODS:
            raise ConsoleError(f"method {method!r}: use {' or '.join(METHODS)}", 404)
        folder = inside(ws(request).state_root / "lines", f"{check_name(track, 'track')}_{method}")
        pngs = sorted(p for p in folder.glob("*.png") if plain_file(p)) if folder.is_dir() else []
        if not pngs:
            raise ConsoleError(f"{track}: no racing line yet", 404)
        return FileResponse(pngs[0], media_type="image/png")

    @app.post("/api/reward/check")
    def reward_check(request: Request, body: Annotated[dict, Body()]):
        args = (body.get("reward", ""), _track_arg(body), number(body, "samples", 20, integer=True, low=1, high=200))
        return run_isolated(_reward_check, *args, timeout_s=REWARD_CHECK_S, what="reward_function.py")


class _Cut(BaseException):
    """A reward call the watchdog cut: ends the whole check (check_reward collects ordinary exceptions)."""


class _Guarded:
    def __init__(self, watchdog):
        self.watchdog = watchdog
        self.__racerlab_source__ = watchdog.__racerlab_source__

    def __call__(self, params):
        from racerlab.reward import RewardTimeout

        try:
            return self.watchdog(params)
        except RewardTimeout as exc:
            raise _Cut(str(exc)) from None


def _reward_check(reward: str, track: str | None, samples: int) -> dict:
    """The wizard's reward check, in a child process (`run_isolated`) whose main thread arms the watchdog."""
    from racerlab import track as tracks
    from racerlab.analysis.plots import reward_map_figure
    from racerlab.analysis.reward_tools import check_reward, reward_map
    from racerlab.console.wizard import check_reward_text
    from racerlab.reward import RewardWatchdog

    fn = check_reward_text(reward)
    t = tracks.load(track or tracks.DEFAULT_TRACK)
    try:
        with RewardWatchdog(fn, REWARD_CALL_S) as watchdog:
            rep = check_reward(_Guarded(watchdog), t, per_segment=samples)
            rm = reward_map(_Guarded(watchdog), t, ds=0.1, across=15)
    except _Cut as cut:
        raise ConsoleError(f"reward_function.py: a call {cut}") from None
    buf = io.BytesIO()
    reward_map_figure(rm).savefig(buf, format="png", dpi=70)
    png = base64.b64encode(buf.getvalue()).decode()
    return {"ok": rep.ok, "report": rep.format(), "map": "data:image/png;base64," + png}


# ---- uploaded log archives ----------------------------------------------------------------------------------

def _uploads_dir(request: Request) -> Path:
    d = ws(request).state_root / "uploads"
    d.mkdir(parents=True, exist_ok=True)
    return d


def upload_name(filename: str) -> str:
    """A safe stored name for an uploaded archive: its base name with unusual characters replaced."""
    base = re.split(r"[\\/]", filename or "")[-1]
    suffix = next((s for s in UPLOAD_SUFFIXES if base.lower().endswith(s)), None)
    if suffix is None:
        raise ConsoleError(f"{base!r}: upload a log archive ending in {', '.join(UPLOAD_SUFFIXES)}")
    stem = re.sub(r"[^A-Za-z0-9._-]", "_", base[: -len(suffix)]).strip("._-")[:48] or "logs"
    return check_name(stem, "upload name") + suffix


def _upload_routes(app: FastAPI) -> None:
    @app.post("/api/uploads")
    async def upload(request: Request, file: Annotated[UploadFile, File()]):
        from racerlab.analysis.report import report_path, write_report

        name = upload_name(file.filename)
        dest = _uploads_dir(request) / name
        if dest.exists():
            raise ConsoleError(f"{name}: already uploaded; delete it or rename the file", 409)
        size = await save_upload(file, dest, request.app.state.upload_limit)
        try:
            files = await run_in_threadpool(check_archive, dest)  # reading a gzip stream: off the loop
        except ConsoleError:
            dest.unlink(missing_ok=True)
            raise
        report = report_path(dest)
        task = ws(request).run_task("upload", f"upload:{name}", lambda: {"report": write_report(dest, report).name})
        return {"name": name, "bytes": size, "files": files, "task": task.to_json()}

    @app.get("/api/uploads")
    def uploads(request: Request):
        from racerlab.analysis.report import report_path

        d = _uploads_dir(request)
        return {"uploads": [{"name": p.name, "bytes": p.stat().st_size, "report": report_path(p).is_file()}
                            for p in sorted(d.iterdir()) if p.name.endswith(UPLOAD_SUFFIXES)]}

    @app.get("/api/uploads/{name}/report")
    def upload_report(request: Request, name: str):
        from racerlab.analysis.report import report_path

        d = _uploads_dir(request)
        path = inside(d, report_path(d / upload_name(name)).name)
        if not plain_file(path):
            raise ConsoleError(f"{name}: no report (yet)", 404)
        return FileResponse(path, media_type="text/html", headers=SANDBOX)

