"""Every route of the league's web app, asked by a stranger and by each role: who gets what.

The table below names every (method, path) the app answers; a route added without a line here fails the first
test, and one added without a check of who asks does not even start (`app._check_routes`). Each request goes
through a real server with a fresh browser session (cookie and CSRF token) of its asker.
Askers: a stranger, bob (a racer who does not own the submission), ana (the racer who does), fay (facilitator),
admin. An expected answer is a status, or "303 /path" (a redirect to a path starting with /path).
"""

from __future__ import annotations

import httpx
import pytest
from fastapi import FastAPI

from racerlab.league.web.app import _check_routes, routes
from tests.league.conftest import PASSWORD, racer
from tests.league.test_seasons import done_final
from tests.league.web_fixtures import LiveServer, app_for, evaluate_queue, model_archive, session_for

ASKERS = ("stranger", "bob", "ana", "fay", "admin")
LOGIN = "303 /login"  # a stranger on a page: sent to log in (and back with ?next=)
ALL = {"stranger": 200, "bob": 200, "ana": 200, "fay": 200, "admin": 200}


def who(stranger, bob, ana, fay, admin) -> dict:
    return dict(zip(ASKERS, (stranger, bob, ana, fay, admin), strict=True))


def page(bob=200, ana=None, fay=None, admin=None) -> dict:
    """A page: a stranger is sent to log in; the others as given (ana, fay, admin default to bob's)."""
    ana = bob if ana is None else ana
    return who(LOGIN, bob, ana, fay if fay is not None else ana, admin if admin is not None else ana)


def api(bob=200, ana=None, fay=None, admin=None) -> dict:
    ana = bob if ana is None else ana
    return who(401, bob, ana, fay if fay is not None else ana, admin if admin is not None else ana)


def same(status) -> dict:
    return dict.fromkeys(ASKERS, status)


STAFF_PAGE = page(403, 403, 200, 200)
STAFF_API = api(403, 403, 200, 200)
TABLE = {
    # the public ones
    ("GET", "/login"): who(200, "303 /", "303 /", "303 /", "303 /"),
    ("POST", "/login"): same(403), ("POST", "/invite"): same(403), ("POST", "/signup"): same(403),  # no form token
    ("GET", "/invite"): same(200), ("GET", "/signup"): same(403), ("GET", "/favicon.ico"): same(200),
    ("GET", "/api/health"): same(200), ("POST", "/api/login"): same(401), ("POST", "/api/invites/accept"): same(404),
    ("POST", "/api/signup"): same(403),
    # pages
    ("GET", "/"): page(), ("GET", "/account"): page(), ("GET", "/races/{name}"): page(),
    ("GET", "/races/{name}/track.svg"): page(), ("GET", "/submissions"): page(),
    ("GET", "/submissions/{sid}"): page(404, 200),
    ("GET", "/admin/audit"): STAFF_PAGE, ("GET", "/admin/people"): STAFF_PAGE, ("GET", "/admin/races/new"): STAFF_PAGE,
    ("POST", "/logout"): page("303 /login"),
    ("POST", "/account/password"): page(401),  # a wrong current password: the form again, with why
    ("POST", "/account/tokens"): page(200),
    ("POST", "/account/tokens/{token_id}/revoke"): page(404, "303 /account", 404, "303 /account"),
    ("POST", "/admin/invites"): STAFF_PAGE,
    ("POST", "/admin/races"): page(403, 403, "303 /races/", "303 /races/"),
    ("POST", "/admin/settings"): page(403, 403, 403, "303 /admin/people"),
    ("POST", "/admin/users/{alias}"): page(403, 403, 403, "303 /admin/people"),
    ("POST", "/races/{name}/submit"): page("303 /submissions/"),
    ("POST", "/races/{name}/update"): page(403, 403, "303 /races/cup", "303 /races/cup"),
    ("POST", "/submissions/{sid}/requeue"): page(403, 403, "303 /submissions/", "303 /submissions/"),
    # the API
    ("GET", "/api/me"): api(), ("GET", "/api/races"): api(), ("GET", "/api/races/{name}"): api(),
    ("GET", "/api/races/{name}/events"): api(), ("GET", "/api/races/{name}/standings"): api(),
    ("GET", "/api/races/{name}/standings.csv"): api(), ("GET", "/api/races/{name}/standings.json"): api(),
    ("GET", "/api/submissions"): api(), ("GET", "/api/submissions/{sid}"): api(404, 200),
    ("GET", "/api/submissions/{sid}/files/{kind}"): api(404, 200), ("GET", "/api/tokens"): api(),
    ("GET", "/api/audit"): STAFF_API, ("GET", "/api/users"): STAFF_API,
    ("PATCH", "/api/races/{name}"): STAFF_API, ("PATCH", "/api/users/{alias}"): api(403, 403, 403, 200),
    ("POST", "/api/invites"): api(403, 403, 201, 201), ("POST", "/api/logout"): api(),
    ("POST", "/api/races"): api(403, 403, 201, 201),
    ("POST", "/api/races/{name}/submissions"): api(201, 200, 201, 201),  # ana's model is in already
    ("POST", "/api/submissions/{sid}/requeue"): api(403, 403, 409, 409),  # staff: it has not failed
    ("POST", "/api/tokens"): api(201), ("DELETE", "/api/tokens/{token_id}"): api(404, 200, 404, 200),
    ("PUT", "/api/settings"): api(403, 403, 403, 200),
    # seasons and finals
    ("GET", "/seasons"): page(), ("GET", "/seasons/{name}"): page(), ("GET", "/finals/{fid}"): page(),
    ("GET", "/finals/{fid}/files/{place}/{kind}"): page(404, 200),  # the first car is ana's
    ("POST", "/admin/seasons"): page(403, 403, "303 /seasons/", "303 /seasons/"),
    ("POST", "/seasons/{name}/races"): page(403, 403, "303 /seasons/cup", "303 /seasons/cup"),
    ("POST", "/seasons/{name}/points"): page(403, 403, "303 /seasons/cup", "303 /seasons/cup"),
    ("POST", "/races/{name}/final"): page(403, 403, "303 /races/cup", "303 /races/cup"),  # one ranked racer
    ("GET", "/api/seasons"): api(), ("GET", "/api/seasons/{name}"): api(), ("GET", "/api/races/{name}/finals"): api(),
    ("GET", "/api/finals/{fid}"): api(), ("POST", "/api/races/{name}/finals"): api(403, 403, 409, 409),
}


