"""The one batched world and the simulator's named state: what training, evaluation and the env rely on."""

from __future__ import annotations

import math

import numpy as np
import pytest

from racerlab.model import ContinuousActions, ModelMetadata
from racerlab.sim import STATUS_NAMES, TRACE_COLUMNS, Simulator, Status, World
from racerlab.sim.env import DeepRacerVectorEnv

MODEL_POINT_AHEAD_M = 0.14  # AWS reports the point 0.14 m ahead of the rear axle (facts §1)


def test_status_codes_have_the_aws_names():
    assert [s.aws_name for s in Status] == list(STATUS_NAMES)
    assert Status.PREPARE.aws_name == "prepare" and Status.TIME_UP.aws_name == "time_up"
    assert STATUS_NAMES[Status.LAP_COMPLETE] == "lap_complete"


def test_state_names_the_pose_and_writes_through(aws_track):
    track = aws_track("reInvent2019_track")
    sim = Simulator(track, 2)
    x, y, yaw = *track.center[10], 0.7
    sim.set_pose(1, x, y, yaw, speed=1.5)
    s = sim.state
    assert (s.x[1], s.y[1], s.yaw[1], s.speed[1]) == (x, y, yaw, 1.5)
    assert s.model_x[1] == pytest.approx(x + MODEL_POINT_AHEAD_M * math.cos(yaw), abs=1e-12)
    assert s.model_y[1] == pytest.approx(y + MODEL_POINT_AHEAD_M * math.sin(yaw), abs=1e-12)
    assert s.heading[1] == pytest.approx(math.degrees(yaw))
    assert s.wheels_on_track[1] == 4 and s.all_wheels_on_track[1]
    assert s.steps[1] == 0 and not s.reversed[1] and s.status[1] == Status.IN_PROGRESS
    assert abs(s.lateral_offset[1]) == pytest.approx(s.distance_from_center[1])
    s.speed[:] = [0.5, 2.5]  # fields are views of the simulator's tables
    assert list(sim.speed) == [0.5, 2.5]


def test_judged_is_what_the_step_judged_and_trace_columns_are_its_row(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 3)
    sim.step(0.0, 1.0)  # prepare
    before = sim.state.model_x.copy()
    codes = sim.step([5.0, -5.0, 0.0], [1.0, 2.0, 3.0])
    assert np.array_equal(sim.judged.model_x, before)  # AWS order: judged on the pose the step started in
    assert not np.array_equal(sim.state.model_x, before)  # the car has moved since
    cars = np.array([2, 0])
    cols = sim.trace_columns(cars)
    assert tuple(cols) == TRACE_COLUMNS
    assert list(cols["X"]) == list(sim.judged.model_x[cars]) and list(cols["steps"]) == [2, 2]
    assert list(cols["steer"]) == [0.0, 5.0] and list(cols["throttle"]) == [3.0, 1.0]
    assert list(cols["tstamp"]) == [sim.time] * 2 and cols["track_len"][0] == sim.track.length
    assert list(sim.trace_columns(cars, judged=False)["X"]) == list(sim.state.model_x[cars])
    assert list(codes) == [Status.IN_PROGRESS] * 3


def test_pause_step_holds_the_car_and_counts_the_step(aws_track):
    sim = Simulator(aws_track("reInvent2019_track"), 1)
    sim.step(0.0, 1.0)
    sim.step(0.0, 1.0)
    pose, t = sim.pose, sim.time
    sim.pause_step(0)
    assert np.array_equal(sim.pose, pose) and sim.steps[0] == 3 and sim.time == pytest.approx(t + 1 / 15)


def test_relocate_and_restart_lap_keep_the_episode(aws_track):
    track = aws_track("reInvent2019_track")
    sim = Simulator(track, 1)
    sim.reset(start_ndist=0.0)
    # put the car a quarter lap on, continuing from 25 % progress
    s = 0.25 * track.length
    (x, y), yaw = track.point_at([s])[0], float(track.heading_at([s])[0])
    sim.relocate(0, x, y, yaw, progress=25.0)
    model_s = 0.25 + MODEL_POINT_AHEAD_M / track.length  # the model point is 0.14 m further
    assert sim.state.progress[0] == pytest.approx(100 * model_s, abs=0.05)
    assert sim.state.steps[0] == 0 and sim.state.start[0] == 0.0
    sim.restart_lap(0)  # as after a completed lap: progress from the start line again
    assert sim.state.progress[0] == pytest.approx(100 * model_s, abs=0.05)
    s = 0.999 * track.length
    (x, y), yaw = track.point_at([s])[0], float(track.heading_at([s])[0])
    sim.relocate(0, x, y, yaw, progress=99.0)
    assert sim.state.progress[0] == 100.0  # past the line: capped, the lap is complete
    sim.restart_lap(0)
    assert sim.state.progress[0] == pytest.approx(100 * (0.999 + MODEL_POINT_AHEAD_M / track.length - 1), abs=0.05)


def test_world_steps_active_cars_only_and_skips_the_reward_on_prepare(aws_track):
    calls = []

    def reward(params):
        calls.append(params["steps"])
        return params["speed"]

    meta = ModelMetadata(ContinuousActions(-30.0, 30.0, 0.5, 4.0), ("FEATURES",), "MLP")
    world = World(aws_track("reInvent2019_track"), 3, meta, reward, keep_params=True, seed=0)
    assert world.observe().shape == (3, world.sim.feature_size)
    codes, rewards = world.step(np.zeros((3, 2)))
    assert list(codes) == [Status.PREPARE] * 3 and list(rewards) == [0.0] * 3 and calls == []
    assert world.params == [None] * 3
    pose = world.sim.pose
    active = np.array([True, False, True])
    codes, rewards = world.step(np.array([[0.0, 1.0], [0.0, -1.0]]), active)  # speeds 4.0 and 0.5 m/s
    assert list(rewards) == [4.0, 0.0, 0.5] and calls == [2.0, 2.0]
    assert np.array_equal(world.sim.pose[1], pose[1]) and world.sim.steps[1] == 1
    assert world.params[1] is None and world.params[2]["speed"] == 0.5
    steer, speed = world.commands([[1.0, -1.0], [-2.0, 0.0]])  # clipped to [-1, 1], then rescaled
    assert list(steer) == [30.0, -30.0] and list(speed) == [0.5, 2.25]


def test_the_vector_env_is_a_world(aws_track):
    track = aws_track("reInvent2019_track")
    env = DeepRacerVectorEnv(4, track, reward_function=lambda p: p["progress"], seed=7)
    world = World(track, 4, None, lambda p: p["progress"], seed=7)
    env.reset(seed=7)
    actions = np.random.default_rng(0).integers(0, env.single_action_space.n, (50, 4))
    for a in actions:
        _, r_env, term, trunc, info = env.step(a)
        codes, r_world = world.step(a)
        assert np.array_equal(r_env, r_world) and list(info["episode_status"]) == [STATUS_NAMES[c] for c in codes]
        if (term | trunc).any():
            world.sim.reset(term | trunc)
