"""Hostile input that the other league tests do not already hold (docs/league.md's table lists every case and its
test): archive bombs, special files in archives, absurd weights, SQL meta-characters in every field, replayed CSRF
tokens. Each is refused in one line, with nothing stored and nothing run."""

from __future__ import annotations

import io
import tarfile
import zipfile

import pytest
from sqlalchemy import func, select, text

from racerlab.league import LeagueError
from racerlab.league.convert import convert_upload
from racerlab.league.tables import Submission, Token, User
from tests.league.conftest import PASSWORD, features_model, racer
from tests.league.web_fixtures import app_for, bearer, browser_login, client_for, page_csrf

BOMB_BYTES = 64 << 20  # 64 MiB of one byte: ~64 kB packed, 64 times what a model_metadata.json may be


def _members(folder) -> dict[str, bytes]:
    return {p.relative_to(folder.path.parent).as_posix(): p.read_bytes()
            for p in sorted(folder.path.rglob("*")) if p.is_file()}


def _tar(path, members: dict[str, bytes], extra=()) -> None:
    with tarfile.open(path, "w:gz") as tar:
        for name, data in members.items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
        for info in extra:
            tar.addfile(info)


def _nothing_written(work) -> bool:
    return not any(p.name == "model_metadata.json" for p in work.rglob("*")) if work.exists() else True


@pytest.mark.parametrize("kind", ["tar.gz", "zip"])
def test_an_archive_bomb_is_refused_before_a_byte_of_it_is_unpacked(tmp_path, straight, kind):
    members = _members(features_model(tmp_path / "m", straight))
    members["m/model_metadata.json"] = b" " * BOMB_BYTES  # valid JSON padding, had it been read
    archive = tmp_path / f"bomb.{kind}"
    if kind == "zip":
        with zipfile.ZipFile(archive, "w", zipfile.ZIP_DEFLATED) as z:
            for name, data in members.items():
                z.writestr(name, data)
    else:
        _tar(archive, members)
    assert archive.stat().st_size < BOMB_BYTES / 100
    with pytest.raises(LeagueError, match=f"unpacks to {BOMB_BYTES} bytes") as err:
        convert_upload(archive, tmp_path / "work")
    assert "\n" not in str(err.value) and _nothing_written(tmp_path / "work")


@pytest.mark.parametrize("member", ["fifo", "char device", "block device", "hard link"])
def test_special_files_in_an_archive_are_refused(tmp_path, straight, member):
    types = {"fifo": tarfile.FIFOTYPE, "char device": tarfile.CHRTYPE, "block device": tarfile.BLKTYPE,
             "hard link": tarfile.LNKTYPE}
    special = tarfile.TarInfo("m/checkpoints/deepracer_checkpoints.json")
    special.type = types[member]
    special.linkname = "/etc/passwd" if member == "hard link" else ""
    members = _members(features_model(tmp_path / "m", straight))
    members.pop("m/checkpoints/deepracer_checkpoints.json")
    _tar(tmp_path / "special.tar.gz", members, [special])
    with pytest.raises(LeagueError, match="is a link or device, not a file") as err:
        convert_upload(tmp_path / "special.tar.gz", tmp_path / "work")
    assert "\n" not in str(err.value) and _nothing_written(tmp_path / "work")


def test_absurd_weights_are_refused(league, admin, straight, tmp_path):
    from racerlab.model import ModelFolder

    folder = features_model(tmp_path / "m", straight)
    state = folder.load_state(folder.resolve_checkpoint("best"))
    next(iter(state.agent["policy"].values())).view(-1)[0] = 1e30  # finite, and no network trains to it
    ModelFolder(folder.path).save_state(state)
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    ana = racer(league, admin, "ana")
    with pytest.raises(LeagueError, match="weights reach 1e\\+30") as err:
        league.submit(ana, "cup", folder.path)
    assert "\n" not in str(err.value)
    with league.store.read() as s:
        assert s.scalar(select(func.count()).select_from(Submission)) == 0
    assert not any((league.store.folder / "models").iterdir())


SQL = "x'); DROP TABLE users; --"


