"""The league's web side over HTTP: logging in, cookies and CSRF, API tokens, uploads and their limits, what each
racer may read, escaping, the exports, the live board."""

from __future__ import annotations

import json
import re

import pytest

from tests.league.conftest import PASSWORD, racer
from tests.league.web_fixtures import (
    LiveServer,
    app_for,
    bearer,
    browser_login,
    client_for,
    evaluate_queue,
    model_archive,
    pre_csrf,
)


@pytest.fixture
def cup(league, admin, straight):
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False,
                                      "max_submissions": 3})
    return "cup"


@pytest.fixture
def web(league):
    return client_for(app_for(league))


# ---- people ---------------------------------------------------------------------------------------------------
def test_a_stranger_is_sent_to_the_login_page_and_the_api_says_401(web):
    r = web.get("/races/cup")
    assert r.status_code == 303 and r.headers["location"] == "/login?next=%2Fraces%2Fcup"
    r = web.get("/api/races")
    assert r.status_code == 401 and r.json() == {"error": "not logged in; log in first"}


def test_login_sets_an_http_only_samesite_session_cookie(web, league):
    r = web.post("/login", data={"csrf": pre_csrf(web), "alias": "admin", "password": PASSWORD,
                                 "next": "/races/cup"})
    assert r.status_code == 303 and r.headers["location"] == "/races/cup"
    cookie = r.headers["set-cookie"]
    assert cookie.startswith("racerlab_league=rls_") and "HttpOnly" in cookie and "SameSite=lax" in cookie
    assert "Secure" not in cookie  # plain http on the loopback
    assert web.get("/").status_code == 200


def test_under_tls_the_cookie_is_secure_and_hsts_is_sent(league):
    web = client_for(app_for(league, tls=True), "https://127.0.0.1")
    r = web.post("/login", data={"csrf": pre_csrf(web), "alias": "admin", "password": PASSWORD})
    assert "Secure" in r.headers["set-cookie"]
    assert r.headers["strict-transport-security"] == "max-age=31536000"


def test_a_login_form_without_its_pre_session_token_is_refused(web):
    r = web.post("/login", data={"alias": "admin", "password": PASSWORD})
    assert r.status_code == 403 and "reload the page" in r.text
    web.get("/login")  # the pre cookie, but a token made for another browser
    r = web.post("/login", data={"csrf": "0" * 64, "alias": "admin", "password": PASSWORD})
    assert r.status_code == 403


def test_a_wrong_password_is_shown_on_the_form_and_throttled_after_five(web):
    for _ in range(5):
        r = web.post("/login", data={"csrf": pre_csrf(web), "alias": "admin", "password": "not the password"})
        assert r.status_code == 401 and "wrong alias or password" in r.text
    r = web.post("/login", data={"csrf": pre_csrf(web), "alias": "admin", "password": PASSWORD})
    assert r.status_code == 429 and "too many failed logins (5 in 15 minutes)" in r.text


def test_the_next_page_after_login_stays_on_this_site(web):
    r = web.post("/login", data={"csrf": pre_csrf(web), "alias": "admin", "password": PASSWORD,
                                 "next": "//evil.example/x"})
    assert r.headers["location"] == "/"


def test_every_state_change_on_a_session_needs_its_csrf_token(web, league, cup):
    csrf = browser_login(web, "admin")
    assert web.post("/api/invites", json={"alias": "ana"}).status_code == 403
    assert web.post("/api/invites", json={"alias": "ana"}, headers={"X-CSRF-Token": "f" * 64}).status_code == 403
    assert web.post("/admin/invites", data={"alias": "ana"}).status_code == 403
    r = web.post("/admin/invites", data={"alias": "ana", "csrf": csrf})
    assert r.status_code == 200 and "/invite?code=rli_" in r.text
    r = web.post("/api/invites", json={"alias": "bob"}, headers={"X-CSRF-Token": csrf})
    assert r.status_code == 201 and r.json()["url"].startswith("http://127.0.0.1/invite?code=rli_")


def test_a_request_from_another_site_is_refused_even_with_the_token(web):
    csrf = browser_login(web, "admin")
    r = web.post("/api/invites", json={"alias": "ana"}, headers={"X-CSRF-Token": csrf,
                                                                  "Origin": "https://evil.example"})
    assert r.status_code == 403 and "another site" in r.text


def test_a_page_whose_dns_name_rebinds_to_the_loopback_is_refused(web):
    r = web.get("/login", headers={"Host": "evil.example"})
    assert r.status_code == 421


