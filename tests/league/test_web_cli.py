"""`racerlab league serve | login | submit | status | standings`: the command line over HTTP, against a real
server; the stored token; what a model folder's upload holds; TLS."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import tarfile
import threading
import time

import pytest

from racerlab.cli import main
from racerlab.league.client import Client, pack_model, server_url
from racerlab.league.store import LeagueError
from tests.league.conftest import PASSWORD, features_model, racer
from tests.league.web_fixtures import STRAIGHT_AHEAD, LiveServer, app_for, evaluate_queue


@pytest.fixture(autouse=True)
def config_home(tmp_path, monkeypatch):
    home = tmp_path / "config"
    monkeypatch.setenv("RACERLAB_CONFIG_HOME", str(home))
    return home


@pytest.fixture
def server(league, admin, straight):
    league.create_race(admin, "may cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    srv = LiveServer(app_for(league))
    yield srv
    srv.stop()


@pytest.fixture
def password_file(tmp_path):
    path = tmp_path / "password"
    path.write_text(PASSWORD + "\n")
    return path


def _login(server, league, admin, password_file, alias="ana"):
    code = league.invite(admin, alias).code
    assert main(["league", "login", server.url, "--invite", code, "--password-file", str(password_file)]) == 0


def test_login_with_an_invite_stores_the_token_for_its_owner_only(server, league, admin, password_file,
                                                                   config_home, capsys):
    _login(server, league, admin, password_file)
    out = capsys.readouterr().out
    assert f"logged in to {server.url} as ana (racer)" in out
    path = config_home / "league.json"
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and stat.S_IMODE(config_home.stat().st_mode) == 0o700
    cfg = json.loads(path.read_text())
    assert cfg["default"] == server.url and cfg["servers"][server.url]["alias"] == "ana"
    token = cfg["servers"][server.url]["token"]
    assert token.startswith("rla_") and PASSWORD not in path.read_text()
    assert league.actor_for_token(token).alias == "ana"
    # later logins with the password work too, and a wrong one is one line from the server
    assert main(["league", "login", server.url, "--alias", "ana", "--password-file", str(password_file)]) == 0
    bad = password_file.parent / "bad"
    bad.write_text("not the password\n")
    assert main(["league", "login", server.url, "--alias", "ana", "--password-file", str(bad)]) == 2
    assert capsys.readouterr().err.strip().endswith(f"{server.url}: wrong alias or password")


def test_submit_status_and_standings_from_the_command_line(server, league, admin, straight, password_file,
                                                            tmp_path, capsys):
    _login(server, league, admin, password_file)
    model = features_model(tmp_path / "ana-model", straight, STRAIGHT_AHEAD, seed=3).path
    capsys.readouterr()
    assert main(["league", "submit", str(model), "may cup"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("may cup #1 (id 1, ana-model, model ") and "queued: #1 in the queue" in out
    assert main(["league", "submit", str(model), "may cup"]) == 0
    assert "the same model always scores the same" in capsys.readouterr().out
    evaluate_queue(league)
    assert main(["league", "status", "--json"]) == 0
    subs = json.loads(capsys.readouterr().out)["submissions"]
    assert [(s["race"], s["status"]) for s in subs] == [("may cup", "ranked")]
    score = subs[0]["score_ms"] / 1000
    assert main(["league", "standings", "may cup"]) == 0
    table = capsys.readouterr().out.splitlines()
    assert table[0].startswith("may cup: best lap, open") and table[2].split()[:3] == ["1", "ana", f"{score:.3f}"]
    assert main(["league", "standings", "may cup", "--csv"]) == 0
    assert capsys.readouterr().out.splitlines()[1].startswith("1,ana,")
    out_file = tmp_path / "final.json"
    assert main(["league", "standings", "may cup", "--json", "-o", str(out_file)]) == 0
    assert json.loads(out_file.read_text())["rows"][0]["submission_id"] == 1


def test_submit_wait_follows_the_status_until_the_result(server, league, admin, straight, password_file, tmp_path,
                                                         capsys):
    _login(server, league, admin, password_file)
    model = features_model(tmp_path / "m", straight, STRAIGHT_AHEAD, seed=4).path

    def worker():
        end = time.monotonic() + 300
        while time.monotonic() < end and not evaluate_queue(league):
            time.sleep(0.2)

    t = threading.Thread(target=worker)
    capsys.readouterr()
    t.start()
    assert main(["league", "submit", str(model), "may cup", "--wait"]) == 0
    t.join()
    lines = capsys.readouterr().out.splitlines()
    assert "queued" in lines[0] and "ranked" in lines[-1] and "best lap" in lines[-1]


def test_a_folder_is_packed_with_its_chosen_checkpoint_and_without_its_reward(tmp_path, straight):
    from racerlab.model import ModelFolder, TrainingState

    folder = features_model(tmp_path / "m", straight, seed=1, iteration=1)
    other = features_model(tmp_path / "n", straight, seed=2, iteration=2)
    state = other.load_state(other.resolve_checkpoint(2))
    ModelFolder(folder.path).save_state(TrainingState(state.agent, state.metadata, iteration=2, train_steps=200))
    (folder.path / "evaluation-x").mkdir()
    (folder.path / "evaluation-x" / "evaluation.mp4").write_bytes(b"\0" * 1000)
    with pack_model(folder.path, "best") as (archive, chosen):
        names = sorted(tarfile.open(archive).getnames())
    assert chosen == "1"  # the index names iteration 1 the best
    assert names == ["m/checkpoints/.coach_checkpoint", "m/checkpoints/1_Step-100.pt",
                     "m/checkpoints/deepracer_checkpoints.json", "m/model_metadata.json", "m/training.toml"]
    with pack_model(folder.path, "last") as (archive, chosen):
        assert chosen == "2" and "m/checkpoints/2_Step-200.pt" in tarfile.open(archive).getnames()
    with pytest.raises(LeagueError, match="no checkpoint for iteration 9"):
        with pack_model(folder.path, "9"):
            pass


def test_addresses_and_unreachable_servers_are_one_line(tmp_path):
    assert server_url("https://league.example.org/") == "https://league.example.org"
    with pytest.raises(LeagueError, match="plain http to another machine"):
        server_url("http://192.168.1.5:8000")
    with pytest.raises(LeagueError, match="without a path"):
        server_url("https://league.example.org/races")
    with pytest.raises(LeagueError, match="cannot reach the league server"):
        Client("http://127.0.0.1:9").races()
    with pytest.raises(LeagueError, match="not logged in; run `racerlab league login URL"):
        Client.stored()


def test_serve_refuses_the_network_without_tls(tmp_path, capsys):
    assert main(["league", "serve", str(tmp_path), "--host", "0.0.0.0"]) == 2
    assert "a league on the network needs TLS" in capsys.readouterr().err
    assert main(["league", "serve", str(tmp_path), "--tls-cert", str(tmp_path / "c.pem")]) == 2
    assert "needs both --tls-cert FILE and --tls-key FILE" in capsys.readouterr().err


@pytest.mark.skipif(not os.path.exists("/usr/bin/openssl"), reason="no openssl to make a certificate")
def test_serve_over_tls_with_the_clubs_own_certificate(league, admin, password_file, tmp_path):
    import socket

    cert, key = tmp_path / "cert.pem", tmp_path / "key.pem"
    subprocess.run(["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out",
                    str(cert), "-days", "2", "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost"],
                   check=True, capture_output=True, timeout=120)
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    code = league.invite(admin, "ana").code
    env = {**os.environ, "PYTHONPATH": os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(["python", "-m", "racerlab", "league", "serve", str(league.store.folder), "--port",
                             str(port), "--tls-cert", str(cert), "--tls-key", str(key)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        assert f"open https://127.0.0.1:{port}/" in proc.stdout.readline()
        url = f"https://localhost:{port}"
        _wait_up(url, cert)
        assert main(["league", "login", url, "--invite", code, "--password-file", str(password_file),
                     "--ca-cert", str(cert)]) == 0
        assert Client.stored(url).me()["alias"] == "ana"
    finally:
        proc.terminate()
        proc.wait(30)
        proc.stdout.close()


def _wait_up(url, cert):
    import httpx

    end = time.monotonic() + 60
    while True:
        try:
            httpx.get(f"{url}/api/health", verify=str(cert) if cert else True, timeout=5)
            return
        except httpx.HTTPError:
            if time.monotonic() > end:
                raise
            time.sleep(0.2)


def test_a_racer_cannot_read_anothers_results_from_the_command_line(server, league, admin, straight,
                                                                     password_file, tmp_path, capsys):
    bob = racer(league, admin, "bob")
    league.submit(bob, "may cup", features_model(tmp_path / "b", straight, STRAIGHT_AHEAD, seed=8).path)
    _login(server, league, admin, password_file, "ana")
    capsys.readouterr()
    assert main(["league", "status"]) == 0
    assert capsys.readouterr().out.strip() == "no submissions yet"
    with pytest.raises(LeagueError, match="no submission 1 of yours"):
        Client.stored().submission(1)


def test_serve_with_workers_evaluates_what_the_command_line_submits(league, admin, straight, password_file,
                                                                     tmp_path, capsys):
    """The whole path a club uses: `league serve DIR --workers 1`, then login, submit --wait and standings."""
    import socket

    league.create_race(admin, "cup", {"track": str(straight), "laps": 1, "time_cap_s": 30, "video": False})
    code = league.invite(admin, "ana").code
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(["python", "-m", "racerlab", "league", "serve", str(league.store.folder), "--port",
                             str(port), "--workers", "1"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        assert "(1 local evaluation worker; Ctrl-C stops the server)" in proc.stdout.readline()
        url = f"http://127.0.0.1:{port}"
        _wait_up(url, None)
        assert main(["league", "login", url, "--invite", code, "--password-file", str(password_file)]) == 0
        model = features_model(tmp_path / "m", straight, STRAIGHT_AHEAD, seed=9).path
        assert main(["league", "submit", str(model), "cup", "--wait", "--json"]) == 0
        out = capsys.readouterr().out
        sub = json.loads(out[out.index("{"):])
        assert sub["status"] == "ranked" and sub["laps"][0]["completed"]
        assert main(["league", "standings", "cup", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["rows"][0]["alias"] == "ana"
        pids = [w.pid for w in _workers_seen(league)]
        assert len(pids) == 1
    finally:
        proc.terminate()  # SIGTERM, as a service manager stops it: the workers stop with the server
        proc.wait(120)
        proc.stdout.close()
    assert proc.returncode == 0
    assert not any(_alive(pid) for pid in pids)


def test_a_server_killed_with_9_leaves_no_worker_behind(league, admin):
    """SIGKILL gives the server no time to stop its workers: they see their parent gone and stop themselves."""
    import signal
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    proc = subprocess.Popen(["python", "-m", "racerlab", "league", "serve", str(league.store.folder), "--port",
                             str(port), "--workers", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    try:
        end = time.monotonic() + 120
        while len(pids := [w.pid for w in _workers_seen(league)]) < 2 and time.monotonic() < end:
            time.sleep(0.5)
        assert len(pids) == 2, "the server's workers did not start"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(30)
    end = time.monotonic() + 30
    while any(_alive(pid) for pid in pids) and time.monotonic() < end:
        time.sleep(0.2)
    assert not any(_alive(pid) for pid in pids)
    assert {w.state for w in _workers_seen(league)} == {"stopped"}


def _workers_seen(league):
    from sqlalchemy import select

    from racerlab.league.tables import Worker

    with league.store.read() as s:
        return s.scalars(select(Worker)).all()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def test_the_readmes_league_lines_parse_with_the_real_parser():
    import shlex
    from pathlib import Path

    from racerlab.cli import build_parser

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    start = text.index("```bash\n", text.index("## Run a league")) + len("```bash\n")
    lines = [shlex.split(line, comments=True) for line in text[start:text.index("```", start)].splitlines()]
    commands = [line[1:] for line in lines if line]
    assert [c[1] for c in commands] == ["init", "race", "invite", "serve", "login", "submit", "standings"]
    for argv in commands:
        build_parser().parse_args(argv)  # a wrong flag exits here
