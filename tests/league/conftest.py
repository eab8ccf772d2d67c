"""League fixtures: a league folder with its admin, small features models (distinct weights per seed), tracks.

The database: the store's, queue's and service's tests (`BOTH_DATABASES`) run twice, on SQLite in the league folder
and on a real PostgreSQL server that the session starts on 127.0.0.1 (Debian's `postgresql` binaries: initdb,
pg_ctl, found on PATH or in /usr/lib/postgresql/*/bin), a fresh database per test; the web, CLI and browser tests,
which reach the database only through that service, run on SQLite. `RACERLAB_TEST_LEAGUE_DB=postgresql` runs
every league test on PostgreSQL alone, `=sqlite` every one on SQLite alone (no PostgreSQL needed).
"""

from __future__ import annotations

import itertools
import json
import os
import shutil
import socket
import subprocess
import tempfile
from pathlib import Path

import pytest

from racerlab.league import League
from tests.conftest import aws_track_path

PASSWORD = "correct horse battery"


def features_model(path: Path, track, actions=((0.0, 1.0),), seed: int = 0, iteration: int = 1,
                   race: str = "time_trial"):
    """A features model folder whose one checkpoint holds a fresh agent drawn with `seed` (best and last), trained
    for a `race` of that type (boxes or bot cars add the nearest objects to its features vector)."""
    from racerlab.agent import make_agent
    from racerlab.model import ModelFolder, TrainingState
    from racerlab.sim.core import Simulator
    from racerlab.sim.observations import make_observation
    from racerlab.spec import RaceConfig
    from racerlab.track import load

    path.mkdir(parents=True, exist_ok=True)
    space = [{"steering_angle": s, "speed": v, "index": i} for i, (s, v) in enumerate(actions)]
    meta = {"action_space": space, "action_space_type": "discrete", "sensor": ["FEATURES"], "neural_network": "MLP",
            "training_algorithm": "clipped_ppo", "version": "5"}
    (path / "model_metadata.json").write_text(json.dumps(meta))
    (path / "reward_function.py").write_text("def reward_function(params):\n    return 1.0\n")
    objects = {"object_avoidance": "number_of_obstacles = 3\n", "head_to_bot": "number_of_bot_cars = 2\n"}
    (path / "training.toml").write_text(f'[track]\nnames = ["{track}"]\n[run]\nnum_cars = 1\n'
                                        f'[race]\ntype = "{race}"\n{objects.get(race, "")}')
    folder = ModelFolder(path)
    m = folder.metadata()
    cfg = folder.config().race if race != "time_trial" else RaceConfig()
    obs = make_observation(None, Simulator(load(str(track)), 1, race=cfg), m)
    agent = make_agent(obs.space, m, folder.hyperparameters(), device="cpu", seed=seed)
    info = folder.save_state(TrainingState(agent.state_dict(), m.to_json(), iteration=iteration,
                                           train_steps=100 * iteration))
    folder.update_index(info, 0.0, info, 0.0)
    return folder


@pytest.fixture
def straight():
    return aws_track_path("Straight_track")


@pytest.fixture
def wide():
    return aws_track_path("reInvent2019_wide")


def _pg_bin(name: str) -> str | None:
    found = shutil.which(name)
    if found:
        return found
    for version in sorted(Path("/usr/lib/postgresql").glob("*/bin"), reverse=True):
        if (version / name).is_file():
            return str(version / name)
    return None


def _as_postgres(cmd: list[str]) -> list[str]:
    """PostgreSQL refuses to run as root: run its programs as the `postgres` user then."""
    return ["runuser", "-u", "postgres", "--", *cmd] if os.geteuid() == 0 else cmd


@pytest.fixture(scope="session")
def postgres():
    """A PostgreSQL server on 127.0.0.1 for this session: yields a function that makes a fresh database URL."""
    initdb, pg_ctl = _pg_bin("initdb"), _pg_bin("pg_ctl")
    if not (initdb and pg_ctl):
        pytest.fail("the league's PostgreSQL tests need PostgreSQL's initdb and pg_ctl: apt install postgresql "
                    "(.ci/run does), or run RACERLAB_TEST_LEAGUE_DB=sqlite pytest to leave them out")
    root = Path(tempfile.mkdtemp(prefix="racerlab-test-pg-"))  # outside pytest's folders, which only root may enter
    root.chmod(0o755)
    if os.geteuid() == 0:
        shutil.chown(root, "postgres")
    data = root / "data"
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port = sock.getsockname()[1]
    subprocess.run(_as_postgres([initdb, "-D", str(data), "-A", "trust", "-U", "postgres", "--no-sync"]),
                   check=True, capture_output=True)
    opts = f"-c listen_addresses=127.0.0.1 -p {port} -k {data} -c fsync=off -c max_connections=200"
    subprocess.run(_as_postgres([pg_ctl, "-D", str(data), "-o", opts, "-w", "-l", str(data / "log"), "start"]),
                   check=True, capture_output=True)
    counter = itertools.count()
    from sqlalchemy import create_engine, text

    admin = create_engine(f"postgresql+psycopg://postgres@127.0.0.1:{port}/postgres", isolation_level="AUTOCOMMIT")

    def fresh() -> str:
        name = f"league_{next(counter)}"
        with admin.connect() as conn:
            conn.execute(text(f"CREATE DATABASE {name}"))
        return f"postgresql://postgres@127.0.0.1:{port}/{name}"

    yield fresh
    admin.dispose()
    subprocess.run(_as_postgres([pg_ctl, "-D", str(data), "-m", "immediate", "stop"]), capture_output=True)
    shutil.rmtree(root, ignore_errors=True)


BOTH_DATABASES = {"test_store", "test_queue", "test_people", "test_races", "test_submissions", "test_results",
                  "test_seasons",
                  "test_migrations", "test_hostile"}
DATABASES = ("sqlite", "postgresql")


def pytest_generate_tests(metafunc):
    """Each test of a `BOTH_DATABASES` module that opens a league runs once per database (ids `[sqlite]`,
    `[postgresql]`), unless RACERLAB_TEST_LEAGUE_DB names one or the test is marked `one_database` (its cost is
    evaluations, which read and write the same rows as the tests beside it)."""
    chosen = os.environ.get("RACERLAB_TEST_LEAGUE_DB", "")
    if chosen and chosen not in DATABASES:
        raise pytest.UsageError(f"RACERLAB_TEST_LEAGUE_DB={chosen}: use sqlite or postgresql")
    if "db_url" not in metafunc.fixturenames:
        return
    module = metafunc.module.__name__.rsplit(".", 1)[-1]
    both = module in BOTH_DATABASES and metafunc.definition.get_closest_marker("one_database") is None
    kinds = [chosen] if chosen else list(DATABASES if both else DATABASES[:1])
    metafunc.parametrize("db_kind", kinds, scope="function")


@pytest.fixture
def db_url(request, db_kind):
    """The database URL a test's league uses: None (SQLite in the folder) or a fresh PostgreSQL database."""
    return request.getfixturevalue("postgres")() if db_kind == "postgresql" else None


@pytest.fixture
def league(tmp_path, db_url):
    lg, _ = League.create(tmp_path / "club", db_url, password=PASSWORD)
    yield lg
    lg.close()


@pytest.fixture
def admin(league):
    return league.local_admin()


def racer(league, admin, alias: str, role: str = "racer"):
    return league.accept_invite(league.invite(admin, alias, role).code, PASSWORD)