def test_sql_meta_characters_in_every_field_are_data(league, admin, straight):
    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    racer(league, admin, "ana")
    web = client_for(app_for(league))
    boss, ana = bearer(web, "admin"), bearer(web, "ana")
    answers = [
        web.post("/api/login", json={"alias": SQL, "password": SQL}).status_code,
        web.post("/api/login", json={"alias": "admin' OR '1'='1", "password": "' OR '1'='1"}).status_code,
        web.post("/api/invites", json={"alias": SQL}, headers=boss).status_code,
        web.post("/api/races", json={"name": SQL, "track": "lab_oval"}, headers=boss).status_code,
        web.get(f"/api/races/{SQL}/standings", headers=ana).status_code,
        web.get("/api/submissions", params={"race": SQL}, headers=ana).status_code,
        web.get("/api/submissions/1 OR 1=1", headers=ana).status_code,
        web.patch(f"/api/users/{SQL}", json={"active": False}, headers=boss).status_code,
        web.post("/api/invites/accept", json={"code": SQL, "password": PASSWORD}).status_code,
    ]
    assert answers == [401, 401, 400, 400, 404, 404, 404, 404, 404]
    r = web.post("/api/tokens", json={"label": SQL}, headers=ana)
    assert r.status_code == 201
    made = web.post("/api/races", json={"name": "quoted", "track": "lab_oval", "description": SQL}, headers=boss)
    assert made.status_code == 201, made.text
    assert web.get("/api/races/quoted", headers=ana).json()["description"] == SQL  # kept as text, verbatim
    with league.store.read() as s:
        assert s.scalar(select(func.count()).select_from(User)) == 2
        assert s.scalars(select(Token.label).where(Token.label == SQL)).all() == [SQL]
        assert s.execute(text("SELECT count(*) FROM users WHERE alias = 'ana'")).scalar() == 1


def test_a_replayed_csrf_token_is_refused(league, admin):
    racer(league, admin, "ana")
    racer(league, admin, "bob")
    ana_web, bob_web = client_for(app_for(league)), client_for(app_for(league))
    ana_csrf, bob_csrf = browser_login(ana_web, "ana"), browser_login(bob_web, "bob")
    token = {"label": "t"}
    assert bob_web.post("/api/tokens", json=token, headers={"X-CSRF-Token": ana_csrf}).status_code == 403
    assert bob_web.post("/api/tokens", json=token, headers={"X-CSRF-Token": bob_csrf}).status_code == 201
    assert ana_web.post("/logout", data={"csrf": ana_csrf}).status_code == 303
    fresh = browser_login(ana_web, "ana")  # a new session: the old session's token is dead with it
    assert fresh != ana_csrf and page_csrf(ana_web) == fresh
    assert ana_web.post("/api/tokens", json=token, headers={"X-CSRF-Token": ana_csrf}).status_code == 403
    assert ana_web.post("/api/tokens", json=token, headers={"X-CSRF-Token": fresh}).status_code == 201


def test_a_model_whose_sensors_do_not_fit_the_race_is_refused_before_it_drives_and_not_counted(league, admin,
                                                                                             straight, tmp_path):
    from racerlab.league import queue
    from racerlab.league.worker import evaluate_claim

    league.create_race(admin, "boxes", {"track": str(straight), "race_type": "object_avoidance", "obstacles": 2,
                                        "laps": 1, "time_cap_s": 30, "video": False, "max_submissions": 1})
    ana = racer(league, admin, "ana")
    league.submit(ana, "boxes", features_model(tmp_path / "m", straight).path)  # trained without boxes
    claim = queue.claim(league.store, "test-worker")
    status, reason, values = evaluate_claim(league.store, claim)
    assert status == "refused" and "reads 20 numbers and this race gives it 24" in reason and "\n" not in reason
    assert values == {} and not list(league.store.results_dir(claim.submission_id).rglob("*.csv"))  # no lap ran
    queue.finish(league.store, claim, status, reason, values)
    assert league.race(ana, "boxes").submissions_used == 0  # the racer's limit is untouched


def test_a_2_gb_upload_is_answered_413_before_one_byte_of_its_body_is_sent(league, admin, straight):
    import socket

    from tests.league.web_fixtures import LiveServer

    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    token = league.issue_token(admin, "api").token
    server = LiveServer(app_for(league))  # the default limit: 256 MiB
    try:
        host, port = server.url.removeprefix("http://").split(":")
        with socket.create_connection((host, int(port)), timeout=30) as sock:
            sock.sendall(f"POST /api/races/cup/submissions HTTP/1.1\r\nHost: {host}:{port}\r\n"
                         f"Authorization: Bearer {token}\r\nContent-Type: multipart/form-data; boundary=b\r\n"
                         f"Content-Length: {2 << 30}\r\n\r\n".encode())  # the headers alone; no body follows
            answer = b""
            while b"}" not in answer:  # the JSON body follows the headers
                chunk = sock.recv(65536)
                if not chunk:
                    break
                answer += chunk
        answer = answer.decode()
        assert answer.startswith("HTTP/1.1 413") and f"the upload is {2 << 30} bytes" in answer
    finally:
        server.stop()
    with league.store.read() as s:
        assert s.scalar(select(func.count()).select_from(Submission)) == 0
