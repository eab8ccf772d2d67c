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
