"""What the league's web server shares between the askers of a crowd (`auth.TokenCache`, `live.Boards`) and that
it never outlives a change: a revoked or logged-out token, a disabled account, a racer's own upload, a race that
closes by the clock, a live board's stream after its session ended."""

from __future__ import annotations

import json
import time
from datetime import timedelta

import pytest

from racerlab.league.tables import utcnow
from racerlab.league.web import auth
from tests.league.conftest import PASSWORD, racer
from tests.league.web_fixtures import LiveServer, app_for, bearer, client_for, evaluate_queue, model_archive


@pytest.fixture
def cup(league, admin, straight):
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    return "cup"


@pytest.fixture
def web(league):
    return client_for(app_for(league))


def test_a_revoked_or_logged_out_token_is_refused_at_once_though_it_was_just_seen(web, league, admin, cup):
    racer(league, admin, "ana")
    first = bearer(web, "ana")
    second = web.post("/api/tokens", json={"label": "laptop"}, headers=first).json()
    other = {"Authorization": f"Bearer {second['token']}"}
    assert web.get(f"/api/races/{cup}/standings", headers=other).status_code == 200  # now in the cache
    assert web.delete(f"/api/tokens/{second['id']}", headers=first).status_code == 200
    assert web.get(f"/api/races/{cup}/standings", headers=other).status_code == 401
    assert web.get(f"/api/submissions?race={cup}", headers=first).status_code == 200
    assert web.post("/api/logout", headers=first).status_code == 200
    assert web.get(f"/api/submissions?race={cup}", headers=first).status_code == 401


def test_an_account_disabled_through_the_server_is_refused_at_once_on_the_shared_reads(web, league, admin, cup):
    racer(league, admin, "ana")
    ana, boss = bearer(web, "ana"), bearer(web, "admin")
    for path in (f"/api/races/{cup}/standings", f"/api/submissions?race={cup}"):
        assert web.get(path, headers=ana).status_code == 200
    assert web.patch("/api/users/ana", json={"active": False}, headers=boss).status_code == 200
    for path in (f"/api/races/{cup}/standings", f"/api/submissions?race={cup}"):
        assert web.get(path, headers=ana).status_code == 401


def test_a_change_made_elsewhere_stops_every_service_read_at_once_and_the_shared_ones_within_the_ttl(
        web, league, admin, cup, monkeypatch):
    monkeypatch.setattr(auth.TokenCache, "TTL_S", 1.0)
    racer(league, admin, "ana")
    ana = bearer(web, "ana")
    assert web.get(f"/api/races/{cup}/standings", headers=ana).status_code == 200
    league.set_user(admin, "ana", active=False)  # as `racerlab league user` does, beside the server
    assert web.get(f"/api/races/{cup}", headers=ana).status_code == 401  # the service looks at the account
    time.sleep(1.1)
    assert web.get(f"/api/races/{cup}/standings", headers=ana).status_code == 401


def test_a_lookup_under_way_when_a_token_is_revoked_is_not_kept(league, admin, monkeypatch):
    cache, real = auth.TokenCache(), league.actor_for_token
    token = league.issue_token(admin, "api").token

    def revoked_meanwhile(tok, kind):
        found = real(tok, kind)
        league.end_session(tok)  # the revoke lands between the store's answer and the cache's note of it
        cache.forget()
        return found

    monkeypatch.setattr(league, "actor_for_token", revoked_meanwhile)
    assert cache.actor(league, token, "api") == admin
    monkeypatch.setattr(league, "actor_for_token", real)
    with pytest.raises(auth.LeagueError, match="revoked"):
        cache.actor(league, token, "api")


def test_a_racers_own_upload_shows_in_their_status_poll_at_once(web, league, admin, cup, straight, tmp_path):
    racer(league, admin, "ana")
    ana = bearer(web, "ana")
    assert web.get(f"/api/submissions?race={cup}", headers=ana).json() == {"submissions": []}
    archive = model_archive(tmp_path, straight, seed=3)
    r = web.post(f"/api/races/{cup}/submissions", headers=ana,
                 files={"model": (archive.name, archive.read_bytes(), "application/gzip")})
    assert r.status_code == 201, r.text
    mine = web.get(f"/api/submissions?race={cup}", headers=ana).json()["submissions"]
    assert [(s["id"], s["status"], s["position"]) for s in mine] == [(r.json()["id"], "queued", 1)]
    assert web.get(f"/api/races/{cup}/standings", headers=ana).json()["rows"][0]["submissions"] == 1


def test_the_shared_standings_say_closed_once_the_clock_passes_the_close_time(web, league, admin, straight):
    league.create_race(admin, "sprint", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False,
                                         "closes": utcnow() + timedelta(seconds=1.5)})
    racer(league, admin, "ana")
    ana = bearer(web, "ana")
    assert web.get("/api/races/sprint/standings", headers=ana).json()["state"] == "open"
    time.sleep(1.6)  # no submission, no result: the race's version has not moved
    assert web.get("/api/races/sprint/standings", headers=ana).json()["state"] == "closed"
    assert web.get("/api/races/sprint/standings", headers=ana).json() == {
        **league.standings(admin, "sprint").to_json(), "generated_at": web.get(
            "/api/races/sprint/standings", headers=ana).json()["generated_at"]}


def _stream_until_error(url: str, token: str, after_first) -> list[tuple[str, dict]]:
    import httpx

    events, kind = [], ""
    with httpx.stream("GET", url, timeout=60, headers={"Authorization": f"Bearer {token}"}) as r:
        for line in r.iter_lines():
            if line.startswith("event: "):
                kind = line[7:]
            elif line.startswith("data: "):
                events.append((kind, json.loads(line[6:])))
                if len(events) == 1:
                    after_first()
    return events


def test_a_live_board_ends_when_its_token_is_logged_out_or_the_account_disabled(league, admin, cup, tmp_path,
                                                                               straight):
    import httpx

    server = LiveServer(app_for(league))
    try:
        ana, bob = racer(league, admin, "ana"), racer(league, admin, "bob")
        league.submit(bob, cup, model_archive(tmp_path, straight, seed=4))
        evaluate_queue(league)
        url = f"{server.url}/api/races/{cup}/events"
        for who, end in ((ana, "logout"), (bob, "disable")):
            token = league.issue_token(who, "api").token
            boss = httpx.post(f"{server.url}/api/login", json={"alias": "admin", "password": PASSWORD}).json()

            def cut(token=token, end=end, who=who, boss=boss["token"]):
                if end == "logout":
                    httpx.post(f"{server.url}/api/logout", headers={"Authorization": f"Bearer {token}"})
                else:
                    httpx.patch(f"{server.url}/api/users/{who.alias}", json={"active": False},
                                headers={"Authorization": f"Bearer {boss}"})

            t0 = time.monotonic()
            events = _stream_until_error(url, token, cut)
            assert [k for k, _ in events] == ["board", "error"], events
            assert events[0][1]["standings"]["rows"][0]["alias"] == "bob"
            assert events[1][1]["status"] == 401 and time.monotonic() - t0 < 5  # not the 10 s refresh
    finally:
        server.stop()
