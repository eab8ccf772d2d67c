"""Rollout workers and sweeps on a real Ray cluster: a head and a second node started on 127.0.0.1.

Both node processes are started here (`ray start --block`) and stopped here, by their own ids.
"""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

ray = pytest.importorskip("ray")

from racerlab.cluster import ClusterTraining, merge_rollouts, split_episodes, train_on_cluster  # noqa: E402
from racerlab.cluster.sweep import run_sweep  # noqa: E402
from racerlab.model import init_model  # noqa: E402

RAY = str(Path(sys.executable).with_name("ray"))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _small_model(path: Path, episodes: int = 4) -> Path:
    """A model whose iteration is `episodes` short episodes and one evaluation episode."""
    folder = init_model(path, num_cars=2)
    hp = json.loads(folder.hyperparameters_path.read_text())
    hp.update(num_episodes_between_training=episodes, num_epochs=1)
    folder.hyperparameters_path.write_text(json.dumps(hp))
    toml = folder.path / "training.toml"
    toml.write_text(toml.read_text().replace("[evaluation]\nepisodes = 5", "[evaluation]\nepisodes = 1"))
    return folder.path


def start_node(args: list[str], tmp: Path, cpus: int = 1) -> subprocess.Popen:
    """`ray start --block` of one node on 127.0.0.1 with `cpus` CPUs, its files under `tmp`, under a reaper
    (`_REAPER`) that takes the node down when this process closes its end of the reaper's stdin or ends, however it
    ends: a test run that died left both nodes running.

    Ray turns 127.0.0.1 given as a node's address into the machine's network address (its services then listen on
    every interface) unless clusters of several machines are off (`collector.loopback_only`), and with them off a
    second node refuses to start: the head runs with them off, the second node with Ray's resolving of 127.0.0.1
    left out (`_KEEP_LOOPBACK`)."""
    head = "--head" in args
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0", RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0" if head else "1")
    command = [RAY] if head else [sys.executable, "-c", _KEEP_LOOPBACK]
    return subprocess.Popen([sys.executable, "-c", _REAPER, *command, "start", *args, "--node-ip-address=127.0.0.1",
                             f"--num-cpus={cpus}", "--block", "--disable-usage-stats", f"--temp-dir={tmp}"], env=env,
                            stdin=subprocess.PIPE, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)


# The reaper leads the node's process group: at the end of its stdin it stops `ray start`, then kills the group (the
# agents a raylet starts outlive it by a minute, and `ray start` sent SIGTERM while it starts its node hangs).
_REAPER = ("import os, signal, subprocess, sys\n"
           "node = subprocess.Popen(sys.argv[1:])\n"
           "sys.stdin.buffer.read()\n"
           "node.terminate()\n"
           "try:\n    node.wait(10)\nexcept subprocess.TimeoutExpired:\n    pass\n"
           "os.killpg(0, signal.SIGKILL)\n")
# `ray start` with the addresses given kept as they are (Ray resolves 127.0.0.1 to the machine's address)
_KEEP_LOOPBACK = ("import sys; from ray._private import services; services.resolve_ip_for_localhost = lambda h: h; "
                  "from ray.scripts.scripts import main; sys.argv[0] = 'ray'; sys.exit(main())")


