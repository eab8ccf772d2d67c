"""`ModelFolder.open`: the one door to a trained model resolves the checkpoint, reads it without running anything,
and refuses an unreadable checkpoint, non-finite weights and an incompatible model_metadata.json with one
`ModelRefused` line each."""

from __future__ import annotations

import json
import pickle

import pytest
import torch

from racerlab.errors import ModelRefused, RacerlabError
from racerlab.model import CheckpointInfo, ModelFolder, OpenModel, TrainingState, init_model


def _save(folder: ModelFolder, iteration: int, weight=0.5, metadata="folder") -> CheckpointInfo:
    """A checkpoint whose agent holds a policy of one 2x2 weight filled with `weight`."""
    stored = folder.metadata().to_json() if metadata == "folder" else metadata
    agent = {"format": "test", "policy": {"w": torch.full((2, 2), weight)}, "value": {"w": torch.ones(3)}}
    return folder.save_state(TrainingState(agent, stored, iteration=iteration, train_steps=100 * iteration))


@pytest.fixture
def model(tmp_path) -> ModelFolder:
    folder = init_model(tmp_path / "m")
    _save(folder, 1)
    best = _save(folder, 2)
    folder.update_index(_save(folder, 3), 0.0, best, 1.0)
    return folder


def test_open_resolves_best_last_a_number_or_an_info_and_gives_the_model(model):
    assert model.open().checkpoint.iteration == 2  # best, as the index names it
    assert model.open("last").checkpoint.iteration == 3
    assert model.open(1).checkpoint.iteration == model.open("1").checkpoint.iteration == 1
    info = CheckpointInfo.of(3, 300)
    opened = model.open(info)
    assert isinstance(opened, OpenModel) and opened.checkpoint == info and opened.folder is model
    assert opened.path == model.checkpoints_dir / "3_Step-300.pt" and opened.name == "m"
    assert torch.equal(opened.state.agent["policy"]["w"], torch.full((2, 2), 0.5))
    assert opened.metadata == model.metadata()
    assert opened.hyperparameters == model.hyperparameters() and opened.config == model.config()
    assert opened.observation == model.config().run.observation and opened.look == model.config().run.look
    with pytest.raises(AttributeError):
        opened.state = None  # frozen: a reader cannot swap what the door let through


def test_a_folder_without_checkpoints_or_without_that_one_is_one_line(tmp_path, model):
    empty = init_model(tmp_path / "empty")
    with pytest.raises(RacerlabError, match="no checkpoints yet; train it first"):
        empty.open()
    with pytest.raises(RacerlabError, match="no checkpoint for iteration 7; have 1, 2, 3"):
        model.open(7)


def _one_line(err) -> str:
    text = str(err.value)
    assert "\n" not in text and text == f"{err.value.path}: {err.value.problem}; {err.value.fix}"
    return text


def test_non_finite_weights_are_refused_naming_the_tensor_and_an_older_checkpoint(model):
    _save(model, 4, weight=float("nan"))
    with pytest.raises(ModelRefused) as err:
        model.open("last")
    assert err.value.reason == ModelRefused.NONFINITE
    assert _one_line(err) == (f"{model.checkpoints_dir / '4_Step-400.pt'}: non-finite weights (policy.w); the "
                              "training diverged there: pick an older one with --checkpoint 3")
    agent = model.load_state(CheckpointInfo.of(1, 100)).agent  # the oldest: only newer ones to point to
    agent["policy"]["w"][0, 0], agent["value"]["w"][1] = float("inf"), float("-inf")
    model.save_state(TrainingState(agent, model.metadata().to_json(), iteration=1, train_steps=100))
    with pytest.raises(ModelRefused, match=r"non-finite weights \(policy.w and 1 more\); the training diverged "
                                           r"there: pick another one with --checkpoint 4$"):
        model.open(1)


def test_a_lone_nan_checkpoint_says_train_again(tmp_path):
    folder = init_model(tmp_path / "m")
    _save(folder, 1, weight=float("nan"))
    with pytest.raises(ModelRefused, match="the training diverged there: train it again$"):
        folder.open()


def test_a_checkpoint_of_another_model_metadata_is_refused_with_what_differs(model):
    meta = json.loads(model.metadata_path.read_text())
    meta["action_space"] = meta["action_space"][:3]
    model.metadata_path.write_text(json.dumps(meta))
    with pytest.raises(ModelRefused) as err:
        model.open()
    assert err.value.reason == ModelRefused.METADATA
    n = len(model.load_state(CheckpointInfo.of(2, 200)).metadata["action_space"])
    assert _one_line(err) == (f"{model.checkpoints_dir / '2_Step-200.pt'}: does not match {model.metadata_path} "
                              f"(trained → now): number of actions {n} → 3; restore the model_metadata.json it was "
                              "trained with or train again")
    meta["action_space"] = [{**a, "speed": 2 * a["speed"]} for a in json.loads(json.dumps(meta["action_space"]))]
    _save(model, 5, metadata=meta)  # other speeds with the same count still fit the weights ...
    assert model.open(5).checkpoint.iteration == 5
    _save(model, 6, metadata=None)  # ... and a checkpoint that stores no metadata is taken as the folder's
    assert model.open(6).state.metadata is None


def test_a_checkpoint_whose_stored_metadata_is_damaged_is_refused(model):
    _save(model, 4, metadata={"action_space": "fast please"})
    with pytest.raises(ModelRefused) as err:
        model.open(4)
    assert err.value.reason == ModelRefused.UNREADABLE and "model_metadata.json stored in it" in _one_line(err)


class Payload:
    """Anything beyond tensors and plain data: weights_only refuses to build it."""


@pytest.mark.parametrize("content", ["damaged", "other format", "no weights", "code"])
def test_a_checkpoint_that_cannot_be_read_is_refused(model, content):
    path = model.checkpoints_dir / "4_Step-400.pt"
    data = {"damaged": None, "other format": {"format": "other/9", "agent": {}}, "no weights": {"agent": 3},
            "code": {"agent": {}, "x": Payload()}}[content]
    if data is None:
        path.write_bytes(b"PK\x03\x04 half a zip")
    else:
        torch.save(data, path)
    with pytest.raises(ModelRefused) as err:
        model.open("last")
    assert err.value.reason == ModelRefused.UNREADABLE and err.value.path == path
    said = {"damaged": "cannot read the checkpoint", "other format": "a checkpoint of format 'other/9'",
            "no weights": "not a racerlab checkpoint", "code": "refused: the checkpoint holds more than"}[content]
    assert said in _one_line(err)


def test_the_refusal_crosses_process_boundaries_whole(model):
    _save(model, 4, weight=float("nan"))
    with pytest.raises(ModelRefused) as err:
        model.open("last")
    back = pickle.loads(pickle.dumps(err.value))
    assert (str(back), back.reason, back.path, back.problem) == (str(err.value), err.value.reason, err.value.path,
                                                                 err.value.problem)
