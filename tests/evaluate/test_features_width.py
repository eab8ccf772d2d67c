"""A features model's vector is longer in a race with boxes or bot cars (the nearest objects ahead end it): racing
it where the length differs is refused with that cause and the race that fits (issue 27, item 8), not blamed on
"networks of other widths"."""

from __future__ import annotations

import gymnasium as gym

import racerlab.cli as cli
from racerlab.sim.objects import FEATURE_OBJECTS
from tests.evaluate.models import write_model


def _objects_model(tmp_path, name: str, race: str):
    """A features model trained for `race` (boxes or bots): its checkpoint's policy reads the longer vector."""
    from racerlab.agent import make_agent
    from racerlab.model.checkpoint import TrainingState
    from racerlab.sim.core import Simulator
    from racerlab.track import load

    folder = write_model(tmp_path / name, "lab_oval")
    count = "number_of_obstacles" if race == "object_avoidance" else "number_of_bot_cars"
    folder.config_path.write_text(folder.config_path.read_text() + f'[race]\ntype = "{race}"\n{count} = 2\n')
    plain = Simulator(load("lab_oval"), 1).feature_size
    wide = gym.spaces.Box(-10.0, 10.0, shape=(plain + 2 * FEATURE_OBJECTS,))
    meta = folder.metadata()
    agent = make_agent(wide, meta, folder.hyperparameters(), device="cpu", seed=0)
    info = folder.save_state(TrainingState(agent.state_dict(), meta.to_json(), iteration=1, train_steps=100))
    folder.update_index(info, 0.0, info, 0.0)
    return folder, plain


def test_racing_an_objects_model_head_to_model_names_the_race_as_the_cause(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    boxes, plain = _objects_model(tmp_path, "boxes", "object_avoidance")
    bots, _ = _objects_model(tmp_path, "bots", "head_to_bot")
    assert cli.main(["race", str(boxes.path), str(bots.path), "--head-to-model", "--trials", "1"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    wide = plain + 2 * FEATURE_OBJECTS
    assert f"reads {wide} numbers and this race gives it {plain}" in err[0]
    assert "object_avoidance" in err[0] and "--race-type object_avoidance" in err[0]
    assert "other widths" not in err[0]


def test_the_same_model_races_in_its_own_kind_of_race(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["evaluate"])
    boxes, plain = _objects_model(tmp_path, "boxes", "object_avoidance")
    assert cli.main(["evaluate", str(boxes.path), "--trials", "1", "--max-resets", "0"]) == 0
    assert cli.main(["evaluate", str(boxes.path), "--race-type", "time_trial", "--trials", "1"]) == 2
    err = capsys.readouterr().err
    assert f"gives it {plain}" in err and "this race has none (a time trial or a head-to-model race)" in err
