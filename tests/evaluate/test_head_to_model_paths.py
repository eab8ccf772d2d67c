"""Head-to-model through every path a user takes: `racerlab init --race head_to_model`, training in pairs
(self-play), `racerlab evaluate` (the model against itself), `racerlab race`, and gymnasium.make's opponent."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pytest

import racerlab.sim  # noqa: F401  (registers racerlab/DeepRacer-v0)
from racerlab.cli import main
from racerlab.errors import ConfigError
from racerlab.model.init import make_metadata
from racerlab.sim.objects import CAR_FOOTPRINT_M
from racerlab.spec import MODEL_POINT_AHEAD_M, RaceConfig
from tests.conftest import aws_track_path

STRAIGHT_FAST = 5  # the default discrete action list's (0°, 1 m/s)


def test_head_to_model_trains_in_pairs_then_evaluates_and_races(tmp_path, capsys):
    model = tmp_path / "pair"
    track = str(aws_track_path("reInvent2019_track"))
    assert main(["init", str(model), "--track", track, "--race", "head_to_model", "--sensor", "features"]) == 0
    assert 'type = "head_to_model"' in (model / "training.toml").read_text()
    # 4 cars race as 2 pairs; the 5 evaluation episodes run on 6 cars (3 pairs)
    assert main(["train", str(model), "--iterations", "2", "--cars", "4"]) == 0
    out = capsys.readouterr().out
    assert "stopped: iteration limit of 2" in out and "eval" in out
    assert main(["evaluate", str(model), "--trials", "1", "--max-resets", "3", "--checkpoint", "last"]) == 0
    run = sorted(model.glob("evaluation-*"))[-1]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["race"]["type"] == "head_to_model" and len(summary["laps"]) == 1
    assert (run / "evaluation-simtrace" / "0-iteration.csv").stat().st_size > 0
    assert main(["race", str(model), str(model), "--head-to-model", "--trials", "1", "--max-resets", "2",
                 "--checkpoint", "last", "--out", str(tmp_path / "h2m.json")]) == 0
    board = json.loads((tmp_path / "h2m.json").read_text())["leaderboard"]
    assert len(board) == 2


def test_head_to_model_training_needs_pairs_of_cars(tmp_path, capsys):
    model = tmp_path / "odd"
    assert main(["init", str(model), "--track", str(aws_track_path("reInvent2019_track")), "--race",
                 "head_to_model"]) == 0
    assert main(["train", str(model), "--iterations", "1", "--cars", "3"]) == 2
    err = capsys.readouterr().err.strip()
    assert "training.toml" in err and "num_cars" in err and "even" in err and "\n" not in err


def test_head_to_model_with_boxes_or_bots_is_one_line_naming_the_limit():
    for extra in ({"number_of_obstacles": 3}, {"object_positions": ["0.5,1"]}, {"number_of_bot_cars": 2}):
        with pytest.raises(ConfigError, match="head_to_model race puts only the racing cars") as exc:
            RaceConfig.from_mapping({"type": "head_to_model", **extra}, where="training.toml [race]")
        assert str(exc.value).startswith("training.toml [race]:") and "\n" not in str(exc.value)


def test_gymnasium_head_to_model_opponent_ahead_is_run_into():
    """The opponent starts 4 % of the lap (0.92 m) ahead on the centre line and crawls at 0.2 m/s; the car drives
    straight at 1 m/s and crashes when its front corners reach the opponent's rear: the gap between the two
    base points closes to one car length (0.324 m)."""
    meta = make_metadata("features")
    env = gym.make("racerlab/DeepRacer-v0", track=aws_track_path("reInvent2019_track"), race="head_to_model",
                   reward_function=lambda p: 1.0, model_metadata=meta, max_episode_steps=300, opponent_speed=0.2,
                   opponent_gap=0.04)
    env.reset(seed=1)
    sim = env.unwrapped.sim
    length = sim.track.length
    assert sim.num_cars == 2
    np.testing.assert_allclose(sim.state.projection_distance[1] - sim.state.projection_distance[0], 0.04 * length,
                               atol=1e-3)  # the model point 0.14 m ahead of each base, on a gentle curve
    gaps = []
    for _ in range(60):
        _, _, term, _, info = env.step(STRAIGHT_FAST)
        p = info.get("params")
        if p is None:
            continue
        # both on the (straight) start of the centre line: base-to-base gap along it
        gaps.append(p["objects_distance"][0] - (p["projection_distance"] - MODEL_POINT_AHEAD_M))
        if term:
            break
    assert info["episode_status"] == "crashed" and info["params"]["is_crashed"]
    assert min(gaps[:-1]) > CAR_FOOTPRINT_M[0] - 0.005
    assert gaps[-1] < CAR_FOOTPRINT_M[0] + 0.01


def test_gymnasium_head_to_model_opponent_policy_and_restart():
    """A given opponent policy sees car 1's observation; when its episode ends (it steers off the road) it
    starts again `opponent_gap` of the lap ahead of the car, while the car's episode goes on."""
    seen = []

    def opponent(obs):
        seen.append(obs)
        return 0  # hard right at 0.5 m/s: off the road within a few seconds

    env = gym.make("racerlab/DeepRacer-v0", track=aws_track_path("reInvent2019_track"), race="head_to_model",
                   model_metadata=make_metadata("features"), opponent=opponent, opponent_gap=0.5)
    obs, _ = env.reset(seed=3)
    sim = env.unwrapped.sim
    length = sim.track.length
    restarts = 0
    for _ in range(200):
        before = int(sim.steps[1])
        obs, _, term, trunc, info = env.step(STRAIGHT_FAST if sim.steps[0] < 40 else 4)
        assert not term or info["episode_status"] != "in_progress"
        if sim.steps[1] < before:  # the opponent restarted
            restarts += 1
            ahead = (sim.state.projection_distance[1] - sim.state.projection_distance[0]) % length
            assert abs(ahead - 0.5 * length) < 0.02
        if term or trunc:
            break
    assert restarts >= 1 and len(seen) >= 30
    assert all(env.observation_space.contains(o) for o in seen)
    with pytest.raises(ConfigError, match="opponent_gap"):
        gym.make("racerlab/DeepRacer-v0", race="head_to_model", opponent_gap=1.5)


def test_vector_env_pairs_its_cars():
    """DeepRacerVectorEnv(race="head_to_model") pairs its cars as training does: car 2k's object is car 2k+1."""
    from racerlab.sim.env import DeepRacerVectorEnv

    env = DeepRacerVectorEnv(4, track=aws_track_path("reInvent2019_track"), race="head_to_model", info_params=True,
                             reward_function=lambda p: 1.0)
    env.reset(seed=0)
    for _ in range(10):
        _, _, _, _, info = env.step(np.full(4, STRAIGHT_FAST))
    sim = env.sim
    for i, p in enumerate(info["params"]):
        np.testing.assert_allclose(p["objects_location"][0], [sim.state.x[i ^ 1], sim.state.y[i ^ 1]], atol=1e-9)
    with pytest.raises(ConfigError, match="even number of cars, not 3"):
        DeepRacerVectorEnv(3, race="head_to_model")