def test_an_api_token_needs_no_csrf_and_a_wrong_one_is_401(web, league, admin):
    headers = bearer(web, "admin")
    r = web.post("/api/invites", json={"alias": "ana", "role": "facilitator"}, headers=headers)
    assert r.status_code == 201 and r.json()["role"] == "facilitator"
    r = web.get("/api/races", headers={"Authorization": "Bearer rla_forged"})
    assert r.status_code == 401 and "unknown, revoked or expired" in r.json()["error"]
    assert web.get("/api/races", headers={"Authorization": "Basic YWRtaW4="}).status_code == 401


def test_accepting_an_invite_on_its_page_logs_the_racer_in_once(web, league, admin):
    code = league.invite(admin, "ana").code
    page = web.get(f"/invite?code={code}")
    assert page.status_code == 200 and f'value="{code}"' in page.text
    form = {"csrf": pre_csrf(web, f"/invite?code={code}"), "code": code, "password": PASSWORD,
            "password2": PASSWORD}
    r = web.post("/invite", data=form)
    assert r.status_code == 303 and "racerlab_league=rls_" in r.headers["set-cookie"]
    assert web.get("/api/me").json()["alias"] == "ana"
    other = client_for(web.app)
    form["csrf"] = pre_csrf(other, "/invite")
    again = other.post("/invite", data=form)
    assert again.status_code == 404 and "unknown, used or expired" in again.text


def test_open_sign_up_is_off_until_an_admin_turns_it_on(web, league, admin):
    assert web.get("/signup").status_code == 403
    league.set_open_signup(admin, True)
    form = {"csrf": pre_csrf(web, "/signup"), "alias": "walkup", "password": PASSWORD, "password2": PASSWORD}
    assert web.post("/signup", data=form).status_code == 303
    assert web.get("/api/me").json() == {"id": 2, "alias": "walkup", "role": "racer", "open_signup": True}


def test_logging_out_ends_the_session_on_the_server(web):
    csrf = browser_login(web, "admin")
    cookie = web.cookies.get("racerlab_league")
    assert web.post("/logout", data={"csrf": csrf}).headers["location"] == "/login"
    web.cookies.set("racerlab_league", cookie)  # a copy of the old cookie no longer works
    assert web.get("/api/me").status_code == 401


# ---- submissions ----------------------------------------------------------------------------------------------
def _upload(web, race, archive, headers=None, **fields):
    with open(archive, "rb") as f:
        return web.post(f"/api/races/{race}/submissions", data={"checkpoint": "best", **fields},
                        files={"model": (archive.name, f, "application/gzip")}, headers=headers or {})


def test_an_upload_is_queued_and_the_same_model_again_gets_its_earlier_result(web, league, admin, cup, straight,
                                                                              tmp_path):
    racer(league, admin, "ana")
    headers = bearer(web, "ana")
    archive = model_archive(tmp_path, straight, seed=1, name="fast-one")
    first = _upload(web, cup, archive, headers)
    assert first.status_code == 201
    sub = first.json()
    assert (sub["status"], sub["number"], sub["position"], sub["model_name"]) == ("queued", 1, 1, "fast-one")
    again = _upload(web, cup, archive, headers)
    assert again.status_code == 200 and again.json()["duplicate"] and again.json()["id"] == sub["id"]
    assert "the same model always scores the same" in again.json()["note"]
    assert not any((league.store.folder / "uploads").iterdir())  # nothing of the upload is left behind


def test_an_upload_over_the_limit_is_refused_before_its_body_is_read(league, admin, cup, straight, tmp_path):
    web = client_for(app_for(league, upload_limit=1000))
    headers = bearer(web, "admin")
    archive = model_archive(tmp_path, straight)
    r = _upload(web, cup, archive, headers)
    assert r.status_code == 413 and "more than the limit of 1000 bytes" in r.json()["error"]
    r = web.post(f"/api/races/{cup}/submissions", content=iter([b"x" * 10]), headers=headers)
    assert r.status_code == 411  # an upload must say its length
    with league.store.read() as s:
        from sqlalchemy import func, select

        from racerlab.league.tables import Submission

        assert s.scalar(select(func.count()).select_from(Submission)) == 0


def test_a_chunked_body_past_the_limit_is_cut_off(web, league):
    headers = bearer(web, "admin")
    chunks = (b'{"name": "' + b"x" * 65536 for _ in range(40))  # 2.6 MB, no Content-Length
    r = web.post("/api/races", content=chunks, headers={**headers, "Content-Type": "application/json"})
    assert r.status_code == 413 and "limit of 1048576 bytes" in r.json()["error"]


def test_an_upload_that_is_not_an_archive_is_one_line(web, league, admin, cup, tmp_path):
    headers = bearer(web, "admin")
    bad = tmp_path / "model.exe"
    bad.write_bytes(b"MZ")
    r = _upload(web, cup, bad, headers)
    assert r.status_code == 400 and r.json()["error"] == "model.exe: upload a model archive (.tar.gz, .tgz, .tar, .zip)"
    junk = tmp_path / "junk.tar.gz"
    junk.write_bytes(b"not a tar")
    r = _upload(web, cup, junk, headers)
    assert r.status_code == 400 and "\n" not in r.json()["error"] and r.json()["error"].startswith("junk.tar.gz")


