"""A club's race in a real browser (Debian's chromium driven by Playwright), against a real server and workers.

The admin creates a race and invites two racers; ana accepts in the browser and submits from the upload form, bob
accepts and submits from the command line; each watches the status change and the leaderboard update live;
ana downloads her simtrace, metrics and video, and cannot open bob's submission or files. A worker process
evaluates, as `league serve --workers 1` starts it.
With RACERLAB_SCREENSHOTS=DIR the pages are saved there as league-*.png (docs/img holds the ones in
docs/league.md). Skipped, with the reason, where chromium or Playwright is missing.
"""

from __future__ import annotations

import json
import os
import re
from pathlib import Path

import pytest

from racerlab.cli import main
from racerlab.league import start_workers
from tests.console.test_browser import browser  # noqa: F401 - the shared chromium fixture
from tests.league.conftest import PASSWORD, features_model
from tests.league.web_fixtures import LiveServer, app_for, model_archive

WAIT_MS = 300_000  # an evaluation on this shared machine, the first conversion's start included


def shot(page, name: str, full_page: bool = True) -> None:
    folder = os.environ.get("RACERLAB_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        page.wait_for_timeout(1800)  # a changed row's highlight fades first
        page.screenshot(path=str(Path(folder) / f"league-{name}.png"), full_page=full_page)


@pytest.fixture
def club(league, tmp_path, monkeypatch):
    monkeypatch.setenv("RACERLAB_CONFIG_HOME", str(tmp_path / "config"))
    server = LiveServer(app_for(league))
    workers = start_workers(league.store.folder, workers=1)  # a real worker process, as `serve --workers 1`
    yield server
    workers.stop()
    server.stop()


def _login(page, url, alias, password=PASSWORD):
    page.goto(f"{url}/login")
    page.fill("#alias", alias)
    page.fill("#password", password)
    page.click("#login")
    page.wait_for_url(f"{url}/")


def _create_race(page, url, straight):
    page.click("#new-race")
    page.wait_for_url(f"{url}/admin/races/new")
    page.fill("#name", "spring-cup")
    page.fill("#description", "Club race, round 1: one lap, fastest lap wins")
    page.set_input_files("#track_file", str(straight))
    page.fill("#laps", "1")
    page.fill("#time_cap_s", "30")
    page.fill("#max_submissions", "5")
    shot(page, "new-race")
    page.click("#create-race")
    page.wait_for_url(f"{url}/races/spring-cup")


def _invite(page, url, alias) -> tuple[str, str]:
    page.goto(f"{url}/admin/people")
    page.fill("#invite-alias", alias)
    page.click("#invite-create")
    page.locator("#invite").wait_for()
    return page.locator("#invite-url").text_content(), page.locator("#invite-code").text_content()


def _submit_from_the_form(page, url, archive) -> int:
    page.goto(f"{url}/races/spring-cup")
    page.set_input_files("#model-file", str(archive))
    page.fill("#model-name", "ana <fast> one")
    with page.expect_navigation(url=re.compile(r".*/submissions/\d+$"), timeout=WAIT_MS):
        page.click("#submit-model", no_wait_after=True)  # the upload is converted before the page answers
    return int(page.url.rsplit("/", 1)[1])


def test_a_club_race_from_invites_to_the_leaderboard(browser, club, league, straight, tmp_path):  # noqa: F811
    url = club.url
    admin = browser.new_context(viewport={"width": 1280, "height": 900})
    ana_ctx = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    bob_ctx = browser.new_context(viewport={"width": 1280, "height": 900})
    try:
        page = admin.new_page()
        _login(page, url, "admin")
        page.locator("#no-races").wait_for()
        _create_race(page, url, straight)
        rules_hash = page.locator("#rules-hash").text_content()
        assert rules_hash == league.race(league.local_admin(), "spring-cup").rules_hash
        ana_link, _ = _invite(page, url, "ana")
        _, bob_code = _invite(page, url, "bob")
        shot(page, "people")

        # ana accepts in the browser and submits from the form
        ana = ana_ctx.new_page()
        ana.goto(ana_link)
        ana.fill("#password", PASSWORD)
        ana.fill("#password2", PASSWORD)
        ana.click("#accept")
        ana.wait_for_url(f"{url}/")
        assert ana.locator("#me").text_content() == "ana"
        ana_sid = _submit_from_the_form(ana, url, model_archive(tmp_path, straight, seed=1, name="ana-model"))
        assert ana.locator("#status").text_content() in ("queued", "under evaluation", "ranked")
        ana.locator("#status", has_text="ranked").wait_for(timeout=WAIT_MS)  # the page follows the status
        assert ana.locator("#laps tbody tr").count() == 1 and "lap complete" in ana.locator("#laps").text_content()
        shot(ana, "submission")

        # bob accepts and submits from the command line, and watches the board in the browser
        password = tmp_path / "bob-password"
        password.write_text(PASSWORD)
        assert main(["league", "login", url, "--invite", bob_code, "--password-file", str(password)]) == 0
        bob = bob_ctx.new_page()
        _login(bob, url, "bob")
        bob.goto(f"{url}/races/spring-cup")
        bob.wait_for_function("() => document.body.dataset.boardVersion !== undefined")
        bob.evaluate("window.__stayed = true")
        assert bob.locator('#leaderboard tr[data-alias="ana"] td').first.text_content() == "1"
        fast = features_model(tmp_path / "bob-model", straight, ((0.0, 1.3),), seed=2).path
        assert main(["league", "submit", str(fast), "spring-cup"]) == 0
        bob.locator('#mine tbody tr[data-status="queued"], #mine tbody tr[data-status="evaluating"], '
                    '#mine tbody tr[data-status="ranked"]').first.wait_for(timeout=WAIT_MS)
        bob.wait_for_function("""() => {
          const row = document.querySelector('#leaderboard tr[data-alias="bob"]');
          return row && row.cells[0].textContent === '1';
        }""", timeout=WAIT_MS)  # bob's faster lap takes the lead without a reload
        assert bob.evaluate("window.__stayed") is True
        assert bob.locator('#leaderboard tr[data-alias="ana"] td').first.text_content() == "2"
        gap = bob.locator('#leaderboard tr[data-alias="ana"] td').nth(3).text_content()
        assert re.fullmatch(r"\+\d+\.\d{3}", gap)
        bob_sid = league.submissions(league.local_admin(), "spring-cup", everyone=True)[0].id
        shot(bob, "race")

        # ana downloads her own evaluation's files
        ana.goto(f"{url}/submissions/{ana_sid}")
        with ana.expect_download() as dl:
            ana.click('a[data-kind="simtrace"]')
        assert Path(dl.value.path()).read_text().startswith("episode,steps,X,Y")
        with ana.expect_download() as dl:
            ana.click('a[data-kind="metrics"]')
        tags = json.loads(Path(dl.value.path()).read_text())["league"]
        assert tags["rules_hash"] == rules_hash and len(tags["model_hash"]) == 64
        ana.wait_for_function("() => document.querySelector('#video').readyState >= 1", timeout=60_000)
        assert ana.evaluate("document.querySelector('#video').videoWidth") > 0
        # ... and cannot open bob's
        answer = ana.goto(f"{url}/submissions/{bob_sid}")
        assert answer.status == 404 and f"no submission {bob_sid} of yours" in ana.locator("#error").text_content()
        assert ana.request.get(f"{url}/api/submissions/{bob_sid}/files/simtrace").status == 404
        assert ana.request.get(f"{url}/api/submissions/{bob_sid}").status == 404

        # the admin sees every result and exports the standings
        page.goto(f"{url}/submissions?everyone=true")
        assert page.locator("#submissions tbody tr").count() == 2
        page.goto(f"{url}/races/spring-cup")
        with page.expect_download() as dl:
            page.click("#export-csv")
        rows = Path(dl.value.path()).read_text().splitlines()
        assert [r.split(",")[1] for r in rows[1:]] == ["bob", "ana"]
        page.goto(f"{url}/")
        shot(page, "races")
    finally:
        for ctx in (admin, ana_ctx, bob_ctx):
            ctx.close()


def test_strangers_text_stays_text_in_the_browser(browser, club, league, straight):  # noqa: F811
    admin = league.local_admin()
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "video": False,
                                      "description": '<img src=y onerror="window.__pwned=1">'})
    page = browser.new_page()
    try:
        _login(page, club.url, "admin")
        page.goto(f"{club.url}/races/cup")
        assert page.locator(".description").text_content() == '<img src=y onerror="window.__pwned=1">'
        assert page.evaluate("window.__pwned") is None and page.locator(".description img").count() == 0
    finally:
        page.close()


