"""Settings AWS or racerlab cannot use are refused in one line naming the file and the key."""

from __future__ import annotations

import json

import pytest

from racerlab.errors import ConfigError
from racerlab.model import init_model, load_model_metadata, parse_training_config


def test_a_steering_angle_past_30_degrees_is_refused(tmp_path):
    folder = init_model(tmp_path / "m")
    meta = json.loads(folder.metadata_path.read_text())
    meta["action_space"][1]["steering_angle"] = 45
    folder.metadata_path.write_text(json.dumps(meta))
    with pytest.raises(ConfigError) as err:
        load_model_metadata(folder.metadata_path)
    msg = str(err.value)
    assert msg.startswith(str(folder.metadata_path)) and "action_space[1].steering_angle is 45" in msg
    assert "30" in msg and "\n" not in msg
    meta["action_space"][1]["steering_angle"] = -30  # the limit itself is allowed
    folder.metadata_path.write_text(json.dumps(meta))
    assert -30.0 in load_model_metadata(folder.metadata_path).actions.steering_deg


def test_a_continuous_steering_range_past_30_degrees_is_refused(tmp_path):
    p = tmp_path / "model_metadata.json"
    space = {"steering_angle": {"low": -40, "high": 30}, "speed": {"low": 0.5, "high": 2}}
    p.write_text(json.dumps({"action_space": space, "action_space_type": "continuous"}))
    with pytest.raises(ConfigError, match=r"action_space\.steering_angle\.low is -40"):
        load_model_metadata(p)


@pytest.mark.parametrize("key", ["minutes", "episodes", "iterations"])
def test_a_negative_stop_value_names_its_key(key):
    with pytest.raises(ConfigError) as err:
        parse_training_config({"stop": {key: -3}}, "m/training.toml")
    assert str(err.value) == f"m/training.toml: stop.{key} must be >= 0 (0 = no limit), got -3"
