"""The checkpoint and the metadata facts every part reads through one method: compatibility, top speed,
and what a clone's first checkpoint keeps."""

from __future__ import annotations

import math

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
