"""`racerlab calibrate` loses nothing and reads only what it can: `--out` merges into a model's training.toml or
refuses, before the fit, a file that is not its own; damaged, endless or too short logs are one line before the fit.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import racerlab.calibrate
from racerlab.cli import main
from racerlab.model import init_model, load_training_config
from tests.calibrate.test_cli import DROA_EVAL

needs_logs = pytest.mark.skipif(not DROA_EVAL.is_dir(), reason="the shared real logs are not beside the checkout")


@pytest.fixture
def no_fit(monkeypatch):
    """The fit must not start: every check these tests make comes before it."""
    def fit(*a, **k):
        raise AssertionError("the fit started before the input was checked")

    monkeypatch.setattr(racerlab.calibrate, "calibrate", fit)


@needs_logs
def test_out_into_a_models_training_toml_merges_the_car_table_and_keeps_the_rest(tmp_path, capsys):
    folder = init_model(tmp_path / "m1")
    toml = folder.path / "training.toml"
    toml.write_text(toml.read_text().replace("[car]\n", "[car]\nstep_jitter = false  # mine\n")
                    .replace("minutes = 0.0", "minutes = 7.0"))
    before = tomllib.loads(toml.read_text())
    assert main(["calibrate", str(DROA_EVAL), "--out", str(toml), "--resamples", "0"]) == 0
    after = tomllib.loads(toml.read_text())
    assert {k: v for k, v in after.items() if k != "car"} == {k: v for k, v in before.items() if k != "car"}
    assert after["stop"]["minutes"] == 7 and after["car"]["step_jitter"] is False  # the user's key stays
    out = capsys.readouterr().out
    printed = tomllib.loads(out[out.index("# racerlab calibrate"):out.index("merged the [car] table")])["car"]
    assert {k: after["car"][k] for k in printed} == printed and len(printed) >= 9
    assert load_training_config(toml).car.params().yaw_gain == pytest.approx(printed["yaw_gain"])
    assert toml.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    assert (folder.path / "reward_function.py").is_file() and len(list(folder.path.iterdir())) == 5  # + the png


def test_merging_twice_replaces_the_earlier_table_and_its_comments():
    from racerlab.calibrate.out import merged

    table = '# racerlab calibrate: a\n# held-out median front-point error (m) after 1: 0.1\n[car]\nyaw_gain = 0.5\n'
    user = '[run]\nseed = 3\n\n[car]\nsimulator = "droa"\nsubsteps = 2\n\n[stop]\nminutes = 1\n'
    once = merged(user, table)
    twice = merged(once, table.replace("0.5", "0.7").replace(": a", ": b"))
    data = tomllib.loads(twice)
    assert data == {"run": {"seed": 3}, "car": {"simulator": "droa", "substeps": 2, "yaw_gain": 0.7},
                    "stop": {"minutes": 1}}
    assert twice.count("# racerlab calibrate") == 1 and "calibrate: b" in twice and "0.5" not in twice
    assert merged("", table) == table and tomllib.loads(merged("[run]\nseed = 1\n", table))["car"] == {"yaw_gain": 0.5}


def _not_toml(tmp_path):
    (tmp_path / "car.toml").write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00")
    return "car.toml", "not a TOML file"


def _foreign_toml(tmp_path):
    (tmp_path / "pyproject.toml").write_text('[tool.black]\nline-length = 100\n')
    return "pyproject.toml", "a TOML file with [tool]"


def _foreign_png(tmp_path):
    (tmp_path / "car.png").write_bytes(b"\x89PNG\r\n\x1a\nsomeone's picture")
    return "car.toml", "which racerlab calibrate did not draw"


def _folder(tmp_path):
    (tmp_path / "x.toml").mkdir()
    return "x.toml", "not a regular file"


def _inline_car(tmp_path):
    (tmp_path / "training.toml").write_text('car = { simulator = "droa" }\n')
    return "training.toml", "copy the table by hand"


@pytest.mark.parametrize("make", [
    lambda tmp: ("notes.txt", "goes into a .toml file"),
    lambda tmp: ("car.png", "goes into a .toml file"),
    lambda tmp: ("", "goes into a .toml file"),
    lambda tmp: ("/dev/null", "goes into a .toml file"),
    lambda tmp: ("/proc/car.toml", "cannot write in /proc"),
    _not_toml, _foreign_toml, _foreign_png, _folder, _inline_car,
], ids=["txt", "png", "empty", "device", "unwritable-folder", "not-toml", "pyproject", "foreign-png", "folder",
        "inline-car"])
def test_an_out_that_is_not_its_own_is_refused_before_the_fit(tmp_path, monkeypatch, capsys, no_fit, make):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "notes.txt").write_text("my notes\n")
    (tmp_path / "notes.png").write_bytes(b"\x89PNG my sketch")
    out, words = make(tmp_path)
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    assert main(["calibrate", str(tmp_path / "notes.txt"), "--out", out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert words in err[-1] and err[-1].startswith("racerlab: error: --out")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == before


def _csv(tmp_path: Path, name: str, change) -> Path:
    df = pd.read_csv(DROA_EVAL / "0-iteration.csv")
    path = tmp_path / name
    text = change(df)
    path.write_text(text if isinstance(text, str) else text.to_csv(index=False))
    return path


def _steer_inf(df):
    df.loc[100:110, "steer"] = np.inf
    return df


def _huge_episode(df):
    return df.to_csv(index=False).replace("\n0,", "\n10000000000000000000000000,")


def _duplicate_column(df):
    df["X2"] = df["X"]
    return df.to_csv(index=False).replace(",X2\n", ",X\n", 1)


@needs_logs
@pytest.mark.parametrize("change, words", [
    (lambda df: df.head(40), "stretches of 15 driven steps to fit (at least 150"),
    (_steer_inf, "not finite numbers"),
    (_huge_episode, "cannot be read as a log"),
    (_duplicate_column, "cannot be read as a log"),
], ids=["26-rows", "inf-steering", "huge-episode", "duplicate-column"])
def test_a_log_that_cannot_pin_the_car_down_is_one_line_before_the_fit(tmp_path, change, words):
    from racerlab.calibrate.run import calibrate
    from racerlab.errors import ConfigError

    log = _csv(tmp_path, "0-iteration.csv", change)
    with pytest.raises(ConfigError) as err:
        calibrate([log], resamples=0)
    msg = str(err.value)
    assert words in msg and str(log) in msg and "\n" not in msg


@needs_logs
def test_damaged_and_endless_inputs_are_one_line(tmp_path, capsys, no_fit):
    (tmp_path / "a").symlink_to(tmp_path / "b")
    (tmp_path / "b").symlink_to(tmp_path / "a")
    os.mkfifo(tmp_path / "fifo")
    cut = tmp_path / "cut.tar.gz"
    subprocess.run(["tar", "-czf", str(tmp_path / "whole.tar.gz"), "-C", str(DROA_EVAL.parent), DROA_EVAL.name],
                   check=True)
    cut.write_bytes((tmp_path / "whole.tar.gz").read_bytes()[:20_000])
    cases = [("a", "Too many levels of symbolic links"), ("fifo", "not a file or a folder"),
             ("/dev/zero", "not a file or a folder")]
    for path, words in cases:
        assert main(["calibrate", str(tmp_path / path), "--out", str(tmp_path / "car.toml")]) == 2
        err = capsys.readouterr().err.strip().splitlines()[-1]
        assert words in err and path in err, err
    assert main(["calibrate", str(DROA_EVAL), "--resamples", "1000000", "--out", str(tmp_path / "car.toml")]) == 2
    assert "--resamples 1000000: give 0 to 50" in capsys.readouterr().err
    from racerlab.calibrate.run import calibrate
    from racerlab.errors import ConfigError

    with pytest.raises(ConfigError, match=r"cut\.tar\.gz: cannot be read as a log \(Compressed file ended"):
        calibrate([cut], resamples=0)
    assert not (tmp_path / "car.toml").exists()


def test_constants_on_the_edge_of_their_search_range_are_named():
    from types import SimpleNamespace

    from racerlab.calibrate.fit import BOUNDS
    from racerlab.calibrate.run import on_bounds
    from racerlab.spec import CarParams

    hi = BOUNDS["brake_mps2"][1]
    notes = on_bounds(SimpleNamespace(car=CarParams(brake_mps2=hi, accel_mps2=20.0)))
    assert len(notes) == 1 and notes[0].startswith(f"brake_mps2 = {hi:g} sits on the edge")
    assert on_bounds(SimpleNamespace(car=CarParams(accel_mps2=20.0, brake_mps2=20.0, ground_factor=1.0))) == []


def test_dev_zero_is_refused_in_a_fresh_process_within_seconds(tmp_path):
    """In a child with 2 GB of address space, so that a reader that does not check cannot eat the machine."""
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (2 << 30, 2 << 30)); "
            "from racerlab.cli import main; sys.exit(main(['calibrate', '/dev/zero', '--out', sys.argv[1]]))")
    env = {**os.environ, "PYTHONPATH": str(Path(racerlab.calibrate.__file__).parents[2])}
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "car.toml")], capture_output=True, text=True,
                         timeout=120, env=env)
    assert out.returncode == 2 and "/dev/zero: not a file or a folder" in out.stderr


def test_the_tables_calibrate_merges_into_are_every_table_a_training_toml_has():
    """calibrate may not import `model` (docs/architecture.md), so it names training.toml's tables itself: a new
    table there (issue 31's [teacher]) made it refuse every new model's training.toml until listed."""
    from racerlab.calibrate.out import TRAINING_TABLES
    from racerlab.model.config import SECTIONS

    assert set(TRAINING_TABLES) == set(SECTIONS) | {"worker"}
