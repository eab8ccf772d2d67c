"""Training over generated tracks (training.toml [track] generated, `racerlab init --preset generalise`)
and under domain randomisation ([randomise])."""

from __future__ import annotations

import pytest

from racerlab.errors import ConfigError, RacerlabError
from racerlab.model import init_model, parse_training_config
from racerlab.train import train
from racerlab.train.loop import Trainer


@pytest.fixture
def preset_model(tmp_path):
    folder = init_model(tmp_path / "m", max_speed=1.5, num_cars=8, preset="generalise")
    text = folder.config_path.read_text().replace("generated = 8", "generated = 3").replace(
        "regenerate_every = 5", "regenerate_every = 1")
    folder.config_path.write_text(text)
    return folder


def test_preset_writes_generated_tracks(tmp_path):
    cfg = init_model(tmp_path / "a", preset="generalise").config()
    assert cfg.track.generated == 8 and cfg.track.regenerate_every == 5
    assert cfg.run.observation == ""
    lidar = init_model(tmp_path / "b", sensor="lidar", preset="generalise").config()
    assert lidar.run.observation == "lidar:walls"  # AWS tracks have no walls: a lidar would see nothing
    with pytest.raises(RacerlabError, match="unknown preset 'fast'"):
        init_model(tmp_path / "c", preset="fast")


def test_cars_spread_over_generated_tracks_redrawn_each_period(preset_model):
    t = Trainer(preset_model.path, progress=False)
    first = [w.sim.track for w in t.collector.worlds]
    assert [w.sim.num_cars for w in t.collector.worlds] == [3, 3, 2]
    assert all(tr.name.startswith("generated_0_") for tr in first)
    assert t.eval_world.sim.track.name == "lab_technical"  # evaluation stays on the named track
    t._resume_or_start()
    t.iterate(0.0)
    assert [w.sim.track.name for w in t.collector.worlds] == [tr.name for tr in first]  # iteration 1 drove draw 0
    t.iterate(0.0)
    drawn = [w.sim.track for w in t.collector.worlds]
    assert all(tr.name.startswith("generated_1_") for tr in drawn)
    assert not any(a.length == b.length for a, b in zip(first, drawn, strict=True))
    t.logs.close()


def test_training_on_generated_tracks_under_randomisation_runs_and_resumes(preset_model):
    text = preset_model.config_path.read_text().replace("latency_steps = 0", "latency_steps = 1").replace(
        "steering_gain = 0.0", "steering_gain = 0.1")
    preset_model.config_path.write_text(text)
    r = train(preset_model.path, iterations=2, progress=False)
    assert r.iterations == 2 and r.env_steps > 0
    r = train(preset_model.path, iterations=1, progress=False)
    assert r.iterations == 3
    t = Trainer(preset_model.path, progress=False)
    assert all(w.actuation is not None for w in t.collector.worlds) and t.eval_world.actuation is None
    t.logs.close()


def test_generated_settings_are_checked():
    with pytest.raises(ConfigError, match="run.num_cars must be at least the number of tracks"):
        parse_training_config({"track": {"generated": 40}})
    with pytest.raises(ConfigError, match="generated_min_length <= generated_max_length"):
        parse_training_config({"track": {"generated": 2, "generated_min_length": 50.0, "generated_max_length": 30}})
