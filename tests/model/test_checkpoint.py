"""The checkpoint and the metadata facts every part reads through one method: compatibility, top speed,
and what a clone's first checkpoint keeps."""

from __future__ import annotations

import math

import pytest

from racerlab.errors import RacerlabError
from racerlab.model import ContinuousActions, DiscreteActions, TrainingState, make_metadata
from racerlab.model.checkpoint import CheckpointInfo


def test_differences_name_what_the_weights_cannot_carry_over():
    camera = make_metadata("camera")
    assert camera.differences(camera) == []
    more_actions = make_metadata("camera", max_speed=2.0)  # other speeds, same count: the weights still fit
    assert camera.differences(more_actions) == []
    features = make_metadata("features", action_space="continuous", algorithm="sac")
    assert camera.differences(features) == [
        "action space type discrete → continuous", "sensors ['FRONT_FACING_CAMERA'] → ['FEATURES']",
        "neural_network DEEP_CONVOLUTIONAL_NETWORK_SHALLOW → MLP", "training_algorithm clipped_ppo → sac"]
    fewer = DiscreteActions((-30.0, 0.0, 30.0), (1.0, 1.0, 1.0))
    assert camera.differences(type(camera)(fewer, camera.sensor, camera.neural_network)) == [
        f"number of actions {camera.actions.n} → 3"]


def test_top_speed_is_the_fastest_action_or_the_range_top():
    assert DiscreteActions((-30.0, 0.0, 30.0), (1.5, 3.25, 0.5)).top_speed == 3.25
    assert ContinuousActions(-30.0, 30.0, 0.7, 2.8).top_speed == 2.8


def test_a_clone_keeps_weights_and_counters_and_starts_the_rest_afresh():
    state = TrainingState({"w": 1}, {"old": True}, iteration=7, episodes=140, env_steps=9000, train_steps=8000,
                          best_name="6_Step-7000.pt", best_metric=55.0, rollbacks=2, collection={"starts": [3]})
    clone = state.cloned_as({"new": True})
    assert (clone.agent, clone.iteration, clone.episodes, clone.train_steps) == ({"w": 1}, 7, 140, 8000)
    assert clone.cloned and clone.metadata == {"new": True} and clone.collection == {}
    assert (clone.best_name, clone.best_metric, clone.rollbacks) == (None, None, 0)
    assert clone.to_dict()["cloned"] is True and clone.info == CheckpointInfo("7_Step-8000.pt", 7, 8000)
    back = TrainingState.from_dict(state.to_dict(), "x.pt")
    assert back.collection == {"starts": [3]} and back.best_metric == 55.0 and math.isnan(back.best_lap_time)


def test_a_checkpoint_of_another_format_is_one_line_naming_the_file():
    data = TrainingState({"w": 1}, iteration=3, collection={"worker_episodes": [4, 5]}).to_dict()
    assert data["format"] == "racerlab.checkpoint/1" and data["worker_episodes"] == [4, 5]
    assert TrainingState.from_dict(data, "x.pt").collection == {"worker_episodes": [4, 5]}  # the collection's keys
    for fmt in ("racerlab.checkpoint/2", None):
        with pytest.raises(RacerlabError) as err:
            TrainingState.from_dict({**data, "format": fmt}, "m/checkpoints/3_Step-10.pt")
        msg = str(err.value)
        assert msg.startswith(f"m/checkpoints/3_Step-10.pt: a checkpoint of format {fmt!r}, and this racerlab reads "
                              "'racerlab.checkpoint/1'") and "\n" not in msg
