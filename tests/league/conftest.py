"""League fixtures: a league folder with its admin, small features models (distinct weights per seed), tracks."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from racerlab.league import League
from tests.conftest import aws_track_path

PASSWORD = "correct horse battery"


def features_model(path: Path, track, actions=((0.0, 1.0),), seed: int = 0, iteration: int = 1):
    """A features model folder whose one checkpoint holds a fresh agent drawn with `seed` (best and last)."""
    from racerlab.agent import make_agent
    from racerlab.model import ModelFolder, TrainingState
    from racerlab.sim.core import Simulator
    from racerlab.sim.observations import make_observation
    from racerlab.track import load

    path.mkdir(parents=True, exist_ok=True)
    space = [{"steering_angle": s, "speed": v, "index": i} for i, (s, v) in enumerate(actions)]
    meta = {"action_space": space, "action_space_type": "discrete", "sensor": ["FEATURES"], "neural_network": "MLP",
            "training_algorithm": "clipped_ppo", "version": "5"}
    (path / "model_metadata.json").write_text(json.dumps(meta))
    (path / "reward_function.py").write_text("def reward_function(params):\n    return 1.0\n")
    (path / "training.toml").write_text(f'[track]\nnames = ["{track}"]\n[run]\nnum_cars = 1\n')
    folder = ModelFolder(path)
    m = folder.metadata()
    obs = make_observation(None, Simulator(load(str(track)), 1), m)
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


@pytest.fixture
def league(tmp_path):
    lg, _ = League.create(tmp_path / "club", password=PASSWORD)
    yield lg
    lg.close()


@pytest.fixture
def admin(league):
    return league.local_admin()


def racer(league, admin, alias: str, role: str = "racer"):
    return league.accept_invite(league.invite(admin, alias, role).code, PASSWORD)