def stop_nodes(procs: list[subprocess.Popen]) -> None:
    """Each node's reaper told to take its node down (newest first), and killed with its group if it does not."""
    for p in reversed(procs):
        if p.stdin and not p.stdin.closed:
            p.stdin.close()
    for p in reversed(procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.fixture(scope="module")
def cluster():
    from racerlab.cluster.collector import loopback_only

    tmp = Path(tempfile.mkdtemp(prefix="rl", dir="/tmp"))
    port = _free_port()
    saved = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # a throw-away cluster on 127.0.0.1: no token to hand around
    loopback_only()  # Ray would give the nodes the machine's address (and listen on every interface) for 127.0.0.1
    procs = [start_node(["--head", f"--port={port}", "--include-dashboard=false"], tmp)]
    address = f"127.0.0.1:{port}"
    try:
        _wait_for_head(address, tmp)
        procs.append(start_node([f"--address={address}"], tmp))
        ray.init(address=address, include_dashboard=False, log_to_driver=False)
        deadline = time.time() + 90
        while len([n for n in ray.nodes() if n["Alive"]]) < 2 and time.time() < deadline:
            time.sleep(0.5)
        yield address
    finally:
        ray.shutdown()
        if saved is None:
            os.environ.pop("RAY_AUTH_MODE", None)
        else:
            os.environ["RAY_AUTH_MODE"] = saved
        stop_nodes(procs)


def _wait_for_head(address: str, tmp: Path) -> None:
    host, port = address.split(":")
    deadline = time.time() + 90
    while time.time() < deadline:
        with socket.socket() as s:
            if s.connect_ex((host, int(port))) == 0:
                return
        time.sleep(0.5)
    raise RuntimeError(f"ray head on {address} did not come up (logs in {tmp})")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_test_run_that_dies_leaves_no_ray_node_behind(tmp_path):
    """Issue 45, item 12: a test run that died (or was killed) left the module's two nodes running. A process that
    starts a node as the fixture does, killed with SIGKILL, takes the node with it."""
    repo = Path(__file__).resolve().parents[2]
    code = ("import sys, time; from pathlib import Path; "
            "from tests.cluster.test_cluster import _free_port, start_node; port = _free_port(); "
            "p = start_node(['--head', f'--port={port}', '--include-dashboard=false'], Path(sys.argv[1])); "
            "print(p.pid, port, flush=True); time.sleep(300)")
    env = dict(os.environ, RAY_AUTH_MODE="disabled", RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER="0",
               PYTHONPATH=os.pathsep.join([str(repo), str(repo / "src"), os.environ.get("PYTHONPATH", "")]))
    tmp = Path(tempfile.mkdtemp(prefix="rl", dir="/tmp"))
    run = subprocess.Popen([sys.executable, "-c", code, str(tmp)], cwd=repo, env=env, stdout=subprocess.PIPE,
                           text=True)
    try:
        pid, port = map(int, run.stdout.readline().split())
        _wait_for_head(f"127.0.0.1:{port}", tmp)
        deadline = time.time() + 90
        while time.time() < deadline and not any(b"raylet" in _cmdline(Path(f"/proc/{p}")) for p in _descendants(pid)):
            time.sleep(0.5)
        node = _descendants(pid)
        assert len(node) >= 3  # ray start, the GCS, the raylet at least
        run.kill()  # the test run dies
        run.wait()
        assert still_running(node, within_s=60) == []
    finally:
        if run.poll() is None:
            run.kill()


def test_episodes_split_as_drfc_serves_them():
    # episode k goes to worker k mod W
    assert split_episodes(20, 3) == [7, 7, 6]
    assert split_episodes(2, 3) == [1, 1, 0]
    assert sum(split_episodes(13, 4)) == 13


def test_train_without_workers_never_imports_ray(tmp_path):
    model = _small_model(tmp_path / "m", episodes=2)
    code = ("import sys; from racerlab.cli import main; "
            f"rc = main(['train', {str(model)!r}, '--iterations', '1']); "
            "assert rc == 0; print('RAY' if 'ray' in sys.modules else 'NO-RAY')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=240)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("NO-RAY")
    assert (model / "training-simtrace" / "0-iteration.csv").is_file()
    assert not (model / "0").exists()


def test_two_workers_one_iteration_writes_drfc_multi_worker_logs(cluster, tmp_path):
    model = _small_model(tmp_path / "m")
    r = train_on_cluster(model, 2, cluster, progress=False, iterations=1)
    assert r.iterations == 1 and r.episodes == 4
    assert not (model / "training-simtrace").exists()  # deepracer-utils takes that for a one-worker folder
    for k in (0, 1):
        assert (model / str(k) / "training-simtrace" / "0-iteration.csv").is_file()
    m0 = json.loads((model / "metrics" / "TrainingMetrics.json").read_text())["metrics"]
    m1 = json.loads((model / "metrics" / "TrainingMetrics_1.json").read_text())["metrics"]
    assert [m["episode"] for m in m1] == [1, 2] and sum(m["phase"] == "training" for m in m0) == 2
    assert sum(m["phase"] == "evaluation" for m in m0) == 1
    entry = json.loads((model / "metrics" / "metrics.jsonl").read_text().splitlines()[-1])
    assert entry["cluster/workers"] == 2 and entry["cluster/failed_workers"] == 0
    assert entry["cluster/weights_bytes"] > 0 and entry["cluster/rollout_bytes"] > 0

    from deepracer.logs import DeepRacerLog

    log = DeepRacerLog(str(model))
    log.load_training_trace()
    df = log.dataframe()
    assert sorted(df["worker"].unique()) == [0, 1]
    assert df["unique_episode"].nunique() == 4
    # the learner trained on exactly the learning steps the workers logged (prepare rows excluded)
    step = int(r.best_checkpoint.split("Step-")[1].split(".")[0]) if "Step-" in r.best_checkpoint else None
    assert step == int((df["episode_status"] != "prepare").sum())


def test_a_worker_killed_mid_run_costs_its_episodes_only_and_resume_continues(cluster, tmp_path, capsys):
    model = _small_model(tmp_path / "m")
    trainer = ClusterTraining(model, 2, cluster, progress=True, iterations=2)
    pids = [i["pid"] for i in trainer.collector.info]
    os.kill(pids[1], signal.SIGKILL)
    r = trainer.run()
    assert r.iterations == 2
    assert trainer.failures == [{"iteration": 1, "workers": [1]}]
    assert "worker 1 (" in capsys.readouterr().out
    lines = [json.loads(x) for x in (model / "metrics" / "metrics.jsonl").read_text().splitlines()]
    assert [e["cluster/workers"] for e in lines] == [1, 2]
    assert r.episodes == 2 + 4  # iteration 1 kept worker 0's two episodes only
    assert not (model / "1" / "training-simtrace" / "0-iteration.csv").exists()
    assert (model / "1" / "training-simtrace" / "1-iteration.csv").is_file()
    # the driver stopped: a new run resumes from the checkpoint, each worker counting on
    r2 = train_on_cluster(model, 2, cluster, progress=False, iterations=1)
    assert r2.iterations == 3
    m1 = json.loads((model / "metrics" / "TrainingMetrics_1.json").read_text())["metrics"]
    assert [m["episode"] for m in m1] == [1, 2, 3, 4]


def test_merge_keeps_episodes_whole_and_renumbers(tmp_path):
    from racerlab.train.rollout import Episode, Rollout

    def part(n_eps, steps):
        eps = [Episode(k, 0, k) for k in range(n_eps)]
        episode = np.repeat(np.arange(n_eps) + 7, steps)
        n = n_eps * steps
        return Rollout(np.ones((n, 3), np.float32), np.zeros(n), {"v": np.arange(n)},
                       np.ones(n_eps * steps, np.float32), np.tile([False] * (steps - 1) + [True], n_eps),
                       np.zeros(n_eps * steps, bool), eps, {"episode": episode}, n_eps * steps, 0.1)

    ro = merge_rollouts([part(2, 3), part(1, 4)], 10, 1.0)
    assert ro.obs.shape == (10, 3) and ro.rewards.size == 10 and ro.env_steps == 10
    assert ro.trace["episode"].tolist() == [10, 10, 10, 11, 11, 11, 12, 12, 12, 12]
    assert ro.record["v"].tolist() == [0, 1, 2, 3, 4, 5, 0, 1, 2, 3]
    assert len(ro.episodes) == 3


def test_sweep_trains_in_parallel_and_ranks_under_one_rule_set(cluster, tmp_path):
    (tmp_path / "centre.py").write_text(
        "def reward_function(params):\n"
        "    return float(max(1e-3, 1 - params['distance_from_center'] / (0.5 * params['track_width'])))\n")
    spec = tmp_path / "sweep.toml"
    spec.write_text('out = "runs"\niterations = 1\ncars = 2\n[race]\ntrials = 1\n'
                    '[[model]]\nname = "disc"\n'
                    'hyperparameters = { num_episodes_between_training = 2, num_epochs = 1 }\n'
                    '[[model]]\nname = "cont-centre"\naction_space = "continuous"\nreward = "centre.py"\n'
                    'hyperparameters = { num_episodes_between_training = 2, num_epochs = 1, lr = 0.001 }\n')
    board = run_sweep(spec, address=cluster)
    data = json.loads(board.json_path.read_text())
    assert sorted(r["model"] for r in data["leaderboard"]) == ["cont-centre", "disc"]
    assert all(r["training"]["iterations"] == 1 for r in data["leaderboard"])
    assert board.png_path.stat().st_size > 5000
    assert (tmp_path / "runs" / "cont-centre" / "reward_function.py").read_text().startswith("def reward_function")
    hp = json.loads((tmp_path / "runs" / "cont-centre" / "hyperparameters.json").read_text())
    assert hp["lr"] == 0.001
    assert "disc" in board.table() and "cont-centre" in board.table()


def test_a_worker_drives_with_the_learners_weights_but_its_own_random_stream(tmp_path):
    import torch

    from racerlab.cluster.worker import RolloutWorker, broadcast_state, worker_cars, worker_tracks
    from racerlab.train.loop import Trainer

    model = _small_model(tmp_path / "m")
    learner = Trainer(model, progress=False)
    with torch.no_grad():
        for p in learner.agent.policy_net.parameters():
            p.add_(0.05)  # the learner has moved on from the initial weights
    weights = broadcast_state(learner.agent)
    assert not any("optimizer" in k or k == "generator" for k in weights)
    w = RolloutWorker(str(model), 1, 2, {})
    assert w.describe()["start_offset"] == 0.5 and w.describe()["cars"] == 1
    ro, starts = w.collect(weights, 2, 10_000, 0)
    assert len(ro.episodes) == 2 and len(starts) == 1 and starts[0] >= 2  # one world, its round-robin counter
    obs = learner.eval_world.observe(np.arange(1))
    assert np.array_equal(w.agent.policy(obs), learner.agent.policy(obs))
    assert w.agent.generator.initial_seed() != learner.agent.generator.initial_seed()
    assert worker_tracks(("a", "b", "c"), 1, 2) == ("b",) and worker_tracks(("a",), 1, 2) == ("a",)
    assert [worker_cars(5, k, 2) for k in (0, 1)] == [3, 2]
    # head_to_model cars race in pairs: 6 cars over 2 workers are 4 + 2, never 3 + 3; a worker gets a pair at least
    assert [worker_cars(6, k, 2, unit=2) for k in (0, 1)] == [4, 2]
    assert [worker_cars(2, k, 3, unit=2) for k in (0, 1, 2)] == [2, 2, 2]


def test_a_worker_table_gives_that_worker_its_own_track_and_direction(tmp_path):
    from racerlab.cluster.worker import RolloutWorker

    model = _small_model(tmp_path / "m")
    cfg = model / "training.toml"
    cfg.write_text(cfg.read_text() + '\n[[worker]]\n\n[[worker]]\ntrack.names = ["lab_oval"]\ntrack.reverse = true\n')
    w0, w1 = RolloutWorker(str(model), 0, 2, {}), RolloutWorker(str(model), 1, 2, {})
    base = w0.describe()["tracks"]
    assert base != ["lab_oval"] and not w0.describe()["reverse"]  # worker 1's table leaves worker 0 alone
    assert w1.describe()["tracks"] == ["lab_oval"] and w1.describe()["reverse"]
    assert w1.worlds[0].sim.start_rules.reverse and w1.worlds[0].sim.track.name == "lab_oval"
    ro, _ = w1.collect(broadcast_state_of(w0), 1, 10_000, 0)
    assert len(ro.episodes) == 1
    # a --track flag wins over the worker tables, as over the file's own [track]
    w1_flag = RolloutWorker(str(model), 1, 2, {"tracks": ("lab_technical",)})
    assert w1_flag.describe()["tracks"] == ["lab_technical"]


def broadcast_state_of(worker):
    from racerlab.cluster.worker import broadcast_state

    return broadcast_state(worker.agent)


def test_a_stopped_worker_is_given_up_at_the_deadline_and_replaced(cluster, tmp_path, capsys):
    """SIGSTOP, not death: the worker's process lives on, so only a deadline ends the wait."""
    import threading

    model = _small_model(tmp_path / "m")
    trainer = ClusterTraining(model, 2, cluster, progress=True, iterations=1)
    trainer.collector.worker_timeout_s = 15.0
    pid = trainer.collector.info[1]["pid"]
    os.kill(pid, signal.SIGSTOP)
    result = {}
    try:
        run = threading.Thread(target=lambda: result.update(r=trainer.run()), daemon=True)
        run.start()
        run.join(150)
        assert not run.is_alive(), "the driver still waits for the stopped worker"
    finally:
        for sig in (signal.SIGCONT, signal.SIGKILL):
            try:
                os.kill(pid, sig)
            except ProcessLookupError:
                pass
    assert result["r"].iterations == 1 and result["r"].episodes == 2  # worker 0's two episodes
    assert trainer.failures == [{"iteration": 1, "workers": [1]}]
    assert "worker 1 (no answer within" in capsys.readouterr().out


def test_a_sweep_gives_up_a_stopped_training_at_its_deadline_and_races_the_rest(cluster, tmp_path):
    """SIGSTOP on one sweep training's worker: the driver waited for it for ever (ray.get without a timeout)."""
    import threading

    from racerlab.model import ModelFolder
    from racerlab.model.lock import TrainingLock

    spec = tmp_path / "sweep.toml"
    hp = "hyperparameters = { num_episodes_between_training = 2, num_epochs = 1 }\n"
    spec.write_text(f'out = "runs"\niterations = 2\ncars = 2\n[race]\ntrials = 1\n[[model]]\nname = "goes"\n{hp}'
                    f'[[model]]\nname = "stops"\n{hp}')
    lock = ModelFolder(tmp_path / "runs" / "stops").lock_path
    notes, result, stopped = [], {}, []
    run = threading.Thread(target=lambda: result.update(board=run_sweep(spec, address=cluster, stall_s=20.0,
                                                                        note=notes.append, tick_s=0.5)), daemon=True)
    run.start()
    try:
        deadline = time.time() + 120
        while not stopped and run.is_alive() and time.time() < deadline:  # the trainer puts its PID in the lock
            pid = TrainingLock(lock).holder()
            if pid:
                os.kill(pid, signal.SIGSTOP)
                stopped.append(pid)
            time.sleep(0.05)
        assert stopped, "the second training never started"
        run.join(180)
        assert not run.is_alive(), "the driver still waits for the stopped training"
        gone = time.time() + 15
        while _alive(stopped[0]) and time.time() < gone:
            time.sleep(0.2)
        assert not _alive(stopped[0]), "the stopped worker was not killed"
    finally:
        for pid in stopped:
            for sig in (signal.SIGCONT, signal.SIGKILL):
                try:
                    os.kill(pid, sig)
                except ProcessLookupError:
                    pass
    board = result["board"]
    assert [r["model"] for r in board.board.rows()] == ["goes"]
    assert board.trained["goes"]["iterations"] == 2 and "failed" in board.trained["stops"]
    data = json.loads(board.json_path.read_text())
    assert list(data["left_out"]) == ["stops"] and "no progress for 20 s after it started" in data["left_out"]["stops"]
    assert len(notes) == 1 and "model 'stops': its training made no progress for 20 s after it started" in notes[0]
    assert "\n" not in notes[0]


def test_an_error_inside_a_sweep_training_is_its_one_line(cluster, tmp_path):
    from racerlab.errors import RewardFunctionError

    (tmp_path / "bad.py").write_text("def reward_function(params):\n    return params['no_such_key']\n")
    spec = tmp_path / "sweep.toml"
    spec.write_text('iterations = 1\ncars = 2\n[[model]]\nname = "bad"\nreward = "bad.py"\n'
                    'hyperparameters = { num_episodes_between_training = 2, num_epochs = 1 }\n')
    with pytest.raises(RewardFunctionError) as err:
        run_sweep(spec, address=cluster)
    msg = str(err.value)
    assert "reward_function.py:2" in msg and "KeyError" in msg and "Traceback" not in msg and len(msg.splitlines()) <= 2


def still_running(pids, within_s: float) -> list[int]:
    """Those of `pids` still running (not zombies) after waiting up to `within_s` for them to end."""
    deadline = time.time() + within_s
    while time.time() < deadline and any(_alive(p) for p in pids):
        time.sleep(0.5)
    return [p for p in pids if _alive(p)]


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(") ", 1)[1][0]
    except (OSError, IndexError):
        return False
    return state != "Z"


def test_a_local_cluster_starts_with_token_authentication_and_old_ray_is_refused(monkeypatch):
    from types import SimpleNamespace

    from racerlab.cluster import collector
    from racerlab.errors import RacerlabError

    seen = {}
    fake = SimpleNamespace(__version__="2.60.0", is_initialized=lambda: False,
                           init=lambda **kw: seen.update(kw, auth=os.environ.get("RAY_AUTH_MODE")))
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    collector.connect()
    assert seen["auth"] == "token" and "address" not in seen
    fake.__version__ = "2.9.3"
    with pytest.raises(RacerlabError, match=r"ray 2\.9\.3 .* ray >= 2\.52"):
        collector.connect()


def test_a_connected_ray_keeps_its_authentication_mode(cluster, monkeypatch):
    """Issue 45, item 12: the token test above re-read the real Ray's configuration through `ray._raylet` while this
    process was connected with authentication off; with no ~/.ray token (a fresh home) the next call into Ray killed
    the test run, which left both nodes running. racerlab touches only the Ray `import ray` gives, and leaves a
    connected one alone."""
    from types import SimpleNamespace

    from ray._raylet import AuthenticationMode, get_authentication_mode

    from racerlab.cluster import collector

    fake = SimpleNamespace(__version__="2.60.0", is_initialized=lambda: False, init=lambda **kw: None)
    monkeypatch.setitem(sys.modules, "ray", fake)
    monkeypatch.delenv("RAY_AUTH_MODE", raising=False)
    collector.connect()
    monkeypatch.setitem(sys.modules, "ray", ray)
    assert get_authentication_mode() != AuthenticationMode.TOKEN
    assert collector.connect() is ray  # connected: used as it is, its mode untouched
    assert get_authentication_mode() != AuthenticationMode.TOKEN and ray.get(ray.put(7)) == 7


def _listening(pids: set[int]) -> set[str]:
    """The local addresses the processes `pids` listen on (TCP), read from /proc."""
    inodes = set()
    for pid in pids:
        try:
            links = [os.readlink(f"/proc/{pid}/fd/{fd}") for fd in os.listdir(f"/proc/{pid}/fd")]
        except OSError:
            continue
        inodes |= {link[8:-1] for link in links if link.startswith("socket:[")}
    out = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        for line in Path(table).read_text().splitlines()[1:]:
            cols = line.split()
            if cols[3] == "0A" and cols[9] in inodes:  # LISTEN
                out.add(_address(cols[1].split(":")[0], width))
    return out


def _address(hexed: str, width: int) -> str:
    raw = bytes.fromhex(hexed)
    words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))  # /proc prints each 32-bit word host-order
    return socket.inet_ntop(socket.AF_INET if width == 8 else socket.AF_INET6, words)


