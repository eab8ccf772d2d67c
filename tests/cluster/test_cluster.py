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


@pytest.fixture(scope="module")
def cluster():
    tmp = Path(tempfile.mkdtemp(prefix="rl", dir="/tmp"))
    port = _free_port()
    saved = os.environ.get("RAY_AUTH_MODE")
    os.environ["RAY_AUTH_MODE"] = "disabled"  # a throw-away cluster on 127.0.0.1: no token to hand around
    env = dict(os.environ, RAY_USAGE_STATS_ENABLED="0")
    common = ["--block", "--disable-usage-stats", f"--temp-dir={tmp}"]
    procs = [subprocess.Popen([RAY, "start", "--head", "--node-ip-address=127.0.0.1", f"--port={port}",
                               "--num-cpus=1", "--include-dashboard=false", *common], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    address = f"127.0.0.1:{port}"
    try:
        _wait_for_head(address, tmp)
        procs.append(subprocess.Popen([RAY, "start", f"--address={address}", "--node-ip-address=127.0.0.1",
                                       "--num-cpus=1", *common], env=env, stdout=subprocess.DEVNULL,
                                      stderr=subprocess.DEVNULL, start_new_session=True))
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
        for p in reversed(procs):
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGTERM)
        for p in reversed(procs):
            try:
                p.wait(timeout=8)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                p.wait()


def _wait_for_head(address: str, tmp: Path) -> None:
    host, port = address.split(":")
    deadline = time.time() + 90
    while time.time() < deadline:
        with socket.socket() as s:
            if s.connect_ex((host, int(port))) == 0:
                return
        time.sleep(0.5)
    raise RuntimeError(f"ray head on {address} did not come up (logs in {tmp})")


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
