"""`racerlab league serve DIR --ray ADDRESS` on a real local Ray cluster: a head and a second node on 127.0.0.1
(started and stopped as tests/cluster starts them; no Ray process is left), the server started as a user starts it
(a fresh process, a fresh HOME, no RAY_* variable but the one that keeps a test cluster on loopback).

The same model is evaluated by a local worker process and through Ray: the outcomes and the simtraces are the same
bit for bit (every column but the wall clock). A Ray worker killed with -9 mid-evaluation, or the whole node, hands
the submission back; evaluated again from the start, it ends with the same result as the undisturbed ones. A server
stopped mid-evaluation queues it again, uncounted. Ray missing and wrong flags are one line.
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from racerlab.cli import main
from racerlab.league import League
from racerlab.league.evaluation import PIN_ENV
from racerlab.league.worker import POLL_S, worker_main
from tests.league.conftest import PASSWORD, features_model, racer
from tests.league.test_queue import _wait

REPO = Path(__file__).resolve().parents[2]
ACTIONS = ((0.0, 1.0), (20.0, 1.0), (-20.0, 1.0))
TASK_TITLE = b"ray::league_evaluation"  # Ray names a worker process after the task it runs
FINAL = ("ranked", "not_ranked", "no_lap", "refused", "failed")
TIMING = ("eval_seconds", "eval_cpu_seconds")  # the one thing in an outcome that is the machine's


@pytest.fixture(scope="module")
def cluster():
    tc = _nodes()
    tmp = Path(tempfile.mkdtemp(prefix="rl", dir="/tmp"))
    port, saved = _free_port(), os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # as `ray start` on a fresh install: no token yet
    # the head runs no evaluation (as on a server that keeps its CPUs for the web pages): they all go to the node
    procs = [tc.start_node(["--head", f"--port={port}", "--include-dashboard=false"], tmp, cpus=0)]
    address = f"127.0.0.1:{port}"
    try:
        tc._wait_for_head(address, tmp)
        procs.append(tc.start_node([f"--address={address}"], tmp))
        yield {"address": address, "procs": procs, "tmp": tmp}
    finally:
        ray_pids = set().union(*(tc._descendants(p.pid) for p in procs))
        tc.stop_nodes(procs)
        shutil.rmtree(tmp, ignore_errors=True)
        if saved is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = saved
        assert tc.still_running(ray_pids, within_s=60) == []


def _nodes():
    """tests/cluster's node helpers (`start_node`, `stop_nodes`, /proc readers); the tests skip without Ray."""
    pytest.importorskip("ray")
    from tests.cluster import test_cluster

    return test_cluster


