"""What the training tests share: a trained features teacher (trained once per session) and a small camera
student for it."""

from __future__ import annotations

import pytest

from racerlab.model import init_model
from racerlab.train import train

TRACK = "lab_technical"  # the bundled default track


@pytest.fixture(scope="session")
def trained_teacher(tmp_path_factory):
    """A features model of two iterations on TRACK: a teacher for `camera_student`s (the tests do not train it)."""
    folder = init_model(tmp_path_factory.mktemp("t") / "teacher", track=TRACK, max_speed=4.0,
                        action_space="continuous")
    train(folder.path, iterations=2, progress=False, num_cars=8)
    return folder


def camera_student(path, **init):
    """A camera model on TRACK with short iterations: 4 episodes each, one PPO epoch when it trains on."""
    model = init_model(path, track=TRACK, sensor="camera", max_speed=4.0, action_space="continuous", teacher=False,
                       **init)
    model.write_hyperparameters(model.hyperparameters().replace(num_episodes_between_training=4, num_epochs=1))
    return model