def _request(route, asker, ids, archive) -> dict:
    """The request one asker sends to one route: path, JSON or form body, files."""
    method, path = route
    filled = path.format(name="cup", sid=ids["sid"], kind="simtrace", token_id=ids["token"], alias="bob",
                         fid=ids["fid"], place=1)
    out = {"method": method, "url": filled}
    bodies = {
        "/api/login": {"json": {"alias": "nobody", "password": "x" * 12}},
        "/api/invites/accept": {"json": {"code": "rli_not-a-code", "password": PASSWORD}},
        "/api/signup": {"json": {"alias": "walker", "password": PASSWORD}},
        "/api/invites": {"json": {"alias": f"api-{asker}"[:20]}},
        "/api/races": {"json": {"name": f"api-{asker}", "track": "lab_oval", "laps": 1}},
        "/api/tokens": {"json": {"label": "walk"}},
        "/api/settings": {"json": {"open_signup": False}},
        "/admin/invites": {"data": {"alias": f"page-{asker}"[:20]}},
        "/admin/races": {"data": {"name": f"page-{asker}", "track": "lab_oval", "laps": "1"}},
        "/admin/settings": {"data": {}}, "/admin/users/bob": {"data": {"role": "racer", "save": "role"}},
        "/account/password": {"data": {"old": "not the password", "new": PASSWORD, "new2": PASSWORD}},
        "/account/tokens": {"data": {"label": "walk"}},
        "/races/cup/update": {"data": {"max_submissions": "60"}},
        "/admin/seasons": {"data": {"name": f"season-{asker}"}},
        "/seasons/cup/races": {"data": {"race": "cup", "action": "remove"}},
        "/seasons/cup/points": {"data": {"points": "10,5"}},
    }
    if method == "PATCH":
        out["json"] = {"max_submissions": 50} if "races" in path else {"role": "racer"}
    out.update(bodies.get(filled, {}))
    if path.endswith(("/submissions", "/submit")) and method == "POST":
        out["files"] = {"model": (archive.name, archive.read_bytes(), "application/gzip")}
    return out


def _ask(http: httpx.Client, league, actors, asker, route, ids, archive):
    req = _request(route, asker, ids, archive)
    headers = {}
    if asker != "stranger":
        session, csrf = session_for(league, actors[asker])
        headers = {"Cookie": f"racerlab_league={session}", "X-CSRF-Token": csrf}
    http.cookies.clear()
    if route[1].endswith("/events"):
        with http.stream(req.pop("method"), req.pop("url"), headers=headers) as r:
            return r.status_code, ""
    r = http.request(req.pop("method"), req.pop("url"), headers=headers, **req)
    return r.status_code, r.headers.get("location", "")


def _meets(expected, status: int, location: str) -> bool:
    if isinstance(expected, int):
        return status == expected
    code, prefix = expected.split(" ", 1)
    return status == int(code) and location.startswith(prefix)


@pytest.fixture
def walk(league, admin, straight, tmp_path):
    actors = {"admin": admin, "fay": racer(league, admin, "fay", "facilitator"), "ana": racer(league, admin, "ana"),
              "bob": racer(league, admin, "bob")}
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    sid = league.submit(actors["ana"], "cup", model_archive(tmp_path, straight, seed=1, name="ana-model")).id
    evaluate_queue(league)
    ids = {"sid": sid, "token": league.issue_token(actors["ana"], "api", label="spare").id,
           "fid": done_final(league, "cup", "ana")}
    league.create_season(admin, "cup")
    league.season_add_race(admin, "cup", "cup")
    app = app_for(league)
    server = LiveServer(app)
    yield app, server, actors, ids, model_archive(tmp_path, straight, seed=1, name="ana-model")
    server.stop()


def test_every_route_answers_each_asker_as_the_table_says(walk, league):
    app, server, actors, ids, archive = walk
    assert set(routes(app)) == set(TABLE), "a route of the app without a line in TABLE, or a line without a route"
    wrong = []
    with httpx.Client(base_url=server.url, timeout=120, follow_redirects=False) as http:
        for asker in ASKERS:
            for route in sorted(TABLE):
                status, location = _ask(http, league, actors, asker, route, ids, archive)
                if not _meets(TABLE[route][asker], status, location):
                    wrong.append(f"{route[0]} {route[1]} as {asker}: {status} {location} (expected "
                                 f"{TABLE[route][asker]})")
    assert not wrong, "\n".join(wrong)


def test_an_app_with_a_route_that_checks_no_one_does_not_start(league):
    app = app_for(league)
    _check_routes(app)

    @app.get("/api/leak")
    def leak():
        return {"secret": 1}

    with pytest.raises(RuntimeError, match="route GET /api/leak does not check who asks"):
        _check_routes(app)
    bare = FastAPI(docs_url=None, redoc_url=None, openapi_url=None)
    bare.add_api_route("/login", lambda: None, methods=["GET"])  # a public one is fine
    _check_routes(bare)
