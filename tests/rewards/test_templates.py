"""Reward templates for `racerlab init --reward`: each runs on real params and prefers what it says."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.cli import main
from racerlab.errors import ConfigError
from racerlab.line import racing_line
from racerlab.rewards import TEMPLATES, reward_source
from tests.conftest import aws_track_path
from tests.sim.test_params import params_at, seg_point


def _load(text: str):
    space: dict = {}
    exec(compile(text, "reward_function.py", "exec"), space)  # noqa: S102 - the user's file, as training loads it
    return space["reward_function"]


@pytest.fixture(scope="module")
def reinvent():
    from racerlab import track

    return track.load(str(aws_track_path("reInvent2019_track")))


def test_every_template_returns_a_positive_float_on_real_params(reinvent):
    c = reinvent.center
    p, head = seg_point(c, 30, 0.5, 0.2)
    params = params_at(reinvent, p, head)
    for name in TEMPLATES:
        fn = _load(reward_source(name, reinvent, 4.0))
        r = fn(params)
        assert type(r) is float and 0 < r < 1e5 and math.isfinite(r), name


def test_centre_line_prefers_the_centre(reinvent):
    fn = _load(reward_source("centre_line"))
    c = reinvent.center
    values = [fn(params_at(reinvent, *seg_point(c, 40, 0.5, off))) for off in (0.0, 0.2, 0.4)]
    # 1 - (offset / half width)^2 with half width 0.5334 m
    expected = [1.0 - (off / (0.5 * 1.0668)) ** 2 for off in (0.0, 0.2, 0.4)]
    assert values == pytest.approx(expected, abs=2e-3)


def test_progress_pays_pace():
    fn = _load(reward_source("progress"))
    base = {"is_offtrack": False, "progress": 10.0, "steps": 20.0}
    assert fn(base) == pytest.approx(0.5)
    assert fn({**base, "steps": 40.0}) == pytest.approx(0.25)  # same progress, twice the steps
    assert fn({**base, "progress": 100.0, "steps": 225.0}) == pytest.approx(100 / 225 + 50.0)  # half of 450
    assert fn({**base, "progress": 100.0, "steps": 600.0}) == pytest.approx(100 / 600)  # too slow: no bonus
    assert fn({**base, "is_offtrack": True}) == 1e-3


def test_racing_line_reward_holds_the_line_and_its_speeds(reinvent):
    text = reward_source("racing_line", reinvent, max_speed=2.5)
    space: dict = {}
    exec(compile(text, "reward_function.py", "exec"), space)  # noqa: S102
    pts = np.array(space["RACING_LINE"])
    line = racing_line(reinvent)
    assert len(pts) < len(line.xy) and pts[:, 2].max() == pytest.approx(min(line.speed.max(), 2.5), abs=1e-3)
    # every embedded point lies on the solver's line
    d = np.min(np.hypot(*(pts[:, None, :2] - line.xy[None]).transpose(2, 0, 1)), axis=1)
    assert d.max() < 1e-3
    fn = space["reward_function"]
    k = 40
    x, y, v = pts[k]
    t = pts[k + 1, :2] - pts[k, :2]
    on = {"is_offtrack": False, "x": x, "y": y, "speed": v, "track_width": 1.0668, "progress": 0.0}
    assert fn(on) == pytest.approx(1.0 + 1e-3, abs=0.05)
    normal = np.array([-t[1], t[0]]) / np.hypot(*t)
    off = {**on, "x": x + 0.25 * normal[0], "y": y + 0.25 * normal[1]}
    assert fn(off) < fn(on) - 0.3
    assert fn({**on, "speed": v / 2}) == pytest.approx(0.5 + 1e-3, abs=0.05)


def test_unknown_template_and_missing_track_are_one_line_errors():
    with pytest.raises(ConfigError, match="choose one of example, centre_line, progress, racing_line"):
        reward_source("fastest")
    with pytest.raises(ConfigError, match="needs the model's track"):
        reward_source("racing_line")


def test_init_writes_the_racing_line_of_the_models_track(tmp_path, capsys):
    track = str(aws_track_path("reInvent2019_track"))
    model = tmp_path / "m"
    assert main(["init", str(model), "--track", track, "--reward", "racing_line", "--max-speed", "3"]) == 0
    text = (model / "reward_function.py").read_text()
    assert "reInvent2019_track" in text and "RACING_LINE = []" not in text
    space: dict = {}
    exec(compile(text, "reward_function.py", "exec"), space)  # noqa: S102
    assert max(p[2] for p in space["RACING_LINE"]) <= 3.0
    assert "(racing_line)" in capsys.readouterr().out
