"""A sweep spec is checked whole before anything is written or trained, and a sweep never re-initialises a model
that is already there (a name like "../victim", an absolute path, an existing model under out = ".")."""

from __future__ import annotations

import json

import pytest

pytest.importorskip("ray")

import racerlab.cluster.sweep as sweep_module  # noqa: E402
from racerlab.cli import main  # noqa: E402
from racerlab.model import init_model  # noqa: E402

HP = "hyperparameters = { num_episodes_between_training = 2, num_epochs = 1 }\n"


@pytest.fixture
def no_cluster(monkeypatch):
    """Every check these tests make comes before the sweep connects to Ray."""
    def connect(*a, **k):
        raise AssertionError("the sweep went on to train")

    monkeypatch.setattr(sweep_module, "connect", connect)


@pytest.fixture
def victim(tmp_path):
    """A model the user trained by hand: its reward and hyperparameters are their work."""
    folder = init_model(tmp_path / "victim")
    folder.write_reward("def reward_function(params):\n    return 42.0\n")
    hp = json.loads(folder.hyperparameters_path.read_text())
    folder.write_hyperparameters({**hp, "lr": 0.000123})
    return folder.path


def _files(folder):
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("where", ["dotdot", "absolute", "out-dot"])
def test_an_existing_model_is_never_reinitialised(tmp_path, capsys, no_cluster, victim, where):
    spec = tmp_path / "sweeps" / "spec.toml"
    spec.parent.mkdir()
    name, out = {"dotdot": ('"../victim"', ""), "absolute": (json.dumps(str(victim)), ""),
                 "out-dot": ('"victim"', 'out = ".."\n')}[where]
    spec.write_text(f'{out}iterations = 1\n[[model]]\nname = "fresh"\n{HP}[[model]]\nname = {name}\n{HP}')
    before = _files(victim)
    assert main(["sweep", str(spec)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and ("is not a folder name" in err or "is there already" in err), err
    assert _files(victim) == before
    assert not (tmp_path / "sweeps" / "spec" / "fresh").exists() and not (tmp_path / "fresh").exists()


@pytest.mark.parametrize("text, words", [
    ('[race]\ntrials = 0\n[[model]]\nname = "a"\n', "[race] trials must be a whole number >= 1, got 0"),
    ('[[model]]\nname = 5\n', "name = 5 is not a folder name"),
    ('cars = "four"\n[[model]]\nname = "a"\n', "cars = 'four'; give a whole number"),
    ('iterations = 0\n[[model]]\nname = "a"\n', "iterations = 0; give a whole number"),
    ('model = 5\n', "model must be [[model]] tables"),
    ('[[model]]\nname = "a"\nreward = "nope.py"\n', "reward file"),
], ids=["trials-0", "name-5", "cars-text", "iterations-0", "model-5", "reward-missing"])
def test_a_bad_spec_is_one_line_before_anything_is_written(tmp_path, capsys, no_cluster, text, words):
    spec = tmp_path / "spec.toml"
    spec.write_text(text)
    assert main(["sweep", str(spec)]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and "\n" not in err and str(spec) in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["spec.toml"]


def test_a_later_entrys_error_removes_the_folders_this_sweep_made(tmp_path, capsys, no_cluster):
    spec = tmp_path / "spec.toml"
    spec.write_text(f'[[model]]\nname = "a"\n{HP}[[model]]\nname = "b"\nhyperparameters = {{ no_such = 1 }}\n')
    assert main(["sweep", str(spec)]) == 2
    assert "unknown hyperparameter 'no_such'" in capsys.readouterr().err
    assert not (tmp_path / "spec" / "a").exists() and not (tmp_path / "spec" / "b").exists()
