"""The car a training drives: named in its result and every metrics row; the in-training evaluation drives exact
steps (a lucky draw of short jittered steps would otherwise count as a faster lap)."""

from __future__ import annotations

from racerlab.logs import read_metrics_jsonl
from racerlab.model import init_model
from racerlab.reward import RewardCaller
from racerlab.train import WorldBuilder, apply_overrides, train
from tests.conftest import aws_track_path


def test_training_names_its_car_and_evaluates_on_exact_steps(tmp_path):
    folder = init_model(tmp_path / "m", track=str(aws_track_path("reInvent2019_track")), max_speed=2.0)
    folder.config_path.write_text(folder.config_path.read_text().replace('[car]\nsimulator = "droa"',
                                                                          '[car]\nsimulator = "console"'))
    cfg = apply_overrides(folder.config(), num_cars=4)
    builder = WorldBuilder(cfg, folder.metadata(), RewardCaller(folder.reward_function()))
    trained = builder.training_worlds()[0].sim.car_params
    evaluated = builder.evaluation_world().sim.car_params
    assert trained.step_jitter and not evaluated.step_jitter
    assert trained.simulator == evaluated.simulator == "console"

    r = train(folder.path, iterations=1, progress=False, num_cars=16)
    name = "console, velocity control (version >= 5)"
    assert r.car == name
    assert [m["car"] for m in read_metrics_jsonl(folder.path / "metrics" / "metrics.jsonl")] == [name]


def test_a_car_table_that_asks_for_jitter_jitters_the_evaluation_too(tmp_path):
    folder = init_model(tmp_path / "m", track=str(aws_track_path("reInvent2019_track")), max_speed=2.0)
    folder.config_path.write_text(folder.config_path.read_text().replace("[car]\n", "[car]\nstep_jitter = true\n"))
    builder = WorldBuilder(folder.config(), folder.metadata(), RewardCaller(folder.reward_function()))
    assert builder.evaluation_world().sim.car_params.step_jitter