def test_a_racer_reads_only_their_own_submissions_and_files(web, league, admin, cup, straight, tmp_path):
    racer(league, admin, "ana"), racer(league, admin, "bob"), racer(league, admin, "fay", "facilitator")
    ana, bob, fay = (bearer(web, a) for a in ("ana", "bob", "fay"))
    sid = _upload(web, cup, model_archive(tmp_path, straight, seed=2), ana).json()["id"]
    evaluate_queue(league)
    mine = web.get(f"/api/submissions/{sid}", headers=ana).json()
    assert mine["status"] == "ranked" and mine["laps"][0]["completed"] and "simtrace" in mine["files"]
    simtrace = web.get(f"/api/submissions/{sid}/files/simtrace", headers=ana)
    assert simtrace.status_code == 200 and simtrace.headers["content-type"].startswith("text/csv")
    assert simtrace.text.splitlines()[0].startswith("episode,steps,X,Y")
    assert "attachment" in simtrace.headers["content-disposition"]
    metrics = web.get(f"/api/submissions/{sid}/files/metrics", headers=ana).json()
    assert metrics["league"]["model_hash"] == mine["model_hash"]
    assert metrics["league"]["rules_hash"] == mine["rules_hash"]
    for path in (f"/api/submissions/{sid}", f"/api/submissions/{sid}/files/simtrace",
                 f"/api/submissions/{sid}/files/metrics"):
        r = web.get(path, headers=bob)
        assert r.status_code == 404 and r.json()["error"] == f"no submission {sid} of yours"
        assert web.get(path, headers=fay).status_code == 200
    assert web.get("/api/submissions", headers=bob).json() == {"submissions": []}
    assert web.get("/api/submissions?everyone=true", headers=bob).status_code == 403
    assert [s["alias"] for s in web.get("/api/submissions?everyone=true", headers=fay).json()["submissions"]] == [
        "ana"]


def test_the_submission_page_shows_its_laps_hashes_and_downloads(web, league, admin, cup, straight, tmp_path):
    racer(league, admin, "ana")
    headers = bearer(web, "ana")
    sid = _upload(web, cup, model_archive(tmp_path, straight, seed=3), headers).json()["id"]
    evaluate_queue(league)
    browser_login(web, "ana")
    page = web.get(f"/submissions/{sid}").text
    sub = league.submission(admin, sid)
    assert sub.model_hash in page and sub.rules_hash in page
    lap = re.search(r'<table id="laps">.*?</table>', page, re.S).group(0)
    assert "lap complete" in lap and f"0:{sub.laps[0]['lap_time']:06.3f}" in lap
    assert f'/api/submissions/{sid}/files/simtrace' in page and f'/api/submissions/{sid}/files/metrics' in page


# ---- races, escaping, exports ---------------------------------------------------------------------------------
def test_strangers_text_is_shown_as_text(web, league, admin, straight, tmp_path):
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "video": False,
                                      "description": '<img src=x onerror="alert(1)">'})
    racer(league, admin, "ana")
    headers = bearer(web, "ana")
    _upload(web, "cup", model_archive(tmp_path, straight), headers, name="<script>alert(2)</script>")
    browser_login(web, "ana")
    page = web.get("/races/cup").text
    assert '<img src=x onerror' not in page and "&lt;img src=x onerror=&#34;alert(1)&#34;&gt;" in page
    assert "<script>alert" not in page and "scriptalert2script" in page  # the service cleaned the name
    assert "script-src 'self'" in web.get("/races/cup").headers["content-security-policy"]


def test_the_csv_export_cannot_run_as_a_formula(web, league, admin, cup, straight, tmp_path):
    racer(league, admin, "-2-3")
    _upload(web, cup, model_archive(tmp_path, straight, seed=4), bearer(web, "-2-3"))
    evaluate_queue(league)
    r = web.get(f"/api/races/{cup}/standings.csv", headers=bearer(web, "admin"))
    assert r.headers["content-type"].startswith("text/csv")
    assert 'filename="cup-standings.csv"' in r.headers["content-disposition"]
    row = r.text.splitlines()[1].split(",")
    assert row[:2] == ["1", "'-2-3"]


def test_the_race_page_shows_the_rules_their_hash_and_the_tie_break(web, league, admin, cup):
    browser_login(web, "admin")
    page = web.get("/races/cup").text
    view = league.race(admin, "cup")
    assert view.rules_hash in page and view.summary in page
    assert "Ties go to the earlier submission" in page
    assert web.get("/races/cup/track.svg").text.startswith("<svg")
    assert web.get("/races/nope").status_code == 404


