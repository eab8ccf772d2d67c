"""Reward re-scoring: params rebuilt from positions equal the simulator's, the same reward reproduces the
logged reward of a racerlab training, and a broken reward is reported with its params instead of crashing."""

from __future__ import annotations

import json
import math
import re

import numpy as np
import pytest

from racerlab.analysis import load
from racerlab.analysis.rescore import compare, correlations, params_columns, rescore
from racerlab.cli import main
from racerlab.sim import Simulator
from racerlab.sim.params import ParamsBuilder
from tests.conftest import aws_track_path

AHEAD = 0.14


def train_tiny_model(folder, iterations: int = 3):
    """A real racerlab training, cut small (8 cars, 8 episodes per iteration, 1 epoch, 2 evaluation episodes):
    about 4 s."""
    from racerlab.model import init_model
    from racerlab.train import train

    f = init_model(folder, track=str(aws_track_path("reInvent2019_track")), max_speed=2.0)
    hp = json.loads(f.hyperparameters_path.read_text())
    hp.update(num_episodes_between_training=8, num_epochs=1)
    f.hyperparameters_path.write_text(json.dumps(hp))
    f.config_path.write_text(re.sub(r"(\[evaluation\]\nepisodes = )\d+", r"\g<1>2", f.config_path.read_text()))
    train(folder, iterations=iterations, progress=False, num_cars=8)
    return f


@pytest.fixture(scope="module")
def model(tmp_path_factory):
    return train_tiny_model(tmp_path_factory.mktemp("rescore") / "model")


def _sim_params(track, pts, yaw, reverse):
    sim = Simulator(track, len(pts))
    for i, ((x, y), h) in enumerate(zip(pts, yaw, strict=True)):
        sim.set_pose(i, x - AHEAD * math.cos(h), y - AHEAD * math.sin(h), h, reverse=reverse)
    sim.step(0.0, 1.0)  # prepare step
    sim.step(5.0, 1.5)  # params of the placed pose
    return ParamsBuilder(sim).build()


@pytest.mark.parametrize("reverse", [False, True])
def test_rebuilt_params_equal_the_simulators(aws_track, reverse):
    """Random poses across and beyond the road: every key but sim_time is identical to the simulator's params,
    to the last bit: both measure with the one kernel, `track.kernels.measure_on_track`."""
    track = aws_track("reInvent2019_track")
    rng = np.random.default_rng(3)
    n = 300
    s = rng.uniform(0, track.length, n)
    head = track.heading_at(s)
    lat = rng.uniform(-0.7, 0.7, n) * track.width
    pts = track.point_at(s) + lat[:, None] * np.stack([-np.sin(head), np.cos(head)], 1)
    yaw = head + rng.uniform(-1, 1, n) + (math.pi if reverse else 0.0)
    ref = _sim_params(track, pts, yaw, reverse)
    pc = params_columns(track, [p["x"] for p in ref], [p["y"] for p in ref], [p["heading"] for p in ref], 1.5, 5.0,
                        [p["progress"] for p in ref], 2, reversed=reverse)
    for i, want in enumerate(ref):
        got = pc.dict_at(i)
        assert got.keys() == want.keys()
        for k, v in want.items():
            if k != "sim_time":
                assert got[k] == v, (i, k)
    assert sum(not p["all_wheels_on_track"] for p in ref) > 50  # the sample does test the wheel rule


def test_same_reward_reproduces_the_logged_reward(model):
    df = load(model.path, cache=False)
    res = rescore(df, model.reward_path, load_track_of(model))
    assert res.ok and res.reversed_episodes == 0
    logged = df["reward"].to_numpy()
    diff = np.abs(res.new_reward - logged)
    # The log keeps 4 decimals of x, y, heading and reward. Most rows agree to that rounding; a handful sit
    # within 0.1 mm of a waypoint boundary, where the rounded position picks the neighbouring pair of
    # closest_waypoints and the example reward's heading term changes by ~0.01.
    assert np.mean(diff <= 1.5e-4) >= 0.99
    assert diff.max() < 0.05
    prepare = (df["episode_status"].astype(str) == "prepare").to_numpy()
    assert (res.new_reward[prepare] == 0).all()
    cmp = compare(df, res.new_reward)
    assert np.allclose(cmp["new_reward"], cmp["reward"], atol=0.05)
    corr = correlations(cmp)
    assert corr.loc["reward", "vs progress (all episodes)"] == pytest.approx(
        corr.loc["new_reward", "vs progress (all episodes)"], abs=0.02)


def load_track_of(model):
    from racerlab import track

    return track.load(model.config().track.names[0])


BROKEN = """\
def reward_function(params):
    if params["closest_waypoints"][0] % 10 == 3:
        return 1.0 / 0.0
    if params["progress"] > 5 and params["is_left_of_center"]:
        return float("nan")
    return 1.0
"""


def test_broken_reward_is_reported_not_raised(model, tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text(BROKEN)
    df = load(model.path, cache=False)
    res = rescore(df, bad, load_track_of(model))
    assert not res.ok and 0 < res.failed < len(df)
    messages = [p.message for p in res.problems]
    assert any(f"{bad}:3: reward_function raised ZeroDivisionError" in m for m in messages)
    assert any(f"{bad}:5: reward_function returned nan" in m for m in messages)
    first = next(p for p in res.problems if "ZeroDivisionError" in p.message)
    assert first.params["closest_waypoints"][0] % 10 == 3 and "closest_waypoints=[" in first.describe()
    assert np.isnan(res.new_reward).sum() == res.failed


def test_rescore_cli_prints_the_comparison_and_writes_the_scatter(model, tmp_path, capsys):
    bad = tmp_path / "bad.py"
    bad.write_text(BROKEN)
    png, csv = tmp_path / "scatter.png", tmp_path / "cmp.csv"
    rc = main(["reward", "rescore", str(model.path), "--reward", str(bad), "--out", str(png), "--csv", str(csv)])
    out = capsys.readouterr().out
    assert rc == 0
    assert "PROBLEMS" in out and "ZeroDivisionError" in out and "Spearman" in out
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and csv.is_file()
    assert out.strip().splitlines()[-1] == str(png)


def test_rescore_cli_without_a_track_is_one_clear_error(tmp_path, capsys):
    from racerlab.logs.synthetic import write_training_folder

    write_training_folder(tmp_path / "drfc", iterations=1, episodes_per_worker=2)
    good = tmp_path / "r.py"
    good.write_text("def reward_function(params):\n    return 1.0\n")
    rc = main(["reward", "rescore", str(tmp_path / "drfc"), "--reward", str(good)])
    err = capsys.readouterr().err
    assert rc == 2 and "pass --track" in err and "Traceback" not in err
