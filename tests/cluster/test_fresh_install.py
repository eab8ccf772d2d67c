"""`racerlab train --workers 2` and `racerlab sweep` as a new user runs them: a fresh process, a local Ray that the
command starts itself, no RAY_* variable set and no ~/.ray token yet (a temporary HOME).

Ray reads its authentication mode when it is imported; racerlab chose the mode after the import, so both commands
failed on a fresh install (the driver had no token, the cluster asked for one) while the tests that set
RAY_AUTH_MODE themselves passed.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray")

from tests.cluster.test_cluster import _small_model  # noqa: E402

pytestmark = pytest.mark.slow  # each command starts and stops its own local Ray (about 20 s on an idle core)


def _user_env(home: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("RAY_")}
    src = str(Path(__file__).resolve().parents[2] / "src")
    env.update(HOME=str(home), PYTHONPATH=os.pathsep.join([src, env.get("PYTHONPATH", "")]))
    return env


def _racerlab(args: list[str], cwd: Path, home: Path) -> subprocess.CompletedProcess:
    code = "import sys; from racerlab.cli import main; sys.exit(main(sys.argv[1:]))"
    return subprocess.run([sys.executable, "-c", code, *args], cwd=cwd, env=_user_env(home), capture_output=True,
                          text=True, timeout=400)


def test_train_with_two_workers_works_on_a_fresh_install(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    _small_model(tmp_path / "m", episodes=2)
    out = _racerlab(["train", "m", "--workers", "2", "--iterations", "1"], tmp_path, home)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    assert (tmp_path / "m" / "metrics" / "TrainingMetrics_1.json").is_file()  # worker 1 drove episodes
    assert list((tmp_path / "m" / "checkpoints").glob("1_Step-*.pt"))
    assert (home / ".ray" / "auth_token").is_file()  # the local cluster ran with token authentication


def test_sweep_works_on_a_fresh_install(tmp_path):
    home = tmp_path / "home"
    home.mkdir()
    (tmp_path / "sweep.toml").write_text(
        'out = "runs"\niterations = 1\ncars = 2\n[race]\ntrials = 1\n[[model]]\nname = "one"\n'
        'hyperparameters = { num_episodes_between_training = 2, num_epochs = 1 }\n')
    out = _racerlab(["sweep", "sweep.toml"], tmp_path, home)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    assert "one" in out.stdout and (tmp_path / "runs" / "leaderboard.json").is_file()


def test_an_error_inside_a_worker_on_a_fresh_install_is_one_line(tmp_path):
    """Issue 45, item 12: on a fresh home the test of this (in test_cluster.py) killed the test run; a user's
    `racerlab train --workers 2` with a reward that fails inside a worker ends with racerlab's one line."""
    home = tmp_path / "home"
    home.mkdir()
    model = _small_model(tmp_path / "m", episodes=2)
    (model / "reward_function.py").write_text("def reward_function(params):\n    return params['no_such_key']\n")
    out = _racerlab(["train", "m", "--workers", "2", "--iterations", "1"], tmp_path, home)
    assert out.returncode == 2, out.stdout[-2000:] + out.stderr[-3000:]
    # the error line, then (as every reward error) the params the reward was called with on the line below
    lines = out.stderr.strip().splitlines()
    at = next(i for i, line in enumerate(lines) if line.startswith("racerlab: error: "))
    assert "reward_function.py:2" in lines[at] and "KeyError" in lines[at], lines[at:]
    assert len(lines) - at <= 2 and (at + 1 == len(lines) or lines[at + 1].startswith("  params: ")), lines[at:]
    assert "Traceback" not in out.stderr and "ray" not in lines[at].lower()


def _descendants(pid: int) -> set[int]:
    from tests.cluster.test_cluster import _descendants as below

    return below(pid)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")
def test_a_local_cluster_serves_on_loopback_and_ctrl_c_leaves_no_ray_process(tmp_path):
    """Issue 45, item 12: racerlab's own local cluster (train --workers without --ray-address) listened on every
    interface with the machine's address; it serves on 127.0.0.1, and an interrupted driver takes it down."""
    import signal

    from tests.cluster.test_cluster import _listening, still_running

    home = tmp_path / "home"
    home.mkdir()
    code = ("import time; from racerlab.cluster.collector import connect; r = connect(num_cpus=1); "
            "print(sorted({n['NodeManagerAddress'] for n in r.nodes()}), flush=True); time.sleep(300)")
    proc = subprocess.Popen([sys.executable, "-c", code], cwd=tmp_path, env=_user_env(home), stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "['127.0.0.1']", proc.stderr.read() if proc.poll() else ""
        ray_pids = _descendants(proc.pid) - {proc.pid}
        served = _listening(ray_pids | {proc.pid})
        assert ray_pids and served and served <= {"127.0.0.1", "::ffff:127.0.0.1"}, served
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=60)
        assert still_running(ray_pids, within_s=60) == []
    finally:
        if proc.poll() is None:
            proc.kill()