def _descendants(pid: int) -> set[int]:
    children: dict[int, list[int]] = {}
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                ppid = int(Path(f"/proc/{d}/stat").read_text().rsplit(") ", 1)[1].split()[1])
            except (OSError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(d))
    out, todo = set(), [pid]
    while todo:
        p = todo.pop()
        out.add(p)
        todo += children.get(p, [])
    return out


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_the_test_clusters_nodes_serve_on_loopback_only(cluster):
    """Issue 45, item 12: Ray turned --node-ip-address=127.0.0.1 into the machine's address, and the GCS and raylets
    listened on every interface."""
    nodes = [n for n in ray.nodes() if n["Alive"]]
    assert len(nodes) == 2 and {n["NodeManagerAddress"] for n in nodes} == {"127.0.0.1"}
    port = cluster.split(":")[1]
    heads = [int(p.name) for p in Path("/proc").iterdir() if p.name.isdigit() and _cmdline(p).startswith(b"/") and
             (f"--port={port}".encode() in _cmdline(p) or f"--address=127.0.0.1:{port}".encode() in _cmdline(p))]
    served = _listening(set().union(*(_descendants(pid) for pid in heads)))
    assert served and served <= {"127.0.0.1", "::ffff:127.0.0.1"}, served


def _cmdline(proc: Path) -> bytes:
    try:
        return (proc / "cmdline").read_bytes()
    except OSError:
        return b""


def test_an_error_inside_a_worker_is_racerlabs_message_not_rays_traceback(cluster, tmp_path):
    from racerlab.errors import RewardFunctionError

    model = _small_model(tmp_path / "m")
    (model / "reward_function.py").write_text("def reward_function(params):\n    return params['no_such_key']\n")
    trainer = ClusterTraining(model, 2, cluster, progress=False, iterations=1)
    with pytest.raises(RewardFunctionError) as err:
        trainer.run()
    msg = str(err.value)
    assert "reward_function.py:2" in msg and "KeyError" in msg
    assert "Traceback" not in msg and "ray" not in msg.lower() and len(msg.splitlines()) <= 2
