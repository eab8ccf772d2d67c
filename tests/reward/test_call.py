"""Reward functions: loading from files, validity rules and the errors a racer sees."""

from __future__ import annotations

import textwrap

import gymnasium as gym
import pytest

import racerlab  # noqa: F401 - registers the environment
from racerlab.errors import RewardFunctionError
from racerlab.reward import load_reward_function


def write(tmp_path, body, name="reward_function.py"):
    p = tmp_path / name
    p.write_text(textwrap.dedent(body))
    return p


def run(reward, track, steps=5):
    env = gym.make("racerlab/DeepRacer-v0", track=track, reward_function=reward)
    env.reset(seed=0)
    out = []
    for _ in range(steps):
        out.append(env.step(2))
    return out


def test_aws_reward_from_file_and_prepare_step(tmp_path, aws_track):
    p = write(tmp_path, """
        calls = []

        def reward_function(params):
            calls.append(params["steps"])
            track_width = params["track_width"]
            distance_from_center = params["distance_from_center"]
            if distance_from_center <= 0.1 * track_width:
                return 1.0
            return 1e-3
    """)
    fn = load_reward_function(p)
    results = run(fn, aws_track("reInvent2019_track"), steps=4)
    assert [r[1] for r in results] == [0.0, 1.0, 1.0, 1.0]
    assert results[0][4]["episode_status"] == "prepare" and "params" not in results[0][4]
    assert fn.__globals__["calls"] == [2.0, 3.0, 4.0]
    assert results[1][4]["params"]["steps"] == 2.0


def test_raising_reward_names_file_line_and_params(tmp_path, aws_track):
    p = write(tmp_path, """
        def reward_function(params):
            speed = params["speed"]
            return 1.0 / (speed - speed)
    """)
    with pytest.raises(RewardFunctionError) as err:
        run(load_reward_function(p), aws_track("reInvent2019_track"))
    msg = str(err.value)
    assert f"{p}:4:" in msg and "ZeroDivisionError" in msg
    assert "params:" in msg and "progress=" in msg and "[154 waypoints]" in msg


def test_misspelt_params_key_suggests_the_real_one(tmp_path):
    p = write(tmp_path, """
        def reward_function(params):
            return params["distance_from_centre"]
    """)
    with pytest.raises(RewardFunctionError) as err:
        run(load_reward_function(p), "lab_oval")
    first = str(err.value).splitlines()[0]
    assert f"{p}:3: reward_function raised KeyError: 'distance_from_centre'" in first
    assert "did you mean 'distance_from_center'?" in first


def test_key_error_on_the_racers_own_dict_gets_no_params_hint(tmp_path):
    p = write(tmp_path, """
        TABLE = {"a": 1.0}
        def reward_function(params):
            return TABLE["b"]
    """)
    with pytest.raises(RewardFunctionError) as err:
        run(load_reward_function(p), "lab_oval")
    assert "did you mean" not in str(err.value) and "KeyError: 'b'" in str(err.value)


@pytest.mark.parametrize(("ret", "what"), [("float('nan')", "not finite"), ("float('inf')", "not finite"),
                                           ("2e5", "beyond"), ("'1.0'", "must return a number"),
                                           ("None", "must return a number"), ("True", "must return a number")])
def test_bad_reward_values(tmp_path, aws_track, ret, what):
    p = write(tmp_path, f"""
        def reward_function(params):
            if params["steps"] > 100:
                return 0.0
            return {ret}
    """)
    with pytest.raises(RewardFunctionError) as err:
        run(load_reward_function(p), aws_track("reInvent2019_track"))
    msg = str(err.value)
    assert what in msg and f"{p}:5" in msg  # the line of the return that produced it


def test_numpy_and_int_rewards_are_accepted(aws_track):
    import numpy as np

    res = run(lambda p: np.float32(0.5) if p["steps"] % 2 else 2, aws_track("reInvent2019_track"))
    assert [r[1] for r in res[1:]] == [2.0, 0.5, 2.0, 0.5]


def test_broken_files(tmp_path):
    with pytest.raises(RewardFunctionError, match=r"reward_function.py:2: syntax error"):
        load_reward_function(write(tmp_path, "def reward_function(params):\n    x = (\n    return 1\n"))
    with pytest.raises(RewardFunctionError, match="defines no function `reward_function"):
        load_reward_function(write(tmp_path, "def reward(params):\n    return 1.0\n", "other.py"))
    with pytest.raises(RewardFunctionError, match="not found"):
        load_reward_function(tmp_path / "missing.py")
    with pytest.raises(RewardFunctionError, match=r"imp.py:1: importing the reward function raised ModuleNotFound"):
        load_reward_function(write(tmp_path, "import no_such_module_xyz\n", "imp.py"))