def test_a_facilitator_creates_a_race_from_the_form_with_an_uploaded_track(web, league, admin, straight):
    racer(league, admin, "fay", "facilitator")
    csrf = browser_login(web, "fay")
    fields = {"name": "june-cup", "timing": "average_lap", "laps": "3", "min_laps": "2", "race_type": "time_trial",
              "off_track_penalty": "2", "collision_penalty": "5", "max_resets": "100", "time_cap_s": "120",
              "car": "droa", "seed": "7", "max_submissions": "5", "closes": "2030-06-01T18:00", "tz": "-120"}
    with open(straight, "rb") as f:
        r = web.post(f"/admin/races?csrf={csrf}", data=fields, files={"track_file": ("Straight_track.npy", f)})
    assert r.status_code == 303, r.text
    race = league.race(admin, "june-cup")
    assert (race.rules["timing"], race.rules["min_laps"], race.rules["seed"], race.max_submissions) == (
        "average_lap", 2, 7, 5)
    assert race.rules["track"] == "Straight_track" and race.rules["video"] is False  # an unticked box is off
    assert race.to_json()["closes_at"] == "2030-06-01T16:00:00Z"  # 18:00 at UTC+2
    r = web.post(f"/admin/races?csrf={csrf}", data={**fields, "name": "bad", "laps": "2.5"})
    assert r.status_code == 400 and "laps must be a finite whole number in [1, 20], got &#39;2.5&#39;" in r.text


def test_a_track_from_the_web_is_a_known_name_never_a_server_path(web, league):
    headers = bearer(web, "admin")
    r = web.post("/api/races", json={"name": "x", "track": "/etc/passwd"}, headers=headers)
    assert r.status_code == 400 and "not a track this server knows" in r.json()["error"]
    r = web.post("/api/races", json={"name": "x", "track": "lab_oval", "laps": 1, "bogus": 1}, headers=headers)
    assert r.status_code == 400 and "'bogus' is not one of" in r.json()["error"]
    assert web.post("/api/races", json={"name": "x", "track": "lab_oval"}, headers=headers).status_code == 201


def test_an_open_race_changes_only_its_close_time_and_limit(web, league, cup):
    headers = bearer(web, "admin")
    r = web.patch(f"/api/races/{cup}", json={"max_submissions": 5, "closes": "+2h"}, headers=headers)
    assert r.status_code == 200 and r.json()["max_submissions"] == 5
    r = web.patch(f"/api/races/{cup}", json={"description": "new"}, headers=headers)
    assert r.status_code == 409 and "only its close time and submission limit" in r.json()["error"]
    r = web.patch(f"/api/races/{cup}", json={"laps": 5}, headers=headers)
    assert r.status_code == 400


def test_the_standings_json_export_is_the_service_standings(web, league, admin, cup, straight, tmp_path):
    racer(league, admin, "ana")
    _upload(web, cup, model_archive(tmp_path, straight, seed=5), bearer(web, "ana"))
    evaluate_queue(league)
    r = web.get(f"/api/races/{cup}/standings.json", headers=bearer(web, "ana"))
    assert "attachment" in r.headers["content-disposition"]
    body = r.json()
    expected = league.standings(admin, cup).to_json()
    assert body["rows"] == expected["rows"] and body["rules_hash"] == expected["rules_hash"]
    assert body["rows"][0]["rank"] == 1 and body["rows"][0]["gap_s"] == 0


def test_the_live_board_sends_the_standings_and_then_each_change(league, admin, cup, straight, tmp_path):
    import httpx

    server = LiveServer(app_for(league))
    try:
        ana = racer(league, admin, "ana")
        token = league.issue_token(ana, "api").token
        events = []
        with httpx.stream("GET", f"{server.url}/api/races/{cup}/events", timeout=60,
                          headers={"Authorization": f"Bearer {token}"}) as r:
            assert r.headers["content-type"].startswith("text/event-stream")
            for line in r.iter_lines():
                if line.startswith("data: "):
                    events.append(json.loads(line[6:]))
                    if len(events) == 1:
                        league.submit(ana, cup, model_archive(tmp_path, straight, seed=6))
                    elif len(events) == 2:
                        evaluate_queue(league)
                    elif events[-1]["mine"][0]["status"] == "ranked":
                        break
        assert events[0]["standings"]["rows"] == [] and events[0]["mine"] == []
        assert events[1]["mine"][0]["status"] == "queued" and events[1]["mine"][0]["position"] == 1
        last = events[-1]
        assert last["standings"]["rows"][0]["alias"] == "ana" and last["standings"]["rows"][0]["rank"] == 1
        assert last["race"]["submissions_used"] == 1
    finally:
        server.stop()
