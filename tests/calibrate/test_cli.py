"""`racerlab calibrate` on a real DRoA log: a report beside the constant-velocity guess, a [car] table that
training.toml takes, a picture."""

import math
import tomllib
from pathlib import Path
from types import SimpleNamespace

import pytest

from racerlab.calibrate.run import _interval_note
from racerlab.cli import main
from racerlab.cli.calibrate import interval_line
from racerlab.model import load_training_config

DROA_EVAL = Path(__file__).resolve().parents[2].parent / "shared" / "reference" / "simtraces" / \
    "droa2026-v6-Spain_track-evaluation"


@pytest.mark.skipif(not DROA_EVAL.is_dir(), reason="the shared real logs are not beside the checkout")
def test_calibrate_writes_a_car_table_training_takes(tmp_path, capsys):
    out = tmp_path / "car.toml"
    assert main(["calibrate", str(DROA_EVAL), "--simulator", "droa", "--out", str(out), "--resamples", "0"]) == 0
    text = capsys.readouterr().out
    assert "constant velocity" in text and "fitted car" in text
    assert "only 1 episode held out: too few" in text  # three episodes, every third held out
    rows = {line.split()[0]: line.split()[1:] for line in text.splitlines() if line.startswith("  ")}
    fitted = [float(v) for v in rows["fitted"][1:]]
    guess = [float(v) for v in rows["constant"][1:]]
    assert len(fitted) == 4 and all(f < g for f, g in zip(fitted, guess, strict=True))  # beats the guess at 1-15
    floor = [float(v) for v in rows["learned"][1:5]]  # the fitted car corrected by a regression: the floor row
    assert floor[3] < guess[3] and floor[3] < 1.5 * fitted[3]
    assert "(constant velocity: " in out.read_text() and "; 1 held-out episode\n" in out.read_text()
    table = tomllib.loads(out.read_text())["car"]
    assert table["simulator"] == "droa" and 0.3 < table["yaw_gain"] < 1.0
    (tmp_path / "training.toml").write_text(out.read_text())
    car = load_training_config(tmp_path / "training.toml").car.params()
    assert car.yaw_gain == pytest.approx(table["yaw_gain"])
    assert out.with_suffix(".png").stat().st_size > 10_000


def test_calibrate_names_a_missing_log(tmp_path, capsys):
    assert main(["calibrate", str(tmp_path / "nope"), "--out", str(tmp_path / "car.toml")]) == 2
    err = capsys.readouterr().err
    assert "nope" in err and "no such file" in err


def test_the_report_says_how_far_the_held_out_figure_would_move():
    fit = SimpleNamespace(held_out={1: 0.01, 15: 0.09}, held_out_interval=(0.081, 0.104), held_out_episodes=12)
    assert interval_line(fit) == ("the fitted car's median after 15 steps lies within 0.081-0.104 m in 90 % of "
                                  "resamples of the 12 held-out episodes")
    few = SimpleNamespace(held_out={15: 0.2}, held_out_interval=(math.nan, math.nan), held_out_episodes=2)
    assert interval_line(few).startswith("only 2 episodes held out: too few")
    assert _interval_note(fit) == "; after 15 steps 0.081-0.104 over 12 resampled episodes"
    assert _interval_note(few) == "; 2 held-out episodes"
