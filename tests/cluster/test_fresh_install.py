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
