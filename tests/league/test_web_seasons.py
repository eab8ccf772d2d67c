"""Seasons and finals on the web: staff make a season with the forms, everyone reads its standings (escaped), a
racer's form is refused, and a final started from the race page runs in the background and shows its order."""

from __future__ import annotations

import time

from tests.league.conftest import PASSWORD
from tests.league.test_seasons import dash, done_final, season  # noqa: F401 - fixtures used by the tests below
from tests.league.web_fixtures import app_for, bearer, browser_login, client_for


def test_staff_make_a_season_with_the_forms_and_racers_read_it(league, admin, season):  # noqa: F811
    web = client_for(app_for(league))
    csrf = browser_login(web, "admin", PASSWORD)
    r = web.post("/admin/seasons", data={"csrf": csrf, "name": "summer", "points": "10,6,3",
                                         "description": "<script>alert(1)</script>"})
    assert r.status_code == 303 and r.headers["location"] == "/seasons/summer"
    r = web.post("/seasons/summer/races", data={"csrf": csrf, "race": "r1"})
    assert "already in season" in web.get(r.headers["location"]).text  # a race counts in one season
    for race in ("r1", "r2"):
        web.post("/seasons/spring/races", data={"csrf": csrf, "race": race, "action": "remove"})
        assert web.post("/seasons/summer/races", data={"csrf": csrf, "race": race}).status_code == 303
    assert league.season(admin, "spring").races == ["r3"]
    r = web.post("/seasons/summer/races", data={"csrf": csrf, "race": "nope"})
    assert r.status_code == 303  # back to the season with the one-line reason
    assert "no race named" in web.get("/seasons/summer").text
    racer = client_for(app_for(league))
    rcsrf = browser_login(racer, "dee", PASSWORD)
    html = racer.get("/seasons/summer").text
    assert "<script>alert(1)</script>" not in html and "&lt;script&gt;alert(1)&lt;/script&gt;" in html
    # r1: ana 10, bob 6, cyd 3; r2: bob 10, dee 6, ana 3 -> bob 16, ana 13, dee 6, cyd 3
    rows = [(r["alias"], r["points"]) for r in racer.get("/api/seasons/summer", headers=bearer(racer, "dee")).json()
            ["rows"]]
    assert rows == [("bob", 16), ("ana", 13), ("dee", 6), ("cyd", 3)]
    assert html.index('data-alias="bob"') < html.index('data-alias="ana"') < html.index('data-alias="dee"')
    assert racer.post("/admin/seasons", data={"csrf": rcsrf, "name": "mine"}).status_code == 403
    assert racer.post("/seasons/summer/points", data={"csrf": rcsrf, "points": "1"}).status_code == 403
    assert "Seasons" in racer.get("/seasons").text and "summer" in racer.get("/seasons").text


def test_a_final_page_shows_the_order_and_only_a_racers_own_files(league, admin, season):  # noqa: F811
    fid = done_final(league, "r1", "ana")
    web = client_for(app_for(league))
    browser_login(web, "bob", PASSWORD)
    html = web.get(f"/finals/{fid}").text
    assert 'data-alias="ana"' in html and "0:09.500" in html and f"/finals/{fid}/files/1/simtrace" not in html
    assert web.get(f"/finals/{fid}/files/1/simtrace").status_code == 404
    assert f"/finals/{fid}" in web.get("/races/r1").text
    mine = client_for(app_for(league))
    browser_login(mine, "ana", PASSWORD)
    assert mine.get(f"/finals/{fid}/files/1/simtrace").status_code == 200


def test_a_final_started_from_the_race_page_runs_and_its_result_shows(league, admin, dash):  # noqa: F811
    web = client_for(app_for(league))
    csrf = browser_login(web, "admin", PASSWORD)
    assert 'id="start-final"' in web.get("/races/dash").text
    r = web.post("/races/dash/final", data={"csrf": csrf})
    assert r.status_code == 303 and r.headers["location"].startswith("/finals/")
    fid = int(r.headers["location"].rsplit("/", 1)[1])
    headers = bearer(web, "admin")
    end = time.monotonic() + 300
    while (view := web.get(f"/api/finals/{fid}", headers=headers).json())["status"] == "running":
        assert time.monotonic() < end, "the final did not finish in 300 s"
        time.sleep(0.5)
    assert view["status"] == "done", view["reason"]
    assert [c["alias"] for c in view["order"]] == ["ana", "bob"]
    html = web.get(f"/finals/{fid}").text
    assert html.index('data-alias="ana"') < html.index('data-alias="bob"') and "lap 2:" in html
    racer = client_for(app_for(league))
    rcsrf = browser_login(racer, "cyd", PASSWORD)
    assert 'id="start-final"' not in racer.get("/races/dash").text
    assert racer.post("/races/dash/final", data={"csrf": rcsrf}).status_code == 403
