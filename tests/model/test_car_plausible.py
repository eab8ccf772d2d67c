"""A [car] table's constants are held to what a DeepRacer car can be: a wheelbase in mm, a steering limit in radians,
an inf or a billion sub-steps is one line naming the key, not a nonsense car, a torch traceback or a hang."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

import racerlab
from racerlab.errors import ConfigError
from racerlab.model import init_model, load_training_config
from racerlab.model.config import parse_training_config


@pytest.mark.parametrize("key, value, words", [
    ("wheelbase_m", 164, "car.wheelbase_m = 164.0 is not a plausible value for a DeepRacer car; give 0.05 to 1 m"),
    ("speed_tau_s", float("inf"), "car.speed_tau_s = inf is not a plausible"),
    ("max_steer_deg", 0.52, "car.max_steer_deg = 0.52 is not a plausible value for a DeepRacer car; give 5 to 60"),
    ("yaw_gain", float("inf"), "car.yaw_gain = inf is not a plausible"),
    ("substeps", 1_000_000_000, "car.substeps = 1000000000 is not a plausible value for a DeepRacer car; give 1 to 64"),
    ("accel_mps2", float("nan"), "car.accel_mps2 = nan is not a plausible"),
])
def test_implausible_car_constants_are_one_line(key, value, words):
    with pytest.raises(ConfigError) as err:
        parse_training_config({"car": {key: value}}, "m/training.toml")
    msg = str(err.value)
    assert msg.startswith("m/training.toml"), msg
    assert words in msg and "\n" not in msg


def test_every_fitted_car_and_the_calibrated_range_are_plausible():
    from racerlab.spec import CAR_TABLE, CarParams, implausible

    for constants in CAR_TABLE.values():
        car = CarParams(**constants)
        assert [k for k in constants if implausible(k, getattr(car, k))] == []
    cfg = parse_training_config({"car": {"wheelbase_m": 0.17, "max_steer_deg": 25, "substeps": 8}})
    assert cfg.car.params().wheelbase_m == 0.17 and cfg.car.params().substeps == 8


def test_train_with_a_billion_substeps_stops_at_once(tmp_path):
    folder = init_model(tmp_path / "m")
    toml = folder.path / "training.toml"
    toml.write_text(toml.read_text().replace("[car]\n", "[car]\nsubsteps = 1000000000\n"))
    with pytest.raises(ConfigError, match="car.substeps = 1000000000"):
        load_training_config(toml)
    env = {**os.environ, "PYTHONPATH": str(Path(racerlab.__file__).parents[1])}
    out = subprocess.run([sys.executable, "-m", "racerlab", "train", str(folder.path), "--iterations", "1"],
                         capture_output=True, text=True, timeout=90, env=env)
    assert out.returncode == 2 and "car.substeps = 1000000000 is not a plausible" in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1
