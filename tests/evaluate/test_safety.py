"""A shared model runs none of its author's code: checkpoints load weights only, and `evaluate` and `race`
never import the folder's reward_function.py. `race` writes into a model folder, not the current directory."""

from __future__ import annotations

import os

import pytest
import torch

from racerlab.errors import RacerlabError
from racerlab.evaluate import evaluate, race
from racerlab.model import CheckpointInfo
from tests.conftest import aws_track_path
from tests.evaluate.models import write_checkpoint, write_model


class _Payload:
    """Unpickling this runs `touch <marker>`: what a crafted checkpoint would do."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


@pytest.fixture
def straight_model(tmp_path):
    folder = write_model(tmp_path / "m", aws_track_path("Straight_track"))
    write_checkpoint(folder)
    return folder


def test_a_crafted_checkpoint_is_refused_without_running_its_code(tmp_path, straight_model):
    marker = tmp_path / "ran"
    good = straight_model.load_checkpoint(straight_model.resolve_checkpoint("last"))
    assert "agent" in good  # what racerlab writes loads under the allow-list
    info = CheckpointInfo("2_Step-200.pt", 2, 200)
    torch.save({**good, "agent": _Payload(marker)}, straight_model.checkpoint_path(info))
    with pytest.raises(RacerlabError) as err:
        straight_model.load_checkpoint(info)
    msg = str(err.value)
    assert "\n" not in msg and str(straight_model.checkpoint_path(info)) in msg and "refused" in msg
    assert "system" in msg  # names what it would have called
    with pytest.raises(RacerlabError, match="refused"):
        evaluate(straight_model.path, checkpoint="last", trials=1, write=False)
    assert not marker.exists()


def test_evaluate_and_race_do_not_import_the_reward_function(tmp_path, straight_model, monkeypatch):
    marker = tmp_path / "imported"
    straight_model.reward_path.write_text(f"open({str(marker)!r}, 'w').close()\n"
                                          "def reward_function(params):\n    return 7.0\n")
    res = evaluate(straight_model.path, trials=1, write=False)
    assert not marker.exists()
    assert res.steps > 10 and not res.run.trace["reward"].any()  # AWS logs evaluation rewards as 0
    monkeypatch.chdir(tmp_path)
    board = race([straight_model.path], rules=None)
    assert not marker.exists()
    # the leaderboard goes to the first model's folder, not the current directory
    assert board.path.parent == straight_model.path and board.path.name.startswith("race-")
    assert not list(tmp_path.glob("race-*.json"))


def test_an_explicit_reward_is_run_and_logged(straight_model):
    res = evaluate(straight_model.path, trials=1, write=False, reward=lambda params: 2.5)
    t = res.run.trace
    assert set(t["reward"][t["episode_status"] != "prepare"]) == {2.5}
