"""`rollout` refuses what it cannot replay, in one line, instead of a NaN path, a silent reshape or a hang."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.errors import ConfigError
from racerlab.sim.car import rollout
from racerlab.spec import CarParams

START = {"x": 0.0, "y": 0.0, "heading": 0.0, "speed": 1.0}


def test_a_good_rollout_still_drives():
    # 1 m/s straight ahead at the droa car's ground factor 1.014: 3 steps of 1/15 s cover about 0.2 m
    end = rollout(START, [[0.0, 1.0]] * 3)[-1]
    assert end[0] == pytest.approx(3 * 1.014 / 15, abs=0.01) and end[1] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("kwargs, words", [
    ({"start": {**START, "x": math.nan}}, "start['x'] = nan is not a finite number"),
    ({"start": {**START, "heading": math.inf}}, "start['heading'] = inf is not a finite number"),
    ({"start": {"x": 0.0, "y": 0.0, "heading": 0.0}}, "start has no 'speed'"),
    ({"actions": [[0.0, math.inf]]}, "actions row 0 is [0.0, inf]: not finite numbers"),
    ({"actions": [[0.0, 1.0], [math.nan, 1.0]]}, "actions row 1"),
    ({"actions": np.zeros((4, 3))}, "actions must have shape (k, 2)"),
    ({"actions": []}, "actions must have shape (k, 2)"),
    ({"history": [[0.0, 1.0, 2.0]]}, "history must have shape (k, 2)"),
    ({"dt": [0.1, 0.1]}, "dt must hold 1 step lengths"),
    ({"dt": [math.nan]}, "dt must hold 1 step lengths"),
    ({"car": CarParams(substeps=1_000_000_000)}, "car.substeps = 1000000000; give 1 to 64"),
], ids=["nan-x", "inf-heading", "no-speed", "inf-action", "nan-action", "4x3", "empty", "history-3", "dt-2",
        "dt-nan", "substeps"])
def test_bad_inputs_are_one_line(kwargs, words):
    args = {"start": START, "actions": [[0.0, 1.0]], **kwargs}
    with pytest.raises(ConfigError) as err:
        rollout(args.pop("start"), args.pop("actions"), **args)
    assert words in str(err.value) and "\n" not in str(err.value)
