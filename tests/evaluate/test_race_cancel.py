"""A running race stops when asked: at the end of the lap on the track, keeping the finished models' evaluations
and writing no leaderboard (issue 28, case 13: a race of 1 000 copies could not be cancelled)."""

from __future__ import annotations

import threading
from pathlib import Path

import pytest

from racerlab.evaluate import RaceCancelled, RaceRules, race
from racerlab.logs import evaluation_dirs
from tests.evaluate.models import write_checkpoint, write_model

RULES = RaceRules(trials=20)  # an untrained model's trials end in ~30 ms each on lab_oval; 20 take about 0.6 s


@pytest.fixture
def models(tmp_path):
    out = []
    for name in ("a", "b", "c"):
        folder = write_model(tmp_path / name, "lab_oval", actions=((0.0, 1.0), (15.0, 1.0)))
        write_checkpoint(folder)
        out.append(folder.path)
    return out


def test_a_race_cancelled_mid_model_stops_at_the_lap_end_and_keeps_only_whole_evaluations(models, monkeypatch):
    """The stop is asked while the second model is on the track, after its second lap: the race ends at that lap's
    end, keeps the first model's whole evaluation and writes nothing for the second (the ask is tied to b's laps,
    not to a clock: a fast machine runs a whole 20-trial evaluation in half a second)."""
    import sys

    race_module = sys.modules["racerlab.evaluate.race"]  # the package's `race` names the function

    cancel = threading.Event()
    laps = {"a": 0, "b": 0, "c": 0}
    real = race_module.evaluate

    def evaluate(model, **kw):
        name, inner = Path(model).name, kw["on_lap"]

        def on_lap(lap):
            laps[name] += 1
            if name == "b" and laps[name] == 2:
                cancel.set()
            inner(lap)
        return real(model, **{**kw, "on_lap": on_lap})

    monkeypatch.setattr(race_module, "evaluate", evaluate)
    with pytest.raises(RaceCancelled) as err:
        race(models, rules=RULES, cancel=cancel)
    assert laps["a"] > 2 and laps["b"] == 2 and laps["c"] == 0  # b stopped at the lap end where the stop was seen
    assert [r.model for r in err.value.done] == ["a"]
    assert str(err.value) == ("race cancelled after 1 of 3 models: the evaluations of a are kept in their model "
                              "folders; no leaderboard was written")
    assert len(evaluation_dirs(models[0])) == 1 and (evaluation_dirs(models[0])[0] / "summary.json").is_file()
    assert evaluation_dirs(models[1]) == [] and evaluation_dirs(models[2]) == []
    assert not list(models[0].glob("race-*.json"))


def test_a_race_cancelled_before_it_starts_writes_nothing(models):
    cancel = threading.Event()
    cancel.set()
    with pytest.raises(RaceCancelled, match="^race cancelled after 0 of 3 models: nothing was written$"):
        race(models, rules=RULES, cancel=cancel)
    assert all(evaluation_dirs(m) == [] for m in models)


def test_a_race_not_cancelled_writes_its_leaderboard(models, tmp_path):
    board = race(models[:2], rules=RaceRules(trials=1), cancel=threading.Event(), out=tmp_path / "board.json")
    assert board.path.is_file() and sorted(r["model"] for r in board.rows()) == ["a", "b"]