RACE_DAY = (("ana", 1.0, 0.0), ("bob", 1.4, 0.0), ("chen", 0.8, 0.0), ("dara", 1.2, 0.0), ("eli", 0.6, 2.0),
            ("fran", 0.5, 30.0))  # (racer, speed m/s, steering °): fran completes one lap of the two needed


@pytest.mark.skipif(not os.environ.get("RACERLAB_SCREENSHOTS"), reason="pictures for docs/league.md only: set "
                    "RACERLAB_SCREENSHOTS=docs/img")
def test_race_day_pictures_for_the_docs(browser, club, league, tmp_path):  # noqa: F811
    import time

    from tests.conftest import aws_track_path
    from tests.league.conftest import racer

    wide = aws_track_path("reInvent2019_wide")
    admin = league.local_admin()
    league.create_race(admin, "spring-cup", {"track": str(wide), "laps": 2, "min_laps": 2, "video": False,
                                             "max_submissions": 10, "closes": "+7d",
                                             "description": "Club race, round 1: the fastest lap of a two-lap run"})
    subs = []
    for k, (alias, speed, steer) in enumerate(RACE_DAY):
        actor = racer(league, admin, alias)
        model = features_model(tmp_path / f"{alias}-model", wide, ((steer, speed),), seed=k)
        subs.append(league.submit(actor, "spring-cup", model.path).id)
    end = time.monotonic() + 600
    while any(league.submission(admin, s).status in ("queued", "evaluating") for s in subs):
        assert time.monotonic() < end
        time.sleep(0.5)
    page = browser.new_page(viewport={"width": 1280, "height": 860})
    try:
        _login(page, club.url, "ana")
        page.goto(f"{club.url}/races/spring-cup")
        page.wait_for_function("() => document.body.dataset.boardVersion !== undefined")
        shot(page, "race")
        page.goto(f"{club.url}/")
        shot(page, "races")
        page.goto(f"{club.url}/submissions/{subs[0]}")
        shot(page, "laps")
        page.click("#logout")
        _login(page, club.url, "admin")
        _invite(page, club.url, "gabi")
        shot(page, "people")
        page.goto(f"{club.url}/admin/audit")
        shot(page, "audit", full_page=False)
    finally:
        page.close()
