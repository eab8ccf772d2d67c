"""training.toml's [car] table: the simulator, overrides of fitted constants, one-line errors naming file and key."""

import pytest

from racerlab.errors import ConfigError
from racerlab.model import load_training_config
from racerlab.sim import World
from racerlab.spec import car_params


def _cfg(tmp_path, text):
    p = tmp_path / "training.toml"
    p.write_text(text)
    return p, load_training_config(p)


def test_car_table_names_the_simulator_and_overrides(tmp_path):
    _, cfg = _cfg(tmp_path, '[car]\nsimulator = "console"\nyaw_gain = 0.5\ndelay_steps = 1\n')
    car = cfg.car.params("4")
    assert (car.simulator, car.control, car.yaw_gain, car.delay_steps) == ("console", "effort", 0.5, 1.0)
    assert car.step_jitter  # training jitters
    assert not cfg.car.params("4", training=False).step_jitter
    # everything not overridden is the console effort car's
    assert car.accel_mps2 == car_params("console", "4").accel_mps2
    # the table survives a round trip through to_toml
    p2 = tmp_path / "again.toml"
    p2.write_text(cfg.to_toml())
    assert load_training_config(p2).car == cfg.car
    # a world built with the settings drives that car
    assert World("lab_oval", 1, car=cfg.car).sim.car_params.yaw_gain == 0.5


def test_default_is_droa_with_jitter(tmp_path):
    _, cfg = _cfg(tmp_path, "")
    car = cfg.car.params()
    assert car.simulator == "droa" and car.control == "velocity" and car.step_jitter


@pytest.mark.parametrize("text, key", [
    ('[car]\nsimulator = "gazebo"\n', "car.simulator"),
    ("[car]\nyaw_gian = 0.5\n", "car.yaw_gian"),
    ("[car]\nyaw_gain = -1\n", "car.yaw_gain"),
    ('[car]\naccel_mps2 = "fast"\n', "car.accel_mps2"),
    ("[car]\ndelay_steps = 7\n", "car.delay_steps"),
    ("[car]\nstep_jitter = 1\n", "car.step_jitter"),
])
def test_bad_car_table_names_file_and_key(tmp_path, text, key):
    p = tmp_path / "training.toml"
    p.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_training_config(p)
    msg = str(err.value)
    assert str(p) in msg and key in msg and "\n" not in msg
