"""Helpers of the league's web tests: the app on a league, logging in as a browser or a script, a real server on a
free loopback port, model archives, and evaluating the queue in this process."""

from __future__ import annotations

import re
import tarfile
import threading
import time
from pathlib import Path

from racerlab.league import people
from tests.league.conftest import PASSWORD, features_model

BASE = "http://127.0.0.1"
STRAIGHT_AHEAD = ((0.0, 1.0),)


def app_for(league, **options):
    from racerlab.league.web import create_app

    return create_app(league.store.folder, league=league, **options)


def client_for(app, base: str = BASE):
    from fastapi.testclient import TestClient

    return TestClient(app, base_url=base, follow_redirects=False)


def pre_csrf(client, page: str = "/login") -> str:
    """The pre-session token of a login, invite or sign-up form (and its cookie, kept by the client)."""
    html = client.get(page).text
    return re.search(r'name="csrf" value="([^"]+)"', html).group(1)


def browser_login(client, alias: str, password: str = PASSWORD) -> str:
    """Log `client` in through the login form; the session's CSRF token (as the pages carry it)."""
    r = client.post("/login", data={"csrf": pre_csrf(client), "alias": alias, "password": password, "next": "/"})
    assert r.status_code == 303, r.text
    return page_csrf(client)


def page_csrf(client) -> str:
    return re.search(r'data-csrf="([^"]*)"', client.get("/").text).group(1)


def bearer(client, alias: str, password: str = PASSWORD) -> dict:
    r = client.post("/api/login", json={"alias": alias, "password": password})
    assert r.status_code == 200, r.text
    return {"Authorization": f"Bearer {r.json()['token']}"}


def session_for(league, actor) -> tuple[str, str]:
    """(a fresh session token of `actor`, its CSRF token), as a login would make them."""
    token = league.issue_token(actor, "session").token
    return token, people.csrf_token(league.secret(), token)


def model_archive(tmp: Path, track, seed: int = 0, name: str = "model") -> Path:
    """A features model folder packed as NAME.tar.gz (distinct weights per seed)."""
    folder = features_model(tmp / name, track, STRAIGHT_AHEAD, seed=seed).path
    out = tmp / f"{name}.tar.gz"
    with tarfile.open(out, "w:gz") as tar:
        tar.add(folder, arcname=name)
    return out


def evaluate_queue(league, limit: int = 50) -> list[int]:
    """Evaluate every queued submission in this process, as a worker does (claim, evaluate, finish); their ids."""
    from racerlab.league import queue
    from racerlab.league.evaluation import evaluate_stored
    from racerlab.league.rules import Rules

    store, done = league.store, []
    for _ in range(limit):
        claim = queue.claim(store, "test-worker")
        if claim is None:
            return done
        out = store.results_dir(claim.submission_id) / f"attempt-{claim.attempt}"
        outcome = evaluate_stored(store.model_dir(claim.model_hash), Rules.from_json(claim.rules_json),
                                  store.folder / "tracks", out)
        outcome["result_dir"] = str(out.relative_to(store.folder))
        queue.finish(store, claim, outcome["status"], outcome["reason"], queue.result_values(outcome))
        done.append(claim.submission_id)
    return done


class LiveServer:
    """The app served by uvicorn on a free loopback port, in a thread (`url`; `stop()`)."""

    def __init__(self, app):
        import uvicorn

        config = uvicorn.Config(app, host="127.0.0.1", port=0, log_level="warning", lifespan="off",
                                timeout_graceful_shutdown=1)
        self.server = uvicorn.Server(config)
        self.thread = threading.Thread(target=self.server.run, daemon=True, name="league-test-server")
        self.thread.start()
        end = time.monotonic() + 30
        while not self.server.started:
            if time.monotonic() > end or not self.thread.is_alive():
                raise RuntimeError("the league's test server did not start")
            time.sleep(0.02)
        port = self.server.servers[0].sockets[0].getsockname()[1]
        self.url = f"http://127.0.0.1:{port}"

    def stop(self) -> None:
        self.server.should_exit = True
        self.thread.join(10)

