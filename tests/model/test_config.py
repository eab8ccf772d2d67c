"""training.toml and `racerlab init`: defaults, round trip, and one-line errors naming file and key."""

from __future__ import annotations

import json

import pytest

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import TrainingConfig, init_model, load_hyperparameters, load_model_metadata, load_training_config


def test_defaults_round_trip(tmp_path):
    p = tmp_path / "training.toml"
    p.write_text(TrainingConfig().to_toml())
    cfg = load_training_config(p)
    assert cfg.track.names == ("lab_technical",) and cfg.run.max_steps_per_iteration == 10_000
    assert cfg.evaluation.episodes == 5 and cfg.track.round_robin_advance == 0.05


@pytest.mark.parametrize(("text", "message"), [
    ("[run]\nnum_carz = 3\n", "unknown key run.num_carz"),
    ("[runn]\n", "unknown section [runn]"),
    ("[run]\nnum_cars = \"many\"\n", "run.num_cars must be a whole number"),
    ("[track]\nreverse = 1\n", "track.reverse must be true or false"),
    ("[evaluation]\nbest_model_metric = \"speed\"\n", "best_model_metric must be one of"),
    ("[run\n", "invalid TOML"),
    ("[run]\nlook = \"gazebo\"\n", "run.look is 'gazebo'; use one of aws, classic"),
])
def test_bad_training_toml(tmp_path, text, message):
    p = tmp_path / "training.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_training_config(p)
    assert str(p) in str(err.value) and message in str(err.value) and "\n" not in str(err.value)


def test_init_writes_a_working_folder(tmp_path):
    folder = init_model(tmp_path / "m")
    meta = load_model_metadata(folder.metadata_path)
    assert meta.action_space_type == "discrete" and meta.actions.n == 10  # the console default
    assert meta.actions.steering_deg[0] == -30.0 and meta.actions.speed[:2] == (0.5, 1.0)
    hp = load_hyperparameters(folder.hyperparameters_path)
    assert hp.batch_size == 64 and hp.lr == 0.0003 and hp.num_episodes_between_training == 20
    assert "def reward_function(params)" in folder.reward_path.read_text()
    assert load_training_config(folder.config_path).run.num_cars == 32
    with pytest.raises(RacerlabError, match="already holds"):
        init_model(tmp_path / "m")


def test_init_camera_and_continuous(tmp_path):
    folder = init_model(tmp_path / "c", sensor="camera", action_space="continuous", max_speed=3.0)
    data = json.loads(folder.metadata_path.read_text())
    assert data["sensor"] == ["FRONT_FACING_CAMERA"]
    assert data["neural_network"] == "DEEP_CONVOLUTIONAL_NETWORK_SHALLOW"
    assert data["action_space"] == {"steering_angle": {"low": -30.0, "high": 30.0}, "speed": {"low": 1.0, "high": 3.0}}
    with pytest.raises(RacerlabError, match="SAC needs a continuous action space"):
        init_model(tmp_path / "s", algorithm="sac")


def test_observation_with_sensor_options(tmp_path):
    from racerlab.model import parse_training_config

    assert parse_training_config({"run": {"observation": "camera:dr"}}).run.observation == "camera:dr"
    with pytest.raises(ConfigError, match="run.observation must be empty .* or one of features, camera"):
        parse_training_config({"run": {"observation": "radar:dr"}})


WORKERS_TOML = """
[track]
names = ["lab_oval"]

[run]
num_cars = 4

[[worker]]
track.names = ["lab_technical", "lab_grand_prix"]
track.reverse = true

[[worker]]
run.seed = 7
"""


def test_worker_tables_change_only_their_worker(tmp_path):
    p = tmp_path / "training.toml"
    p.write_text(WORKERS_TOML)
    cfg = load_training_config(p)
    w0, w1, w2 = (cfg.for_worker(k) for k in range(3))
    assert w0.track.names == ("lab_technical", "lab_grand_prix") and w0.track.reverse
    assert w0.run.num_cars == 4 and w0.run.seed == 0  # the rest comes from the file's own sections
    assert w1.track.names == ("lab_oval",) and not w1.track.reverse and w1.run.seed == 7
    assert w2.track == cfg.track and w2.run == cfg.run and w2.workers == ()
    assert cfg.worker_sets(0, "track", "names") and not cfg.worker_sets(1, "track", "names")
    assert not cfg.worker_sets(5, "track", "names")
    # written back out, the tables survive
    p.write_text(cfg.to_toml())
    assert load_training_config(p).workers == cfg.workers


@pytest.mark.parametrize("table, message", [
    ("[[worker]]\ntrack.reverse = 1\n", "[[worker]] 1: track.reverse must be true or false"),
    ("[[worker]]\ntrack.speed = 1\n", "[[worker]] 1: unknown key track.speed"),
    ("[[worker]]\n\n[[worker]]\ncars = 2\n", "[[worker]] 2: unknown section cars"),
    ("[[worker]]\ntrack.start_offset = 1.5\n", "[[worker]] 1: track.start_offset must be in [0, 1)"),
])
def test_bad_worker_tables_name_the_worker_and_key(tmp_path, table, message):
    p = tmp_path / "training.toml"
    p.write_text(table)
    with pytest.raises(ConfigError) as err:
        load_training_config(p)
    assert str(p) in str(err.value) and message in str(err.value)
