"""The three race types through `gymnasium.make` and the command line: train, evaluate, race."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import racerlab.sim  # noqa: F401  (registers racerlab/DeepRacer-v0)
from racerlab.cli import main
from tests.conftest import aws_track_path

RACES = {
    "time_trial": ({"type": "time_trial"}, 0),
    "object_avoidance": ({"type": "object_avoidance", "object_positions": ["0.3,1", "0.6,-1"]}, 2),
    "head_to_bot": ({"type": "head_to_bot", "number_of_bot_cars": 2, "bot_car_speed": 0.5, "is_lane_change": True,
                     "lower_lane_change_time": 1.0, "upper_lane_change_time": 2.0}, 2),
}


@pytest.mark.parametrize("name", list(RACES))
def test_each_race_type_through_gymnasium_make(name):
    race, n_objects = RACES[name]
    env = gym.make("racerlab/DeepRacer-v0", track=aws_track_path("reInvent2019_track"), race=race,
                   reward_function=lambda params: 1.0, observation="lidar", max_episode_steps=200)
    obs, info = env.reset(seed=1)
    assert env.observation_space.contains(obs)
    prev, statuses, checked = None, set(), 0
    for k in range(120):
        obs, reward, term, trunc, info = env.step(env.action_space.sample() if k % 7 else 0)
        assert env.observation_space.contains(obs)
        statuses.add(info["episode_status"])
        if "params" in info:
            p = info["params"]
            assert len(p["objects_location"]) == n_objects == len(p["objects_distance"])
            where = np.array(p["objects_location"]).reshape(-1, 2)
            if prev is not None and n_objects:
                moved = np.hypot(*(where - prev).T)
                if name == "head_to_bot":  # bots drive at 0.5 m/s: 1/30 m of centre line a step
                    assert (moved > 0.01).all() and (moved < 0.06).all()
                else:
                    assert (moved == 0).all()  # boxes stand still
                checked += 1
            prev = where
        if term or trunc:
            env.reset()
            prev = None
    assert statuses <= {"prepare", "in_progress", "off_track", "crashed", "immobilized", "reversed", "lap_complete"}
    assert checked > 10 or n_objects == 0

def test_a_seeded_reset_repeats_random_layouts_and_bot_timings():
    race = {"type": "object_avoidance", "number_of_obstacles": 4, "randomize_obstacle_locations": True}
    bots = {"type": "head_to_bot", "number_of_bot_cars": 2, "is_lane_change": True,
            "lower_lane_change_time": 1.0, "upper_lane_change_time": 2.0}
    for table in (race, bots):
        layouts = []
        for warm_up in (0, 3):  # a different history before the seeded reset must not matter
            env = gym.make("racerlab/DeepRacer-v0", track=aws_track_path("reInvent2019_track"), race=table,
                           observation="lidar", max_episode_steps=200)
            for _ in range(warm_up):
                env.reset()
            env.reset(seed=7)
            for _ in range(40):  # bots drive and draw their lane-change times
                env.step(0)
            layouts.append(env.unwrapped.sim.objects.xy[0].copy())
        np.testing.assert_array_equal(layouts[0], layouts[1])


@pytest.mark.parametrize(("race", "toml", "flags"), [
    ("object_avoidance", "object_positions = [[0.25, 1], [0.5, -1], [0.75, 1]]",
     ["--race-type", "object_avoidance", "--number-of-obstacles", "4", "--randomize-obstacle-locations"]),
    ("head_to_bot", "number_of_bot_cars = 3", ["--bot-car-speed", "0.6", "--is-lane-change"]),
])
def test_race_types_from_the_command_line(tmp_path, capsys, race, toml, flags):
    """init --race, a short training, an evaluation, and a race with other settings from the [race] flags."""
    model = tmp_path / race
    track = str(aws_track_path("reInvent2019_track"))
    assert main(["init", str(model), "--track", track, "--race", race, "--sensor", "features"]) == 0
    text = (model / "training.toml").read_text()
    assert f'type = "{race}"' in text and toml in text
    assert main(["train", str(model), "--iterations", "1", "--cars", "4"]) == 0
    assert "stopped: iteration limit of 1" in capsys.readouterr().out
    assert main(["evaluate", str(model), "--trials", "1", "--max-resets", "3", "--checkpoint", "last"]) == 0
    run = sorted(model.glob("evaluation-*"))[-1]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["laps"] and "crashes" in summary["result"] and summary["race"]["type"] == race
    assert main(["race", str(model), "--trials", "1", "--max-resets", "2", "--checkpoint", "last", *flags,
                 "--out", str(tmp_path / "b.json")]) == 0
    assert json.loads((tmp_path / "b.json").read_text())["leaderboard"][0]["model"] == race