def _user_env(home: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    env.update(HOME=str(home), RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0",  # the test cluster's nodes serve on loopback
               PYTHONPATH=os.pathsep.join([str(REPO / "src"), env.get("PYTHONPATH", "")]))
    return env


def _one_job(folder: str) -> None:
    worker_main(folder, None, "local-reference", max_jobs=1, poll_s=0.1)


@pytest.fixture(scope="module")
def club(tmp_path_factory):
    """A league with one race and one model, evaluated once by a local worker process (the reference)."""
    from tests.conftest import aws_track_path

    root = tmp_path_factory.mktemp("ray-league")
    league, _ = League.create(root / "club", password=PASSWORD)
    admin = league.local_admin()
    wide = aws_track_path("reInvent2019_wide")
    league.create_race(admin, "wide", {"track": str(wide), "laps": 1, "time_cap_s": 60, "video": False,
                                       "off_track_penalty": 1.0})
    model = features_model(root / "m", wide, ACTIONS, seed=3).path
    local = league.submit(racer(league, admin, "local"), "wide", model)
    p = mp.get_context("spawn").Process(target=_one_job, args=(str(league.store.folder),))
    p.start()
    p.join(300)
    assert p.exitcode == 0
    (root / "home").mkdir()
    yield {"league": league, "admin": admin, "model": model, "local": league.submission(admin, local.id),
           "home": root / "home"}
    league.close()


def _serve(cluster, club, err_path: Path) -> tuple[subprocess.Popen, set[int]]:
    """`racerlab league serve DIR --ray ADDRESS` in a fresh process, up (its first line printed); what it prints goes
    to `err_path`. Also the PIDs of its children when it was up (none are expected to outlive it)."""
    with err_path.open("a") as err:
        proc = subprocess.Popen([sys.executable, "-m", "racerlab", "league", "serve",
                                 str(club["league"].store.folder), "--port", str(_free_port()), "--ray",
                                 cluster["address"]], cwd=club["home"], env=_user_env(club["home"]), stdout=err,
                                stderr=err)
    end = time.monotonic() + 120
    while "Ctrl-C stops the server" not in err_path.read_text() and proc.poll() is None and time.monotonic() < end:
        time.sleep(0.1)
    said = err_path.read_text()
    assert "evaluations on the Ray cluster at" in said and "one per CPU of the cluster" in said, said[-3000:]
    return proc, _nodes()._descendants(proc.pid) - {proc.pid}


def _stopped(proc: subprocess.Popen, children: set[int], err_path: Path) -> None:
    """SIGTERM, as a service manager stops a server: it ends with status 0, no traceback, no child left."""
    proc.terminate()
    proc.wait(120)
    err = err_path.read_text()
    assert proc.returncode == 0, err[-3000:]
    assert "Traceback" not in err, err[-3000:]
    assert _nodes().still_running(children, within_s=30) == []


@pytest.fixture(scope="module")
def server(cluster, club):
    """The module's server; its stderr's path."""
    err_path = club["home"] / "serve.err"
    proc, children = _serve(cluster, club, err_path)
    try:
        yield err_path
    finally:
        _stopped(proc, children, err_path)


def _task_pid(cluster, within_s: float = 240.0) -> int:
    """The Ray worker process that runs an evaluation, as soon as one does."""
    tc, end = _nodes(), time.monotonic() + within_s
    while time.monotonic() < end:
        for pid in set().union(*(tc._descendants(p.pid) for p in cluster["procs"])):
            if tc._cmdline(Path(f"/proc/{pid}")).startswith(TASK_TITLE):
                return pid
        time.sleep(0.02)
    raise AssertionError("no Ray worker ever ran the evaluation")


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _simtrace_without_clock(league, admin, sid) -> list[list[str]]:
    """The simtrace's text, cell by cell, without the wall_clock column (the one that is the machine's)."""
    rows = [line.split(",") for line in league.submission_file(admin, sid, "simtrace").read_text().splitlines()]
    at = rows[0].index("wall_clock")
    return [row[:at] + row[at + 1:] for row in rows]


def _outcome(league, admin, sid) -> dict:
    doc = json.loads(league.submission_file(admin, sid, "result").read_text())
    return {k: v for k, v in doc.items() if k not in TIMING}


def _same_as_local(club, sub) -> None:
    league, admin, local = club["league"], club["admin"], club["local"]
    assert (sub.status, sub.score_ms, sub.laps) == (local.status, local.score_ms, local.laps)
    assert sub.status == "ranked" and sub.laps
    assert _outcome(league, admin, sub.id) == _outcome(league, admin, local.id)
    assert _simtrace_without_clock(league, admin, sub.id) == _simtrace_without_clock(league, admin, local.id)


@pytest.mark.slow  # a two-node Ray cluster, a local evaluation and a server's start: about a minute on 2 cores
def test_a_server_stopped_mid_evaluation_queues_it_again_uncounted(club, cluster, request):
    """SIGTERM while a Ray task evaluates: the task is cancelled and the submission queued again without counting the
    attempt; the next server (the module's) evaluates it, attempt 1, with the local result. Runs before the module's
    server is up, so that the first server alone claims."""
    league, admin = club["league"], club["admin"]
    err_path = club["home"] / "first.err"
    proc, children = _serve(cluster, club, err_path)
    sub = league.submit(racer(league, admin, "stop"), "wide", club["model"])
    task = None
    try:
        task = _task_pid(cluster)
        os.kill(task, signal.SIGSTOP)  # held mid-evaluation: it cannot finish while the server stops
    finally:
        _stopped(proc, children, err_path)
        if task is not None:
            os.kill(task, signal.SIGCONT)
    again = league.submission(admin, sub.id)
    assert (again.status, again.attempts) == ("queued", 0)
    assert _nodes().still_running({task}, within_s=60) == []  # cancelled, its driver gone: Ray ended the worker
    request.getfixturevalue("server")
    done = _wait(league, admin, sub.id, FINAL, timeout=300)
    assert done.attempts == 1
    _same_as_local(club, done)


@pytest.mark.slow
def test_ray_evaluates_a_submission_bit_for_bit_as_a_local_worker(club, server):
    league, admin = club["league"], club["admin"]
    sub = league.submit(racer(league, admin, "ray"), "wide", club["model"])
    done = _wait(league, admin, sub.id, FINAL, timeout=300)
    assert done.attempts == 1
    _same_as_local(club, done)
    folder = league.submission_file(admin, sub.id, "result").parent  # where a local worker writes it:
    assert folder.parent == league.store.folder / "results" / str(sub.id) / "attempt-1"  # results/<id>/attempt-<n>
    assert (folder.parent / "model_metadata.json").is_file()
    summary = json.loads((folder / "summary.json").read_text())
    assert summary["model_dir"] == str(league.store.model_dir(done.model_hash))  # the server's, not the node's


@pytest.mark.slow
def test_a_ray_worker_killed_mid_evaluation_requeues_its_submission(club, cluster, server):
    league, admin = club["league"], club["admin"]
    sub = league.submit(racer(league, admin, "kill"), "wide", club["model"])
    killed = _task_pid(cluster)
    env = dict(v.split(b"=", 1) for v in Path(f"/proc/{killed}/environ").read_bytes().split(b"\0") if v)
    os.kill(killed, signal.SIGKILL)
    # the evaluation's pinned kernels were in the Ray worker's environment from its start, before torch loaded
    assert {k: env.get(k.encode(), b"").decode() for k in PIN_ENV} == {k: os.environ.get(k, v) for k, v in
                                                                       PIN_ENV.items()}
    done = _wait(league, admin, sub.id, FINAL, timeout=300)
    assert done.attempts == 2  # the lost attempt counted once, as a local worker killed with -9
    assert league.submission_file(admin, sub.id, "result").parent.parent.name == "attempt-2"
    _same_as_local(club, done)
    said = [line for line in server.read_text().splitlines() if f"submission {sub.id}:" in line]
    assert said == [f"racerlab league: submission {sub.id}: its Ray worker was lost (WorkerCrashedError); evaluated "
                    "again from the start"], said


@pytest.mark.slow
def test_a_node_lost_mid_evaluation_requeues_it_and_a_machine_added_evaluates_it(club, cluster, server):
    """Every process of the node killed (-9) while it evaluates: the submission goes back to the queue, counted
    as a local worker killed with -9; with no CPU left it waits, and a machine that joins evaluates it."""
    tc, league, admin = _nodes(), club["league"], club["admin"]
    sub = league.submit(racer(league, admin, "node"), "wide", club["model"])
    _task_pid(cluster)
    node = cluster["procs"][1]
    node_pids = tc._descendants(node.pid)
    for pid in node_pids:  # the machine is gone: its raylet, its agents and the worker (in its own process group)
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    node.wait()
    assert tc.still_running(node_pids, within_s=60) == []
    end = time.monotonic() + 300  # Ray finds a dead node by its missed health checks: slower on a loaded machine
    while f"submission {sub.id}: its Ray worker was lost" not in server.read_text() and time.monotonic() < end:
        time.sleep(0.1)
    assert f"submission {sub.id}: its Ray worker was lost" in server.read_text(), "the loss was not seen in 300 s"
    # nothing can evaluate it: the cluster has no CPU left. Ray still showed the dead node's CPU as free over 10 s
    # after the loss (a claim made on it showed by then), so the wait covers that lag
    time.sleep(15 + 3 * POLL_S)
    assert league.submission(admin, sub.id).status == "queued", server.read_text()[-2000:]
    cluster["procs"].append(tc.start_node([f"--address={cluster['address']}"], cluster["tmp"]))
    done = _wait(league, admin, sub.id, FINAL, timeout=300)
    assert done.attempts == 2
    _same_as_local(club, done)
    said = [line for line in server.read_text().splitlines() if f"submission {sub.id}:" in line]
    assert len(said) == 1 and "its Ray worker was lost (" in said[0], said


def test_ray_without_the_cluster_extra_is_one_line(tmp_path):
    League.create(tmp_path / "club", password=PASSWORD)[0].close()
    code = ("import sys; sys.modules['ray'] = None; from racerlab.cli import main; "
            "sys.exit(main(sys.argv[1:]))")
    out = subprocess.run([sys.executable, "-c", code, "league", "serve", str(tmp_path / "club"), "--ray",
                          "10.0.0.5:6379"], capture_output=True, text=True, timeout=120, env=_user_env(tmp_path))
    assert out.returncode == 2
    assert out.stderr.strip().splitlines() == ["racerlab: error: --ray 10.0.0.5:6379: Ray is not installed; run "
                                               "`pip install 'racerlab[cluster]'`"]


@pytest.mark.parametrize("flags, says", [
    (["--ray", "127.0.0.1:{port}"], "no Ray cluster answers there"),
    (["--ray", "head-node"], "give the Ray head's address as HOST:PORT"),
    (["--ray", "127.0.0.1:{port}", "--workers", "2"], "give one of them"),
    (["--ray-workers", "2"], "give --ray ADDRESS as well"),
])
def test_a_wrong_ray_flag_is_one_line(tmp_path, capsys, flags, says):
    pytest.importorskip("ray")
    League.create(tmp_path / "club", password=PASSWORD)[0].close()
    port = _free_port()  # nothing listens there
    args = [f.format(port=port) for f in flags]
    assert main(["league", "serve", str(tmp_path / "club"), "--port", str(_free_port()), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and err[0].startswith("racerlab: error: --"), err


def test_an_address_where_a_web_server_answers_is_one_line_not_minutes_of_retries(tmp_path, capsys):
    """ray.init retried for many minutes on a port where something other than a Ray head answers (the league's own
    port, the dashboard's): the head's gRPC is asked first."""
    import threading
    from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

    pytest.importorskip("ray")
    League.create(tmp_path / "club", password=PASSWORD)[0].close()
    class Quiet(BaseHTTPRequestHandler):
        def log_message(self, *args) -> None:  # its log lines would mix with the command's stderr
            pass

    web = ThreadingHTTPServer(("127.0.0.1", 0), Quiet)
    threading.Thread(target=web.serve_forever, daemon=True).start()
    try:
        start = time.monotonic()
        rc = main(["league", "serve", str(tmp_path / "club"), "--port", str(_free_port()), "--ray",
                   f"127.0.0.1:{web.server_address[1]}"])
        took = time.monotonic() - start
    finally:
        web.shutdown()
        web.server_close()
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "no Ray cluster answers there (something answers, but not a Ray head's " \
        "gRPC)" in err[0], err
    assert took < 30


def test_a_node_with_other_versions_refuses_the_task_in_one_line():
    """Bit-identity holds for the same racerlab, torch and NumPy builds: a node with others would race other sums."""
    from racerlab.errors import RacerlabError
    from racerlab.league.ray_pool import league_evaluation, versions

    job = {"versions": {**versions(), "torch": "0.0.1"}}
    with pytest.raises(RacerlabError) as err:
        league_evaluation(job)
    assert str(err.value).endswith(f"torch {versions()['torch']} here, 0.0.1 on the server; install the server's "
                                   "versions on every node")
    assert str(err.value).startswith("Ray node ") and "\n" not in str(err.value)
