"""Training a folder unattended: one trainer per folder, bad settings refused in one line, edits honoured on
resume, faults rolled back, watchdogs, bounded logs."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

from racerlab.errors import ConfigError, RacerlabError, TrackError
from racerlab.model import ModelFolder, init_model
from racerlab.train import train
from tests.conftest import aws_track_path

FAST = dict(progress=False, num_cars=8)
SRC = os.path.join(os.path.dirname(__file__), "..", "..", "src")


@pytest.fixture
def model(tmp_path):
    return init_model(tmp_path / "model", track=str(aws_track_path("reInvent2019_track")), max_speed=2.0)


# ---- the lock ------------------------------------------------------------------------------------------------
def _holder(folder: ModelFolder) -> subprocess.Popen:
    code = ("import sys, time\nfrom racerlab.model import ModelFolder\n"
            f"ModelFolder({str(folder.path)!r}).lock().acquire()\nprint('held', flush=True)\ntime.sleep(60)\n")
    env = {**os.environ, "PYTHONPATH": os.path.abspath(SRC)}
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=env)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_trainer_is_refused_with_the_first_ones_pid(model):
    proc = _holder(model)
    try:
        with pytest.raises(RacerlabError) as err:
            train(model.path, iterations=1, **FAST)
        msg = str(err.value)
        assert f"process {proc.pid}" in msg and str(model.lock_path) in msg and "\n" not in msg
        assert not model.checkpoints()  # refused before touching anything
    finally:
        proc.kill()
        proc.wait()


def test_a_stale_lock_is_taken_over_and_released(model):
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()
    model.lock_path.write_text(f"{gone.pid}\n")  # a trainer that was killed -9
    r = train(model.path, iterations=1, **FAST)
    assert r.iterations == 1
    assert not model.lock_path.exists()  # released at the end
    with model.lock():
        assert model.lock().holder() == os.getpid()
    assert not model.lock_path.exists()


# ---- validation ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(("flags", "expected"), [
    ({"minutes": -3}, "--minutes must be a number >= 0 (0 = no limit), got -3"),
    ({"num_cars": 0}, "--cars must be at least 1, got 0"),
    ({"iterations": -1}, "--iterations must be a number >= 0 (0 = no limit), got -1"),
])
def test_bad_flags_are_refused_before_training(model, flags, expected):
    with pytest.raises(ConfigError) as err:
        train(model.path, progress=False, **flags)
    assert str(err.value) == expected
    assert not model.checkpoints()


def test_an_unknown_track_in_training_toml_names_the_file_and_key(model):
    model.config_path.write_text('[track]\nnames = ["no_such_track_anywhere"]\n')
    with pytest.raises(TrackError) as err:
        train(model.path, iterations=1, **FAST)
    msg = str(err.value)
    assert msg.startswith(f"{model.config_path}: track.names: ") and "no_such_track_anywhere" in msg


# ---- edits on resume -----------------------------------------------------------------------------------------
def _set_hp(folder: ModelFolder, **changes) -> None:
    hp = json.loads(folder.hyperparameters_path.read_text())
    folder.hyperparameters_path.write_text(json.dumps({**hp, **changes}))


def test_an_edited_learning_rate_takes_effect_on_resume_and_is_reported(model):
    train(model.path, iterations=1, **FAST)
    _set_hp(model, lr=0.0001, num_epochs=3)
    r = train(model.path, iterations=1, **FAST)
    assert r.history[-1]["lr"] == pytest.approx(0.0001)
    assert any("lr 0.0003 → 0.0001" in n and "num_epochs 10 → 3" in n and str(model.hyperparameters_path) in n
               for n in r.notes)
    r = train(model.path, iterations=1, **FAST)  # unchanged since: nothing to report, the lr stays
    assert r.history[-1]["lr"] == pytest.approx(0.0001) and not any("changed since" in n for n in r.notes)


def test_changes_that_cannot_apply_are_refused_with_the_reason(model):
    train(model.path, iterations=1, **FAST)
    meta = json.loads(model.metadata_path.read_text())
    meta["action_space"] = meta["action_space"][:3]
    model.metadata_path.write_text(json.dumps(meta))
    with pytest.raises(ConfigError, match="number of actions"):
        train(model.path, iterations=1, **FAST)
